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


JUNCTION = (0.42, 0.24)  # off the centroid (0.5, 0.289), where a free field's singularity is


def kites_of_a_triangle() -> str:
    """Built-in kernel: the equilateral triangle (0, 0), (1, 0), (1/2, √3/2) cut into three
    regions by the perpendiculars from :data:`JUNCTION` to its sides, which meet at 120°
    there (and the sides at 90°)."""
    r = math.sqrt(3)
    g = np.array(JUNCTION)
    b, along_bc, along_ca = np.array([1.0, 0.0]), np.array([-0.5, r / 2]), np.array([0.5, r / 2])
    feet = [(g[0], 0.0), tuple(b + ((g - b) @ along_bc) * along_bc),
            tuple((g @ along_ca) * along_ca)]
    p = {1: (0, 0), 2: (1, 0), 3: (0.5, r / 2), 4: feet[0], 5: feet[1], 6: feet[2], 7: g}
    lines = [f"Point({k}) = {{{float(x)!r}, {float(y)!r}, 0}};" for k, (x, y) in p.items()]
    segments = {1: (1, 4), 2: (4, 2), 3: (2, 5), 4: (5, 3), 5: (3, 6), 6: (6, 1),
                7: (7, 4), 8: (7, 5), 9: (7, 6)}
    lines += [f"Line({k}) = {{{a}, {b}}};" for k, (a, b) in segments.items()]
    lines += ["Curve Loop(1) = {1, -7, 9, 6}; Plane Surface(1) = {1};",
              "Curve Loop(2) = {3, -8, 7, 2}; Plane Surface(2) = {2};",
              "Curve Loop(3) = {5, -9, 8, 4}; Plane Surface(3) = {3};"]
    return "\n".join(lines) + "\n"


def test_three_interfaces_at_120_degrees_force_a_quarter_singularity(tmp_path):
    domain = load(COMM, write(tmp_path, "kites.geo", kites_of_a_triangle()), 0.03)
    inside = [j for j in domain.junctions if not j.on_boundary]
    assert len(inside) == 1 and (inside[0].x, inside[0].y) == pytest.approx(JUNCTION)
    assert inside[0].sectors == pytest.approx((2 * math.pi / 3,) * 3)
    assert inside[0].index == 0.25
    boundary = [j for j in domain.junctions if j.on_boundary]
    assert len(boundary) == 3 and all(j.index == 0 for j in boundary)  # 90° at the sides
    assert len(domain.corners) == 3
    field = FrameField.initial(domain, isotropic=True)
    check = field.index_theorem()
    assert check["expected"] == 0.25 and check["agrees"]  # three 60° corners
    assert check["junction_index"] == 0.25
    # the field is aligned to the three interfaces: its one singularity is at the junction
    assert [s["index"] for s in field.singularities] == [0.25]
    (s,) = field.singularities
    assert math.dist((s["x"], s["y"]), JUNCTION) < 0.03
