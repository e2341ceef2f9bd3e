r"""Quad extraction: the integer iso-lines of an integer-grid map, traced through the
triangles, and the quads they bound (the idea of QEx, Ebke et al. 2013).

The map (U, V) of :func:`~ufl_frames.param.quantise.quantise` is affine on every triangle
and, across a seam, related to the neighbour's by a quarter turn and an integer
translation. So the lines U = i and V = j (i, j integers) form, pulled back to the mesh, a
graph whose vertices are the integer points (i, j) and whose faces are quads:

1. exact arithmetic: the wedge values are rounded to fixed point (2⁻¹⁶ of a quad edge),
   and the seams' transitions are made exact in it, so that every decision below (does a
   line cross this edge, does it pass through this vertex, is this point inside) is the
   same seen from both sides of an edge;
2. per triangle, in its own chart (:mod:`~ufl_frames.quads.isolines`): where each
   integer line meets the triangle's boundary (its vertices, and points on its edges named
   by the edge and the exact parameter along it, so that the two triangles of an edge name
   them alike), the integer points inside, and the pieces of line between consecutive
   points;
3. the pieces joined into chains between integer points (through the points where a line
   merely crosses an edge); around every integer point its chains sorted by direction; the
   faces traced by turning left; the bounded faces are the quads, their corners the
   integer points (the chains, curved in the mesh, become straight quad edges).

A singular vertex of the field is an integer point that 3 or 5 chains leave; a boundary
curve lies on an integer line, so its integer points are quad vertices on the boundary.

Pure NumPy, all triangles, lines and chains at once (arrays, no loop over triangles),
every decision exact integer arithmetic on the fixed-point values (see
:mod:`~ufl_frames.quads.isolines`).
"""

from collections import defaultdict
from dataclasses import dataclass

import numpy as np

from ufl_frames.param.quantise import IntegerGridMap
from ufl_frames.param.seamless import quarter_turn, wedge_of
from ufl_frames.quads.isolines import UNIT, lines

__all__ = ["ExtractionError", "QuadMesh", "extract_quads", "fixed_point", "with_features"]


class ExtractionError(RuntimeError):
    """The iso-lines do not bound quads (the map is not a valid integer-grid map)."""


@dataclass(frozen=True)
class QuadMesh:
    """A quad mesh: ``points`` (n, 2), ``quads`` (m, 4) counter-clockwise; ``chains`` the
    polyline (k, 2) under every quad edge (the traced iso-line, for pictures), keyed by the
    sorted point pair; ``boundary`` the boundary edges (b, 2). Where the triangles had
    :class:`~ufl_frames.param.features.Features` (:func:`with_features`; None without):
    ``quad_region`` (m,) the region of every quad, ``curve_edges`` (k, 2) the quad edges
    on model curves (boundary and interior) with their curve ``edge_curve`` (k,), and
    ``point_nodes`` the quad vertices at model points with their ``point_tag``."""

    points: np.ndarray
    quads: np.ndarray
    chains: dict
    boundary: np.ndarray
    quad_region: np.ndarray | None = None
    curve_edges: np.ndarray | None = None
    edge_curve: np.ndarray | None = None
    point_nodes: np.ndarray | None = None
    point_tag: np.ndarray | None = None

    @property
    def num_quads(self) -> int:
        return int(self.quads.shape[0])


