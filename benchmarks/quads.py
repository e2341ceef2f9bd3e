"""Quad meshes of planar shapes: Gmsh's quad meshers next to ufl_frames' quads.

    python benchmarks/quads.py [--shapes NAME_OR_FILE ...] [--quads 400 | --quad-size S]
                               [--methods qs blossom fullquad ufl_frames] [--json FILE]
                               [--out DIR] [--mesh-size H] [--timeout 600]
                               [--gmsh-timeout 300] [--area-rtol 0.02]

Shapes: every ``benchmarks/shapes/*.geo`` (each says in its first comment what it
exercises) and ``meshes/annulus.geo``, ``meshes/piano.geo``, named by their stem;
``--shapes`` picks some by name or takes any geometry file.

Methods (``--methods``, default all but ``simple`` and ``delaunay``):

* ``qs``: Gmsh's quasi-structured quads (``Mesh.Algorithm = 11``);
* ``blossom``: Frontal-Delaunay for quads (``Mesh.Algorithm = 8``) recombined
  (``Mesh.RecombineAll = 1``) with Gmsh's default ``Mesh.RecombinationAlgorithm`` (1,
  Blossom);
* ``fullquad``: the same with ``Mesh.RecombinationAlgorithm = 3`` (Blossom full-quad);
* ``simple``: the same with ``Mesh.RecombinationAlgorithm = 0`` (simple; may leave
  triangles); ``delaunay``: Gmsh's default 2D algorithm (6) recombined by default;
* ``ufl_frames``: ``ufl-frames solve SHAPE --quads --quad-size S --out DIR --force -q``
  (general frames, the CLI's default), ``ufl_frames_iso`` the same with ``--isotropic``,
  ``ufl_frames_conf`` with ``--conformal`` (the conformal isotropic field, no TAO),
  ``ufl_frames_sized`` is ``ufl-frames mesh SHAPE --size file --quads N`` (the sized
  non-isotropic field: quads graded as the file's own point sizes ask, as Gmsh's; N the
  target; ``--mesh-size`` not passed on), each in a subprocess (``--mesh-size H`` passed
  on when given to the others); its ``summary.json`` object ``"quads"`` (the keys of
  :func:`ufl_frames.quads.measures.quad_quality` plus ``valid`` and ``seconds``) is
  reported with the run's seconds per step (``stage_seconds``: mesh,
  field, report, param and quads), and ``DIR/quads.msh`` is measured again here. A run that
  fails (the option not there yet, say) shows "not available" and its one-line error.

Size: the target is ``--quads`` quads (default 400), or area / S² with ``--quad-size S``;
ufl_frames gets ``--quad-size`` S = √(area / target). Gmsh meshes with
``Mesh.MeshSizeMax`` = h from a first guess per method (``Mesh.MeshSizeFactor`` 1), then h
and the factor are rescaled together by √(quads / target) (the count goes as 1/h²; the
factor for files whose own point sizes are below h) at most twice, until within 10 %. The Gmsh
runs use the project's loader settings for curves (at least 12 points per full circle, 8
per other curve; ``ufl_frames.mesh``). Every Gmsh parse of the file (the area, then each
size) is a subprocess of this script, since Gmsh keeps a ``.geo``'s ``Function``s for the
life of its process (``--gmsh-timeout``, default 300 s for them all: algorithm 11 can
hang); the time reported is that of ``gmsh.model.mesh.generate(2)`` at the final size.

Measures: :func:`~ufl_frames.quads.measures.quad_quality` (irregular vertices, scaled
Jacobian, edge ratio) and :func:`~ufl_frames.quads.measures.check_quad_mesh` (valid:
conforming, counter-clockwise, manifold, no triangles left, area within ``--area-rtol``
(default 2 %, the polygonal boundary's deficit) of the exact CAD area). Each surface's
quads are turned counter-clockwise first if Gmsh gave them clockwise (whole surfaces, so
an inverted quad stays inverted).

Output: a table per shape, then a summary (on how many shapes each method has the fewest
irregular vertices, the best min and mean SJ, ...: ties count for every tied method,
valid meshes only); ``--json FILE`` writes everything; a picture of every mesh
(:func:`~ufl_frames.quads.msh.plot_quads`) and its ``.msh`` go to ``--out`` (default
``benchmarks/out/quads``, git-ignored).
"""

