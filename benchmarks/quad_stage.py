"""The quad stage's time at three sizes: the T-mesh layout against greedy rounding.

    python benchmarks/quad_stage.py [--shape benchmarks/shapes/polyline_airfoil.geo]
                                    [--quads 1e3 1e4 1e5] [--triangles-per-quad 4]
                                    [--greedy-timeout 600] [--json FILE]
                                    [--save-quads FOLDER]

For each target number of quads N the shape is meshed with about ``--triangles-per-quad``
× N triangles, the MBO field is computed and made conformal (``--conformal``, as
``ufl-frames mesh`` would), and the field is gathered and cut once
(:class:`ufl_frames.pipeline.stages.RootField`). Then, on that cut mesh, each stage is
timed on its own:

* ``cut``: :func:`ufl_frames.param.cut.cut_mesh` (the cut graph, the combing) with the
  model's features (regions, curves, the points that must be quad vertices, the smooth
  joints), as the CLI cuts (``--no-features``: the bare mesh, as this script did before
  2026-12-07's second session);
* ``integrate``: the seamless map (:func:`ufl_frames.param.seamless.integrate`);
* ``layout``: the motorcycle graph and its patches (:func:`ufl_frames.quads.layout.layout`,
  with :func:`~ufl_frames.quads.layout.untangle` first where the map folds);
* ``lengths``: the integer program (:func:`ufl_frames.quads.patches.integer_lengths`);
* ``quads``: the patches' grids mapped back (:func:`ufl_frames.quads.patches.patch_quads`)
  and their regions, curve edges and model points found
  (:func:`ufl_frames.quads.extract.with_features`);
* ``improve`` and ``check``: :func:`ufl_frames.quads.improve.improve_worst_quads` and the
  checks of the stage (with the features: quads in their region, model points quad
  vertices, curve lengths kept; ``problem`` gives the first failed check);
* ``greedy``: the older path, greedy rounding and iso-line extraction
  (:func:`ufl_frames.param.quantise.quantise` + :func:`ufl_frames.quads.extract.extract_quads`),
  in a child process stopped after ``--greedy-timeout`` seconds (0: not run).

``quad stage`` is the sum from ``cut`` to ``check`` (issue 37's quad stage); each stage
has its CPU seconds (``time.process_time``, this process, all its threads) beside its
wall seconds.

Serial. Prints one Markdown table (seconds per stage, quads, irregular vertices, min SJ,
patches, arcs, collapsed arcs, peak memory) and writes ``--json`` if given.
"""

import argparse
import json
import multiprocessing
import resource
import sys
import time
from pathlib import Path

from _common import ROOT, table_rule

DEFAULT_SHAPE = ROOT / "benchmarks" / "shapes" / "polyline_airfoil.geo"


def _greedy_child(mesh, scale, queue) -> None:
    from ufl_frames.param import quantise
    from ufl_frames.quads import extract

    start = time.perf_counter()
    try:
        quads = extract.extract_quads(quantise.quantise(mesh, scale))
        queue.put((time.perf_counter() - start, quads.num_quads, None))
    except Exception as e:  # reported in the table
        queue.put((time.perf_counter() - start, None, " ".join(str(e).split())[:80]))


def greedy(mesh, scale, timeout: float) -> tuple:
    """(seconds, quads or None, error or None) of the greedy path, in a child process."""
    queue = multiprocessing.get_context("fork").Queue()
    child = multiprocessing.get_context("fork").Process(target=_greedy_child,
                                                        args=(mesh, scale, queue))
    child.start()
    child.join(timeout)
    if child.is_alive():
        child.kill()
        child.join()
        return timeout, None, f"stopped after {timeout:.0f} s"
    return queue.get() if not queue.empty() else (None, None, "the child died")


