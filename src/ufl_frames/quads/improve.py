"""The worst quads improved: their interior vertices moved to raise the smallest scaled
Jacobian around them; and boundary vertices whose place along the boundary is free put where
their two boundary edges follow the boundary best (:func:`onto_boundary`).

The extracted quads (:mod:`~ufl_frames.quads.extract`) are the integer grid of the map,
exact but with the map's kinks: next to a singular vertex, a boundary cusp or a seam the
grid bends within a quad, and a few quads come out skewed. Moving only the vertices of
those quads, each to the position that maximises the worst scaled Jacobian of its own
quads (boundary vertices stay), straightens them without touching the rest of the mesh;
a move is taken only if it helps, so the worst quad never gets worse. Pure NumPy.
"""

import numpy as np

from ufl_frames.param.bends import boundary_loops
from ufl_frames.quads.measures import scaled_jacobians

__all__ = ["improve_worst_quads", "onto_boundary"]


#: Quads under this scaled Jacobian have their interior vertices optimised
#: (:func:`improve_worst_quads`).
WORST_SJ = 0.8


def improve_worst_quads(points, quads, sweeps: int = 3, searches: int = 12,
                        fixed=None) -> np.ndarray:
    """The points with every interior vertex of a quad with SJ < :data:`WORST_SJ` moved,
    one at a time, to raise the smallest SJ of its quads (a pattern search: 8 directions,
    the step halved when none helps, starting at a quarter of its mean edge); boundary
    vertices stay. A move is taken only if it raises that local minimum, so no quad
    around a moved vertex ends worse than the worst one there before. The ``fixed``
    points (indices: on model curves, at model points) stay too.

    Args:
        points: the points (n, 2); not modified.
        quads: point indices (m, 4), counter-clockwise.
        sweeps: passes over the bad vertices at most (fewer when none is left).
        searches: pattern-search steps per vertex and sweep.
        fixed: point indices that must not move, or None.

    Returns:
        The moved points (n, 2), a new array.
    """
    x = np.array(points, dtype=np.float64)
    quads = np.asarray(quads, dtype=np.int64)
    n = x.shape[0]
    pairs = np.sort(np.concatenate([quads[:, [i, (i + 1) % 4]] for i in range(4)]), axis=1)
    edges, counts = np.unique(pairs, axis=0, return_counts=True)
    boundary = np.zeros(n, dtype=bool)
    boundary[edges[counts == 1].ravel()] = True
    if fixed is not None:
        boundary[np.asarray(fixed, dtype=np.int64)] = True
    around = [[] for _ in range(n)]
    for k, quad in enumerate(quads):
        for v in quad:
            around[int(v)].append(k)
    directions = np.array([[np.cos(a), np.sin(a)] for a in np.arange(8) * np.pi / 4])
    for _ in range(sweeps):
        sj = scaled_jacobians(x, quads)
        bad = np.unique(quads[sj < WORST_SJ].ravel())
        bad = bad[~boundary[bad]]
        if bad.size == 0:
            break
        for v in bad[np.argsort([sj[around[v]].min() for v in bad])]:
            local = quads[around[v]]
            length = np.mean([np.linalg.norm(x[a] - x[b]) for q in local
                              for a, b in zip(q, np.roll(q, 1), strict=True) if v in (a, b)])
            h, best = 0.25 * length, scaled_jacobians(x, local).min()
            for _ in range(searches):
                start = x[v].copy()
                scores = []
                for d in directions:
                    x[v] = start + h * d
                    scores.append(scaled_jacobians(x, local).min())
                x[v] = start
                i = int(np.argmax(scores))
                if scores[i] > best + 1e-9:
                    x[v], best = start + h * directions[i], scores[i]
                else:
                    h *= 0.5
    return x