def fixed_point(grid_map: IntegerGridMap) -> np.ndarray:
    """The wedge values in fixed point (W, 2) int64, ``UNIT`` per grid step, with every
    seam's transition exact: X_g = Rot^j X_f + t (t a multiple of UNIT) at both ends of
    every cut edge. Raises :class:`ExtractionError` where the seams disagree."""
    mesh = grid_map.mesh
    uv = grid_map.param.uv
    if np.abs(uv).max(initial=0.0) * UNIT > 2.0**40:
        raise ExtractionError("the map is too large for fixed point (over 16 million quads "
                              "across)")
    P = np.rint(uv * UNIT).astype(np.int64)
    # Wedge graph across cut edges: each link w_f -> w_g with X_g = R X_f + t.
    links = defaultdict(list)
    for e in mesh.cut:
        f, g = int(mesh.faces[e, 0]), int(mesh.faces[e, 1])
        rot = quarter_turn(mesh.jump[e]).astype(np.int64)
        ends = [(wedge_of(mesh, f, int(v)), wedge_of(mesh, g, int(v))) for v in mesh.edges[e]]
        wf, wg = ends[0]
        t = P[wg] - rot @ P[wf]
        t = UNIT * np.rint(t / UNIT).astype(np.int64)
        for wf, wg in ends:
            links[wf].append((wg, rot, t))
            links[wg].append((wf, rot.T, -(rot.T @ t)))  # inverse: X_f = Rᵀ (X_g − t)
    done = np.zeros(P.shape[0], dtype=bool)
    for start in list(links):
        if done[start]:
            continue
        done[start] = True
        stack = [start]
        while stack:
            w = stack.pop()
            for other, rot, t in links[w]:
                value = rot @ P[w] + t
                if not done[other]:
                    P[other] = value
                    done[other] = True
                    stack.append(other)
                elif np.any(P[other] != value):
                    raise ExtractionError("the seams' transitions do not close around a "
                                          "vertex (the map is not an integer-grid map)")
    return P


def extract_quads(grid_map: IntegerGridMap) -> QuadMesh:
    """The quad mesh of the integer-grid map ``grid_map`` (see the module text).

    Raises :class:`ExtractionError` if the traced lines do not bound quads only.
    """
    mesh = grid_map.mesh
    P = fixed_point(grid_map)
    C = P[mesh.corners]
    det = ((C[:, 1, 0] - C[:, 0, 0]) * (C[:, 2, 1] - C[:, 0, 1])
           - (C[:, 1, 1] - C[:, 0, 1]) * (C[:, 2, 0] - C[:, 0, 0]))
    if np.any(det <= 0):
        raise ExtractionError(f"{int(np.count_nonzero(det <= 0))} triangles fold or collapse "
                              "in the integer-grid map")
    return with_features(_faces(*lines(mesh, C)), mesh)


def with_features(quad_mesh: QuadMesh, mesh) -> QuadMesh:
    """``quad_mesh`` with the model entities of the cut mesh ``mesh``'s features found on
    it (:func:`~ufl_frames.quads.features.quad_features`); unchanged where ``mesh`` has
    none."""
    if getattr(mesh, "features", None) is None:
        return quad_mesh
    from ufl_frames.quads.features import quad_features

    return quad_features(quad_mesh, mesh.x, mesh.cells, mesh.features)


def _faces(points_all, is_grid, lo, hi, direction, exterior_p, exterior_q) -> QuadMesh:
    """Chains between integer points, their cyclic order, the faces; the quads.

    The pieces lo[s] -> hi[s] are directed half-pieces 2 s, back 2 s + 1.

    Args:
        points_all, is_grid, lo, hi, direction, exterior_p, exterior_q: the nodes and the
            pieces as :func:`~ufl_frames.quads.isolines.lines` returns them.

    Returns:
        The quad mesh.

    Raises:
        ExtractionError: where the pieces do not bound quads only.
    """
    n = points_all.shape[0]
    tail = np.stack([lo, hi], axis=1).ravel()
    head = np.stack([hi, lo], axis=1).ravel()
    heading = np.stack([direction, -direction], axis=1).reshape(-1, 2)
    degree = np.bincount(tail, minlength=n)
    onward = _onward(tail, head, degree, is_grid)
    start = np.flatnonzero(is_grid[tail])
    chain_of, piece_of, last = _trace_chains(onward, start)
    grid_ids = np.flatnonzero(is_grid & (degree > 0))
    number = np.full(n, -1, dtype=np.int64)
    number[grid_ids] = np.arange(grid_ids.size)
    begin, finish = number[tail[start]], number[head[last]]
    turn = _next_chains(heading, start, last, begin, grid_ids.size)
    face = _cycles(turn)
    outside = _outside(lo, hi, n, exterior_p, exterior_q)
    quads = _quads(face, turn, begin, chain_of, outside[piece_of],
                   points_all[tail[piece_of]], points_all[head[piece_of]])
    chains = _polylines(points_all, begin, finish, chain_of,
                        tail[start], head[piece_of])
    return QuadMesh(points=points_all[grid_ids], quads=quads, chains=chains,
                    boundary=_boundary_edges(quads, grid_ids.size))


