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
    return odeco.q_to_frames(q[cells].mean(axis=1))[1]


def singular_graph(cells: np.ndarray, q: np.ndarray) -> SingularGraph:
    """The singular graph of the P1 frame field ``q`` (n, 15) on the tetrahedra ``cells``
    (m, 4).

    Args:
        cells: vertex indices (m, 4).
        q: the frame coefficients at the vertices (n, 15).

    Returns:
        The :class:`SingularGraph`.
    """
    cells = np.asarray(cells, dtype=np.int64)
    R = cell_rotations(cells, np.asarray(q, dtype=np.float64))
    n = int(cells.max()) + 1
    pairs = np.array([(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)])
    others = np.array([(2, 3), (1, 3), (1, 2), (0, 3), (0, 2), (0, 1)])
    a = cells[:, pairs[:, 0]].ravel()
    b = cells[:, pairs[:, 1]].ravel()
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    c = cells[:, others[:, 0]].ravel()
    d = cells[:, others[:, 1]].ravel()
    tet = np.repeat(np.arange(cells.shape[0]), 6)
    key = lo * n + hi
    order = np.argsort(key, kind="stable")
    key, lo, hi, c, d, tet = (v[order] for v in (key, lo, hi, c, d, tet))
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    ends = np.r_[starts[1:], key.size]
    singular, turns, open_rings = [], [], 0
    for s, e in zip(starts, ends, strict=True):
        ring = _ring(c[s:e], d[s:e], tet[s:e])
        if ring is None:
            open_rings += 1
            continue
        G = np.eye(3)
        for i in range(len(ring)):
            t0, t1 = ring[i], ring[(i + 1) % len(ring)]
            g = OCTAHEDRAL[closest_symmetry((R[t0].T @ R[t1])[None])[0]]
            G = G @ g
        if not np.allclose(G, np.eye(3)):
            angle = np.arccos(np.clip((np.trace(G) - 1) / 2, -1, 1))
            singular.append((lo[s], hi[s]))
            turns.append(int(round(angle / (np.pi / 2))))
    edges = np.array(singular, dtype=np.int64).reshape(-1, 2)
    chains = _components(edges)
    on_boundary = boundary_vertices(cells)
    degree = np.bincount(edges.ravel(), minlength=n) if edges.size else np.zeros(n, int)
    open_ends = np.flatnonzero((degree == 1) & ~on_boundary)
    return SingularGraph(edges=edges, turn=np.array(turns, dtype=np.int64), chains=chains,
                         open_ends=open_ends, boundary_edges=open_rings)


def _ring(c, d, tets):
    """The tetrahedra around an edge in cyclic order (each has the edge and two more
    vertices c, d; neighbours share one of them), or None where the ring is open (an edge
    on the boundary)."""
    if tets.size < 3:
        return None
    at: dict[int, list[int]] = {}
    for i, (ci, di) in enumerate(zip(c, d, strict=True)):
        at.setdefault(int(ci), []).append(i)
        at.setdefault(int(di), []).append(i)
    if any(len(v) != 2 for v in at.values()):
        return None
    ring, i, came = [0], 0, int(c[0])
    while True:
        nxt_vertex = int(d[i]) if int(c[i]) == came else int(c[i])
        j = at[nxt_vertex][0] if at[nxt_vertex][0] != i else at[nxt_vertex][1]
        if j == 0:
            break
        ring.append(j)
        i, came = j, nxt_vertex
        if len(ring) > tets.size:
            return None
    return [int(tets[k]) for k in ring] if len(ring) == tets.size else None


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