import argparse
import json
import math
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from _common import BUILTIN_GEO, GEOMETRY_SUFFIXES, ROOT, gmsh_errors, one_line, surface_elements
from _processes import last_line, run_in_group

SHAPES = ROOT / "benchmarks" / "shapes"

#: Gmsh options per method, and the first guess of MeshSizeMax in units of √(area/target).
GMSH_METHODS = {
    "qs": ({"Mesh.Algorithm": 11, "Mesh.RecombineAll": 0}, 2.3),
    "blossom": ({"Mesh.Algorithm": 8, "Mesh.RecombineAll": 1}, 1.06),
    "fullquad": ({"Mesh.Algorithm": 8, "Mesh.RecombineAll": 1,
                  "Mesh.RecombinationAlgorithm": 3}, 1.06),
    "simple": ({"Mesh.Algorithm": 8, "Mesh.RecombineAll": 1,
                "Mesh.RecombinationAlgorithm": 0}, 1.06),
    "delaunay": ({"Mesh.RecombineAll": 1}, 1.06),
}
#: ufl_frames' two fields: general (non-isotropic, the CLI's default) and isotropic frames.
UFL_FRAMES_METHODS = {"ufl_frames": [], "ufl_frames_iso": ["--isotropic"],
                      "ufl_frames_conf": ["--conformal"], "ufl_frames_sized": None}
#: ``ufl-frames mesh`` with the file's own sizes: the quads graded as the file asks.
SIZED_METHOD = "ufl_frames_sized"
DEFAULT_METHODS = ("qs", "blossom", "fullquad", "ufl_frames", "ufl_frames_iso",
                   "ufl_frames_conf")
ALL_METHODS = (*GMSH_METHODS, *UFL_FRAMES_METHODS)
#: Loader settings for curves (ufl_frames.mesh.meshing.CURVE_POINTS_PER_TURN / _PER_CURVE).
CURVE_OPTIONS = {"Mesh.MinimumCirclePoints": 12, "Mesh.MinimumCurvePoints": 8}
RESCALES = 2
WITHIN = 0.10


# --- one Gmsh run (in a subprocess: --worker) -------------------------------------------


def _merge(path: Path) -> None:
    """Load ``path`` into the current Gmsh model; its errors raised as one line."""
    import gmsh

    gmsh.option.setNumber("General.AbortOnError", 0)
    errors = gmsh_errors(lambda: gmsh.merge(str(path)))
    if errors:
        raise RuntimeError(one_line(errors[0]).removeprefix("Error: "))


def _cad_area() -> float:
    """Exact area of the OpenCASCADE surfaces, else of a fine triangle mesh."""
    import gmsh

    surfaces = gmsh.model.getEntities(2)
    if surfaces and sorted(gmsh.model.occ.getEntities(2)) == sorted(surfaces):
        return float(sum(gmsh.model.occ.getMass(2, t) for _, t in surfaces))
    x0, y0, _, x1, y1, _ = gmsh.model.getBoundingBox(-1, -1)
    gmsh.option.setNumber("Mesh.MeshSizeMax", math.hypot(x1 - x0, y1 - y0) / 200)
    gmsh.model.mesh.generate(2)
    x, quads, triangles = _mesh_arrays()
    area = 0.0
    for cells in (quads, triangles):
        if len(cells):
            p = x[cells]
            area += 0.5 * abs(np.sum(p[:, :, 0] * np.roll(p[:, :, 1], -1, axis=1)
                                     - np.roll(p[:, :, 0], -1, axis=1) * p[:, :, 1]))
    gmsh.model.mesh.clear()
    return area