def _boundary_neighbours(quads: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(the previous, the next) boundary vertex of every vertex along the quads' boundary
    (counter-clockwise quads: the domain on the left), −1 where a vertex has not exactly
    one of each (inside, or where the boundary touches itself)."""
    directed = np.concatenate([quads[:, [i, (i + 1) % 4]] for i in range(4)])
    key = directed[:, 0] * n + directed[:, 1]
    boundary = directed[~np.isin(key, directed[:, 1] * n + directed[:, 0])]
    before, after = np.full(n, -1), np.full(n, -1)
    for column, out, other in ((0, after, 1), (1, before, 0)):
        ends, counts = np.unique(boundary[:, column], return_counts=True)
        once = ends[counts == 1]
        rows = boundary[np.isin(boundary[:, column], once)]
        out[rows[:, column]] = rows[:, other]
    return before, after


def onto_boundary(points, quads, vertices, x, cells) -> np.ndarray:
    """The points with each of ``vertices`` (boundary vertices of the quads whose place
    along the boundary is free, such as a point that stands for several points of the map
    glued together: :func:`~ufl_frames.quads.patches.patch_quads`) put on the boundary of
    the triangles ``x``, ``cells`` between its two boundary neighbours a and b, where the
    two quad edges to them (chords of the boundary) are longest together: where they follow
    the boundary best (on a circular arc, its middle; on a straight boundary anywhere: the
    vertex then stays where it is, put onto the boundary). |ap| + |pb| is convex along a
    straight segment, so the best p is a vertex of the boundary polyline between a and b,
    or where the vertex is now. Only places where the vertex's quads keep a positive
    scaled Jacobian are taken (none: the best of all); vertices with no single neighbour
    on each side, or whose neighbours are not on one boundary loop with it between them,
    stay.

    Args:
        points: the quads' points (n, 2+); not modified.
        quads: point indices (m, 4), counter-clockwise.
        vertices: the point indices to place.
        x: the triangles' vertices (N, 2+).
        cells: the triangles (M, 3), counter-clockwise.

    Returns:
        The points (n, 2+), a new array.
    """
    out = np.array(points, dtype=np.float64)
    vertices = np.asarray(vertices, dtype=np.int64)
    if vertices.size == 0:
        return out
    quads = np.asarray(quads, dtype=np.int64)
    x = np.asarray(x, dtype=np.float64)[:, :2]
    loops = boundary_loops(x, cells)
    if not loops:
        return out
    starts = np.concatenate([x[loop] for loop in loops])
    ends = np.concatenate([x[np.roll(loop, -1)] for loop in loops])
    owner = np.concatenate([np.full(loop.size, k) for k, loop in enumerate(loops)])
    length = np.linalg.norm(ends - starts, axis=1)
    offset = np.concatenate([np.concatenate([[0.0], np.cumsum(length[owner == k])[:-1]])
                             for k in range(len(loops))])
    total = np.array([length[owner == k].sum() for k in range(len(loops))])

    def project(p):
        """(loop, arc position, the point) of the boundary nearest to p."""
        d = ends - starts
        t = np.clip(np.einsum("kj,kj->k", p - starts, d) / np.maximum(
            np.einsum("kj,kj->k", d, d), 1e-300), 0.0, 1.0)
        near = starts + t[:, None] * d
        k = int(np.argmin(np.linalg.norm(near - p, axis=1)))
        return int(owner[k]), float(offset[k] + t[k] * length[k]), near[k]

    before, after = _boundary_neighbours(quads, out.shape[0])
    around = {int(v): np.flatnonzero((quads == v).any(axis=1)) for v in vertices}
    for v in vertices.tolist():
        a, b = int(before[v]), int(after[v])
        if a < 0 or b < 0:
            continue
        (la, sa, _), (lv, sv, here), (lb, sb, _) = (project(out[i, :2]) for i in (a, v, b))
        span = (sb - sa) % total[lv]
        if not la == lv == lb or not 0 < (sv - sa) % total[lv] < span:
            continue
        mine = np.flatnonzero(owner == lv)
        inside = mine[(0 < (offset[mine] - sa) % total[lv])
                      & ((offset[mine] - sa) % total[lv] < span)]
        candidates = np.concatenate([here[None], starts[inside]])
        chords = (np.linalg.norm(candidates - out[a, :2], axis=1)
                  + np.linalg.norm(candidates - out[b, :2], axis=1))
        chords[1:][chords[1:] <= chords[0] * (1 + 1e-9)] = -np.inf  # ties: where it is
        worst = []
        for p in candidates:
            out[v, :2] = p
            worst.append(scaled_jacobians(out, quads[around[v]]).min())
        keep = np.asarray(worst) > 0
        order = np.argsort(-np.where(keep, chords, -np.inf) if keep.any() else -chords,
                          kind="stable")
        out[v, :2] = candidates[order[0]]
    return out
