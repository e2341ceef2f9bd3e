"""Multi-region quad meshes: ``ufl-frames mesh`` next to Gmsh's quasi-structured quads,
and whether the regions and tags survive.

    python benchmarks/regions.py [--shapes two_materials stator strips] [--out DIR]
                                 [--json FILE]

Shapes (each a ``.geo`` with named physical surfaces and curves):

* ``two_materials``: ``demos/two_materials.geo`` (a plate with a round inclusion);
* ``stator``: a disc of radius 1 with a bore of radius 0.3 and six radial slots
  (0.16 x 0.3) as separate surfaces (groups ``iron``, ``slots``, ``outer``, ``bore``,
  ``slot_walls``), built here;
* ``strips``: three materials side by side in [0, 3] x [0, 1] (``a``, ``b``, ``c``,
  ``inlet``, ``outlet``, ``walls``, ``interfaces``), built here.

Methods: ``ufl_frames``, the library call of ``ufl-frames mesh`` (``RunConfig.for_mesh``
with ``--quad-size`` given per shape, and ``run``), in this process; then Gmsh's
quasi-structured quads (``Mesh.Algorithm = 11``, :func:`quads.gmsh_run`, its size rescaled
to the same number of quads within 10 %). Seconds: the whole ``run`` for ufl_frames
(triangles, field, map, quads, CAD snapping, files), ``gmsh.model.mesh.generate(2)`` at
the final size for Gmsh.

Measures, on the ``.msh`` each writes, read back with Gmsh: quads, irregular vertices,
min and mean scaled Jacobian (:func:`~ufl_frames.quads.measures.quad_quality`), and
whether the regions and tags survived:

* ``groups``: the file's physical groups (dimension, number, name) are those of the
  ``.msh``;
* ``one region``: every quad lies in exactly one surface of a surface group;
* ``interfaces``: every line element of a curve is a quad edge, and every quad edge
  between two surfaces is a line element (the interfaces are made of quad edges and
  tagged).

Output: a table (Markdown) and, with ``--json``, the rows; meshes in ``--out`` (default
``benchmarks/out/regions``, git-ignored).
"""

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
from _common import ROOT, one_line, table_rule

SLOTS, R_OUT, R_BORE, SLOT_IN, SLOT_OUT, SLOT_W = 6, 1.0, 0.3, 0.5, 0.8, 0.16


def circle_geo(first_point: int, first_curve: int, centre, radius) -> tuple[str, list]:
    """Four arcs of a circle (built-in kernel): (text, curve tags)."""
    cx, cy = centre
    p = first_point
    text = f"Point({p}) = {{{cx}, {cy}, 0}};\n"
    for k, (dx, dy) in enumerate(((1, 0), (0, 1), (-1, 0), (0, -1))):
        text += f"Point({p + 1 + k}) = {{{cx + radius * dx}, {cy + radius * dy}, 0}};\n"
    curves = [first_curve + k for k in range(4)]
    for k, c in enumerate(curves):
        text += f"Circle({c}) = {{{p + 1 + k}, {p}, {p + 1 + (k + 1) % 4}}};\n"
    return text, curves


def stator_geo() -> str:
    """The stator-like disc: an iron annulus with six slots as separate surfaces."""
    text = "// stator-like disc: iron with six slots as surfaces of their own\n"
    outer_text, outer = circle_geo(1, 1, (0, 0), R_OUT)
    bore_text, bore = circle_geo(10, 10, (0, 0), R_BORE)
    text += outer_text + bore_text
    text += f"Curve Loop(1) = {{{', '.join(map(str, outer))}}};\n"
    text += f"Curve Loop(2) = {{{', '.join(map(str, bore))}}};\n"
    walls, loops = [], []
    for s in range(SLOTS):
        angle = 2 * math.pi * (s + 0.5) / SLOTS
        u = np.array([math.cos(angle), math.sin(angle)])
        v = np.array([-u[1], u[0]])
        corners = [r * u + w * v for r, w in ((SLOT_IN, -SLOT_W / 2), (SLOT_OUT, -SLOT_W / 2),
                                              (SLOT_OUT, SLOT_W / 2), (SLOT_IN, SLOT_W / 2))]
        p0, c0 = 100 + 10 * s, 100 + 10 * s
        for k, (x, y) in enumerate(corners):
            text += f"Point({p0 + k}) = {{{x:.15g}, {y:.15g}, 0}};\n"
        for k in range(4):
            text += f"Line({c0 + k}) = {{{p0 + k}, {p0 + (k + 1) % 4}}};\n"
        walls += [c0 + k for k in range(4)]
        text += f"Curve Loop({10 + s}) = {{{c0}, {c0 + 1}, {c0 + 2}, {c0 + 3}}};\n"
        text += f"Plane Surface({10 + s}) = {{{10 + s}}};\n"
        loops.append(10 + s)
    text += f"Plane Surface(1) = {{1, 2, {', '.join(map(str, loops))}}};\n"
    text += 'Physical Surface("iron", 1) = {1};\n'
    text += f'Physical Surface("slots", 2) = {{{", ".join(map(str, loops))}}};\n'
    text += f'Physical Curve("outer", 3) = {{{", ".join(map(str, outer))}}};\n'
    text += f'Physical Curve("bore", 4) = {{{", ".join(map(str, bore))}}};\n'
    text += f'Physical Curve("slot_walls", 5) = {{{", ".join(map(str, walls))}}};\n'
    return text