def _mesh_arrays():
    """(points (n, 2), quads (m, 4), triangles (t, 3)) of the current 2D mesh: used nodes
    only, each surface's cells counter-clockwise (as a whole)."""
    import gmsh

    if len(gmsh.model.getEntities(2)) > 1:
        gmsh.model.mesh.removeDuplicateNodes()
    xyz, surfaces = surface_elements()
    cells = {3: [], 2: []}
    for found in surfaces:
        for kind in found:
            if kind not in cells:
                raise RuntimeError(f"unexpected 2D element type {kind}")
        signed = 0.0
        for c in found.values():
            p = xyz[c][:, :, :2]
            signed += float(np.sum(p[:, :, 0] * np.roll(p[:, :, 1], -1, axis=1)
                                   - np.roll(p[:, :, 0], -1, axis=1) * p[:, :, 1]))
        for kind, c in found.items():
            cells[kind].append(c[:, ::-1] if signed < 0 else c)
    quads = np.concatenate(cells[3]) if cells[3] else np.zeros((0, 4), np.int64)
    triangles = np.concatenate(cells[2]) if cells[2] else np.zeros((0, 3), np.int64)
    used, inverse = np.unique(np.concatenate([quads.ravel(), triangles.ravel()]),
                              return_inverse=True)
    inverse = inverse.ravel()
    return (xyz[used, :2], inverse[:quads.size].reshape(-1, 4),
            inverse[quads.size:].reshape(-1, 3))


def _count_quads() -> tuple[int, int]:
    import gmsh

    counts = {2: 0, 3: 0}
    for _, surface in gmsh.model.getEntities(2):
        for kind, tags, _ in zip(*gmsh.model.mesh.getElements(2, surface), strict=True):
            counts[int(kind)] = counts.get(int(kind), 0) + len(tags)
    return counts[3], counts[2]