def measure(shape: Path, quads: float, per_quad: float, greedy_timeout: float,
            features: bool = True, save: Path | None = None) -> dict:
    """One row: every stage of the quad mesh of ``shape`` at about ``quads`` quads.

    ``greedy_timeout`` ≤ 0 skips the greedy path; ``save`` (a folder) keeps the quads'
    points and vertices as ``quads_N.npz`` (to compare two versions' quads).
    """
    import numpy as np
    from mpi4py import MPI

    from ufl_frames.fem.scales import mean_cell_edge
    from ufl_frames.mesh import load
    from ufl_frames.param import cut, seamless
    from ufl_frames.pipeline import FrameField
    from ufl_frames.pipeline.stages import RootField, _improved, _problems
    from ufl_frames.quads import layout, measures, patches
    from ufl_frames.quads.extract import with_features

    comm = MPI.COMM_SELF
    probe = load(comm, shape)  # the shape's own default mesh: its area and mean edge
    area = probe.mesh.comm.allreduce(
        float(np.sum(np.abs(_areas(probe.mesh)))), op=MPI.SUM)
    quad_size = float(np.sqrt(area / quads))
    h = quad_size / np.sqrt(per_quad / 2)  # two triangles of edge h per h² of area
    start = time.perf_counter()
    domain = load(comm, shape, mesh_size=h)
    field = FrameField.initial(domain, isotropic=True).conformal()
    row = {"target quads": int(quads), "triangles": domain.num_cells,
           "field s": time.perf_counter() - start,
           "mean edge": mean_cell_edge(domain.mesh)}
    root = RootField(field)
    t, c = time.perf_counter(), time.process_time()
    mesh = cut.cut_mesh(*root._arrays, features=root.features if features else None)
    _stop(row, "cut", t, c)
    scale = seamless.scale_for_quad_size(mesh, quad_size)
    t, c = time.perf_counter(), time.process_time()
    param = seamless.integrate(mesh, scale)
    _stop(row, "integrate", t, c)
    t, c = time.perf_counter(), time.process_time()
    folds = int(np.count_nonzero(seamless.folded(param)))
    if folds:
        param, _ = layout.untangle(param)
    lay = layout.layout(param)
    _stop(row, "layout", t, c)
    t, c = time.perf_counter(), time.process_time()
    n = patches.integer_lengths(lay)
    _stop(row, "lengths", t, c)
    t, c = time.perf_counter(), time.process_time()
    quad_mesh, _ = patches.patch_quads(lay, n)
    quad_mesh = with_features(quad_mesh, param.mesh)  # as patches.quads_of_map does
    _stop(row, "quads", t, c)
    t, c = time.perf_counter(), time.process_time()
    quad_mesh, _ = _improved(quad_mesh)
    _stop(row, "improve", t, c)
    t, c = time.perf_counter(), time.process_time()
    problems = _problems(mesh, quad_mesh)
    _stop(row, "check", t, c)
    quality = measures.quad_quality(quad_mesh.points, quad_mesh.quads)
    row.update({"quads": quality["quads"], "irregular": quality["irregular_vertices"],
                "min SJ": quality["min_sj"], "valid": not problems,
                "problem": problems[0] if problems else "",
                "patches": len(lay.patches), "arcs": len(lay.arcs),
                "collapsed": int(np.count_nonzero(np.asarray(n) == 0)),
                "folded before": folds})
    stages = ("cut", "integrate", "layout", "lengths", "quads", "improve", "check")
    row["quad stage s"] = sum(row[f"{k} s"] for k in stages)
    row["quad stage cpu"] = sum(row[f"{k} cpu"] for k in stages)
    row["peak MB"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    if save is not None:
        save.mkdir(parents=True, exist_ok=True)
        np.savez(save / f"quads_{int(quads)}.npz", points=quad_mesh.points,
                 quads=quad_mesh.quads)
    if greedy_timeout <= 0:
        return row
    seconds, greedy_quads, error = greedy(mesh, scale, greedy_timeout)
    row["greedy s"] = seconds
    row["greedy"] = error or f"{greedy_quads} quads"
    return row


def _stop(row: dict, stage: str, wall: float, cpu: float) -> None:
    """Record ``stage``'s wall seconds (``"stage s"``) and CPU seconds (``"stage cpu"``)."""
    row[f"{stage} s"] = time.perf_counter() - wall
    row[f"{stage} cpu"] = time.process_time() - cpu


def _areas(mesh):

    x = mesh.geometry.x[:, :2]
    c = mesh.geometry.dofmaps[0]
    a, b, d = x[c[:, 0]], x[c[:, 1]], x[c[:, 2]]
    return 0.5 * ((b[:, 0] - a[:, 0]) * (d[:, 1] - a[:, 1])
                  - (b[:, 1] - a[:, 1]) * (d[:, 0] - a[:, 0]))


COLUMNS = ("target quads", "triangles", "quads", "irregular", "min SJ", "valid", "problem",
           "patches",
           "arcs", "collapsed", "folded before", "cut cpu", "integrate cpu", "layout cpu",
           "lengths cpu", "quads cpu", "improve cpu", "check cpu", "quad stage cpu",
           "cut s", "integrate s", "layout s",
           "lengths s", "quads s", "improve s", "check s", "quad stage s", "greedy s",
           "greedy", "field s", "peak MB")


def table(rows: list[dict]) -> str:
    def cell(value):
        if isinstance(value, float):
            return f"{value:.3g}" if value < 100 else f"{value:.0f}"
        return str(value)

    header = "| " + " | ".join(COLUMNS) + " |"
    lines = [header, table_rule(header)]
    lines += ["| " + " | ".join(cell(r.get(k, "")) for k in COLUMNS) + " |" for r in rows]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shape", type=Path, default=DEFAULT_SHAPE)
    parser.add_argument("--quads", type=float, nargs="+", default=[1e3, 1e4, 1e5])
    parser.add_argument("--triangles-per-quad", type=float, default=4.0)
    parser.add_argument("--greedy-timeout", type=float, default=600.0)
    parser.add_argument("--no-features", action="store_true",
                        help="cut the bare mesh (no regions, curves, points), not the CLI's")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--save-quads", type=Path, metavar="FOLDER",
                        help="write each size's quads (points, vertices) as quads_N.npz")
    args = parser.parse_args()
    from ufl_frames.bootstrap import init_petsc

    init_petsc(sys.argv[:1])
    rows = []
    for n in args.quads:
        print(f"{args.shape.name}: {n:.0f} quads ...", flush=True)
        rows.append(measure(args.shape, n, args.triangles_per_quad, args.greedy_timeout,
                            features=not args.no_features, save=args.save_quads))
    print(table(rows))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
