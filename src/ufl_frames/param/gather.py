"""A distributed P1 frame field gathered onto one rank as global arrays (collective).

The cut graph and the seamless map are global problems on a 2D mesh (their cost is that of
one sparse solve); :func:`gather_field` collects the vertex coordinates, the triangles and
the frame of every vertex, numbered by the mesh's input node indices, on rank 0.
"""

from ufl_frames.bootstrap import init_petsc

init_petsc()

import numpy as np  # noqa: E402

from ufl_frames.fem.gather import gather_rows  # noqa: E402
from ufl_frames.frames2d import odeco  # noqa: E402

__all__ = ["gather_field"]


def gather_field(q, root: int = 0):
    """(x (n, 2), cells (m, 3), q (n, 5)) of the P1 field ``q`` on rank ``root``, in input
    node order with unused numbers dropped; (None, None, None) on the other ranks."""
    V = q.function_space
    mesh = V.mesh
    if mesh.topology.dim != 2 or V.dofmap.index_map_bs != odeco.NUM_COEFFICIENTS:
        raise ValueError("gather_field needs a P1 frame field (5 coefficients) on triangles")
    comm = mesh.comm
    owned = mesh.topology.index_map(2).size_local
    nodes = mesh.geometry.dofmaps[0][:owned]  # geometry nodes of the owned cells
    ids = np.asarray(mesh.geometry.input_global_indices, dtype=np.int64)
    rows = q.x.array.reshape(-1, odeco.NUM_COEFFICIENTS)
    dofs = V.dofmap.list[:owned]  # P1: a cell's dofs are its vertices, in node order
    cells = gather_rows(comm, ids[nodes], root=root)
    x_all = gather_rows(comm, mesh.geometry.x[nodes.ravel(), :2], root=root)
    q_all = gather_rows(comm, rows[dofs.ravel()], root=root)
    if comm.rank != root:
        return None, None, None
    flat = cells.ravel()
    numbers, first, inverse = np.unique(flat, return_index=True, return_inverse=True)
    return x_all[first], inverse.reshape(-1, 3), q_all[first]