def gmsh_area(path: Path) -> float:
    """The exact area of ``path``'s surfaces (:func:`_cad_area`): one parse of the file."""
    import gmsh

    gmsh.initialize(argv=[], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        _merge(path)
        return _cad_area()
    finally:
        gmsh.finalize()


def gmsh_try(path: Path, method: str, h: float, factor: float, area: float,
             area_rtol: float, out: Path | None, stem: str) -> dict:
    """Gmsh's quads of ``path`` with ``method`` at ``Mesh.MeshSizeMax`` = ``h`` and
    ``Mesh.MeshSizeFactor`` = ``factor``, measured (picture and ``.msh`` in ``out`` if
    given): one parse of the file, in a fresh model."""
    import gmsh

    from ufl_frames.quads.measures import check_quad_mesh, quad_quality
    from ufl_frames.quads.msh import plot_quads

    options, _ = GMSH_METHODS[method]
    gmsh.initialize(argv=[], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        _merge(path)
        for key, value in {**CURVE_OPTIONS, **options, "Mesh.SubdivisionAlgorithm": 0,
                           "Mesh.ElementOrder": 1, "Mesh.MeshSizeMax": h,
                           "Mesh.MeshSizeFactor": factor}.items():
            gmsh.option.setNumber(key, value)
        gmsh.logger.start()
        start = time.perf_counter()
        try:
            gmsh.model.mesh.generate(2)  # errors are logged (General.AbortOnError 0)
            seconds = time.perf_counter() - start
            errors = [m for m in gmsh.logger.get() if m.startswith("Error")]
        finally:
            gmsh.logger.stop()
        if errors:
            return {"mesh_size": h, "size_factor": factor,
                    "error": one_line(errors[0]).removeprefix("Error: ")}
        quads, triangles = _count_quads()
        row = {"mesh_size": h, "size_factor": factor, "quads": quads, "triangles": triangles,
               "seconds": seconds}
        x, q, t = _mesh_arrays()
        used, q = np.unique(q, return_inverse=True)  # the quads' points only
        x, q = x[used], q.reshape(-1, 4)
        if len(q) == 0:
            return row
        problems = check_quad_mesh(x, q, area=area, rtol=area_rtol)
        if len(t):
            problems.insert(0, f"{len(t)} triangles left")
        quality = quad_quality(x, q)
        row.update(quality=quality, valid=not problems, problems=problems,
                   area_error=quality["area"] / area - 1)
        if out is not None:
            out.mkdir(parents=True, exist_ok=True)
            gmsh.write(str(out / f"{stem}.msh"))
            row["picture"] = str(plot_quads(
                out / f"{stem}.png", x, q,
                title=f"{stem}: {len(q)} quads, {quality['irregular_vertices']} irregular, "
                f"min SJ {quality['min_sj']:.2f}"))
        return row
    finally:
        gmsh.finalize()


def _worker(cmd: list[str], deadline: float) -> dict:
    """A ``--worker`` subprocess of this script, until ``deadline`` (``time.monotonic``):
    its one JSON line; its failure raised."""
    left = deadline - time.monotonic()
    rc, out, err, _ = _run([sys.executable, str(Path(__file__).resolve()), "--worker", *cmd],
                           max(left, 1.0)) if left > 0 else (None, "", "", 0.0)
    if rc is None:
        raise TimeoutError("Gmsh ran over its time")
    try:
        row = json.loads(out.strip().splitlines()[-1])
    except (json.JSONDecodeError, IndexError):
        raise RuntimeError(last_line(err) or f"exit status {rc}") from None
    if "failed" in row:
        raise RuntimeError(row["failed"])
    return row


def gmsh_run(path: Path, method: str, quads: float, quad_size: float | None,
             out: Path | None, stem: str, area_rtol: float, timeout: float = 300.0) -> dict:
    """Gmsh's quads of ``path`` with ``method`` at about ``quads`` quads (area /
    ``quad_size``² if given), measured.

    Every parse of the file is in its own subprocess (:func:`gmsh_area`, then
    :func:`gmsh_try` per size): Gmsh's parser keeps a ``.geo``'s ``Function``s for the
    life of the process (``gmsh.clear`` and ``gmsh.finalize`` do not forget them), so a
    second parse of such a file in one process is a redefinition, and its ``Call`` then
    reads a closed file. Raises :class:`TimeoutError` past ``timeout`` seconds in all.
    """
    deadline = time.monotonic() + timeout
    area = _worker([str(path), method, "--area-only"], deadline)["area"]
    target = area / quad_size**2 if quad_size else quads
    guess = GMSH_METHODS[method][1]
    with tempfile.TemporaryDirectory(prefix="quads_gmsh_") as tmp:
        def generate(h, factor):  # a fresh process: algorithm 11 keeps its sizes
            folder = Path(tmp) / str(len(tries))
            cmd = [str(path), method, "--at", repr(h), "--factor", repr(factor),
                   "--area", repr(area),
                   "--area-rtol", repr(area_rtol), "--stem", stem]
            if out is not None:  # the try's picture and .msh; the best one's are kept
                cmd += ["--out", str(folder)]
            return {**_worker(cmd, deadline), "folder": str(folder)}

        # Rescale until within WITHIN of the target; a size Gmsh fails at is nudged by 5 %
        # (the full-quad Blossom needs an even number of boundary edges per loop). The cap
        # and the factor of the file's own sizes are scaled together, so the size field
        # min(factor * file's size, cap) is scaled as a whole, whichever of them binds.
        tries = []
        tries.append(generate(guess * math.sqrt(area / target), 1.0))
        while len(tries) <= RESCALES + 2:
            last = tries[-1]
            h, factor = last["mesh_size"], last["size_factor"]
            if "error" in last:
                tries.append(generate(h * 1.05, factor * 1.05))
            elif last["quads"] and abs(last["quads"] / target - 1) > WITHIN:
                scale = math.sqrt(last["quads"] / target)
                tries.append(generate(h * scale, factor * scale))
            else:
                break
            if sum("error" not in t for t in tries) > RESCALES:
                break
        done = [t for t in tries if "error" not in t]
        if not done:
            sizes = ", ".join(f"{t['mesh_size']:.3g}" for t in tries)
            raise RuntimeError(f"Gmsh failed at sizes {sizes}: {tries[0]['error']}")
        best = min(done, key=lambda t: abs(math.log(max(t["quads"], 1) / target)))
        row = {"method": method, "status": "ok", "target": target,
               "mesh_size": best["mesh_size"], "size_factor": best["size_factor"],
               "seconds": best["seconds"],
               "total_s": sum(t.get("seconds", 0) for t in tries),
               "tries": [{k: t[k] for k in ("mesh_size", "size_factor", "quads", "triangles",
                                            "seconds", "error") if k in t} for t in tries],
               "area_exact": area, "triangles": best["triangles"]}
        if "quality" not in best:
            return {**row, "status": "failed", "error": "no quads"}
        row.update({k: best[k] for k in ("quality", "valid", "problems", "area_error")})
        if out is not None:  # the best try's files
            out.mkdir(parents=True, exist_ok=True)
            for ending in (".msh", ".png"):
                shutil.copyfile(Path(best["folder"]) / f"{stem}{ending}",
                                out / f"{stem}{ending}")
            row["picture"] = str(out / f"{stem}.png")
        return row


# --- the subprocesses -------------------------------------------------------------------


def _tool(name: str) -> str | None:
    beside = Path(sys.executable).parent / name
    return str(beside) if beside.exists() else shutil.which(name)


def _run(cmd: list[str], timeout: float) -> tuple[int | None, str, str, float]:
    """Run ``cmd`` in its own process group; kill the group on timeout (rc None)."""
    env = {**os.environ, "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1"),
           "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS", "1")}
    return run_in_group(cmd, timeout, env=env, cwd=ROOT)