def _onward(tail, head, degree, is_grid):
    """Into a point where a line crosses an edge: on along the other half-piece leaving it.

    Args:
        tail, head: the half-pieces' nodes.
        degree: the half-pieces leaving every node.
        is_grid: which nodes are integer points.

    Returns:
        The half-piece after every half-piece (−1 into an integer point or a dead end).

    Raises:
        ExtractionError: where such a point is not on exactly one line.
    """
    through = (degree > 0) & ~is_grid
    bad = int(np.count_nonzero(through & (degree != 2)))
    if bad:
        raise ExtractionError(f"{bad} points where an iso-line crosses an edge are not "
                              "on exactly one line (the map folds or the grid is broken)")
    leaving = np.argsort(tail, kind="stable")
    first_leaving = np.cumsum(degree) - degree
    onward = np.full(tail.size, -1)
    enter = np.flatnonzero(through[head])
    one = leaving[first_leaving[head[enter]]]
    two = leaving[first_leaving[head[enter]] + 1]
    onward[enter] = np.where(one == (enter ^ 1), two, one)
    return onward


def _trace_chains(onward, start):
    """Chains: from each integer point, along each half-piece ``start``, to the next
    integer point (all chains a step at a time). Returns the chain of every half-piece on
    a chain and the half-piece, sorted by chain and in order along it, and the last
    half-piece of every chain."""
    chain_of, piece_of = [np.arange(start.size)], [start]
    last = start.copy()
    active, current = np.arange(start.size), start
    while True:
        current = onward[current]
        keep = current >= 0
        if not keep.any():
            break
        active, current = active[keep], current[keep]
        last[active] = current
        chain_of.append(active)
        piece_of.append(current)
        if len(chain_of) > onward.size + 1:
            raise ExtractionError("an iso-line closes on itself without an integer "
                                  "point")
    chain_of, piece_of = np.concatenate(chain_of), np.concatenate(piece_of)
    along = np.argsort(chain_of, kind="stable")  # by chain, in order along it
    return chain_of[along], piece_of[along], last


def _next_chains(heading, start, last, begin, points):
    """The next chain of every chain's face (the face on its left): around every integer
    point its chains counter-clockwise; the twin runs the same path back; the next is the
    one clockwise of the twin at the end point.

    Args:
        heading: (H, 2) the physical direction of every half-piece.
        start, last: the first and the last half-piece of every chain.
        begin: the integer point each chain leaves (numbered 0 .. points − 1).
        points: the number of integer points.

    Returns:
        The next chain of every chain.
    """
    angle = np.arctan2(heading[start, 1], heading[start, 0])
    around = np.lexsort((np.arange(start.size), angle, begin))
    count = np.bincount(begin, minlength=points)
    offset = np.cumsum(count) - count
    rank = np.empty(start.size, dtype=np.int64)
    rank[around] = np.arange(start.size) - offset[begin[around]]
    chain_from = np.full(heading.shape[0], -1)
    chain_from[start] = np.arange(start.size)
    twin = chain_from[last ^ 1]
    at = begin[twin]
    return around[offset[at] + (rank[twin] - 1) % count[at]]


def _cycles(turn):
    """The cycles of the permutation ``turn``, each named by its smallest member (by
    pointer jumping): the cycle of every member."""
    face = np.arange(turn.size)
    jump = turn
    while True:
        merged = np.minimum(face, face[jump])
        if np.array_equal(merged, face):
            break
        face, jump = merged, jump[jump]
    return face


