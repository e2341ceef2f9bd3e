"""The frame field aligned to curves inside the domain: an interface between two regions
(a circle) and a curve embedded in a surface hold the cross like the boundary does, in
the constraints, the MBO field, the TAO solve and the conformal field. Serial and MPI.

Truth: the interface is the circle |x − c| = r, whose tangent at a node is e_θ about c;
the embedded curve a straight segment of known direction.
"""

import math

import numpy as np
import pytest

from ufl_frames.bootstrap import init_petsc

init_petsc([])  # not pytest's command line

from mpi4py import MPI  # noqa: E402

from ufl_frames.fem.constraints import Fixed  # noqa: E402
from ufl_frames.frames2d import odeco  # noqa: E402
from ufl_frames.mesh import load  # noqa: E402
from ufl_frames.pipeline import FrameField  # noqa: E402

COMM = MPI.COMM_WORLD
CENTRE, RADIUS = (1.0, 0.5), 0.3

# A disc region inside a rectangle region: the circle is their interface.
DISC_IN_RECTANGLE = f"""SetFactory("OpenCASCADE");
Rectangle(1) = {{0, 0, 0, 2, 1}};
Disk(2) = {{{CENTRE[0]}, {CENTRE[1]}, 0, {RADIUS}}};
BooleanFragments{{ Surface{{1}}; Delete; }}{{ Surface{{2}}; Delete; }}
"""

# A segment at 30° embedded in a square.
ANGLE = math.radians(30)
EMBEDDED = f"""SetFactory("OpenCASCADE");
Rectangle(1) = {{0, 0, 0, 2, 2}};
Point(10) = {{0.5, 0.6, 0}};
Point(11) = {{{0.5 + math.cos(ANGLE)}, {0.6 + math.sin(ANGLE)}, 0}};
Line(20) = {{10, 11}};
Curve{{20}} In Surface{{1}};
"""


def write(tmp_path, name, text):
    path = tmp_path / name
    if COMM.rank == 0:
        path.write_text(text)
    COMM.Barrier()
    return path


def misalignment(q, rows, tangent) -> float:
    """max |e^{4iθ} − e^{4iψ}| over ``rows`` (all ranks): θ the field's cross angle, ψ the
    curve's tangent angle."""
    _, theta = odeco.q_to_frames(q.x.array.reshape(-1, 5)[rows])
    psi = np.arctan2(tangent[:, 1], tangent[:, 0])
    local = float(np.abs(np.exp(4j * theta) - np.exp(4j * psi)).max(initial=0.0))
    return COMM.allreduce(local, op=MPI.MAX)


def on_circle(field):
    """The local rows on the interface circle and its tangent there."""
    x = field.q.function_space.tabulate_dof_coordinates()[:, :2]
    d = x - np.array(CENTRE)
    rows = np.flatnonzero(np.abs(np.hypot(d[:, 0], d[:, 1]) - RADIUS) < 1e-9)
    return rows, np.stack([-d[rows, 1], d[rows, 0]], axis=1)


@pytest.fixture(scope="module")
def disc_field(tmp_path_factory):
    folder = tmp_path_factory.mktemp("interface") if COMM.rank == 0 else None
    folder = COMM.bcast(folder, root=0)
    domain = load(COMM, write(folder, "disc.geo", DISC_IN_RECTANGLE), 0.08)
    return FrameField.initial(domain, isotropic=False)


def test_interface_rows_are_prescribed_along_the_circle(disc_field):
    rows, tangent = on_circle(disc_field)
    assert COMM.allreduce(rows.size, op=MPI.SUM) >= 20
    c = disc_field.constraints
    prescribed = c.fixed_as(Fixed.PRESCRIBED)
    assert set(rows.tolist()) == set(prescribed.tolist())  # the circle, and nothing else
    direction = c.directions[c.kind == Fixed.PRESCRIBED][np.argsort(prescribed)]
    tangent = tangent[np.argsort(rows)]
    psi = np.arctan2(direction[:, 1], direction[:, 0])
    want = np.arctan2(tangent[:, 1], tangent[:, 0])
    # the CAD tangent, exact to the node positions Gmsh writes
    assert np.abs(np.exp(4j * psi) - np.exp(4j * want)).max(initial=0) < 1e-8


def test_mbo_solve_and_conformal_fields_are_tangent_to_the_interface(disc_field):
    rows, tangent = on_circle(disc_field)
    assert misalignment(disc_field.q, rows, tangent) < 1e-8  # the MBO field
    disc_field.solve(max_it=5)
    assert misalignment(disc_field.q, rows, tangent) < 1e-8  # after TAO steps
    conformal = disc_field.conformal()
    assert misalignment(conformal.q, rows, tangent) < 1e-8
    # the interface is no boundary: the field's singularities still sum as for a rectangle
    assert disc_field.index_theorem()["agrees"]
    assert disc_field.index_theorem()["junction_index"] == 0.0


def test_embedded_curve_aligns_the_field(tmp_path):
    domain = load(COMM, write(tmp_path, "embedded.geo", EMBEDDED), 0.1)
    field = FrameField.initial(domain, isotropic=True)
    x = field.q.function_space.tabulate_dof_coordinates()[:, :2]
    d = x - np.array([0.5, 0.6])
    along = d[:, 0] * math.cos(ANGLE) + d[:, 1] * math.sin(ANGLE)
    across = -d[:, 0] * math.sin(ANGLE) + d[:, 1] * math.cos(ANGLE)
    rows = np.flatnonzero((np.abs(across) < 1e-9) & (along > -1e-9) & (along < 1 + 1e-9))
    assert COMM.allreduce(rows.size, op=MPI.SUM) >= 10
    tangent = np.tile([math.cos(ANGLE), math.sin(ANGLE)], (rows.size, 1))
    assert misalignment(field.q, rows, tangent) < 1e-8
    # far from the curve the cross is free: the field differs from the 30° cross there
    free = np.flatnonzero(np.abs(across) > 0.3)
    _, theta = odeco.q_to_frames(field.q.x.array.reshape(-1, 5)[free])
    worst = COMM.allreduce(float(np.abs(np.exp(4j * theta) - np.exp(4j * ANGLE)).max(
        initial=0.0)), op=MPI.MAX)
    assert worst > 0.1