def run_gmsh(path: Path, method: str, args, stem: str, quads: float | None = None) -> dict:
    """:func:`gmsh_run` within ``--gmsh-timeout`` (``quads`` overrides the size asked for);
    its failure a row."""
    quad_size = args.quad_size if quads is None else None
    try:
        return gmsh_run(path, method, quads or args.quads, quad_size, args.out, stem,
                        args.area_rtol, timeout=args.gmsh_timeout)
    except TimeoutError:
        return {"method": method, "status": "timeout",
                "error": f"Gmsh ran over {args.gmsh_timeout:g} s"}
    except RuntimeError as e:
        return {"method": method, "status": "failed", "error": one_line(e)}


def _msh_quads(path: Path):
    """(points, quads) of the 4-node quads in a ``.msh`` file."""
    import gmsh

    owns = not gmsh.isInitialized()
    if owns:
        gmsh.initialize(argv=[], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("ufl_frames quads")
        _merge(path)
        x, q, t = _mesh_arrays()
        if len(t):
            raise RuntimeError(f"{len(t)} triangles in {path.name}")
        return x, q
    finally:
        if owns:
            gmsh.finalize()
        else:
            gmsh.model.remove()


def run_ufl_frames(argument: str, quad_size: float, area: float | None, args,
                   stem: str, method: str = "ufl_frames") -> dict:
    """The CLI's quads: its own summary, and quads.msh measured again here."""
    from ufl_frames.quads.measures import check_quad_mesh, quad_quality

    frames = _tool("ufl-frames")
    base = [frames] if frames else [sys.executable, "-m", "ufl_frames.app"]
    row = {"method": method, "quad_size": quad_size}
    with tempfile.TemporaryDirectory(prefix="quads_") as tmp:
        folder = Path(tmp) / "run"
        if method == SIZED_METHOD:  # the count, graded by the file's sizes
            cmd = [*base, "mesh", argument, "--size", "file", "--quads",
                   str(round(area / quad_size**2)), "--out", str(folder), "--force", "-q"]
        else:
            cmd = [*base, "solve", argument, *UFL_FRAMES_METHODS[method], "--quads",
                   "--quad-size", repr(quad_size), "--out", str(folder), "--force", "-q"]
        if args.mesh_size and method != SIZED_METHOD:
            cmd += ["--mesh-size", repr(args.mesh_size)]
        rc, _, err, wall = _run(cmd, args.timeout)
        row["command"] = " ".join(cmd)
        row["wall_s"] = wall
        if rc is None:
            return {**row, "status": "timeout", "error": f"ran over {args.timeout:g} s"}
        if rc != 0:
            return {**row, "status": "not available", "error": last_line(err) or f"exit {rc}"}
        try:
            summary = json.loads((folder / "summary.json").read_text())
            reported = summary["quads"]
        except (OSError, ValueError, KeyError, TypeError) as e:
            return {**row, "status": "not available",
                    "error": f"no 'quads' in summary.json ({one_line(e)})"}
        seconds = reported.get("seconds")
        if isinstance(seconds, dict):  # per step: quantise, extract, ...
            seconds = sum(v for v in seconds.values() if isinstance(v, int | float))
        row.update(status="ok", reported=reported, seconds=seconds, total_s=wall,
                   valid_reported=reported.get("valid"),
                   stage_seconds=summary.get("stage_seconds"),
                   field_triangles=summary.get("num_cells"))
        try:
            x, q = _msh_quads(folder / "quads.msh")
        except Exception as e:  # reported, not raised
            return {**row, "quality": {k: v for k, v in reported.items()
                                       if k not in ("valid", "seconds")},
                    "valid": bool(reported.get("valid")),
                    "problems": [f"quads.msh not measured: {one_line(e)}"]}
        quality = quad_quality(x, q)
        # a shape cut open along a slit has its points there twice, on the slit's two sides
        slits = any("slit" in note for note in summary.get("loader_notes") or [])
        problems = check_quad_mesh(x, q, area=area, rtol=args.area_rtol, slits=slits)
        mismatch = sorted(k for k, v in quality.items()
                          if k in reported and not _close(v, reported[k]))
        row.update(quality=quality, valid=not problems, problems=problems,
                   summary_mismatch=mismatch)
        if area:
            row["area_error"] = quality["area"] / area - 1
        if args.out:
            from ufl_frames.quads.msh import plot_quads

            args.out.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(folder / "quads.msh", args.out / f"{stem}.msh")
            row["picture"] = str(plot_quads(
                args.out / f"{stem}.png", x, q,
                title=f"{stem}: {len(q)} quads, {quality['irregular_vertices']} irregular, "
                f"min SJ {quality['min_sj']:.2f}"))
    return row


def _close(a, b) -> bool:
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_close(a[k], b[k]) for k in a)
    if isinstance(a, int | float) and isinstance(b, int | float):
        return math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12)
    return a == b


