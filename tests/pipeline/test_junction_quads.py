"""Quads of a square with a 60° notch whose 300° tip three interfaces leave (up, down,
right): deal.II step-49's slit tip in small, split 60° + 90° + 90° + 60° (4 quarter
turns by its sectors, 3 whole: index −1/4). Serial and MPI.

Truth, from the outline: each of the four regions is a quad-meshable polygon whose corner
at the tip is one quad corner, so a valid quad mesh keeps every interface as quad edges
(the stage's feature checks: every region's area, every curve's length, no quad across
an interface) and is valid by :func:`ufl_frames.quads.measures.check_quad_mesh`. Before
the triangles at the tip took the frames of their other vertices
(:func:`ufl_frames.param.cut.junction_frames`), the one-triangle 60° sectors took the
tip's cross (45° off the interfaces') and folded flat in the map: the stage refused.
"""

import math

import pytest

from ufl_frames.bootstrap import init_petsc

init_petsc([])  # not pytest's command line

from mpi4py import MPI  # noqa: E402

from ufl_frames.mesh import load  # noqa: E402
from ufl_frames.pipeline import FrameField  # noqa: E402
from ufl_frames.pipeline.stages import quadrangulate  # noqa: E402

COMM = MPI.COMM_WORLD
H = math.tan(math.radians(30))

# [0, 2]², the notch from (0, 1 ± tan 30°) to the tip (1, 1); the interfaces from the tip
# to (1, 2), (1, 0) and (2, 1)
NOTCH = """Point(1) = {1, 1, 0}; Point(2) = {2, 1, 0}; Point(3) = {2, 2, 0};
Point(4) = {1, 2, 0}; Point(5) = {0, 2, 0}; Point(6) = {0, %(up)r, 0};
Point(7) = {0, %(down)r, 0}; Point(8) = {0, 0, 0}; Point(9) = {1, 0, 0}; Point(10) = {2, 0, 0};
Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 1};
Line(5) = {4, 5}; Line(6) = {5, 6}; Line(7) = {6, 1};
Line(8) = {1, 7}; Line(9) = {7, 8}; Line(10) = {8, 9}; Line(11) = {9, 1};
Line(12) = {9, 10}; Line(13) = {10, 2};
Curve Loop(1) = {1, 2, 3, 4}; Plane Surface(1) = {1};
Curve Loop(2) = {-4, 5, 6, 7}; Plane Surface(2) = {2};
Curve Loop(3) = {8, 9, 10, 11}; Plane Surface(3) = {3};
Curve Loop(4) = {-11, 12, 13, -1}; Plane Surface(4) = {4};
""" % {"up": 1 + H, "down": 1 - H}


@pytest.fixture(scope="module")
def notch(tmp_path_factory):
    folder = tmp_path_factory.mktemp("notch") if COMM.rank == 0 else None
    path = COMM.bcast(folder, root=0) / "notch.geo"
    if COMM.rank == 0:
        path.write_text(NOTCH)
    COMM.Barrier()
    return path


@pytest.mark.parametrize("quad_size", [0.25, 0.125])
def test_interfaces_at_a_300_degree_slit_tip_stay_quad_edges(notch, quad_size):
    domain = load(COMM, notch, quad_size / 2)
    tip = [j for j in domain.junctions if math.dist((j.x, j.y), (1, 1)) < 1e-9]
    assert len(tip) == 1 and tip[0].index == -0.25
    field = FrameField.initial(domain, isotropic=True)
    field.solve(max_it=50)
    quality = quadrangulate(field, quad_size).quality  # raises where refused
    assert quality["valid"] and quality["problems"] == []
    assert quality["features"]["regions"] == 4
    assert quality["min_sj"] >= 0.3
    area = 4 - H  # the notch: base 2 tan 30°, depth 1
    assert quality["area"] == pytest.approx(area, rel=5e-3)
