"""Quads of a square with a right-angled notch in one side: two 135° corners beside a 270°
tip (deal.II step-49's notch in small), at quad sizes larger than a third of the notch's
sides. Serial and MPI.

Truth, from the outline: [0, 2]² less the triangle (2, 0.5), (1.5, 1), (2, 1.5), area
4 − 1/4. Every corner is a vertex of a valid quad mesh whose boundary lies on the polygon,
so its area is the polygon's to round-off. Before, the 135° corners counted as smooth
joints a quad edge may span (135°/90° rounds to two quarter turns: the field takes the
boundary as straight), and a quad edge cut the corner off: greedy rounding's quads 0.6 %
short of the area, or none valid (a quad corner of SJ 0); and the field turns by 45° in a
135° corner's fan, one triangle wide here, which left the map a quad corner on the
straight side next to it (SJ 0; the TAO field at 0.5 and 0.3 refused). Now the corners
turn too much to be joints (:data:`~ufl_frames.param.features.SMOOTH_TURN`) and their
triangles take their other vertices' frames
(:func:`~ufl_frames.param.features.with_tie_corners`).
"""

import pytest

from ufl_frames.bootstrap import init_petsc

init_petsc([])  # not pytest's command line

from mpi4py import MPI  # noqa: E402

from ufl_frames.mesh import load  # noqa: E402
from ufl_frames.pipeline import FrameField  # noqa: E402
from ufl_frames.pipeline.stages import quadrangulate  # noqa: E402

COMM = MPI.COMM_WORLD

NOTCH = """Point(1) = {0, 0, 0}; Point(2) = {2, 0, 0}; Point(3) = {2, 0.5, 0};
Point(4) = {1.5, 1, 0}; Point(5) = {2, 1.5, 0}; Point(6) = {2, 2, 0}; Point(7) = {0, 2, 0};
Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 5}; Line(5) = {5, 6};
Line(6) = {6, 7}; Line(7) = {7, 1};
Curve Loop(1) = {1, 2, 3, 4, 5, 6, 7}; Plane Surface(1) = {1};
"""


@pytest.fixture(scope="module")
def notch(tmp_path_factory):
    folder = tmp_path_factory.mktemp("notch") if COMM.rank == 0 else None
    path = COMM.bcast(folder, root=0) / "notch.geo"
    if COMM.rank == 0:
        path.write_text(NOTCH)
    COMM.Barrier()
    return path


@pytest.mark.parametrize("conformal", [True, False], ids=["conformal", "tao"])
@pytest.mark.parametrize("quad_size", [0.5, 0.3])
def test_135_degree_corners_stay_quad_corners(notch, quad_size, conformal):
    domain = load(COMM, notch, quad_size, resolve_features=True)  # as `solve --quad-size`
    field = FrameField.initial(domain, isotropic=True)
    if conformal:
        field = field.conformal()
    else:
        field.solve(max_it=50)
    quality = quadrangulate(field, quad_size).quality  # raises where refused
    assert quality["valid"] and quality["problems"] == []
    assert quality["min_sj"] >= 0.3
    assert quality["area"] == pytest.approx(4 - 0.25, rel=1e-9)
