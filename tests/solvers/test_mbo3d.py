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