# --- tables -----------------------------------------------------------------------------

HEADER = (f"  {'method':<16}{'quads':>6}{'tris':>5}{'irreg':>6}{'(int+bnd)':>10}"
          f"{'minSJ':>7}{'meanSJ':>7}{'SJ>=.8':>7}{'ratio':>6}{'max':>6}{'area err':>9}"
          f"{'valid':>6}{'time s':>8}{'total s':>8}")


def format_row(row: dict) -> str:
    if "quality" not in row:
        return f"  {row['method']:<16}{row['status']}: {row.get('error', '')}"
    m = row["quality"]
    ratio = m["edge_length_ratio"]
    split = f"({m['irregular_interior']}+{m['irregular_boundary']})"
    area = f"{100 * row['area_error']:+8.2f}%" if "area_error" in row else f"{'-':>9}"
    seconds = row.get("seconds")
    time_s = "".join(f"{v:8.2f}" if isinstance(v, int | float) else f"{'-':>8}"
                     for v in (seconds, row.get("total_s")))
    text = (f"  {row['method']:<16}{m['quads']:>6}{row.get('triangles', 0):>5}"
            f"{m['irregular_vertices']:>6}{split:>10}{m['min_sj']:>7.3f}{m['mean_sj']:>7.3f}"
            f"{m['sj_at_least_0_8']:>7.2f}{ratio['mean']:>6.2f}{ratio['max']:>6.1f}{area}"
            f"{'yes' if row['valid'] else 'NO':>6}{time_s}")
    if row.get("stage_seconds"):
        text += "\n      stages: " + ", ".join(f"{k} {v:.2f} s"
                                              for k, v in row["stage_seconds"].items())
    if row.get("problems"):
        text += "\n" + "\n".join(f"      ! {p}" for p in row["problems"])
    if row.get("summary_mismatch"):
        text += f"\n      ! summary.json differs from quads.msh in {row['summary_mismatch']}"
    return text


