"""The worst quads improved: their interior vertices moved to raise the smallest scaled
Jacobian around them.

The extracted quads (:mod:`~ufl_frames.quads.extract`) are the integer grid of the map,
exact but with the map's kinks: next to a singular vertex, a boundary cusp or a seam the
grid bends within a quad, and a few quads come out skewed. Moving only the vertices of
those quads, each to the position that maximises the worst scaled Jacobian of its own
quads (boundary vertices stay), straightens them without touching the rest of the mesh;
a move is taken only if it helps, so the worst quad never gets worse. Pure NumPy.
"""

import numpy as np

from ufl_frames.quads.measures import scaled_jacobians

__all__ = ["improve_worst_quads"]


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
