"""Frame fields on a gallery of real planar shapes, next to Gmsh's quasi-structured quads.

    python benchmarks/gallery.py [--shapes NAME_OR_FILE ...] [--max-it 500] [--timeout 300]
                                 [--mesh-size-factor 0.02] [--quad-size-factor 2]
                                 [--gmsh-timeout 300] [--np N] [--json FILE] [--keep DIR]
                                 [--no-gmsh] [PETSc options for every solve]

Shapes: every file in ``meshes/gallery/`` (public Gmsh, deal.II and Firedrake inputs; see
``meshes/gallery/SOURCES.md``), named by their stem, plus the built-in ``annulus`` and
``piano`` (probed through ``meshes/annulus.geo`` and ``meshes/piano.geo``). ``--shapes``
picks some of them by name, or takes any geometry file.

For every shape, first a probe in a subprocess (this script with ``--probe``): Gmsh
loads the file and gives its bounding box; the mesh size of the solves is
H = ``--mesh-size-factor`` x the diagonal of that box, so that a drawing in millimetres
and one in metres get the same resolution (the file's own finer point sizes and size
fields still apply: ``--mesh-size`` is the largest element size); with
``--mesh-size-factor 0`` no ``--mesh-size`` is passed (the loader's default; Gmsh's quads
then use 0.02 x the diagonal). The probe then meshes the
same geometry with Gmsh's quasi-structured quad mesher (``Mesh.Algorithm = 11``; the
file's meshing constraints and boundary-layer fields removed, first order, no
subdivision; every size scaled by ``--quad-size-factor``, default 2: ``Mesh.MeshSizeFactor``
2 and ``Mesh.MeshSizeMax`` 2 H, as Gmsh's documentation asks for twice the wanted edge
length with this algorithm) and counts its irregular vertices: interior vertices in a
number of quads != 4, and boundary vertices whose number of quads is not
max(1, round(interior angle / 90 deg)) (2 on a straight or smooth boundary, 1 at a 90 deg
convex corner, 3 at a 270 deg concave one; the angle is the sum of the element angles at
the vertex). ``.msh`` files have no geometry to remesh: "n/a". Algorithm 11 takes from
under a second to a few minutes (``--gmsh-timeout``; ``--no-gmsh`` skips it).

Then, for isotropic and non-isotropic frames, the project's pipeline in a subprocess
(crashes stay isolated; ``--timeout`` per run, default 300 s; the process group is killed
after it)::

    ufl-frames solve SHAPE --out TMP --force -q --max-it N --mesh-size H [--isotropic]

under ``mpirun -n N`` with ``--np N``. A row per (shape, frames) is printed as soon as
the run ends: vertices, triangles, iterations, TAO's converged reason, total time
(``total_time_s``), H_initial, H_final, singularities (+1/4, -1/4, other indices) and the
Poincare-Hopf check of ``summary.json`` (index sum / expected, "n/a" while the summary has
no ``poincare_hopf``). A failed run shows its status instead: ``error`` (non-zero exit
with a last line ``ufl-frames: error: ...`` and no traceback), ``crash`` (traceback,
signal or MPI abort; the exit status and the last stderr line, MPI's closing ``Abort(...)``
line skipped) or ``timeout``. Then the Gmsh table and a verdict: how many runs solved,
failed with a clear error, crashed, timed out, and whether Poincare-Hopf agreed on every
solved run. ``--json FILE`` writes all rows (with the command and the stderr tail of each
failure) and probes; ``--keep DIR`` keeps each run's output folder (DIR/<shape>-iso,
DIR/<shape>-noniso) instead of a temporary one.

Unknown arguments (single dash, e.g. ``-tao_type lmvm``) are passed to every solve. The
script itself imports neither PETSc nor DOLFINx (everything runs in subprocesses); the
solves use the ``ufl_frames`` that the interpreter imports, so ``PYTHONPATH=OTHER/src``
measures another checkout.
"""

