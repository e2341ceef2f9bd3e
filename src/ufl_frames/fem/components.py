r"""Connected components of a distributed mesh, as labels on a P1 space's dofs.

A domain of several pieces (two I-beams in one file, a part and its separate insert) makes
every problem with only natural boundary conditions singular once per piece: the
conformal scale's Poisson problem has one constant null vector per component, not one.
Each rank labels the components of its own part of the mesh (SciPy's ``csgraph``); a
ghost dof joins the local component that holds it to the owner's component of the same
dof; the few (local component, owner component) pairs are gathered on every rank and
merged by union–find, so that every rank ends with the same global numbering.
"""

from ufl_frames.bootstrap import init_petsc

init_petsc()

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402
from mpi4py import MPI  # noqa: E402
from scipy.sparse import csgraph  # noqa: E402

__all__ = ["dof_components"]


def _local_labels(cells: np.ndarray, count: int) -> tuple[int, np.ndarray]:
    """Components of the graph whose cliques are the rows of ``cells`` on ``count`` dofs."""
    if cells.size == 0:
        return count, np.arange(count, dtype=np.int64)
    k = cells.shape[1]
    rows = np.repeat(cells, k, axis=1).ravel()
    cols = np.tile(cells, (1, k)).ravel()
    graph = sp.csr_matrix((np.ones(rows.size, dtype=np.int8), (rows, cols)), shape=(count, count))
    n, labels = csgraph.connected_components(graph, directed=False)
    return int(n), labels.astype(np.int64)


def _find(parent: np.ndarray, i: int) -> int:
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


def dof_components(S) -> tuple[int, np.ndarray]:
    """The connected components of the mesh of the scalar P1 space ``S`` (collective).

    Returns:
        (count, labels): the number of components of the whole mesh, and per local dof
        (owned and ghost) its component in 0 … count − 1, numbered alike on every rank.
    """
    comm = S.mesh.comm
    index_map = S.dofmap.index_map
    owned, ghosts = index_map.size_local, index_map.num_ghosts
    cells = np.asarray(S.dofmap.list, dtype=np.int64)
    local_count, local = _local_labels(cells, owned + ghosts)
    offset = comm.exscan(local_count, op=MPI.SUM) if comm.size > 1 else 0
    offset = offset or 0
    label = local + offset
    total = comm.allreduce(local_count, op=MPI.SUM)
    pairs = np.zeros((0, 2), dtype=np.int64)
    if comm.size > 1 and comm.allreduce(ghosts, op=MPI.SUM):
        import dolfinx.fem as fem

        owner_label = fem.Function(S)
        owner_label.x.array[:owned] = label[:owned]
        owner_label.x.scatter_forward()
        theirs = np.rint(owner_label.x.array[owned:]).astype(np.int64)
        pairs = np.unique(np.stack([label[owned:], theirs], axis=1), axis=0)
    every = comm.allgather(pairs) if comm.size > 1 else [pairs]
    parent = np.arange(total, dtype=np.int64)
    for a, b in np.concatenate(every):
        ra, rb = _find(parent, int(a)), _find(parent, int(b))
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    roots = np.array([_find(parent, i) for i in range(total)], dtype=np.int64)
    unique, numbered = np.unique(roots, return_inverse=True)
    return int(unique.size), numbered[label]