#: (label, key in quality or a function of it, better = max or min)
CRITERIA = (
    ("fewest irregular vertices", lambda m: m["irregular_vertices"], min),
    ("best min SJ", lambda m: m["min_sj"], max),
    ("best mean SJ", lambda m: m["mean_sj"], max),
    ("most quads with SJ >= 0.8", lambda m: m["sj_at_least_0_8"], max),
    ("lowest mean edge ratio", lambda m: m["edge_length_ratio"]["mean"], min),
)


def summarise(shapes: list[dict], methods: list[str]) -> dict:
    """Per criterion, on how many shapes each method is best (ties count for all; valid
    meshes only); per method, how many meshes were valid and the totals."""
    wins = {label: dict.fromkeys(methods, 0) for label, _, _ in CRITERIA}
    valid = dict.fromkeys(methods, 0)
    ran = dict.fromkeys(methods, 0)
    irregular = dict.fromkeys(methods, 0)
    for shape in shapes:
        rows = [r for r in shape["rows"] if "quality" in r]
        for r in rows:
            ran[r["method"]] += 1
            valid[r["method"]] += bool(r["valid"])
            irregular[r["method"]] += r["quality"]["irregular_vertices"]
        good = [r for r in rows if r["valid"]]
        if not good:
            continue
        for label, value, best in CRITERIA:
            top = best(value(r["quality"]) for r in good)
            for r in good:
                if math.isclose(value(r["quality"]), top, rel_tol=1e-9, abs_tol=1e-12):
                    wins[label][r["method"]] += 1
    return {"wins": wins, "valid": valid, "measured": ran, "irregular_total": irregular,
            "shapes": len(shapes)}


def print_summary(summary: dict, methods: list[str]) -> None:
    width = max(len(label) for label, _, _ in CRITERIA) + 2
    print(f"\nSummary over {summary['shapes']} shapes (valid meshes only; ties count for each)")
    print(f"  {'':<{width}}" + "".join(f"{m:>16}" for m in methods))
    for label, _, _ in CRITERIA:
        print(f"  {label:<{width}}" + "".join(f"{summary['wins'][label][m]:>16}"
                                              for m in methods))
    print(f"  {'valid / measured':<{width}}" + "".join(
        f"{summary['valid'][m]:>12}/{summary['measured'][m]:<3}" for m in methods))
    print(f"  {'irregular vertices, total':<{width}}" + "".join(
        f"{summary['irregular_total'][m]:>16}" for m in methods))


# --- main -------------------------------------------------------------------------------


def resolve(names: list[str] | None) -> list[tuple[str, Path]]:
    known = {p.stem: p for p in sorted(SHAPES.glob("*.geo"))} | BUILTIN_GEO
    if not names:
        return list(known.items())
    found = []
    for name in names:
        path = Path(name)
        if name in known:
            found.append((name, known[name]))
        elif path.suffix.lower() in GEOMETRY_SUFFIXES and path.exists():
            found.append((path.stem, path.resolve()))
        else:
            sys.exit(f"quads.py: unknown shape {name!r} (known: {', '.join(known)}; or a file)")
    return found