STRIPS_GEO = """// three materials side by side
Point(1) = {0, 0, 0}; Point(2) = {1, 0, 0}; Point(3) = {2, 0, 0}; Point(4) = {3, 0, 0};
Point(5) = {3, 1, 0}; Point(6) = {2, 1, 0}; Point(7) = {1, 1, 0}; Point(8) = {0, 1, 0};
Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 5};
Line(5) = {5, 6}; Line(6) = {6, 7}; Line(7) = {7, 8}; Line(8) = {8, 1};
Line(9) = {2, 7}; Line(10) = {3, 6};
Curve Loop(1) = {1, 9, 7, 8}; Curve Loop(2) = {2, 10, 6, -9}; Curve Loop(3) = {3, 4, 5, -10};
Plane Surface(1) = {1}; Plane Surface(2) = {2}; Plane Surface(3) = {3};
Physical Surface("a", 1) = {1}; Physical Surface("b", 2) = {2};
Physical Surface("c", 3) = {3};
Physical Curve("inlet", 4) = {8}; Physical Curve("outlet", 5) = {4};
Physical Curve("walls", 6) = {1, 2, 3, 5, 6, 7};
Physical Curve("interfaces", 7) = {9, 10};
"""

#: name -> (the .geo's text, or None for a file of the repository; its path; quad size)
SHAPES = {
    "two_materials": (None, ROOT / "demos" / "two_materials.geo", 0.05),
    "stator": (stator_geo(), "stator.geo", 0.035),
    "strips": (STRIPS_GEO, "strips.geo", 0.05),
}


