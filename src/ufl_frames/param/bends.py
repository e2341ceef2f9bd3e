r"""The boundary's tightest bend: the largest uniform quad size whose quads can follow it.

A quad edge on the boundary is a chord of the boundary curve. Where the curve turns by much
more than a quad corner's worth over one quad edge (the round nose of an airfoil whose
radius is a fraction of the quad size), the quads cut across it: the layout's quad centres
fall outside the triangles and the rounded map folds, whatever the field. Corners are not
bends: at a boundary vertex the turn is taken modulo a quarter turn (the field turns with
the corner by whole quarter turns, the quads' corners follow), only the rest counts. Where
the model's corners are known (the points that must be quad vertices), only they are; every
other vertex's turn counts whole, so that a coarse polygon of a round curve is not taken for
corners.

For a boundary arc of length w, its bend is the absolute value of the sum of those rests
over it, each vertex's rest spread over the half edges beside it (the polygon's curvature
smeared out). :func:`bend_size` is the largest w at which no arc of length w
bends by more than :data:`MAX_BEND`: on a circle of radius r, w = :data:`MAX_BEND` · r.
Pure NumPy.
"""

from dataclasses import dataclass

import numpy as np

__all__ = ["MAX_BEND", "Bend", "bend_size", "boundary_loops"]

QUARTER = np.pi / 2

#: The turn (radians) the boundary may take over one quad edge, apart from whole quarter
#: turns at corners: 2 rad, a quad edge of twice the radius on a circle
#: (benchmarks/README.md, issue 37 leftovers, third part: the measured limit).
MAX_BEND = 2.0


@dataclass(frozen=True)
class Bend:
    """The tightest bend of a boundary.

    ``size``: the largest quad size whose edges turn by at most ``MAX_BEND`` along the
    boundary (``inf`` where no arc bends that much, e.g. a polygon with corners only);
    ``radius``: ``size / MAX_BEND``, the radius of the circle bending as much; ``at``: (2,)
    the boundary vertex in the middle of the arc that bends the most at ``size``.
    """

    size: float
    radius: float
    at: np.ndarray


def boundary_loops(x: np.ndarray, cells: np.ndarray) -> list[np.ndarray]:
    """The boundary of a counter-clockwise triangle mesh as closed vertex loops, the domain
    on their left. A vertex where the boundary touches itself (two outgoing boundary edges)
    ends the loops through it: each loop is then followed until it comes back or meets one.

    Args:
        x: vertex coordinates (n, 2).
        cells: triangles (m, 3), counter-clockwise.

    Returns:
        One array of vertex ids per loop (the first vertex not repeated at the end).
    """
    cells = np.asarray(cells, dtype=np.int64)
    directed = np.concatenate([cells[:, [0, 1]], cells[:, [1, 2]], cells[:, [2, 0]]])
    n = int(cells.max()) + 1 if cells.size else 0
    key = directed[:, 0] * n + directed[:, 1]
    reverse = directed[:, 1] * n + directed[:, 0]
    boundary = directed[~np.isin(key, reverse)]  # no twin: on the boundary, domain on the left
    succ = {}
    for a, b in boundary:
        succ.setdefault(int(a), []).append(int(b))
    loops, seen = [], set()
    for start in (int(a) for a in boundary[:, 0]):
        if start in seen:
            continue
        loop, v = [], start
        while v not in seen:
            seen.add(v)
            loop.append(v)
            after = succ.get(v, [])
            if len(after) != 1:
                break
            v = after[0]
        if len(loop) >= 3:
            loops.append(np.asarray(loop, dtype=np.int64))
    return loops


