r"""The singular graph of a 3D frame field on tetrahedra.

A frame is defined up to the 24 rotations of the cube (the octahedral group O). Between
two tetrahedra that share a face the frames are matched by the element g of O closest to
R_aᵀ R_b (R the tetrahedra's frame rotations). Going once around an interior edge, the
product of the matchings is the edge's monodromy: the identity on a regular edge, a
quarter turn (index ±1/4) or a half turn on a singular one. A boundary-aligned smooth
field has singular curves, not points: the singular edges form chains that are closed
or end on the boundary (or meet at nodes of the graph).

Pure NumPy; the field is given per vertex (P1) and read per tetrahedron as the frame
closest to the mean of its vertices' coefficients.
"""

from dataclasses import dataclass
from itertools import permutations, product

import numpy as np

from ufl_frames.frames3d import odeco

__all__ = ["OCTAHEDRAL", "SingularGraph", "singular_graph"]


def _octahedral_group() -> np.ndarray:
    """The 24 rotations (24, 3, 3) that map the coordinate axes onto themselves."""
    out = []
    for perm in permutations(range(3)):
        for signs in product((1.0, -1.0), repeat=3):
            g = np.zeros((3, 3))
            g[list(range(3)), list(perm)] = signs
            if np.linalg.det(g) > 0:
                out.append(g)
    return np.array(out)


#: The octahedral group O (24, 3, 3); element 0 is the identity.
OCTAHEDRAL = _octahedral_group()
assert np.allclose(OCTAHEDRAL[0], np.eye(3))


def closest_symmetry(M: np.ndarray) -> np.ndarray:
    """Index (N,) into :data:`OCTAHEDRAL` of the element closest to each M (N, 3, 3)."""
    return np.argmax(np.einsum("gij,nij->ng", OCTAHEDRAL, M), axis=1)


@dataclass(frozen=True)
class SingularGraph:
    """The singular edges of a field: ``edges`` (k, 2) vertex pairs, ``turn`` (k,) the
    monodromy's angle in quarter turns (1: a quarter turn, 2: a half turn, 3: three
    quarters), ``chains`` (k,) the connected component of each edge, ``open_ends``
    the graph's vertices of degree 1 inside the domain (a valid field has none), and
    ``boundary_edges`` the number of edges on the boundary (not examined)."""

    edges: np.ndarray
    turn: np.ndarray
    chains: np.ndarray
    open_ends: np.ndarray
    boundary_edges: int

    @property
    def num_chains(self) -> int:
        return int(self.chains.max()) + 1 if self.chains.size else 0


