"""Corners under 45° (issue 37: Gmsh's "fleur"): a quad corner squeezed, not a flat one.

Truth: a box around two disks that meet at 27° cusps. Its Poincaré–Hopf sum, with every
corner at least one quarter turn, is χ − Σ(2 − k)/4 = 0 − 4/4 − 2/4 = −1.5; the cusps
must be quad vertices of two edges (one quad each, valence k + 1 = 2), and the quads valid
by the independent checks of :func:`ufl_frames.quads.measures.check_quad_mesh`. Before
the rule a cusp rounded to 0 quarter turns: the field left a −1/4 singular vertex in each
gap, the map folded around it ("3 axis directions in its fan") and no quad size worked.
"""

from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from ufl_frames.mesh import load
from ufl_frames.pipeline import FrameField
from ufl_frames.pipeline.stages import RootField, quadrangulate

COMM = MPI.COMM_WORLD

#: Disks of radius 0.5 with centres 2 · 0.5 · sin(76.5°) apart meet at 180° − 153° = 27°.
CUSPS = """SetFactory("OpenCASCADE");
Rectangle(1) = {-1.5, -1, 0, 3, 2};
Disk(2) = {-0.48624, 0, 0, 0.5};
Disk(3) = {0.48624, 0, 0, 0.5};
BooleanDifference(4) = { Surface{1}; Delete; }{ Surface{2, 3}; Delete; };
"""


def test_cusps_of_27_degrees_are_squeezed_quad_corners(tmp_path):
    from ufl_frames.quads.measures import vertex_valence

    path = Path(COMM.bcast(str(tmp_path), root=0)) / "cusps.geo"
    if COMM.rank == 0:
        path.write_text(CUSPS)
    COMM.barrier()
    domain = load(COMM, path, 0.05)
    cusps = [c for c in domain.corners if c.angle < np.pi / 4]
    assert len(cusps) == 2 and all(np.degrees(c.angle) == pytest.approx(27, abs=0.1)
                                   for c in cusps)
    field = FrameField.initial(domain, isotropic=True).conformal()
    check = field.index_theorem()
    assert check["expected"] == -1.5 and check["agrees"]
    root = RootField(field)
    if COMM.rank == 0:  # each gap's −1/4 singular vertex moved into its cusp
        assert len(root.corners.absorbed) == 2 and root.corners.kept == ()
    quads = quadrangulate(root, 0.15)
    quality = quads.quality
    assert quality["valid"] and quality["problems"] == []
    assert quality["min_sj"] >= 0.3 and quality["area_error"] < 0.01
    if COMM.rank == 0:
        points, cells = quads.mesh.points[:, :2], quads.mesh.quads
        valence = vertex_valence(points, cells)["valence"]
        for c in cusps:
            at = np.linalg.norm(points - [c.x, c.y], axis=1)
            assert at.min() < 1e-9 and valence[np.argmin(at)] == 2


#: Two of Gmsh's fleur's petals (ellipses 0.71 × 0.145 from the origin, 30° apart) cut out
#: of a box: one 23.6° cusp between them, and tips bent with a radius of 0.03, where the
#: field's −1/4 singular vertices sit 0.01–0.04 off the boundary.
PETALS = """SetFactory("OpenCASCADE");
Rectangle(1) = {-1, -1, 0, 3, 3};
Disk(2) = {0.71, 0, 0, 0.71, 0.145};
Disk(3) = {0.71, 0, 0, 0.71, 0.145};
Rotate {{0, 0, 1}, {0, 0, 0}, Pi/6} { Surface{3}; }
BooleanUnion(4) = { Surface{2}; Delete; }{ Surface{3}; Delete; };
BooleanDifference(5) = { Surface{1}; Delete; }{ Surface{4}; Delete; };
Mesh.MeshSizeFromCurvature = 15;
Mesh.MeshSizeMax = 0.1;
"""


def test_singular_vertices_at_the_petals_tips_are_glued_to_the_boundary(tmp_path):
    """Before, the −1/4 next to each tip stayed a sliver off the boundary and its
    separatrix ran along the petal to the cusp: the layout made quads of no width there
    (SJ ≤ 0 or non-positive area at quad sizes 0.3, 0.2, 0.15) and greedy rounding
    folded. Now they are moved onto the boundary (``stages.GLUE_WITHIN``)."""
    from ufl_frames.quads.measures import vertex_valence

    path = Path(COMM.bcast(str(tmp_path), root=0)) / "petals.geo"
    if COMM.rank == 0:
        path.write_text(PETALS)
    COMM.barrier()
    domain = load(COMM, path)
    cusps = [c for c in domain.corners if c.angle < np.pi / 4]
    assert len(cusps) == 1 and np.degrees(cusps[0].angle) == pytest.approx(23.6, abs=0.3)
    field = FrameField.initial(domain, isotropic=True).conformal()
    quads = quadrangulate(RootField(field), 0.2)
    quality = quads.quality
    assert quality["valid"] and quality["problems"] == []
    assert quality["quantisation"] == "layout" and quality["cancelled_singularities"] >= 2
    assert quality["min_sj"] >= 0.3 and quality["area_error"] < 0.005
    if COMM.rank == 0:
        points, cells = quads.mesh.points[:, :2], quads.mesh.quads
        at = np.linalg.norm(points - [cusps[0].x, cusps[0].y], axis=1)
        assert at.min() < 1e-9 and vertex_valence(points, cells)["valence"][np.argmin(at)] == 2