def _turns(p: np.ndarray, corner: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(each vertex's turn, less its whole quarter turns where ``corner`` (k,) is True; the
    lengths of the edges from each vertex to the next) of the closed polygon ``p`` (k, 2)."""
    incoming = p - np.roll(p, 1, axis=0)
    outgoing = np.roll(p, -1, axis=0) - p
    turn = np.arctan2(incoming[:, 0] * outgoing[:, 1] - incoming[:, 1] * outgoing[:, 0],
                      np.einsum("ij,ij->i", incoming, outgoing))
    rest = np.where(corner, turn - QUARTER * np.rint(turn / QUARTER), turn)
    return rest, np.linalg.norm(outgoing, axis=1)


def _worst_arc(rest: np.ndarray, length: np.ndarray, w: float) -> tuple[float, int]:
    """(the largest bend of an arc of length ``w`` on one closed loop, the vertex nearest
    the middle of that arc). Each vertex's turn is spread evenly over the half edges beside
    it (so that a polygon inscribed in a circle of radius R bends by 1/R per unit length,
    however fine); the bend of the arc [a, a + w] is then piecewise linear in a, largest
    where a or a + w is an edge's midpoint."""
    total = float(length.sum())
    if w >= total:  # the arc is the whole loop
        return abs(float(rest.sum())), int(np.argmax(np.abs(rest)))
    s = np.concatenate([[0.0], np.cumsum(length)[:-1]])  # arc position of each vertex
    mid = s + length / 2  # the knot after vertex j: its turn all counted there
    turned, whole = np.cumsum(rest), float(rest.sum())
    knots = np.concatenate([mid - total, mid, mid + total])
    values = np.concatenate([turned - whole, turned, turned + whole])
    a = np.mod(np.concatenate([mid, mid - w]) - mid[0], total) + mid[0]
    bend = np.abs(np.interp(a + w, knots, values) - np.interp(a, knots, values))
    i = int(np.argmax(bend))
    centre = np.mod(a[i] + w / 2, total)
    return float(bend[i]), int(np.argmin(np.abs(np.mod(s - centre + total / 2, total)
                                                - total / 2)))


def bend_size(x: np.ndarray, cells: np.ndarray, corners: np.ndarray | None = None,
              max_bend: float = MAX_BEND) -> Bend:
    """The boundary's tightest bend (:class:`Bend`): the largest w such that no boundary
    arc of length w turns by more than ``max_bend`` (whole quarter turns at corners not
    counted), found by bisection to 1 %.

    Args:
        x: vertex coordinates (n, 2) (or (n, 3), z ignored).
        cells: triangles (m, 3), counter-clockwise.
        corners: the vertices that are corners (the model points that must be quad
            vertices); None: every boundary vertex may be one.
        max_bend: the turn allowed over one quad edge, radians (> 0).

    Returns:
        The :class:`Bend`; ``size`` ``inf`` where no arc, not even a whole loop, bends by
        more than ``max_bend``.
    """
    if not max_bend > 0:
        raise ValueError(f"max_bend must be > 0, got {max_bend}")
    x = np.asarray(x, dtype=np.float64)[:, :2]
    loops = [(loop, *_turns(x[loop], np.ones(loop.size, bool) if corners is None
                            else np.isin(loop, corners)))
             for loop in boundary_loops(x, cells)]

    def worst(w):
        found = [(*_worst_arc(rest, length, w), loop) for loop, rest, length in loops]
        bend, i, loop = max(found, key=lambda f: f[0]) if found else (0.0, 0, None)
        return bend, None if loop is None else x[loop[i]]

    longest = max((float(length.sum()) for _, _, length in loops), default=0.0)
    bend, at = worst(longest)
    if bend <= max_bend:
        return Bend(size=np.inf, radius=np.inf, at=np.full(2, np.nan) if at is None else at)
    lo = min(float(length.min()) for _, _, length in loops)  # one edge: bends at one vertex
    hi = longest
    while hi > 1.01 * lo:
        mid = np.sqrt(lo * hi)
        if worst(mid)[0] <= max_bend:
            lo = mid
        else:
            hi = mid
    return Bend(size=lo, radius=lo / max_bend, at=worst(hi)[1])
