"""Quads that follow a file's sizes: ufl-frames against Gmsh's quasi-structured mesher.

For each graded file (default: the ``benchmarks/shapes`` files with size fields, point
sizes, MathEval, Box and Distance/Threshold fields), at about ``--quads`` quads:

* ufl-frames: ``solve FILE --quads --quad-count N`` (the file's own sizes, the sized
  non-isotropic field), in a subprocess; its ``summary.json``'s ``sizes.quads``;
* Gmsh: ``Mesh.Algorithm = 11`` (quasi-structured quads) on the same file, its size
  factor tuned (twice) to the same count.

Both are measured the same way against the file's sizes as Gmsh evaluates them
(:func:`ufl_frames.mesh.sizes.read_file_sizes`): the Pearson correlation of the log of each
quad's mean edge length with the log of h at its centroid, the spread of their ratio (up
to the global factor: median and 90th percentile of |log ratio|, its 10th and 90th
percentiles), the irregular vertices (:func:`ufl_frames.quads.measures.quad_quality`) and
the worst scaled Jacobian. One process; prints a table, asserts nothing.

    .venv/bin/python benchmarks/sizes.py [--files F ...] [--quads 400] [--timeout 600]
        [--size-weight W]
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "src"))

FILES = ["graded_corner.geo", "l_shape_graded.geo", "point_sizes.geo", "matheval_disk.geo",
         "box_field.geo"]


class _Mesh:
    def __init__(self, points, quads):
        self.points, self.quads = points, quads


def gmsh_quasi_structured(path: Path, quads: int) -> tuple[_Mesh, float, float]:
    """Gmsh's quasi-structured quads of ``path`` at about ``quads`` quads: (mesh, size
    factor, seconds of the last meshing)."""
    import gmsh

    factor, mesh, seconds = 1.0, None, 0.0
    gmsh.initialize(argv=[], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        for _ in range(3):
            gmsh.clear()
            gmsh.open(str(path))
            gmsh.option.setNumber("Mesh.Algorithm", 11)
            gmsh.option.setNumber("Mesh.MeshSizeFactor", factor)
            start = time.perf_counter()
            gmsh.model.mesh.generate(2)
            seconds = time.perf_counter() - start
            tags, coords, _ = gmsh.model.mesh.getNodes()
            index = np.zeros(int(tags.max()) + 1, dtype=np.int64)
            index[tags.astype(np.int64)] = np.arange(len(tags))
            _, nodes = gmsh.model.mesh.getElementsByType(3)
            cells = index[nodes.astype(np.int64)].reshape(-1, 4)
            mesh = _Mesh(coords.reshape(-1, 3)[:, :2], cells)
            if abs(len(cells) - quads) <= 0.05 * quads:
                break
            factor *= np.sqrt(len(cells) / quads)
    finally:
        gmsh.finalize()
    return mesh, factor, seconds


def measure(mesh, target) -> dict:
    from ufl_frames.pipeline.sizes import quad_size_record
    from ufl_frames.quads.measures import quad_quality

    quality = quad_quality(mesh.points, mesh.quads)
    return {**quad_size_record(mesh, target), "irregular": quality["irregular_vertices"],
            "min_sj": quality["min_sj"]}


def ours(path: Path, quads: int, timeout: float, weight: float | None = None
         ) -> tuple[dict | str, float]:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out"
        start = time.perf_counter()
        done = subprocess.run([sys.executable, "-m", "ufl_frames.app", "solve", str(path),
                               "--quads", "--quad-count", str(quads), "--out", str(out), "-q",
                               *([] if weight is None else ["--size-weight", str(weight)])],
                              capture_output=True, text=True, timeout=timeout,
                              env={**os.environ, "PYTHONPATH": str(ROOT / "src"),
                                   "OMP_NUM_THREADS": "1"})
        seconds = time.perf_counter() - start
        if done.returncode != 0:
            return (done.stderr.strip().splitlines() or ["failed"])[-1], seconds
        summary = json.loads((out / "summary.json").read_text())
        points, cells = _read_quads(out / "quads.msh")
        return {"mesh": _Mesh(points, cells), "summary": summary}, seconds


def _read_quads(path: Path):
    import gmsh

    gmsh.initialize(argv=[], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.open(str(path))
        tags, coords, _ = gmsh.model.mesh.getNodes()
        index = np.zeros(int(tags.max()) + 1, dtype=np.int64)
        index[tags.astype(np.int64)] = np.arange(len(tags))
        _, nodes = gmsh.model.mesh.getElementsByType(3)
        return coords.reshape(-1, 3)[:, :2], index[nodes.astype(np.int64)].reshape(-1, 4)
    finally:
        gmsh.finalize()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--files", nargs="+", default=[str(ROOT / "benchmarks" / "shapes" / f)
                                                       for f in FILES])
    parser.add_argument("--quads", type=int, default=400)
    parser.add_argument("--timeout", type=float, default=600)
    parser.add_argument("--size-weight", type=float, default=None,
                        help="w of the sized energy (ufl-frames' --size-weight; default its own)")
    args = parser.parse_args()
    from ufl_frames.mesh.sizes import SizeTarget, read_file_sizes

    header = (f"{'file':22s} {'mesher':10s} {'quads':>6s} {'irreg':>5s} {'corr':>6s} "
              f"{'med|log|':>8s} {'p90|log|':>8s} {'r10':>5s} {'r90':>5s} {'minSJ':>6s} "
              f"{'s':>6s}")
    print(header)
    for name in args.files:
        path = Path(name)
        target = SizeTarget.of_samples(read_file_sizes(str(path)))
        rows = []
        found, seconds = ours(path, args.quads, args.timeout, args.size_weight)
        rows.append(("ufl-frames", found if isinstance(found, str)
                     else measure(found["mesh"], target), seconds))
        mesh, _, seconds = gmsh_quasi_structured(path, args.quads)
        rows.append(("gmsh QS", measure(mesh, target), seconds))
        for mesher, m, seconds in rows:
            if isinstance(m, str):
                print(f"{path.name:22s} {mesher:10s} failed: {m}")
                continue
            corr = m["log_correlation"]
            print(f"{path.name:22s} {mesher:10s} {m['quads']:6d} {m['irregular']:5d} "
                  f"{corr if corr is not None else float('nan'):6.3f} "
                  f"{m['median_abs_log']:8.3f} {m['p90_abs_log']:8.3f} {m['ratio_p10']:5.2f} "
                  f"{m['ratio_p90']:5.2f} {m['min_sj']:6.3f} {seconds:6.1f}", flush=True)


if __name__ == "__main__":
    main()