def cell_rotations(cells: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The frame rotation (m, 3, 3) of each tetrahedron: of the frame closest to the mean
    of its vertices' coefficients."""
    mean = q[cells[:, 0]]  # summed vertex by vertex: q[cells] would hold (m, 4, 15)
    for k in range(1, cells.shape[1]):
        mean += q[cells[:, k]]
    return odeco.q_to_frames(mean / cells.shape[1])[1]


def singular_graph(cells: np.ndarray, q: np.ndarray, x: np.ndarray | None = None) -> SingularGraph:
    """The singular graph of the P1 frame field ``q`` (n, 15) on the tetrahedra ``cells``
    (m, 4).

    Around every edge (a, b) the tetrahedra are ordered by orienting each one's other two
    vertices (c, d) so that (a, b, c, d) is positive: the next one around the edge has
    c' = d. The monodromy is the product of the matchings in that order, composed in the
    group's multiplication table (all edges at once). Where the cycle does not close the
    edge lies on the boundary and is not examined.

    Args:
        cells: vertex indices (m, 4).
        q: the frame coefficients at the vertices (n, 15).
        x: the vertex coordinates (n, 3), to orient the cells (None: they are taken as
            positively oriented, as :func:`orient` makes them).

    Returns:
        The :class:`SingularGraph`.
    """
    cells = np.asarray(cells, dtype=np.int64)
    if x is not None:
        cells = orient(cells, np.asarray(x, dtype=np.float64))
    R = cell_rotations(cells, np.asarray(q, dtype=np.float64))
    n = int(cells.max()) + 1
    m = cells.shape[0]
    # the six edges of a positive tetrahedron (0, 1, 2, 3), each with its other two
    # vertices in the order that keeps (a, b, c, d) positive
    local = np.array([(0, 1, 2, 3), (0, 2, 3, 1), (0, 3, 1, 2), (1, 2, 0, 3), (1, 3, 2, 0),
                      (2, 3, 0, 1)])
    a, b, c, d = (cells[:, local[:, k]].ravel() for k in range(4))
    flip = a > b  # (b, a, d, c) is as positive as (a, b, c, d)
    a, b = np.where(flip, b, a), np.where(flip, a, b)
    c, d = np.where(flip, d, c), np.where(flip, c, d)
    # the next incidence around the edge: the one of the same edge whose c is this d (the
    # 6m-long arrays are dropped as soon as they are used: at 10⁶ tetrahedra each is 48 MB;
    # keys edge number · n + vertex stay below 6m·n, far from int64's end)
    edges, first, edge_id = np.unique(a * n + b, return_index=True, return_inverse=True)
    del a, b, flip
    key_c = edge_id * n + c
    del c
    order = np.argsort(key_c)
    sorted_c = key_c[order]
    del key_c
    wanted = edge_id * n + d
    del d, edge_id
    pos = np.minimum(np.searchsorted(sorted_c, wanted), order.size - 1)
    nxt = np.where(sorted_c[pos] == wanted, order[pos], -1)
    del sorted_c, wanted, pos, order
    match = np.full(nxt.size, -1, dtype=np.int64)
    ok = np.flatnonzero(nxt >= 0)
    match[ok] = _matchings(R, ok // 6, nxt[ok] // 6)  # incidence k is in tetrahedron k // 6
    del ok
    G = np.zeros(first.size, dtype=np.int64)  # the identity
    cur = first.copy()
    closed = np.zeros(first.size, dtype=bool)
    open_ring = np.zeros(first.size, dtype=bool)
    for _ in range(m + 1):
        idx = np.flatnonzero(~(closed | open_ring))
        if idx.size == 0:
            break
        step = match[cur[idx]]
        open_ring[idx[step < 0]] = True
        idx, step = idx[step >= 0], step[step >= 0]
        G[idx] = _PRODUCT[G[idx], step]
        cur[idx] = nxt[cur[idx]]
        closed[idx] = cur[idx] == first[idx]
    singular_edge = closed & (G != 0)
    pairs = np.stack([edges // n, edges % n], axis=1)[singular_edge]
    turns = np.rint(_ANGLE[G[singular_edge]] / (np.pi / 2)).astype(np.int64)
    chains = _components(pairs)
    on_boundary = boundary_vertices(cells)
    degree = np.bincount(pairs.ravel(), minlength=n)
    open_ends = np.flatnonzero((degree == 1) & ~on_boundary)
    return SingularGraph(edges=pairs, turn=turns, chains=chains, open_ends=open_ends,
                         boundary_edges=int(np.count_nonzero(~closed)))


#: Incidences matched per chunk: the relative rotations and their 24 scores are built a
#: chunk at a time (at 10⁶ tetrahedra, 6·10⁶ at once took about 1.7 GB).
_CHUNK = 1 << 17


def _matchings(R: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Index (k,) into :data:`OCTAHEDRAL` of the element closest to R_iᵀ R_j for each pair
    of tetrahedra (i, j) (k,), chunk by chunk."""
    out = np.empty(i.size, dtype=np.int64)
    for start in range(0, i.size, _CHUNK):
        rows = slice(start, start + _CHUNK)
        out[rows] = closest_symmetry(np.einsum("nji,njk->nik", R[i[rows]], R[j[rows]]))
    return out


def orient(cells: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The tetrahedra with two vertices swapped where their volume is negative."""
    e = x[cells[:, 1:]] - x[cells[:, [0]]]
    negative = np.einsum("ni,ni->n", e[:, 0], np.cross(e[:, 1], e[:, 2])) < 0
    return np.where(negative[:, None], cells[:, [0, 2, 1, 3]], cells)


#: Multiplication table of :data:`OCTAHEDRAL` (g_i g_j = g_k, k = _PRODUCT[i, j]) and
#: the rotation angle of each element.
_PRODUCT = np.array([[int(np.argmax(np.einsum("gij,ij->g", OCTAHEDRAL, gi @ gj)))
                      for gj in OCTAHEDRAL] for gi in OCTAHEDRAL])
_ANGLE = np.arccos(np.clip((np.trace(OCTAHEDRAL, axis1=1, axis2=2) - 1) / 2, -1, 1))


def _components(edges: np.ndarray) -> np.ndarray:
    if edges.size == 0:
        return np.zeros(0, dtype=np.int64)
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    nodes, inverse = np.unique(edges, return_inverse=True)
    inverse = inverse.reshape(-1, 2)
    graph = coo_matrix((np.ones(len(edges)), (inverse[:, 0], inverse[:, 1])),
                       shape=(nodes.size, nodes.size))
    _, label = connected_components(graph, directed=False)
    return label[inverse[:, 0]]


def boundary_vertices(cells: np.ndarray) -> np.ndarray:
    """Mask (n,) of the vertices on the boundary faces of the tetrahedra (m, 4)."""
    faces = np.sort(np.concatenate([cells[:, [1, 2, 3]], cells[:, [0, 2, 3]],
                                    cells[:, [0, 1, 3]], cells[:, [0, 1, 2]]]), axis=1)
    unique, counts = np.unique(faces, axis=0, return_counts=True)
    out = np.zeros(int(cells.max()) + 1, dtype=bool)
    out[unique[counts == 1].ravel()] = True
    return out
