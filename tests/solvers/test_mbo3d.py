"""MBO for 3D frame fields on tetrahedra (serial and under ``mpirun -n 2``): on a box the
frames are the axes, on a hollow cylinder they follow (r, θ, z), on a ball the singular
graph is closed or ends on the boundary; the results written for ParaView read back."""

import numpy as np
import pytest
from mpi4py import MPI

from ufl_frames.fem.gather import gather_p1_field
from ufl_frames.frames3d import odeco, singular
from ufl_frames.mesh import volumes
from ufl_frames.solvers.mbo3d import mbo_frame_field_3d

COMM = MPI.COMM_WORLD


def field_on_root(volume, **kwargs):
    q = mbo_frame_field_3d(volume, **kwargs)
    return gather_p1_field(q)


def test_box_frames_are_the_axes():
    x, cells, rows = field_on_root(volumes.box(COMM, (1.0, 0.7, 0.5), mesh_size=0.2))
    if COMM.rank:
        return
    lengths, R = odeco.q_to_frames(rows)
    assert np.abs(np.abs(R).max(axis=1) - 1).max() < 1e-10
    assert np.abs(lengths - 1).max() < 1e-10
    assert len(singular.singular_graph(cells, rows, x).edges) == 0


def test_hollow_cylinder_frames_follow_the_polar_axes():
    x, cells, rows = field_on_root(volumes.hollow_cylinder(COMM, mesh_size=0.15))
    if COMM.rank:
        return
    _, R = odeco.q_to_frames(rows)
    r = np.hypot(x[:, 0], x[:, 1])
    e_r = np.stack([x[:, 0] / r, x[:, 1] / r, np.zeros_like(r)], axis=1)
    assert (1 - np.abs(np.einsum("nij,ni->nj", R, e_r)).max(axis=1)).max() < 1e-3
    assert (1 - np.abs(R[:, 2, :]).max(axis=1)).max() < 1e-6  # one axis along z
    assert len(singular.singular_graph(cells, rows, x).edges) == 0


def test_ball_singular_graph_is_closed_or_ends_on_the_boundary(tmp_path_factory):
    x, cells, rows = field_on_root(volumes.ball(COMM, mesh_size=0.2))
    if COMM.rank:
        return
    graph = singular.singular_graph(cells, rows, x)
    assert len(graph.edges) > 0  # a boundary-aligned field on a ball must have some
    assert graph.open_ends.size == 0
    # boundary vertices are aligned with the sphere's normal
    on_boundary = singular.boundary_vertices(cells)
    _, R = odeco.q_to_frames(rows[on_boundary])
    n = x[on_boundary] / np.linalg.norm(x[on_boundary], axis=1)[:, None]
    assert (1 - np.abs(np.einsum("nij,ni->nj", R, n)).max(axis=1)).max() < 1e-10

    from ufl_frames.output.volume import write_volume_field
    from ufl_frames.output.vtk import read_vtk

    folder = tmp_path_factory.mktemp("ball")
    write_volume_field(folder, x, cells, rows, graph)
    frames = read_vtk(folder / "frames3d.vtu")
    assert frames["cells"].shape == cells.shape
    u1 = frames["point_data"]["u1"]
    assert np.allclose(np.linalg.norm(u1, axis=1), 1.0)
    lines = read_vtk(folder / "singular.vtu")
    assert lines["cells"].shape == graph.edges.shape
    assert (folder / "singular.png").stat().st_size > 10_000


def test_serial_and_parallel_fields_agree(tmp_path_factory):
    """The gathered field does not depend on the number of ranks (to the solver's
    tolerance): compared with a serial run on rank 0 of a fresh communicator."""
    volume = volumes.box(COMM, mesh_size=0.3)
    _, _, rows = field_on_root(volume)
    self_volume = volumes.box(MPI.COMM_SELF, mesh_size=0.3) if COMM.rank == 0 else None
    if COMM.rank:
        return
    _, _, alone = field_on_root(self_volume)
    assert np.abs(rows - alone).max() < 1e-9


def test_bad_volume_input_is_refused():
    from ufl_frames.mesh.domain import GeometryError

    with pytest.raises(GeometryError, match="not found"):
        volumes.load(COMM, "/nonexistent/part.step")


# A CAD part with fillets (OpenCASCADE): the plate [0, 1] × [0, 0.6] × [0, 0.3] with a
# vertical through hole (centre (0.4, 0.3), radius 0.12) and its two vertical edges at
# x = 1 rounded with radius 0.2 (axes at (0.8, 0.2) and (0.8, 0.4)).
FILLETED_PLATE_GEO = """SetFactory("OpenCASCADE");
Box(1) = {0, 0, 0, 1, 0.6, 0.3};
Cylinder(2) = {0.4, 0.3, -0.1, 0, 0, 0.5, 0.12};
BooleanDifference(3) = {Volume{1}; Delete;}{Volume{2}; Delete;};
e() = Curve In BoundingBox{0.99, -0.01, -0.01, 1.01, 0.01, 0.31};
e() += Curve In BoundingBox{0.99, 0.59, -0.01, 1.01, 0.61, 0.31};
Fillet{3}{e()}{0.2}
"""