def read_msh(path: Path) -> dict:
    """A ``.msh`` (or a ``.geo``'s model, unmeshed) read with Gmsh: physical groups
    (name -> (dim, number)), entities of each group, nodes, quads per surface, lines per
    curve."""
    import gmsh

    gmsh.initialize(argv=[], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.open(str(path))
        groups, members = {}, {}
        for dim, number in gmsh.model.getPhysicalGroups():
            name = gmsh.model.getPhysicalName(dim, number)
            groups[name] = (dim, number)
            members[name] = [int(t) for t in
                             gmsh.model.getEntitiesForPhysicalGroup(dim, number)]
        x, quads, lines = None, {}, {}
        tags, coords, _ = gmsh.model.mesh.getNodes()
        if len(tags):
            x = np.full((int(tags.max()) + 1, 2), np.nan)
            x[tags.astype(int)] = coords.reshape(-1, 3)[:, :2]
            for dim, store, kind, n in ((2, quads, 3, 4), (1, lines, 1, 2)):
                for _, t in gmsh.model.getEntities(dim):
                    ids, nodes = gmsh.model.mesh.getElementsByType(kind, t)
                    store[t] = (ids.astype(int), nodes.astype(int).reshape(-1, n))
        return {"groups": groups, "members": members, "x": x, "quads": quads,
                "lines": lines}
    finally:
        gmsh.finalize()


def survival(geo: dict, msh: dict) -> dict:
    """Whether the regions and tags of the file (``geo``: :func:`read_msh` of it) survived
    in ``msh``: groups, each quad in one region, interfaces of tagged quad edges."""
    groups_ok = geo["groups"] == msh["groups"] and all(
        sorted(geo["members"][n]) == sorted(msh["members"].get(n, [])) for n in geo["groups"])
    in_groups = {s for n, (d, _) in msh["groups"].items() if d == 2
                 for s in msh["members"][n]}
    ids = np.concatenate([i for i, _ in msh["quads"].values()]) if msh["quads"] else []
    counted = sum(len(msh["quads"][s][0]) for s in in_groups if s in msh["quads"])
    one_region = len(ids) > 0 and len(np.unique(ids)) == len(ids) == counted
    # quad edges (sorted node pairs) -> the surfaces they border
    sides: dict[tuple, set] = {}
    for s, (_, q) in msh["quads"].items():
        for a, b in zip(q.ravel(), np.roll(q, -1, axis=1).ravel(), strict=True):
            sides.setdefault((min(a, b), max(a, b)), set()).add(s)
    tagged = {(min(a, b), max(a, b)) for _, e in msh["lines"].values() for a, b in e}
    lines_on_edges = tagged <= set(sides)
    interface = {e for e, s in sides.items() if len(s) > 1}
    return {"groups": groups_ok, "one_region": one_region,
            "interfaces": bool(lines_on_edges and interface <= tagged),
            "interface_edges": len(interface)}


def measure(msh_path: Path, geo: dict) -> dict:
    """Quad quality and survival of the quads in ``msh_path``."""
    from ufl_frames.quads.measures import quad_quality

    msh = read_msh(msh_path)
    q = np.concatenate([c for _, c in msh["quads"].values()])
    used, q = np.unique(q, return_inverse=True)
    x, q = msh["x"][used], q.reshape(-1, 4)
    # counter-clockwise, as quad_quality expects (whole meshes are turned, not single quads)
    p = x[q]
    signed = np.sum(p[:, :, 0] * np.roll(p[:, :, 1], -1, axis=1)
                    - np.roll(p[:, :, 0], -1, axis=1) * p[:, :, 1], axis=1)
    q = np.where((signed < 0)[:, None], q[:, ::-1], q)
    return {"quality": quad_quality(x, q), **survival(geo, msh)}


def run_ufl_frames(path: Path, quad_size: float, out: Path, comm) -> dict:
    from ufl_frames.app.run import RunConfig, run

    start = time.perf_counter()
    try:
        summary = run(RunConfig.for_mesh(str(path), quad_size=quad_size, out=out,
                                         force=True, quiet=True), comm=comm)
    except Exception as error:  # noqa: BLE001 - a failed run is a row of the table
        return {"method": "ufl_frames", "status": "failed", "error": one_line(str(error))}
    seconds = time.perf_counter() - start
    if "quads" not in summary or not summary["quads"].get("valid"):
        return {"method": "ufl_frames", "status": "failed", "error": "no valid quads"}
    return {"method": "ufl_frames", "status": "ok", "seconds": seconds,
            "msh": out / "quads.msh"}


def run_gmsh_qs(path: Path, quads: int, out: Path) -> dict:
    from quads import gmsh_run

    try:
        row = gmsh_run(path, "qs", quads, None, out, "qs", 0.02)
    except RuntimeError as error:
        return {"method": "gmsh_qs", "status": "failed", "error": one_line(str(error))}
    return {"method": "gmsh_qs", "status": row["status"], "seconds": row["seconds"],
            "msh": out / "qs.msh", "error": row.get("error")}


HEADER = ("| shape | method | quads | irregular | min SJ | mean SJ | seconds | groups "
          "| each quad in one region | interfaces of tagged quad edges |")


def format_row(shape: str, row: dict) -> str:
    if row["status"] != "ok":
        return f"| {shape} | {row['method']} | failed: {row.get('error')} | | | | | | | |"
    m = row["quality"]

    def yes(flag):
        return "yes" if flag else "**no**"

    return (f"| {shape} | {row['method']} | {m['quads']} | {m['irregular_vertices']} | "
            f"{m['min_sj']:.3f} | {m['mean_sj']:.3f} | {row['seconds']:.2f} | "
            f"{yes(row['groups'])} | {yes(row['one_region'])} | "
            f"{yes(row['interfaces'])} ({row['interface_edges']} edges) |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--shapes", nargs="+", choices=sorted(SHAPES), default=list(SHAPES))
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "out" / "regions")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()

    from ufl_frames.bootstrap import init_petsc

    init_petsc([])
    from mpi4py import MPI

    comm = MPI.COMM_WORLD
    if comm.size > 1:
        sys.exit("regions.py: run it serially")
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    print(HEADER)
    print(table_rule(HEADER))
    for name in args.shapes:
        text, path, quad_size = SHAPES[name]
        if text is not None:
            path = args.out / path
            path.write_text(text)
        geo = read_msh(path)
        mine = run_ufl_frames(path, quad_size, args.out / name, comm)
        if mine["status"] == "ok":
            mine.update(measure(mine["msh"], geo))
        target = mine["quality"]["quads"] if mine["status"] == "ok" else 1000
        theirs = run_gmsh_qs(path, target, args.out / name)
        if theirs["status"] == "ok":
            theirs.update(measure(theirs["msh"], geo))
        for row in (mine, theirs):
            print(format_row(name, row), flush=True)
            rows.append({"shape": name, **{k: (str(v) if isinstance(v, Path) else v)
                                           for k, v in row.items()}})
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1, default=float))


if __name__ == "__main__":
    main()