import argparse
import json
import math
import os
import shutil
import signal
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from _common import BUILTIN_GEO, GEOMETRY_SUFFIXES, ROOT, gmsh_errors, one_line, surface_elements
from _processes import last_line, run_in_group

GALLERY = ROOT / "meshes" / "gallery"


# --- the Gmsh probe (runs in its own process: Gmsh may crash or hang) -----------------


def _corner_angles(xy, cells):
    """Angle at every corner of every cell (rows of node indices, either orientation)."""
    k = cells.shape[1]
    p = xy[cells]
    before = p[:, [(i - 1) % k for i in range(k)]] - p
    after = p[:, [(i + 1) % k for i in range(k)]] - p
    cos = (before * after).sum(-1) / (
        np.linalg.norm(before, axis=-1) * np.linalg.norm(after, axis=-1) + 1e-300
    )
    return np.arccos(np.clip(cos, -1.0, 1.0))


def irregular_vertices(xy, quads, triangles):
    """Irregular vertices of a quad(-dominant) mesh: (interior, boundary) counts.

    ``xy``: (n, 2) coordinates; ``quads`` (m, 4), ``triangles`` (t, 3): node indices.
    An edge used by one element is on the boundary. Interior vertices are irregular when
    not in exactly 4 quads; boundary ones when the number of quads differs from
    max(1, round(angle / 90 deg)), the angle being the sum of the element angles there.
    """
    n = len(xy)
    edges = [
        np.sort(np.stack([c, np.roll(c, -1, axis=1)], -1).reshape(-1, 2), axis=1)
        for c in (quads, triangles)
        if len(c)
    ]
    edges = np.concatenate(edges)
    _, inverse, counts = np.unique(
        edges[:, 0] * n + edges[:, 1], return_inverse=True, return_counts=True
    )
    on_boundary = np.zeros(n, bool)
    on_boundary[edges[counts[inverse] == 1].ravel()] = True
    used = np.zeros(n, bool)
    angle = np.zeros(n)
    for cells in (quads, triangles):
        if len(cells):
            used[cells.ravel()] = True
            np.add.at(angle, cells.ravel(), _corner_angles(xy, cells).ravel())
    valence = np.bincount(quads.ravel(), minlength=n) if len(quads) else np.zeros(n, int)
    expected = np.maximum(1, np.rint(angle / (np.pi / 2))).astype(int)
    interior = used & ~on_boundary
    return int(np.sum(interior & (valence != 4))), int(np.sum(on_boundary & (valence != expected)))


def _elements_2d():
    """(coordinates (n, 2), quads, triangles, other element count) of the current model."""
    xyz, surfaces = surface_elements()
    cells = {}
    for etype, k in ((3, 4), (2, 3)):
        parts = [found[etype] for found in surfaces if etype in found]
        cells[etype] = np.concatenate(parts) if parts else np.zeros((0, k), np.int64)
    other = sum(c.size for found in surfaces for etype, c in found.items() if etype not in cells)
    return xyz[:, :2], cells[3], cells[2], other


