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
2. per triangle, in its own chart: where each integer line meets the triangle's boundary
   (its vertices, and points on its edges named by the edge and the exact parameter along
   it, so that the two triangles of an edge name them alike), the integer points inside,
   and the pieces of line between consecutive points;
3. the pieces joined into chains between integer points (through the points where a line
   merely crosses an edge); around every integer point its chains sorted by direction; the
   faces traced by turning left; the bounded faces are the quads, their corners the
   integer points (the chains, curved in the mesh, become straight quad edges).

A singular vertex of the field is an integer point that 3 or 5 chains leave; a boundary
curve lies on an integer line, so its integer points are quad vertices on the boundary.

Pure NumPy, all triangles, lines and chains at once (arrays, no loop over triangles). The
decisions are exact integer arithmetic on the fixed-point values: a line's side of a vertex
is the sign of a difference, the order of a line's two ends follows from which way the
counter-clockwise boundary crosses it, an edge point's parameter t = num/den is a reduced
pair of integers, and a point's other coordinate is compared with the grid by floor
division (see :func:`_lines` for the bounds that keep it within int64).
"""

from collections import defaultdict
from dataclasses import dataclass

import numpy as np

from ufl_frames.param.quantise import IntegerGridMap
from ufl_frames.param.seamless import quarter_turn, wedge_of

__all__ = ["ExtractionError", "QuadMesh", "extract_quads", "fixed_point"]

#: Fixed-point units per grid step: coordinates up to 10⁴ steps keep every product of two
#: differences within int64 (and Python's integers are used where they could not).
UNIT = 2**16


class ExtractionError(RuntimeError):
    """The iso-lines do not bound quads (the map is not a valid integer-grid map)."""


@dataclass(frozen=True)
class QuadMesh:
    """A quad mesh: ``points`` (n, 2), ``quads`` (m, 4) counter-clockwise; ``chains`` the
    polyline (k, 2) under every quad edge (the traced iso-line, for pictures), keyed by the
    sorted point pair; ``boundary`` the boundary edges (b, 2)."""

    points: np.ndarray
    quads: np.ndarray
    chains: dict
    boundary: np.ndarray

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


#: Local vertices (from, to) of edge i of a counter-clockwise triangle (the edge opposite i).
EDGE_ENDS = np.array([[1, 2], [2, 0], [0, 1]])

#: Local fixed-point coordinates below this keep every product of two within int64 (see
#: :func:`_lines`); a triangle that spans more (some 16000 quads) is done in Python ints.
SMALL = 2**30


def _ceil_div(a, b):
    return -((-a) // b)


def _ranges(start, count):
    """Consecutive integers start[i], start[i] + 1, ... (count[i] of them) for every i, and
    the i of each: (owner, value)."""
    owner = np.repeat(np.arange(count.size), count)
    first = np.cumsum(count) - count
    return owner, start[owner] + np.arange(owner.size) - first[owner]


def _group(*columns):
    """Equal rows of integer columns: the index of each group's first row (in the given
    order) and the group of every row."""
    key = _packed(columns)
    order = np.lexsort(columns[::-1]) if key is None else np.argsort(key, kind="stable")
    starts = np.zeros(order.size, dtype=bool)
    starts[:1] = True
    for column in columns if key is None else (key,):
        s = column[order]
        starts[1:] |= s[1:] != s[:-1]
    group = np.empty_like(order)
    group[order] = np.cumsum(starts) - 1
    return order[starts], group


def _packed(columns):
    """The rows as one int64 each, ordered as the rows are, where their ranges allow."""
    if columns[0].size == 0:
        return None
    low = [int(c.min()) for c in columns]
    span = [int(c.max()) - b + 1 for c, b in zip(columns, low, strict=True)]
    if np.prod([float(w) for w in span]) >= 2.0**62:
        return None
    key = np.zeros(columns[0].size, dtype=np.int64)
    for c, b, w in zip(columns, low, span, strict=True):
        key = key * w + (c - b)
    return key


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
    return _faces(*_lines(mesh, C))


def _lines(mesh, C):
    """The nodes and the pieces of the integer lines through every triangle (``C`` (m, 3, 2)
    its corners' fixed-point values).

    Nodes: the mesh vertices (ids 0 .. n−1, used where a line passes), the points where a
    line crosses an edge inside (keyed by the edge and the reduced t = num/den from its
    smaller vertex), the integer points inside a triangle (keyed by the triangle and
    (U, V)). Returns their positions (N, 2), which are integer points (N,), the pieces as
    node pairs lo < hi with the physical direction (S, 2) from lo to hi (that of the first
    triangle that has the piece), and the directed pieces (p, q) along the boundary that
    have the outside on their left.
    """
    x, cells = mesh.x, mesh.cells
    n = x.shape[0]
    # Each triangle's chart moved by a multiple of UNIT (which keeps every decision) to
    # 0 <= X < D, D = its span + UNIT. On an edge A -> B crossed by X_c = level:
    # t = num/den, 0 < num < den <= |B_c − A_c| < D, and the other coordinate
    # A_o + t (B_o − A_o) = (A_o den + num (B_o − A_o)) / den, a numerator below 2 D²:
    # within int64 for D <= 2^30; beyond that (a triangle over 16000 quads across) the
    # numerators are Python integers (object arrays), exact either way.
    X = C - UNIT * (C.min(axis=1) // UNIT)[:, None, :]
    wide = X.max(initial=0) >= SMALL
    exact = (lambda a: a.astype(object)) if wide else (lambda a: a)
    # edge ids of the local edges, and the local vertex of each one's smaller end
    edge_vertices = cells[:, EDGE_ENDS]
    keys = mesh.edges[:, 0] * n + mesh.edges[:, 1]
    edge_id = np.searchsorted(keys, edge_vertices.min(axis=2) * n + edge_vertices.max(axis=2))
    flip = edge_vertices[:, :, 0] > edge_vertices[:, :, 1]
    first_end = np.where(flip, EDGE_ENDS[:, 1], EDGE_ENDS[:, 0])
    second_end = np.where(flip, EDGE_ENDS[:, 0], EDGE_ENDS[:, 1])
    # the affine map of each triangle: physical = x0 + M (param − X0)
    xf = x[cells]
    dx = np.stack([xf[:, 1] - xf[:, 0], xf[:, 2] - xf[:, 0]], axis=2)
    dp = np.stack([C[:, 1] - C[:, 0], C[:, 2] - C[:, 0]], axis=2).astype(float)
    M = dx @ np.linalg.inv(dp)

    def crossing(f, j, c, level):
        """Where X_c = level crosses edge j of triangle f inside: the edge, t = num/den
        reduced, whether it is an integer point, and floor, ceil of the other coordinate
        in grid steps."""
        rows = np.arange(f.size)
        A, B = X[f, first_end[f, j]], X[f, second_end[f, j]]
        num, den = level - A[rows, c], B[rows, c] - A[rows, c]
        sign = np.sign(den)
        num, den = num * sign, den * sign
        common = np.gcd(num, den)
        num, den = num // common, den // common
        o = 1 - c
        other = exact(A[rows, o]) * den + exact(num) * (B[rows, o] - A[rows, o])
        step = exact(den) * UNIT
        low, high = other // step, _ceil_div(other, step)
        grid = (other % step == 0).astype(bool)
        return (edge_id[f, j], num, den, grid, low.astype(np.int64), high.astype(np.int64))

    # the integer lines X_c = level through each closed triangle
    f, c, level = [], [], []
    for k in (0, 1):
        v = X[:, :, k]
        lowest = _ceil_div(v.min(axis=1), UNIT)
        owner, value = _ranges(lowest, np.maximum(v.max(axis=1) // UNIT - lowest + 1, 0))
        f.append(owner)
        c.append(np.full(owner.size, k))
        level.append(value * UNIT)
    f, c, level = np.concatenate(f), np.concatenate(c), np.concatenate(level)
    side = np.sign(X[f, :, c] - level[:, None])
    on = side == 0
    # edge j crossed inside, its boundary (counter-clockwise) going from below to above
    rising = (side[:, EDGE_ENDS[:, 0]] < 0) & (side[:, EDGE_ENDS[:, 1]] > 0)
    falling = (side[:, EDGE_ENDS[:, 0]] > 0) & (side[:, EDGE_ENDS[:, 1]] < 0)
    through = rising.any(axis=1) | falling.any(axis=1)  # not along an edge, nor touching
    along = on.sum(axis=1) == 2

    met = []  # (edge, num, den, grid) of the edge points met, in order

    def meet(edge, num, den, grid):
        """Placeholder ids −1, −2, ... of edge points, named once all are met."""
        before = sum(k[0].size for k in met)
        met.append((edge, num, den, grid))
        return -1 - (before + np.arange(edge.size))

    # Lines through the inside: two ends, each an edge point or a vertex. The inside is
    # left of the counter-clockwise boundary, so where it rises through a U line it is the
    # line's low end (smaller V), and through a V line its high end (larger U).
    t = np.flatnonzero(through)
    ft, ct, lt = f[t], c[t], level[t]
    ends = []
    for crossed in (rising, falling):
        is_edge = crossed[t].any(axis=1)
        j = np.where(is_edge, crossed[t].argmax(axis=1), on[t].argmax(axis=1))
        node = cells[ft, j]
        value = X[ft, j, 1 - ct]
        low, top = value // UNIT, _ceil_div(value, UNIT)  # of the other coordinate
        e = np.flatnonzero(is_edge)
        edge, num, den, grid, low[e], top[e] = crossing(ft[e], j[e], ct[e], lt[e])
        node[e] = meet(edge, num, den, grid)
        ends.append((node, low, top))
    (node_r, low_r, top_r), (node_f, low_f, top_f) = ends
    high_r = ct == 1  # the rising end is the high one
    first_node = np.where(high_r, node_f, node_r)
    last_node = np.where(high_r, node_r, node_f)
    floor_first = np.where(high_r, low_f, low_r)
    ceil_last = np.where(high_r, top_r, top_f)
    inner_count = np.maximum(ceil_last - floor_first - 1, 0)
    owner, step = _ranges(floor_first + 1, inner_count)
    grid_u = np.where(ct[owner] == 0, lt[owner] // UNIT, step)
    grid_v = np.where(ct[owner] == 0, step, lt[owner] // UNIT)
    inner_first, inner_group = _group(ft[owner], grid_u, grid_v)

    # Lines along an edge: its two vertices and the edge points between them (where the
    # lines of the other coordinate cross), in the order of the other coordinate.
    a = np.flatnonzero(along)
    fa, ca = f[a], c[a]
    ja = (~on[a]).argmax(axis=1)  # the edge opposite the one vertex off the line
    v_start, v_end = EDGE_ENDS[ja, 0], EDGE_ENDS[ja, 1]
    w_start, w_end = X[fa, v_start, 1 - ca], X[fa, v_end, 1 - ca]
    ascending = w_start < w_end
    w_low, w_high = np.minimum(w_start, w_end), np.maximum(w_start, w_end)
    along_first = cells[fa, np.where(ascending, v_start, v_end)]
    along_last = cells[fa, np.where(ascending, v_end, v_start)]
    along_count = np.maximum(_ceil_div(w_high, UNIT) - w_low // UNIT - 1, 0)
    along_owner, crossed_at = _ranges(w_low // UNIT + 1, along_count)
    edge, num, den, grid, _, _ = crossing(fa[along_owner], ja[along_owner],
                                          1 - ca[along_owner], crossed_at * UNIT)
    along_inner = meet(edge, num, den, grid)

    # node ids: vertices, then edge points, then inner points
    edge, num, den, grid = (np.concatenate(k) for k in zip(*met, strict=True))
    edge_first, edge_group = _group(edge, num, den)
    n_edge = edge_first.size
    def node_ids(k):  # edge point −1 − i is node n + its group; vertices keep their id
        ids, points = k.copy(), k < 0  # (np.where would index edge_group with every k)
        ids[points] = n + edge_group[-1 - k[points]]
        return ids

    first_node, last_node, along_inner = (node_ids(k)
                                          for k in (first_node, last_node, along_inner))
    e, ta = edge[edge_first], num[edge_first] / den[edge_first]
    va, vb = mesh.edges[e, 0], mesh.edges[e, 1]
    edge_points = x[va] + ta[:, None] * (x[vb] - x[va])
    fo = ft[owner][inner_first]
    offset = (np.stack([grid_u[inner_first], grid_v[inner_first]], axis=1) * UNIT
              - X[fo, 0]).astype(float)
    inner_points = x[cells[fo, 0]] + (M[fo] @ offset[:, :, None])[:, :, 0]
    inner_ids = n + n_edge + inner_group

    vertex_grid = np.zeros(n, dtype=bool)
    vertex_grid[cells] = (C % UNIT == 0).all(axis=2)
    points_all = np.concatenate([x, edge_points, inner_points])
    is_grid = np.concatenate([vertex_grid, grid[edge_first],
                              np.ones(inner_first.size, dtype=bool)])

    # the pieces: consecutive nodes of every line
    p_t, q_t, line_t = _pieces(first_node, owner, inner_ids, last_node, inner_count)
    p_a, q_a, line_a = _pieces(along_first, along_owner, along_inner, along_last, along_count)
    p, q = np.concatenate([p_t, p_a]), np.concatenate([q_t, q_a])
    face = np.concatenate([ft[line_t], fa[line_a]])
    other = 1 - np.concatenate([ct[line_t], ca[line_a]])
    direction = M[face, :, other]  # physical direction of the other coordinate's increase
    # pieces along the boundary: the domain is left of the counter-clockwise edge
    boundary = mesh.faces[edge_id[fa, ja], 1] < 0
    mark = boundary[line_a]
    up = ascending[line_a][mark]
    exterior_p = np.where(up, q_a[mark], p_a[mark])
    exterior_q = np.where(up, p_a[mark], q_a[mark])
    # one piece per node pair, its direction from the first triangle that has it
    order = np.argsort(face, kind="stable")
    p, q, direction = p[order], q[order], direction[order]
    lo, hi = np.minimum(p, q), np.maximum(p, q)
    direction = np.where((p < q)[:, None], direction, -direction)
    first, _ = _group(lo, hi)
    return (points_all, is_grid, lo[first], hi[first], direction[first],
            exterior_p, exterior_q)


def _pieces(first, owner, inner, last, count):
    """The pieces (p, q) of lines [first[i], inner nodes of owner i..., last[i]] (the inner
    nodes in order), and the line of each piece."""
    length = count + 2
    offset = np.cumsum(length) - length
    nodes = np.empty(int(length.sum()), dtype=np.int64)
    nodes[offset] = first
    nodes[offset + length - 1] = last
    rank = np.arange(owner.size) - (np.cumsum(count) - count)[owner]
    nodes[offset[owner] + 1 + rank] = inner
    line = np.repeat(np.arange(count.size), length)
    piece = line[1:] == line[:-1]
    return nodes[:-1][piece], nodes[1:][piece], line[:-1][piece]


def _faces(points_all, is_grid, lo, hi, direction, exterior_p, exterior_q) -> QuadMesh:
    """Chains between integer points, their cyclic order, the faces; the quads.

    The pieces lo[s] -> hi[s] are directed half-pieces 2 s, back 2 s + 1."""
    n = points_all.shape[0]
    tail = np.stack([lo, hi], axis=1).ravel()
    head = np.stack([hi, lo], axis=1).ravel()
    heading = np.stack([direction, -direction], axis=1).reshape(-1, 2)
    degree = np.bincount(tail, minlength=n)
    through = (degree > 0) & ~is_grid
    bad = int(np.count_nonzero(through & (degree != 2)))
    if bad:
        raise ExtractionError(f"{bad} points where an iso-line crosses an edge are not "
                              "on exactly one line (the map folds or the grid is broken)")
    # into a point where a line crosses an edge: on along the other half-piece leaving it
    leaving = np.argsort(tail, kind="stable")
    first_leaving = np.cumsum(degree) - degree
    onward = np.full(tail.size, -1)
    enter = np.flatnonzero(through[head])
    one = leaving[first_leaving[head[enter]]]
    two = leaving[first_leaving[head[enter]] + 1]
    onward[enter] = np.where(one == (enter ^ 1), two, one)
    # chains: from each integer point, along each half-piece, to the next integer point
    start = np.flatnonzero(is_grid[tail])
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
        if len(chain_of) > tail.size + 1:
            raise ExtractionError("an iso-line closes on itself without an integer "
                                  "point")
    chain_of, piece_of = np.concatenate(chain_of), np.concatenate(piece_of)
    along = np.argsort(chain_of, kind="stable")  # by chain, in order along it
    chain_of, piece_of = chain_of[along], piece_of[along]
    grid_ids = np.flatnonzero(is_grid & (degree > 0))
    number = np.full(n, -1, dtype=np.int64)
    number[grid_ids] = np.arange(grid_ids.size)
    begin, finish = number[tail[start]], number[head[last]]
    # around every integer point its chains counter-clockwise
    angle = np.arctan2(heading[start, 1], heading[start, 0])
    around = np.lexsort((np.arange(start.size), angle, begin))
    count = np.bincount(begin, minlength=grid_ids.size)
    offset = np.cumsum(count) - count
    rank = np.empty(start.size, dtype=np.int64)
    rank[around] = np.arange(start.size) - offset[begin[around]]
    # the twin runs the same path back; the next chain of a face: the one clockwise of
    # the twin at the end point (the face on the left)
    chain_from = np.full(tail.size, -1)
    chain_from[start] = np.arange(start.size)
    twin = chain_from[last ^ 1]
    at = begin[twin]
    turn = around[offset[at] + (rank[twin] - 1) % count[at]]
    # faces: the cycles of turn, each named by its smallest chain
    face = np.arange(start.size)
    jump = turn
    while True:
        merged = np.minimum(face, face[jump])
        if np.array_equal(merged, face):
            break
        face, jump = merged, jump[jump]
    # boundary loops: a piece with the outside on its left
    outside = np.zeros(tail.size, dtype=bool)
    keys = lo * n + hi
    p, q = exterior_p, exterior_q
    s = np.searchsorted(keys, np.minimum(p, q) * n + np.maximum(p, q))
    outside[2 * s + (p > q)] = True
    pieces_face = face[chain_of]
    loop = np.bincount(pieces_face, weights=outside[piece_of], minlength=start.size) > 0
    a, b = points_all[tail[piece_of]], points_all[head[piece_of]]
    area = 0.5 * np.bincount(pieces_face, weights=a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1],
                             minlength=start.size)
    sides = np.bincount(face, minlength=start.size)
    named = np.flatnonzero((face == np.arange(start.size)) & ~loop)
    is_quad = (sides[named] == 4) & (area[named] > 0)
    other_faces = int(np.count_nonzero(~is_quad))
    if other_faces:
        raise ExtractionError(f"{other_faces} faces of the traced iso-lines are not quads")
    corner = named
    quads = []
    for _ in range(4):
        quads.append(begin[corner])
        corner = turn[corner]
    quads = np.stack(quads, axis=1).reshape(-1, 4)
    # the chains (for pictures) by their sorted point pair, each from its lower point
    kept = np.flatnonzero(begin < finish)
    sizes = np.bincount(chain_of, minlength=start.size)[kept] + 1
    path = _chain_points(tail[start], chain_of, head[piece_of], kept, start.size)
    ring = points_all[path]
    bounds = np.cumsum(sizes).tolist()
    polylines = [ring[b - k:b] for b, k in zip(bounds, sizes.tolist(), strict=True)]
    chains = dict(zip(zip(begin[kept].tolist(), finish[kept].tolist(), strict=True),
                      polylines, strict=True))
    # boundary edges: those of one quad only
    a, b = quads.ravel(), np.roll(quads, -1, axis=1).ravel()
    pairs, counts = np.unique(np.minimum(a, b) * grid_ids.size + np.maximum(a, b),
                              return_counts=True)
    once = pairs[counts == 1]
    boundary = np.stack([once // grid_ids.size, once % grid_ids.size], axis=1)
    return QuadMesh(points=points_all[grid_ids], quads=quads, chains=chains,
                    boundary=boundary.reshape(-1, 2))


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