def _area(row_list: list[dict]) -> float | None:
    return next((r["area_exact"] for r in row_list if "area_exact" in r), None)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shapes", nargs="+", metavar="NAME",
                        help="shape names (file stems) or geometry files; default: all")
    size = parser.add_mutually_exclusive_group()
    size.add_argument("--quads", type=float, default=400.0, metavar="N",
                      help="target number of quads (default 400)")
    size.add_argument("--quad-size", type=float, metavar="S",
                      help="target quad edge length instead: N = area / S^2")
    parser.add_argument("--methods", nargs="+", choices=ALL_METHODS, default=DEFAULT_METHODS,
                        metavar="M", help=f"of {', '.join(ALL_METHODS)} "
                        f"(default {' '.join(DEFAULT_METHODS)})")
    parser.add_argument("--json", metavar="FILE", help="write all rows to FILE")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "out" / "quads",
                        help="pictures and .msh files (default benchmarks/out/quads)")
    parser.add_argument("--no-out", action="store_true", help="no pictures, no .msh files")
    parser.add_argument("--mesh-size", type=float, metavar="H",
                        help="passed to ufl-frames solve (the frame field's triangles)")
    parser.add_argument("--timeout", type=float, default=600.0,
                        help="seconds per ufl-frames run (default 600)")
    parser.add_argument("--gmsh-timeout", type=float, default=300.0,
                        help="seconds per Gmsh run (default 300)")
    parser.add_argument("--area-rtol", type=float, default=0.02,
                        help="relative area tolerance of the validity check (default 0.02)")
    parser.add_argument("--worker", nargs=2, metavar=("FILE", "METHOD"),
                        help=argparse.SUPPRESS)
    parser.add_argument("--stem", help=argparse.SUPPRESS)
    parser.add_argument("--area-only", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--at", type=float, help=argparse.SUPPRESS)
    parser.add_argument("--factor", type=float, default=1.0, help=argparse.SUPPRESS)
    parser.add_argument("--area", type=float, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.no_out:
        args.out = None
    if args.worker:  # internal: one parse of the file, one JSON line on stdout
        path, method = Path(args.worker[0]), args.worker[1]
        try:
            if args.area_only:
                row = {"area": gmsh_area(path)}
            else:
                row = gmsh_try(path, method, args.at, args.factor, args.area,
                               args.area_rtol, args.out, args.stem)
        except Exception as e:  # reported, not raised
            row = {"failed": one_line(e)}
        print(json.dumps(row))
        return

    shapes = []
    gmsh_methods = [m for m in args.methods if m in GMSH_METHODS]
    for name, path in resolve(args.shapes):
        print(f"\n{name} ({path.relative_to(ROOT) if path.is_relative_to(ROOT) else path})",
              flush=True)
        rows = []
        area = None
        for method in gmsh_methods:
            rows.append(run_gmsh(path, method, args, f"{name}_{method}"))
            area = area or _area(rows)
            if len(rows) == 1:
                print(HEADER, flush=True)
            print(format_row(rows[-1]), flush=True)
        for method in [m for m in args.methods if m in UFL_FRAMES_METHODS]:
            if area is None:  # no Gmsh run: ask one for the area only
                try:
                    area = _worker([str(path), "blossom", "--area-only"],
                                   time.monotonic() + args.gmsh_timeout)["area"]
                except (TimeoutError, RuntimeError):
                    area = None
            if area is None:
                rows.append({"method": method, "status": "not available",
                             "error": "the shape's area is unknown (Gmsh could not load it)"})
            else:
                s = args.quad_size or math.sqrt(area / args.quads)
                rows.append(run_ufl_frames(str(path), s, area, args, f"{name}_{method}",
                                           method))
            if len(rows) == 1:
                print(HEADER)
            print(format_row(rows[-1]), flush=True)
        shapes.append({"name": name, "file": str(path), "area": area, "rows": rows})
    summary = summarise(shapes, list(args.methods))
    print_summary(summary, list(args.methods))
    if args.json:
        Path(args.json).write_text(json.dumps(
            {"target_quads": args.quads if not args.quad_size else None,
             "quad_size": args.quad_size, "methods": list(args.methods),
             "area_rtol": args.area_rtol, "shapes": shapes, "summary": summary},
            indent=1))
        print(f"\nwrote {args.json}")


if __name__ == "__main__":
    main()
