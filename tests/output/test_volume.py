"""ufl_frames.output.volume: the outline drawn around the singular graph (the sharp edges
of a tetrahedral mesh's boundary) on shapes whose edges are known exactly. Each rank works
on its own serial mesh (also under ``mpirun -n 2``)."""

import numpy as np
from mpi4py import MPI

from ufl_frames.mesh import volumes
from ufl_frames.output.volume import outline


def serial_arrays(volume):
    mesh = volume.mesh
    cells = mesh.topology.connectivity(3, 0).array.reshape(-1, 4)
    return mesh.geometry.x, cells


def test_outline_of_a_box_is_its_twelve_edges():
    x, cells = serial_arrays(volumes.box(MPI.COMM_SELF, (1.0, 0.7, 0.5), mesh_size=0.2))
    edges = outline(x, cells)
    extreme = np.isclose(x, 0) | np.isclose(x, [1.0, 0.7, 0.5])
    # an edge of the box: both ends have two extreme coordinates, the same two
    both = extreme[edges[:, 0]] & extreme[edges[:, 1]]
    assert np.all(both.sum(axis=1) == 2)
    # and every mesh edge along the box's edges is found: their lengths add up to 4 × (a+b+c)
    length = np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1).sum()
    assert abs(length - 4 * (1.0 + 0.7 + 0.5)) < 1e-9


def test_outline_of_a_ball_is_empty_and_a_cylinder_has_its_rims():
    x, cells = serial_arrays(volumes.ball(MPI.COMM_SELF, mesh_size=0.2))
    assert outline(x, cells).shape == (0, 2)
    x, cells = serial_arrays(volumes.hollow_cylinder(MPI.COMM_SELF, mesh_size=0.15))
    edges = outline(x, cells)
    ends = x[edges]  # (k, 2, 3)
    r = np.hypot(ends[..., 0], ends[..., 1])
    on_rim = (np.isclose(ends[..., 2], 0) | np.isclose(ends[..., 2], 1.0)) & (
        np.isclose(r, 0.5, atol=1e-9) | np.isclose(r, 1.0, atol=1e-9))
    assert on_rim.all()
    # the four rims' polygons: close to 2π (0.5 + 1) × 2 in length
    length = np.linalg.norm(ends[:, 0] - ends[:, 1], axis=1).sum()
    assert abs(length - 2 * np.pi * 1.5 * 2) < 0.02 * length