def _outside(lo, hi, n, exterior_p, exterior_q):
    """Which half-pieces have the outside on their left.

    Args:
        lo, hi: the pieces, half-pieces 2 s along lo[s] -> hi[s] and 2 s + 1 back.
        n: the number of nodes.
        exterior_p, exterior_q: the boundary pieces, the outside on their left.

    Returns:
        (2 S,) bool over the half-pieces.
    """
    outside = np.zeros(2 * lo.size, dtype=bool)
    keys = lo * n + hi
    p, q = exterior_p, exterior_q
    s = np.searchsorted(keys, np.minimum(p, q) * n + np.maximum(p, q))
    outside[2 * s + (p > q)] = True
    return outside


def _quads(face, turn, begin, chain_of, outside, a, b):
    """The quads: the faces that are not boundary loops, each corner an integer point.

    Args:
        face: the face of every chain (named by its smallest chain).
        turn: the next chain of every chain along its face.
        begin: the integer point every chain leaves.
        chain_of: the chain of every half-piece on a chain.
        outside: for every such half-piece, whether the outside is on its left.
        a, b: (k, 2) the positions of every such half-piece's tail and head.

    Returns:
        The quads (q, 4), counter-clockwise.

    Raises:
        ExtractionError: where a bounded face is not a positive quad.
    """
    total = face.size
    pieces_face = face[chain_of]
    loop = np.bincount(pieces_face, weights=outside, minlength=total) > 0
    area = 0.5 * np.bincount(pieces_face, weights=a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1],
                             minlength=total)
    sides = np.bincount(face, minlength=total)
    named = np.flatnonzero((face == np.arange(total)) & ~loop)
    is_quad = (sides[named] == 4) & (area[named] > 0)
    other_faces = int(np.count_nonzero(~is_quad))
    if other_faces:
        raise ExtractionError(f"{other_faces} faces of the traced iso-lines are not quads")
    corner = named
    quads = []
    for _ in range(4):
        quads.append(begin[corner])
        corner = turn[corner]
    return np.stack(quads, axis=1).reshape(-1, 4)


def _polylines(points_all, begin, finish, chain_of, first, heads):
    """The chains (for pictures) by their sorted point pair, each from its lower point.

    Args:
        points_all: the nodes' positions.
        begin, finish: the integer points every chain leaves and reaches.
        chain_of: the chain of every half-piece on a chain (sorted).
        first: the first node of every chain.
        heads: the head node of every half-piece on a chain.

    Returns:
        ``{(i, j): polyline (k, 2)}`` for the chains with i < j.
    """
    total = begin.size
    kept = np.flatnonzero(begin < finish)
    sizes = np.bincount(chain_of, minlength=total)[kept] + 1
    ring = points_all[_chain_points(first, chain_of, heads, kept, total)]
    bounds = np.cumsum(sizes).tolist()
    polylines = [ring[b - k:b] for b, k in zip(bounds, sizes.tolist(), strict=True)]
    return dict(zip(zip(begin[kept].tolist(), finish[kept].tolist(), strict=True),
                    polylines, strict=True))


def _boundary_edges(quads, points):
    """The boundary edges (b, 2) of ``quads`` on ``points`` points: those of one quad only."""
    a, b = quads.ravel(), np.roll(quads, -1, axis=1).ravel()
    pairs, counts = np.unique(np.minimum(a, b) * points + np.maximum(a, b),
                              return_counts=True)
    once = pairs[counts == 1]
    return np.stack([once // points, once % points], axis=1).reshape(-1, 2)


def _chain_points(first, chain_of, heads, kept, total):
    """Node ids along the chains ``kept``: the first node of each, then the heads of its
    half-pieces (``chain_of`` sorted), chain after chain."""
    wanted = np.zeros(total, dtype=bool)
    wanted[kept] = True
    sizes = np.bincount(chain_of, minlength=total) + 1
    offset = np.cumsum(sizes) - sizes
    nodes = np.empty(int(sizes.sum()), dtype=np.int64)
    nodes[offset] = first
    rank = np.arange(chain_of.size) - (offset[chain_of] - chain_of)
    nodes[offset[chain_of] + 1 + rank] = heads
    owner = np.repeat(np.arange(total), sizes)
    return nodes[wanted[owner]]