def plate_normals(x: np.ndarray, tol: float = 1e-6) -> list[list[np.ndarray]]:
    """The exact unit normals of the filleted plate's surfaces through each point of
    ``x`` (n, 3): none inside, one on a face, two or three on a sharp edge or corner."""
    out = []
    for p in x:
        ns = []
        if abs(p[2]) < tol or abs(p[2] - 0.3) < tol:  # bottom, top
            ns.append(np.array([0.0, 0.0, 1.0]))
        xy = p[:2]
        for centre, radius, inside in (((0.4, 0.3), 0.12, None),  # the hole
                                       ((0.8, 0.2), 0.2, lambda q: q[0] > 0.8 and q[1] < 0.2),
                                       ((0.8, 0.4), 0.2, lambda q: q[0] > 0.8 and q[1] > 0.4)):
            d = xy - np.array(centre)
            if abs(np.linalg.norm(d) - radius) < tol and (inside is None or inside(xy)):
                ns.append(np.array([*(d / radius), 0.0]))
        if abs(p[0]) < tol or (abs(p[0] - 1) < tol and 0.2 <= p[1] <= 0.4):
            ns.append(np.array([1.0, 0.0, 0.0]))
        if (abs(p[1]) < tol or abs(p[1] - 0.6) < tol) and p[0] <= 0.8:
            ns.append(np.array([0.0, 1.0, 0.0]))
        # a fillet meets its planes tangentially: keep one of equal normals
        distinct = []
        for n in ns:
            if all(abs(n @ m) < 1 - 1e-9 for m in distinct):
                distinct.append(n)
        out.append(distinct)
    return out


@pytest.fixture(scope="module")
def filleted_plate(tmp_path_factory):
    path = None
    if COMM.rank == 0:
        path = tmp_path_factory.mktemp("filleted") / "plate.geo"
        path.write_text(FILLETED_PLATE_GEO)
    return COMM.bcast(str(path) if path else None, root=0)


def test_filleted_part_follows_its_cad_normals(filleted_plate):
    """On a CAD part with fillets, a hole and sharp edges: every boundary vertex's frame
    has an axis along each exact surface normal there (one on a face or across a fillet's
    tangent edge, two on a sharp edge: one axis along the edge), the loader holds exactly
    the vertices on sharp edges, and the singular curves end on the boundary."""
    from ufl_frames.fem.gather import input_node_order

    volume = volumes.load(COMM, filleted_plate, mesh_size=0.1)
    q = mbo_frame_field_3d(volume)
    (_, _), (features, _) = volume.boundary_frames(q.function_space)
    held = np.unique(np.concatenate(COMM.allgather(input_node_order(q.function_space)[features])))
    x, cells, rows = gather_p1_field(q)
    if COMM.rank:
        return
    normals = plate_normals(x)
    on_boundary = singular.boundary_vertices(cells)
    counts = np.array([len(ns) for ns in normals])
    assert np.array_equal(counts > 0, on_boundary)  # the exact surfaces are the boundary
    assert np.count_nonzero(counts == 1) > 100 and np.count_nonzero(counts >= 2) > 20
    assert np.array_equal(held, np.flatnonzero(counts >= 2))  # sharp edges and corners
    _, R = odeco.q_to_frames(rows)
    worst = max(1 - np.abs(R[i].T @ n).max() for i in np.flatnonzero(on_boundary)
                for n in normals[i])
    assert worst < 1e-9
    graph = singular.singular_graph(cells, rows, x)
    assert len(graph.edges) > 0  # the hole and the two fillets call for singular curves
    assert graph.open_ends.size == 0
    assert on_boundary[graph.edges.ravel()].any()  # some end on the boundary


def test_filleted_part_serial_and_parallel_agree(filleted_plate):
    """The same singular edges and the same frames (up to the cube's symmetry, to the
    solver's tolerance) on this communicator and on one process."""
    _, _, rows = field_on_root(volumes.load(COMM, filleted_plate, mesh_size=0.1))
    alone = (volumes.load(MPI.COMM_SELF, filleted_plate, mesh_size=0.1)
             if COMM.rank == 0 else None)
    if COMM.rank:
        return
    x, cells, alone_rows = field_on_root(alone)
    assert np.abs(rows - alone_rows).max() < 1e-8
    mine = singular.singular_graph(cells, rows, x)
    theirs = singular.singular_graph(cells, alone_rows, x)
    assert len(mine.edges) > 0
    assert np.array_equal(mine.edges, theirs.edges)
