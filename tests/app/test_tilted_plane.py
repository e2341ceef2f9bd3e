"""``ufl-frames mesh`` of a planar geometry in a tilted plane (rotated about a skew axis and
translated): ``quads.msh``, read back by Gmsh, has its nodes in the tilted plane, the
shape's area, its boundary nodes on the tilted circles (the CAD snapping projects in the
model's own coordinates); ``summary.json`` records the plane; the same shape in z = 0
gives the same quad mesh (counts and qualities).

In-process (collective): these also run under ``mpirun -n 2 python -m pytest -m "not
serial"``.
"""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from ufl_frames.bootstrap import init_petsc

init_petsc([])  # not pytest's command line

from mpi4py import MPI  # noqa: E402
from msh_readback import read_msh

from ufl_frames.app import cli  # noqa: E402

COMM = MPI.COMM_WORLD
AXIS = np.array([1.0, 2.0, 3.0]) / math.sqrt(14.0)
ANGLE = 0.7
SHIFT = np.array([0.3, -0.5, 1.2])
OUTER, INNER = 1.0, 0.4

SHAPES = {
    # name: (OCC script of the shape in z = 0, its area, circles (centre, radius) in z = 0)
    "rectangle": ("Rectangle(1) = {-1, -0.5, 0, 2, 1};\n", 2.0, ()),
    "holed_disk": (f"Disk(1) = {{0, 0, 0, {OUTER}}};\nDisk(2) = {{0, 0, 0, {INNER}}};\n"
                   "BooleanDifference{ Surface{1}; Delete; }{ Surface{2}; Delete; }\n",
                   math.pi * (OUTER**2 - INNER**2), ((0.0, OUTER), (0.0, INNER))),
}


def rotate(p: np.ndarray) -> np.ndarray:
    """The points (n, 3) rotated by ANGLE about AXIS through the origin (Rodrigues)."""
    k, c, s = AXIS, math.cos(ANGLE), math.sin(ANGLE)
    return p * c + np.cross(k, p) * s + np.outer(p @ k, k) * (1 - c)


def tilt(p: np.ndarray) -> np.ndarray:
    """The points (n, 3) as the tilted geometry has them: rotated, then translated."""
    return rotate(np.asarray(p, dtype=float).reshape(-1, 3)) + SHIFT


def in_plane_angle() -> float:
    """The angle, in the tilted plane's own axes (:func:`ufl_frames.mesh.arrays.plane_frame`:
    e1 horizontal, e2 = normal × e1), of the rotated x axis: the flat shape turned by it
    about z is the tilted one as the loader meshes it, up to a translation."""
    normal = rotate(np.array([[0.0, 0.0, 1.0]]))[0]
    normal = normal if normal[2] > 0 else -normal
    e1 = np.cross([0.0, 0.0, 1.0], normal)
    e1 /= np.linalg.norm(e1)
    x = rotate(np.array([[1.0, 0.0, 0.0]]))[0]
    return math.atan2(x @ np.cross(normal, e1), x @ e1)


def geo(shape: str, tilted: bool, shift=(0.0, 0.0)) -> str:
    """The shape's script: tilted, or flat turned by :func:`in_plane_angle` and moved by
    ``shift``."""
    text = 'SetFactory("OpenCASCADE");\n' + SHAPES[shape][0]
    if not tilted:
        text += (f"Rotate {{{{0, 0, 1}}, {{0, 0, 0}}, {in_plane_angle()!r}}} "
                 "{ Surface{:}; }\n"
                 f"Translate {{{float(shift[0])!r}, {float(shift[1])!r}, 0}} "
                 "{ Surface{:}; }\n")
    if tilted:
        axis, move = (", ".join(repr(float(c)) for c in v) for v in (AXIS, SHIFT))
        text += (f"Rotate {{{{{axis}}}, {{0, 0, 0}}, {ANGLE!r}}} {{ Surface{{:}}; }}\n"
                 f"Translate {{{move}}} {{ Surface{{:}}; }}\n")
    return text


def mesh_run(root: Path, shape: str, tilted: bool, shift=(0.0, 0.0)):
    """``ufl-frames mesh`` of ``shape`` (collective): (out folder, summary)."""
    name = f"{shape}_{'tilted' if tilted else 'flat'}"
    path = root / f"{name}.geo"
    if COMM.rank == 0:
        path.write_text(geo(shape, tilted, shift))
    COMM.Barrier()
    out = root / name
    assert cli.main(["mesh", str(path), "--out", str(out), "-q"]) == 0
    return out, json.loads((out / "summary.json").read_text())


@pytest.fixture(scope="module", params=sorted(SHAPES))
def runs(request, tmp_path_factory):
    """The shape's tilted and flat runs: (shape, (out, summary) tilted, flat)."""
    root = Path(COMM.bcast(str(tmp_path_factory.mktemp(request.param)), root=0))
    shape = request.param
    tilted = mesh_run(root, shape, True)
    plane = tilted[1]["plane"]  # the flat shape where the loader puts the tilted one
    centre = SHIFT - np.asarray(plane["origin"])
    shift = (centre @ np.asarray(plane["e1"]), centre @ np.asarray(plane["e2"]))
    return shape, tilted, mesh_run(root, shape, False, shift)


def test_quads_written_in_the_tilted_plane(runs):
    shape, (out, summary), _ = runs
    normal = rotate(np.array([[0.0, 0.0, 1.0]]))[0]
    plane = summary["plane"]
    assert plane is not None and "quads.msh" in summary["plane_note"]
    assert abs(abs(np.dot(plane["normal"], normal)) - 1) < 1e-12
    assert abs(np.dot(np.subtract(plane["origin"], SHIFT), normal)) < 1e-12
    if COMM.rank != 0:
        return
    x, quads, boundary = read_msh(out / "quads.msh")
    assert quads.shape[0] == summary["quads"]["quads"]
    assert np.abs((x - SHIFT) @ normal).max() < 1e-12
    # the quads' area in 3D: half the cross product of their diagonals
    d1, d2 = x[quads[:, 2]] - x[quads[:, 0]], x[quads[:, 3]] - x[quads[:, 1]]
    area = 0.5 * np.linalg.norm(np.cross(d1, d2), axis=1).sum()
    assert area == pytest.approx(SHAPES[shape][1], rel=5e-3)
    circles = SHAPES[shape][2]
    if circles:
        centre = tilt([0.0, 0.0, 0.0])[0]
        r = np.linalg.norm(x[boundary] - centre, axis=1)
        gap = np.min([np.abs(r - radius) for _, radius in circles], axis=0)
        assert gap.max() < 1e-9
        cad = summary["quads"]["cad"]
        assert cad["moved"] > 0 and cad["refused"] == 0


def test_same_quads_as_in_z0(runs):
    shape, (_, tilted), (_, flat) = runs
    assert flat["plane"] is None and flat["plane_note"] is None
    for key in ("quads", "vertices", "irregular_vertices", "patches", "arcs"):
        assert tilted["quads"][key] == flat["quads"][key], key
    assert tilted["quads"]["area"] == pytest.approx(flat["quads"]["area"], rel=1e-6)
    # The rectangle's triangles are the same; Gmsh triangulates the circles of the two
    # models (equal up to round-off) slightly differently: the worst quad differs by ~2e-3.
    worst = 1e-9 if shape == "rectangle" else 5e-3
    assert tilted["quads"]["min_sj"] == pytest.approx(flat["quads"]["min_sj"], abs=worst)
    assert tilted["quads"]["mean_sj"] == pytest.approx(flat["quads"]["mean_sj"],
                                                       abs=worst / 10)
