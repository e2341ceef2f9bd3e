"""Rows of a distributed array gathered onto one rank (collective).

Every rank holds some rows of one array (P1 rows of its owned vertices, points it found,
facets of its boundary); :func:`gather_rows` puts them together on one rank, either one
rank's rows after the other's (the order of the ranks) or each row at its global index.
For P1 data the global index is the mesh's input node index (:func:`input_node_order`):
the order of rank 0's Gmsh mesh, the same whatever the number of processes.
"""

import numpy as np

__all__ = ["gather_p1_field", "gather_rows", "input_node_order"]


def input_node_order(V) -> np.ndarray:
    """Input node index of every local dof (owned and ghost) of the P1 space ``V``."""
    geometry = V.mesh.geometry
    nodes = np.asarray(geometry.input_global_indices, dtype=np.int64)
    index_map = V.dofmap.index_map
    order = np.full(index_map.size_local + index_map.num_ghosts, -1, dtype=np.int64)
    # P1: the dofs of a cell are its vertices, in the order of its geometry nodes.
    order[V.dofmap.list.ravel()] = nodes[geometry.dofmaps[0].ravel()]
    return order


def gather_rows(comm, rows: np.ndarray, index: np.ndarray | None = None,
                size: int | None = None, root: int = 0) -> np.ndarray | None:
    """The ``rows`` of every rank of ``comm`` on rank ``root`` (None elsewhere; collective).

    Args:
        comm: the communicator.
        rows: this rank's rows (k, ...); the trailing shape is the same on every rank.
        index: None: the ranks' rows one after the other, in rank order. Otherwise the
            global index (k,) of each row: the result has row ``index[i]`` = ``rows[i]``
            (a row given by several ranks is the last rank's; rows given by none are 0).
        size: with ``index``, the number of rows of the result (default: the largest
            index + 1).
        root: the rank that receives the result.

    Returns:
        The gathered array on ``root``, with the dtype of ``root``'s ``rows``; None on
        the other ranks.
    """
    if index is None:
        parts = comm.gather(np.ascontiguousarray(rows), root=root)
        return np.concatenate(parts) if comm.rank == root else None
    rows = np.asarray(rows)
    parts = comm.gather((index, rows), root=root)
    if comm.rank != root:
        return None
    if size is None:
        size = int(max(int(np.max(i, initial=-1)) for i, _ in parts) + 1)
    out = np.zeros((size, *rows.shape[1:]), dtype=rows.dtype)
    for where, part in parts:
        out[where] = part
    return out


def gather_p1_field(q, root: int = 0):
    """(x (n, gdim), cells (m, k), rows (n, count)) of the P1 vector field ``q`` on rank
    ``root``, numbered by input node index (the whole mesh's; collective), (None, None,
    None) elsewhere. Every input node is a vertex of a simplex mesh of degree 1."""
    V = q.function_space
    mesh = V.mesh
    comm = mesh.comm
    tdim = mesh.topology.dim
    order = input_node_order(V)
    owned_cells = mesh.topology.index_map(tdim).size_local
    count = V.dofmap.index_map_bs
    ids = np.asarray(mesh.geometry.input_global_indices, dtype=np.int64)
    cells = gather_rows(comm, ids[mesh.geometry.dofmaps[0][:owned_cells]], root=root)
    from mpi4py import MPI

    size = comm.allreduce(int(order.max(initial=-1)) + 1, op=MPI.MAX)
    x = gather_rows(comm, mesh.geometry.x[:, :tdim][_row_nodes(V)], index=order, size=size,
                    root=root)
    rows = gather_rows(comm, q.x.array.reshape(-1, count), index=order, size=size, root=root)
    return x, cells, rows


def _row_nodes(V) -> np.ndarray:
    """The geometry node of every local dof of the P1 space ``V``."""
    geometry = V.mesh.geometry
    index_map = V.dofmap.index_map
    node = np.zeros(index_map.size_local + index_map.num_ghosts, dtype=np.int64)
    node[V.dofmap.list.ravel()] = geometry.dofmaps[0].ravel()
    return node
