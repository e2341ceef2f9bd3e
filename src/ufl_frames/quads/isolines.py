r"""The integer iso-lines of an integer-grid map traced through the triangles: the nodes
(vertices, points on edges, integer points inside) and the pieces of line between them,
whose faces :mod:`ufl_frames.quads.extract` turns into quads (its step 2).

Per triangle, in its own chart (the fixed-point values of
:func:`~ufl_frames.quads.extract.fixed_point`): where each integer line meets the
triangle's boundary (its vertices, and points on its edges named by the edge and the exact
parameter along it, so that the two triangles of an edge name them alike), the integer
points inside, and the pieces of line between consecutive points.

Pure NumPy, all triangles and lines at once (arrays, no loop over triangles). The
decisions are exact integer arithmetic on the fixed-point values: a line's side of a vertex
is the sign of a difference, the order of a line's two ends follows from which way the
counter-clockwise boundary crosses it, an edge point's parameter t = num/den is a reduced
pair of integers, and a point's other coordinate is compared with the grid by floor
division (see :func:`_charts` for the bounds that keep it within int64).
"""

from dataclasses import dataclass

import numpy as np

__all__ = ["UNIT", "lines"]

#: Fixed-point units per grid step: coordinates up to 10⁴ steps keep every product of two
#: differences within int64 (and Python's integers are used where they could not).
UNIT = 2**16


#: Local vertices (from, to) of edge i of a counter-clockwise triangle (the edge opposite i).
EDGE_ENDS = np.array([[1, 2], [2, 0], [0, 1]])

#: Local fixed-point coordinates below this keep every product of two within int64 (see
#: :func:`_charts`); a triangle that spans more (some 16000 quads) is done in Python ints.
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


def lines(mesh, C):
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
    charts = _charts(mesh, C)
    f, c, level = _integer_lines(charts.X)
    on, rising, falling = _line_sides(charts.X, f, c, level)
    # the lines through the inside (not along an edge, nor touching), and those along an edge
    t = np.flatnonzero(rising.any(axis=1) | falling.any(axis=1))
    a = np.flatnonzero(on.sum(axis=1) == 2)
    ft, ct, fa, ca = f[t], c[t], f[a], c[a]
    met = []  # (edge, num, den, grid) of the edge points met, in order
    first_t, last_t, owner_t, count_t, grid_u, grid_v = _through_lines(
        charts, cells, (ft, ct, level[t]), on[t], rising[t], falling[t], met)
    first_a, last_a, owner_a, count_a, inner_a, edge_a, ascending = _along_lines(
        charts, cells, (fa, ca), on[a], met)

    # node ids: vertices, then edge points, then inner points
    edge, num, den, grid, edge_group = _edge_points(met)
    first_t, last_t, inner_a = (_node_ids(k, n, edge_group) for k in (first_t, last_t, inner_a))
    inner_first, inner_group = _group(ft[owner_t], grid_u, grid_v)
    inner_t = n + edge.size + inner_group
    points_all = np.concatenate([
        x, _edge_point_positions(x, mesh.edges, edge, num, den),
        _inner_point_positions(x, cells, charts, ft[owner_t][inner_first],
                               grid_u[inner_first], grid_v[inner_first])])
    is_grid = np.concatenate([_vertices_on_grid(n, cells, C), grid,
                              np.ones(inner_first.size, dtype=bool)])

    # the pieces: consecutive nodes of every line
    p_t, q_t, line_t = _pieces(first_t, owner_t, inner_t, last_t, count_t)
    p_a, q_a, line_a = _pieces(first_a, owner_a, inner_a, last_a, count_a)
    face = np.concatenate([ft[line_t], fa[line_a]])
    other = 1 - np.concatenate([ct[line_t], ca[line_a]])
    direction = charts.M[face, :, other]  # physical direction of the other coordinate's increase
    lo, hi, direction = _distinct_pieces(np.concatenate([p_t, p_a]),
                                         np.concatenate([q_t, q_a]), face, direction)
    exterior_p, exterior_q = _exterior_pieces(p_a, q_a, (mesh.faces[edge_a, 1] < 0)[line_a],
                                              ascending[line_a])
    return points_all, is_grid, lo, hi, direction, exterior_p, exterior_q