def probe(path: Path, mesh_size_factor: float, quad_size_factor: float, quads: bool) -> dict:
    """Bounding box and mesh size of ``path``; Gmsh's quasi-structured quad statistics."""
    import gmsh

    result = {"file": str(path)}
    gmsh.initialize(argv=[], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.AbortOnError", 0)
        errors = gmsh_errors(lambda: gmsh.merge(str(path)), catch=True)  # reported, not raised
        if errors:
            result["error"] = "Gmsh cannot read it: " + one_line(errors[0]).removeprefix("Error: ")
            return result
        if not gmsh.model.getEntities():
            result["error"] = "Gmsh found no geometry in the file"
            return result
        box = gmsh.model.getBoundingBox(-1, -1)
        if path.suffix.lower() == ".msh" or not all(math.isfinite(v) for v in box):
            _, coords, _ = gmsh.model.mesh.getNodes()
            c = coords.reshape(-1, 3)
            box = (*c.min(axis=0), *c.max(axis=0))
        diagonal = math.dist(box[:3], box[3:])
        result.update(
            bbox=[float(v) for v in box],
            diagonal=diagonal,
            mesh_size=mesh_size_factor * diagonal,
            surfaces=len(gmsh.model.getEntities(2)),
            volumes=len(gmsh.model.getEntities(3)),
        )
        if not quads:
            return result
        if path.suffix.lower() == ".msh":
            result["quad_error"] = "n/a: a .msh file has no geometry to remesh"
            return result
        result["quad"] = _quad_mesh(result["mesh_size"], quad_size_factor)
    finally:
        gmsh.finalize()
    return result


def _quad_mesh(size: float, factor: float) -> dict:
    """Gmsh's quasi-structured quads at sizes ``factor`` x the solve's (``size`` = its H)."""
    import gmsh

    removed = []
    for field in gmsh.model.mesh.field.list():
        if gmsh.model.mesh.field.getType(field) == "BoundaryLayer":
            gmsh.model.mesh.field.remove(field)
            removed.append(f"boundary-layer field {field}")
    gmsh.model.mesh.removeConstraints()
    for option, value in (
        ("Mesh.ElementOrder", 1),
        ("Mesh.SubdivisionAlgorithm", 0),
        ("Mesh.RecombineAll", 0),
        ("Mesh.MeshSizeMax", size * factor),
        ("Mesh.MeshSizeFactor", factor),
        ("Mesh.Algorithm", 11),
    ):
        gmsh.option.setNumber(option, value)
    gmsh.model.mesh.clear()
    start = time.perf_counter()
    errors = gmsh_errors(lambda: gmsh.model.mesh.generate(2), catch=True)  # reported, not raised
    seconds = time.perf_counter() - start
    if errors:
        message = one_line(errors[0]).removeprefix("Error: ")
        return {"error": f"Gmsh algorithm 11 failed: {message}", "seconds": seconds}
    xy, quads, triangles, other = _elements_2d()
    interior, boundary = irregular_vertices(xy, quads, triangles)
    return {
        "size": size * factor,
        "quads": len(quads),
        "triangles": len(triangles),
        "other": other,
        "irregular_interior": interior,
        "irregular_boundary": boundary,
        "irregular": interior + boundary,
        "seconds": seconds,
        "removed": removed,
    }


# --- the solves ------------------------------------------------------------------------


def _tool(name: str) -> str | None:
    beside = Path(sys.executable).parent / name
    return str(beside) if beside.exists() else shutil.which(name)


def _command(np_: int) -> list[str]:
    frames = _tool("ufl-frames")
    cmd = [frames] if frames else [sys.executable, "-m", "ufl_frames.app"]
    if np_ > 1:
        mpirun = _tool("mpirun")
        if mpirun is None:
            sys.exit("gallery.py: --np needs mpirun (none beside the interpreter or on PATH)")
        cmd = [mpirun, "-n", str(np_), *cmd]
    return cmd


def _run(cmd: list[str], timeout: float, env: dict) -> tuple[int | None, str, str, float]:
    """Run ``cmd`` in its own process group; kill the group on timeout (rc None)."""
    return run_in_group(cmd, timeout, env=env, cwd=ROOT)


def _telling_line(text: str) -> str:
    """The last stderr line, skipping MPI's closing ``Abort(...)`` boilerplate."""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    while len(lines) > 1 and lines[-1].startswith(("Abort(", "[unset]:", "application called")):
        lines.pop()
    return lines[-1] if lines else ""


def classify(rc: int | None, err: str, summary: dict | None) -> tuple[str, str]:
    """(status, message): solved, error (one clear line), crash or timeout."""
    if rc is None:
        return "timeout", "killed after the timeout"
    if rc == 0 and summary is not None:
        return "solved", ""
    if rc == 0:
        return "crash", "exit status 0 but no summary.json"
    last = _telling_line(err) or "-"
    if rc < 0 or rc > 128:
        number = -rc if rc < 0 else rc - 128
        try:
            name = signal.Signals(number).name
        except ValueError:
            name = f"signal {number}"
        return "crash", f"{name} (exit {rc}): {last}"
    if "Traceback (most recent call last)" in err or not last.startswith("ufl-frames: error:"):
        return "crash", f"exit {rc}: {last}"
    return "error", last


def solve(shape: dict, isotropic: bool, args, extras: list[str], keep: Path | None) -> dict:
    kind = "iso" if isotropic else "noniso"
    row = {"shape": shape["name"], "frames": kind, "mesh_size": shape["mesh_size"]}
    if keep is not None:
        out = keep / f"{shape['name']}-{kind}"
        out.mkdir(parents=True, exist_ok=True)
        holder = None
    else:
        holder = tempfile.TemporaryDirectory(prefix=f"gallery-{shape['name']}-{kind}-")
        out = Path(holder.name)
    try:
        cmd = [
            *_command(args.np),
            "solve",
            shape["argument"],
            "--out",
            str(out),
            "--force",
            "-q",
            "--max-it",
            str(args.max_it),
        ]
        if args.mesh_size_factor > 0 and shape["mesh_size"] is not None:
            cmd += ["--mesh-size", f"{shape['mesh_size']:.6g}"]
        if isotropic:
            cmd.append("--isotropic")
        cmd += extras
        env = dict(os.environ)
        env.setdefault("OMP_NUM_THREADS", "1")
        env.setdefault("OPENBLAS_NUM_THREADS", "1")
        rc, _, err, seconds = _run(cmd, args.timeout, env)
        summary = None
        if (out / "summary.json").is_file():
            with open(out / "summary.json") as f:
                summary = json.load(f)
        status, message = classify(rc, err, summary)
        if status == "timeout":
            message = f"killed after {args.timeout:g} s"
        row.update(
            status=status,
            message=message,
            exit=rc,
            wall_s=seconds,
            command=" ".join(cmd),
            last_stderr_line=last_line(err),
            stderr_tail=err.splitlines()[-30:] if status != "solved" else [],
        )
        if summary is not None and status == "solved":
            row.update(_from_summary(summary))
    finally:
        if holder is not None:
            holder.cleanup()
    return row


def _from_summary(s: dict) -> dict:
    quarters = [round(4 * float(x["index"])) for x in s.get("singularities", [])]
    ph = s.get("poincare_hopf")
    return {
        "vertices": s.get("num_vertices"),
        "triangles": s.get("num_cells"),
        "iterations": s.get("iterations"),
        "converged_reason": s.get("converged_reason"),
        "total_time_s": s.get("total_time_s"),
        "H_initial": s.get("H_initial"),
        "H_final": s.get("H_final"),
        "plus_quarter": quarters.count(1),
        "minus_quarter": quarters.count(-1),
        "other_singularities": len(quarters) - quarters.count(1) - quarters.count(-1),
        "poincare_hopf": ph if isinstance(ph, dict) else None,
        "summary_mesh_size": s.get("mesh_size"),
        "loader_notes": s.get("loader_notes"),
    }


# --- printing ----------------------------------------------------------------------------

HEADER = (
    f"{'shape':<30} {'frames':<6} {'verts':>6} {'tris':>6} {'its':>5} {'reason':<24} "
    f"{'time s':>7} {'H_initial':>10} {'H_final':>10} {'+1/4':>4} {'-1/4':>4} "
    f"{'oth':>3}  Poincare-Hopf"
)


def format_row(row: dict) -> str:
    head = f"{row['shape']:<30} {row['frames']:<6} "
    if row["status"] != "solved":
        return head + f"{row['status'].upper()}: {row['message']}"
    ph = row["poincare_hopf"]
    if ph is None:
        check = "n/a"
    else:
        nan = float("nan")
        verdict = "ok" if ph.get("agrees") else "DISAGREES"
        corners = ph.get("corners")
        if isinstance(corners, (list, tuple)):
            corners = len(corners)
        check = (
            f"{ph.get('index_sum', nan):+.2f} / {ph.get('expected', nan):+.2f} {verdict} "
            f"(chi {ph.get('euler_characteristic')}, {corners} corners)"
        )
    return head + (
        f"{row['vertices']:>6} {row['triangles']:>6} {row['iterations']:>5} "
        f"{row['converged_reason']:<24} {row['total_time_s']:>7.1f} {row['H_initial']:>10.3e} "
        f"{row['H_final']:>10.3e} {row['plus_quarter']:>4} {row['minus_quarter']:>4} "
        f"{row['other_singularities']:>3}  {check}"
    )


def format_quad(shape: dict) -> str:
    size = shape["mesh_size"]
    size = "-" if size is None else format(size, ".4g")
    head = f"{shape['name']:<30} {size:>10} "
    if "error" in shape:
        return head + f"probe failed: {shape['error']}"
    if "quad_error" in shape:
        return head + shape["quad_error"]
    q = shape.get("quad")
    if q is None:
        return head + "not run"
    if "error" in q:
        return head + q["error"]
    return head + (
        f"{q['quads']:>7} {q['triangles']:>5} {q['irregular_interior']:>9} "
        f"{q['irregular_boundary']:>9} {q['irregular']:>9} {q['seconds']:>7.1f}"
    )


# --- driver ---------------------------------------------------------------------------


def gallery_shapes() -> dict[str, Path]:
    files = sorted(p for p in GALLERY.iterdir() if p.suffix.lower() in GEOMETRY_SUFFIXES)
    return {**{p.stem: p for p in files}, **BUILTIN_GEO}


def resolve(names: list[str] | None) -> list[tuple[str, Path, str]]:
    """(name, file the probe loads, argument given to ufl-frames solve) per shape."""
    known = gallery_shapes()
    chosen = []
    for name in names or list(known):
        if name in BUILTIN_GEO:
            chosen.append((name, BUILTIN_GEO[name], name))
        elif name in known:
            chosen.append((name, known[name], str(known[name].relative_to(ROOT))))
        elif Path(name).exists():
            path = Path(name).resolve()
            chosen.append((path.stem, path, str(path)))
        else:
            sys.exit(f"gallery.py: unknown shape {name!r}; known: {', '.join(known)}")
    return chosen


def run_probe(path: Path, args) -> dict:
    cmd = [
        sys.executable,
        str(Path(__file__).resolve()),
        "--probe",
        str(path),
        "--mesh-size-factor",
        repr(args.mesh_size_factor if args.mesh_size_factor > 0 else 0.02),
        "--quad-size-factor",
        repr(args.quad_size_factor),
    ]
    if args.no_gmsh:
        cmd.append("--no-gmsh")
    rc, out, err, _ = _run(cmd, args.gmsh_timeout, dict(os.environ))
    if rc is None:
        return {"error": f"Gmsh probe killed after {args.gmsh_timeout:g} s"}
    try:
        return json.loads(last_line(out))
    except json.JSONDecodeError:
        status, message = classify(rc if rc != 0 else 1, err, None)
        return {"error": f"Gmsh probe {status}: {message}"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--shapes",
        nargs="+",
        metavar="NAME",
        help="gallery names (file stems, annulus, piano) or geometry files; default: all",
    )
    parser.add_argument("--max-it", type=int, default=500)
    parser.add_argument("--timeout", type=float, default=300.0, help="seconds per solve")
    parser.add_argument(
        "--gmsh-timeout",
        type=float,
        default=300.0,
        help="seconds per Gmsh probe (quad meshing included)",
    )
    parser.add_argument(
        "--mesh-size-factor",
        type=float,
        default=0.02,
        help="mesh size = factor x bounding-box diagonal (default 0.02); 0: no --mesh-size "
        "(the loader's own default)",
    )
    parser.add_argument(
        "--quad-size-factor",
        type=float,
        default=2.0,
        help="Gmsh's algorithm 11 gets every size x this (default 2: twice the edge length)",
    )
    parser.add_argument("--np", type=int, default=1, help="run each solve under mpirun -n N")
    parser.add_argument("--json", metavar="FILE", help="write all rows and probes to FILE")
    parser.add_argument("--keep", metavar="DIR", help="keep the output folders under DIR")
    parser.add_argument(
        "--no-gmsh", action="store_true", help="skip Gmsh's quad meshing (bounding box only)"
    )
    parser.add_argument("--probe", metavar="FILE", help=argparse.SUPPRESS)
    args, extras = parser.parse_known_args()
    if args.probe:  # internal: one JSON line on stdout
        print(
            json.dumps(
                probe(
                    Path(args.probe),
                    args.mesh_size_factor,
                    args.quad_size_factor,
                    quads=not args.no_gmsh,
                )
            )
        )
        return
    bad = [a for a in extras if a.startswith("--")]
    if bad:
        parser.error(f"unrecognized arguments: {' '.join(bad)}")
    keep = Path(args.keep).resolve() if args.keep else None

    shapes, rows = [], []
    start = time.perf_counter()
    print(HEADER, flush=True)
    for name, path, argument in resolve(args.shapes):
        shape = {"name": name, "file": str(path), "argument": argument}
        shape.update(run_probe(path, args))
        shape["name"] = name  # the probe reports the file only
        shape.setdefault("mesh_size", None)  # probe failed: the loader's default size
        shapes.append(shape)
        for isotropic in (True, False):
            row = solve(shape, isotropic, args, extras, keep)
            rows.append(row)
            print(format_row(row), flush=True)

    print(
        f"\nGmsh quasi-structured quads (Mesh.Algorithm 11, all sizes x {args.quad_size_factor:g}"
        f", at most {args.quad_size_factor:g} H; irregular: interior valence != 4, boundary "
        f"valence != max(1, round(angle / 90 deg)))"
    )
    print(
        f"{'shape':<30} {'H':>10} {'quads':>7} {'tris':>5} {'irr. int.':>9} {'irr. bdry':>9} "
        f"{'irregular':>9} {'time s':>7}"
    )
    for shape in shapes:
        print(format_quad(shape))

    solved = [r for r in rows if r["status"] == "solved"]
    count = {k: sum(r["status"] == k for r in rows) for k in ("error", "crash", "timeout")}
    checked = [r for r in solved if r["poincare_hopf"] is not None]
    agree = [r for r in checked if r["poincare_hopf"].get("agrees")]
    elapsed = time.perf_counter() - start
    print(
        f"\nverdict ({len(rows)} runs on {len(shapes)} shapes, {elapsed:.0f} s):"
        f" {len(solved)} solved, {count['error']} failed with a clear one-line error, "
        f"{count['crash']} crashed (traceback or signal), {count['timeout']} timed out "
        f"(> {args.timeout:g} s)"
    )
    shapes_ok = sorted({r["shape"] for r in solved})
    print(
        f"  shapes with both runs solved: "
        f"{sum(all(r['status'] == 'solved' for r in rows if r['shape'] == s) for s in shapes_ok)}"
        f" of {len(shapes)}"
    )
    if not solved:
        print("  Poincare-Hopf: no solved run")
    elif not checked:
        print("  Poincare-Hopf: n/a (no summary.json has a 'poincare_hopf' entry yet)")
    else:
        wrong = [f"{r['shape']}/{r['frames']}" for r in checked if r not in agree]
        print(
            f"  Poincare-Hopf agrees on {len(agree)} of {len(checked)} checked solved runs"
            + (
                f" ({len(solved) - len(checked)} without the check)"
                if len(checked) < len(solved)
                else ""
            )
            + (f"; disagrees on: {', '.join(wrong)}" if wrong else " (all)")
        )
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        with open(args.json, "w") as f:
            json.dump(
                {"arguments": vars(args), "petsc_options": extras, "shapes": shapes, "rows": rows},
                f,
                indent=1,
            )
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