@dataclass(frozen=True)
class _Charts:
    """Every triangle's chart, for the m triangles of a mesh.

    ``X`` (m, 3, 2) the corners' fixed-point values, moved by a multiple of UNIT (which
    keeps every decision) to 0 <= X < D; ``wide`` whether some X reaches SMALL (then the
    crossings' numerators are Python integers); ``edge_id`` (m, 3) the mesh edge of each
    local edge and ``first_end``, ``second_end`` (m, 3) its local vertices at the smaller
    and the larger vertex id; ``M`` (m, 2, 2) the affine map, physical = x0 + M (X − X0).
    """

    X: np.ndarray
    wide: bool
    edge_id: np.ndarray
    first_end: np.ndarray
    second_end: np.ndarray
    M: np.ndarray

    def exact(self, a):
        """``a`` as Python integers (an object array) where the charts are wide, else as is."""
        return a.astype(object) if self.wide else a


def _charts(mesh, C) -> _Charts:
    """The triangles' charts of ``mesh`` with corners' fixed-point values ``C`` (m, 3, 2).

    Each chart moved to 0 <= X < D, D = its span + UNIT. On an edge A -> B crossed by
    X_c = level: t = num/den, 0 < num < den <= |B_c − A_c| < D, and the other coordinate
    A_o + t (B_o − A_o) = (A_o den + num (B_o − A_o)) / den, a numerator below 2 D²: within
    int64 for D <= 2^30; beyond that (a triangle over 16000 quads across) the numerators
    are Python integers (object arrays), exact either way.
    """
    x, cells = mesh.x, mesh.cells
    n = x.shape[0]
    X = C - UNIT * (C.min(axis=1) // UNIT)[:, None, :]
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
    return _Charts(X=X, wide=bool(X.max(initial=0) >= SMALL), edge_id=edge_id,
                   first_end=first_end, second_end=second_end, M=M)


def _crossing(charts, f, j, c, level):
    """Where X_c = level crosses edge j of triangle f inside.

    Args:
        charts: the triangles' charts.
        f, j, c, level: per crossing, the triangle, its local edge, the coordinate (0 or 1)
            and the fixed-point level of the line.

    Returns:
        The mesh edge, t = num/den reduced (from the edge's smaller vertex), whether the
        point is an integer point, and floor and ceil of the other coordinate in grid steps.
    """
    rows = np.arange(f.size)
    X = charts.X
    A, B = X[f, charts.first_end[f, j]], X[f, charts.second_end[f, j]]
    num, den = level - A[rows, c], B[rows, c] - A[rows, c]
    sign = np.sign(den)
    num, den = num * sign, den * sign
    common = np.gcd(num, den)
    num, den = num // common, den // common
    o = 1 - c
    other = charts.exact(A[rows, o]) * den + charts.exact(num) * (B[rows, o] - A[rows, o])
    step = charts.exact(den) * UNIT
    low, high = other // step, _ceil_div(other, step)
    grid = (other % step == 0).astype(bool)
    return (charts.edge_id[f, j], num, den, grid, low.astype(np.int64), high.astype(np.int64))


def _integer_lines(X):
    """The integer lines X_c = level through each closed triangle (charts ``X`` (m, 3, 2)):
    the triangle, the coordinate c and the fixed-point level of each."""
    f, c, level = [], [], []
    for k in (0, 1):
        v = X[:, :, k]
        lowest = _ceil_div(v.min(axis=1), UNIT)
        owner, value = _ranges(lowest, np.maximum(v.max(axis=1) // UNIT - lowest + 1, 0))
        f.append(owner)
        c.append(np.full(owner.size, k))
        level.append(value * UNIT)
    return np.concatenate(f), np.concatenate(c), np.concatenate(level)


def _line_sides(X, f, c, level):
    """How each line (triangle f, coordinate c, level) meets its triangle's boundary.

    Args:
        X: the charts' corners (m, 3, 2).
        f, c, level: per line, the triangle, the coordinate and the fixed-point level.

    Returns:
        ``on`` (L, 3) the vertices on the line; ``rising``, ``falling`` (L, 3) the edges j
        crossed inside, the counter-clockwise boundary going from below to above the line
        (rising) or from above to below (falling).
    """
    side = np.sign(X[f, :, c] - level[:, None])
    on = side == 0
    rising = (side[:, EDGE_ENDS[:, 0]] < 0) & (side[:, EDGE_ENDS[:, 1]] > 0)
    falling = (side[:, EDGE_ENDS[:, 0]] > 0) & (side[:, EDGE_ENDS[:, 1]] < 0)
    return on, rising, falling


def _meet(met, edge, num, den, grid):
    """Record edge points met, under placeholder ids (named by :func:`_node_ids` once all
    are met).

    Args:
        met: the edge points met so far, a list of (edge, num, den, grid); appended to.
        edge, num, den, grid: the new points' mesh edge, t = num/den, and whether each is
            an integer point (as :func:`_crossing` gives them).

    Returns:
        Their placeholder ids: −1 − i for the i-th point met in all.
    """
    before = sum(k[0].size for k in met)
    met.append((edge, num, den, grid))
    return -1 - (before + np.arange(edge.size))


def _line_end(charts, cells, lines, crossed, on, met):
    """One end of every line through the inside: the edge point where the boundary crosses
    it the way ``crossed`` gives, or else the vertex on it.

    Args:
        charts: the triangles' charts.
        cells: the mesh's triangles (m, 3).
        lines: per line, (triangle, coordinate, fixed-point level).
        crossed: (L, 3) the edges crossed inside in the direction of this end.
        on: (L, 3) the vertices on the line.
        met: the edge points met so far; this end's are appended (see :func:`_meet`).

    Returns:
        The end's node (a vertex id, or an edge point's placeholder id), and floor and
        ceil of the other coordinate there, in grid steps.
    """
    f, c, level = lines
    is_edge = crossed.any(axis=1)
    j = np.where(is_edge, crossed.argmax(axis=1), on.argmax(axis=1))
    node = cells[f, j]
    value = charts.X[f, j, 1 - c]
    low, top = value // UNIT, _ceil_div(value, UNIT)  # of the other coordinate
    e = np.flatnonzero(is_edge)
    edge, num, den, grid, low[e], top[e] = _crossing(charts, f[e], j[e], c[e], level[e])
    node[e] = _meet(met, edge, num, den, grid)
    return node, low, top


def _through_lines(charts, cells, lines, on, rising, falling, met):
    """Lines through the inside: two ends, each an edge point or a vertex, and the integer
    points between them. The inside is left of the counter-clockwise boundary, so where it
    rises through a U line it is the line's low end (smaller V), and through a V line its
    high end (larger U).

    Args:
        charts: the triangles' charts.
        cells: the mesh's triangles (m, 3).
        lines: per line, (triangle, coordinate, fixed-point level).
        on, rising, falling: (L, 3) as :func:`_line_sides` gives them.
        met: the edge points met so far; the ends' are appended (see :func:`_meet`).

    Returns:
        ``first``, ``last`` the end nodes (low, high) of every line; ``owner`` the line of
        every inner integer point, in order along it; ``count`` the inner points of every
        line; ``grid_u``, ``grid_v`` the inner points' integer coordinates.
    """
    c, level = lines[1], lines[2]
    node_r, low_r, top_r = _line_end(charts, cells, lines, rising, on, met)
    node_f, low_f, top_f = _line_end(charts, cells, lines, falling, on, met)
    high_r = c == 1  # the rising end is the high one
    first = np.where(high_r, node_f, node_r)
    last = np.where(high_r, node_r, node_f)
    floor_first = np.where(high_r, low_f, low_r)
    ceil_last = np.where(high_r, top_r, top_f)
    count = np.maximum(ceil_last - floor_first - 1, 0)
    owner, step = _ranges(floor_first + 1, count)
    grid_u = np.where(c[owner] == 0, level[owner] // UNIT, step)
    grid_v = np.where(c[owner] == 0, step, level[owner] // UNIT)
    return first, last, owner, count, grid_u, grid_v


def _along_lines(charts, cells, lines, on, met):
    """Lines along an edge: its two vertices and the edge points between them (where the
    lines of the other coordinate cross), in the order of the other coordinate.

    Args:
        charts: the triangles' charts.
        cells: the mesh's triangles (m, 3).
        lines: per line, (triangle, coordinate).
        on: (L, 3) the vertices on the line (two of them).
        met: the edge points met so far; the lines' are appended (see :func:`_meet`).

    Returns:
        ``first``, ``last`` the end vertices (low, high); ``owner`` the line of every edge
        point between them, in order; ``count`` the edge points of every line; ``inner``
        their placeholder ids; ``edge`` the mesh edge of every line; ``ascending`` whether
        the line runs with its triangle's counter-clockwise edge.
    """
    fa, ca = lines
    ja = (~on).argmax(axis=1)  # the edge opposite the one vertex off the line
    v_start, v_end = EDGE_ENDS[ja, 0], EDGE_ENDS[ja, 1]
    w_start, w_end = charts.X[fa, v_start, 1 - ca], charts.X[fa, v_end, 1 - ca]
    ascending = w_start < w_end
    w_low, w_high = np.minimum(w_start, w_end), np.maximum(w_start, w_end)
    first = cells[fa, np.where(ascending, v_start, v_end)]
    last = cells[fa, np.where(ascending, v_end, v_start)]
    count = np.maximum(_ceil_div(w_high, UNIT) - w_low // UNIT - 1, 0)
    owner, crossed_at = _ranges(w_low // UNIT + 1, count)
    edge, num, den, grid, _, _ = _crossing(charts, fa[owner], ja[owner], 1 - ca[owner],
                                           crossed_at * UNIT)
    inner = _meet(met, edge, num, den, grid)
    return first, last, owner, count, inner, charts.edge_id[fa, ja], ascending


def _edge_points(met):
    """The distinct edge points among those ``met`` (equal edge and t): the edge, num, den
    and whether an integer point of each, and the point of every one met."""
    edge, num, den, grid = (np.concatenate(k) for k in zip(*met, strict=True))
    edge_first, edge_group = _group(edge, num, den)
    return edge[edge_first], num[edge_first], den[edge_first], grid[edge_first], edge_group


def _node_ids(k, n, edge_group):
    """The node ids of nodes named by vertex or placeholder.

    Args:
        k: vertex ids (>= 0) and edge points' placeholder ids (−1 − i, see :func:`_meet`).
        n: the number of vertices.
        edge_group: the distinct edge point of every edge point met.

    Returns:
        The ids: a vertex keeps its id, edge point −1 − i is node n + edge_group[i].
    """
    ids, points = k.copy(), k < 0  # (np.where would index edge_group with every k)
    ids[points] = n + edge_group[-1 - k[points]]
    return ids


def _edge_point_positions(x, edges, e, num, den):
    """Physical positions of points on mesh edges.

    Args:
        x: the mesh's vertices (n, 2).
        edges: the mesh's edges (E, 2), smaller vertex first.
        e, num, den: per point, its edge and t = num/den from the edge's smaller vertex.

    Returns:
        The positions (k, 2).
    """
    ta = num / den
    va, vb = edges[e, 0], edges[e, 1]
    return x[va] + ta[:, None] * (x[vb] - x[va])


def _inner_point_positions(x, cells, charts, face, grid_u, grid_v):
    """Physical positions of the integer points (grid_u, grid_v) inside triangles ``face``.

    Args:
        x: the mesh's vertices (n, 2).
        cells: the mesh's triangles (m, 3).
        charts: the triangles' charts.
        face, grid_u, grid_v: per point, the triangle and the integer coordinates.

    Returns:
        The positions (k, 2), by the triangles' affine maps.
    """
    offset = (np.stack([grid_u, grid_v], axis=1) * UNIT - charts.X[face, 0]).astype(float)
    return x[cells[face, 0]] + (charts.M[face] @ offset[:, :, None])[:, :, 0]


def _vertices_on_grid(n, cells, C):
    """Which vertices are integer points.

    Args:
        n: the number of vertices.
        cells: the mesh's triangles (m, 3).
        C: (m, 3, 2) the corners' fixed-point values.

    Returns:
        (n,) bool, True at the vertices whose values are integer points.
    """
    vertex_grid = np.zeros(n, dtype=bool)
    vertex_grid[cells] = (C % UNIT == 0).all(axis=2)
    return vertex_grid


def _distinct_pieces(p, q, face, direction):
    """One piece per node pair, its direction from the first triangle that has it.

    Args:
        p, q: the pieces' nodes, from p to q.
        face: the triangle of every piece.
        direction: (S, 2) the physical direction of every piece from p to q.

    Returns:
        The node pairs lo < hi and the direction (S', 2) from lo to hi.
    """
    order = np.argsort(face, kind="stable")
    p, q, direction = p[order], q[order], direction[order]
    lo, hi = np.minimum(p, q), np.maximum(p, q)
    direction = np.where((p < q)[:, None], direction, -direction)
    first, _ = _group(lo, hi)
    return lo[first], hi[first], direction[first]


def _exterior_pieces(p, q, boundary, ascending):
    """The boundary pieces, directed so that the outside is on their left (the domain is
    left of the counter-clockwise edge).

    Args:
        p, q: the pieces of the lines along an edge, p before q along the line.
        boundary: whether each piece's edge is a boundary edge.
        ascending: whether each piece's line runs with its triangle's counter-clockwise
            edge (then the edge runs from p to q).

    Returns:
        The boundary pieces' two nodes, the outside on the left of the first to the second.
    """
    up = ascending[boundary]
    return np.where(up, q[boundary], p[boundary]), np.where(up, p[boundary], q[boundary])


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
