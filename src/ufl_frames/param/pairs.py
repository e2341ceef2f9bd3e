r"""± pairs of singularities closer than a quad, removed from the map's input field.

A +1/4 and a −1/4 singularity closer than a quad edge cannot both be quad vertices (they
would have to sit at two grid points less than a grid step apart): the integer-grid map
folds around them or the quantisation has to move one a whole quad away. On a small disk
of triangles around such a pair the field's total index is 0, so its boundary frames have
a continuous angle (a lift of the cross angle along the boundary loop comes back to
itself) and a field without singularities exists inside. :func:`remove_close_pairs`
replaces the field there by the harmonic extension of the boundary's lifted angle and log
lengths (for a conformal field, whose angle and log scale are conjugate harmonic
functions, the smooth field with those boundary frames) and checks that no singular
vertex is left inside and none is made at the patch's rim. Only the rank-0 arrays the map
is built from change; the field itself (its files) does not.

A patch may reach the domain's boundary, whose aligned frames it keeps (on its rim).
Left alone: a pair whose patch would hold a corner or another model point (a singularity
near a corner may carry the corner's index; a point the user placed), an interior model
curve (an interface or an embedded curve: frames the user prescribed), or a third
singularity; and every pair at or beyond the threshold. The singularities the solver
pinned on a level of a nested solve are the solver's, not the user's: they may be removed.

The threshold is in local quad edges: at scale s the grid's cells have edges l1/s, l2/s
(:func:`~ufl_frames.param.seamless.scale_for_quad_size`), so the local quad edge is
(l1 + l2)/(2s) at the pair's midpoint.
"""

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph
from scipy.sparse.linalg import spsolve

from ufl_frames.frames2d import odeco
from ufl_frames.param import cut as cutting
from ufl_frames.param.features import Features

__all__ = ["CLOSER_THAN", "AbsorbedCorners", "RemovedPairs", "absorb_at_acute_corners",
           "acute_corners", "describe", "local_quad_edge", "remove_close_pairs"]

#: Pairs closer than this many local quad edges are removed: both would have to be quad
#: vertices a whole edge apart, so together they move by more than their distance. (The
#: MathEval disk's two pairs at 400 quads sit 0.30 quad edges apart: kept at 0.3, the layout's
#: quads fail the checks and greedy rounding makes 10 irregular vertices; removed at 0.5,
#: the layout makes quads with 6: benchmarks/README.md, 2026-12-07 second session.)
CLOSER_THAN = 0.5

QUARTER = np.pi / 2


@dataclass(frozen=True)
class RemovedPairs:
    """What :func:`remove_close_pairs` did: ``within`` the threshold (local quad edges),
    ``removed`` the pairs removed and ``kept`` the close pairs left, each a dict
    ``{"plus": [x, y], "minus": [x, y], "distance", "quads"}`` (the distance in local
    quad edges), those kept with ``"why"``; ``changed`` the vertices whose frames were
    replaced (into the arrays it was given)."""

    within: float
    removed: tuple = ()
    kept: tuple = ()
    changed: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64),
                                repr=False)

    @property
    def key(self) -> tuple:
        """The removed pairs' positions: equal keys, equal fields."""
        return tuple((tuple(p["plus"]), tuple(p["minus"])) for p in self.removed)

    def as_dict(self) -> dict:
        """The record for ``summary.json``."""
        return {"within_quads": self.within, "removed": len(self.removed),
                "pairs": list(self.removed), "kept_close": list(self.kept)}



def describe(removed: dict | None) -> str | None:
    """One log line of :meth:`RemovedPairs.as_dict`'s record (None where no pair was
    closer than the threshold)."""
    if not removed or not (removed["removed"] or removed["kept_close"]):
        return None
    count, kept = removed["removed"], removed["kept_close"]
    text = (f"{count} ± pair{'' if count == 1 else 's'} closer than "
            f"{removed['within_quads']:g} quad removed before the map")
    if kept:
        text += f" ({len(kept)} kept: {kept[0]['why']})"
    return text


def local_quad_edge(x, cells, q, quad_size: float | None = None,
                    quad_count: float | None = None) -> np.ndarray:
    """The quads' local edge length (l1 + l2)/(2s) at every vertex (n,), at the scale s
    that :func:`~ufl_frames.param.seamless.scale_for_quad_size` (``quad_size``) or
    :func:`~ufl_frames.param.seamless.scale_for_quad_count` (``quad_count``) gives the
    cut mesh of this field (its per-triangle l1 l2 and l1 + l2 do not depend on the cut).

    Args:
        x: vertex coordinates (n, 2+).
        cells: triangles (m, 3).
        q: the P1 frame field (n, 5).
        quad_size: the quads' mean edge length, or
        quad_count: about this many quads (exactly one of the two).

    Returns:
        The local quad edge length per vertex (n,).
    """
    from ufl_frames.param.seamless import gradients

    if (quad_size is None) == (quad_count is None):
        raise ValueError("give a quad size or a quad count")
    x = np.asarray(x, dtype=np.float64)[:, :2]
    cells = np.asarray(cells, dtype=np.int64)
    area, _ = gradients(x, cells)
    area = np.abs(area)
    _, l1, l2 = cutting.face_frames(cells, np.asarray(q, dtype=np.float64))
    density = area / (l1 * l2)
    if quad_size is not None:
        scale = float(np.dot(density, 0.5 * (l1 + l2)) / density.sum() / quad_size)
    else:
        scale = float(np.sqrt(quad_count / density.sum()))
    lengths, _ = odeco.q_to_frames(np.asarray(q, dtype=np.float64))
    return lengths.sum(axis=1) / (2 * scale)


def remove_close_pairs(x, cells, q, edge, within: float = CLOSER_THAN,
                       features: Features | None = None, given_frames=None):
    """The field ``q`` with every ± pair of singular vertices closer than ``within`` local
    quad edges replaced, on a disk of triangles around it, by a field without
    singularities (see the module's note); closest pairs first, each vertex once.

    Args:
        x: vertex coordinates (n, 2+).
        cells: triangles (m, 3), either orientation.
        q: the P1 frame field (n, 5); not modified.
        edge: the local quad edge length per vertex (n,) (:func:`local_quad_edge`).
        within: the threshold in local quad edges.
        features: the model's curves and points on this mesh (patches keep off them).
        given_frames: triangle frames the map takes as they are
            (:attr:`AbsorbedCorners.frames`; their vertices are the corners' and stay
            out of the patches), or None.

    Returns:
        (q, record): the new field (n, 5) (``q`` itself where nothing was removed) and
        the :class:`RemovedPairs`.
    """
    x = np.asarray(x, dtype=np.float64)[:, :2]
    cells = np.asarray(cells, dtype=np.int64)
    q = np.asarray(q, dtype=np.float64)
    cells = cutting.counterclockwise(x, cells)
    edges, faces = cutting.interior_edges(cells)
    singular, turns = _singular(cells, q, edges, faces, given_frames)
    positive, negative = singular[turns == 1], singular[turns == -1]
    if positive.size == 0 or negative.size == 0:
        return q, RemovedPairs(within=within)
    edge = np.asarray(edge, dtype=np.float64)
    distance = np.linalg.norm(x[positive][:, None] - x[negative][None], axis=2)
    local = 0.5 * (edge[positive][:, None] + edge[negative][None])
    close = sorted((distance[i, j], i, j)
                   for i, j in zip(*np.nonzero(distance < within * local), strict=True))
    if not close:
        return q, RemovedPairs(within=within)
    blocked, rim = _blocked_vertices(x, cells, edges, faces, features)
    if given_frames is not None:
        blocked[cells[given_frames[0]].ravel()] = True
    n = x.shape[0]
    neighbours = _vertex_graph(edges, n)
    removed, kept, used, changed = [], [], set(), []
    q_new, current = q.copy(), np.sort(singular)  # the singular vertices left
    for d, i, j in close:
        a, b = int(positive[i]), int(negative[j])
        entry = {"plus": x[a].tolist(), "minus": x[b].tolist(), "distance": float(d),
                 "quads": float(d / local[i, j])}
        if a in used or b in used:
            continue
        used.update((a, b))
        patch = _patch(x, cells, neighbours, a, b, d, rim)
        why = _unusable(patch, cells, edges, faces, blocked, current, {a, b})
        if why is None:
            trial = q_new.copy()
            why = _smooth_inside(x, cells, trial, patch)
            if why is None:
                left, _ = _singular(cells, trial, edges, faces, given_frames)
                expected = np.setdiff1d(current, [a, b])
                if not np.array_equal(np.sort(left), expected):
                    why = "the smooth field inside would still be singular"
                else:
                    q_new, current = trial, expected
                    changed.append(patch[0])
                    removed.append(entry)
                    continue
        kept.append(dict(entry, why=why))
    record = RemovedPairs(within=within, removed=tuple(removed), kept=tuple(kept),
                          changed=np.unique(np.concatenate(changed)) if changed
                          else np.zeros(0, dtype=np.int64))
    return (q_new if removed else q), record


def _singular(cells, q, edges, faces, given=None):
    """(singular interior vertices, their turns in quarters) of the face field of ``q``
    (:func:`~ufl_frames.param.cut.singular_vertices`; ``given`` frames as for
    :func:`~ufl_frames.param.cut.face_frames_with`)."""
    angle, _, _ = cutting.face_frames_with(cells, q, given)
    return cutting.singular_vertices(cells, angle, edges, faces)


def _blocked_vertices(x, cells, edges, faces, features):
    """(blocked, rim): the vertices a patch may not hold at all — the model's required
    points (corners, points the user placed: a singularity near one may carry its index)
    and the ends of interior model curve edges (interfaces, embedded curves: frames the
    user prescribed) — and those it may hold only on its rim, fixed: the domain's
    boundary (its frames are aligned and stay)."""
    blocked = np.zeros(x.shape[0], dtype=bool)
    rim = np.zeros(x.shape[0], dtype=bool)
    rim[edges[faces[:, 1] < 0].ravel()] = True
    if features is not None:
        blocked[np.asarray(features.required_points, dtype=np.int64)] = True
        inner = features.interior_curve_edges(cells)
        blocked[np.asarray(features.curve_edges, dtype=np.int64)[inner].ravel()] = True
    return blocked, rim


#: A patch reaches this many times the pair's distance, and at least this many rings of
#: triangles, beyond the segment between the two.
PATCH_REACH = 1.0
PATCH_RINGS = 3


def _patch(x, cells, neighbours, a, b, d, on_boundary):
    """(free vertices, triangles) of the disk around the pair (a, b): the vertices within
    max(PATCH_REACH d, PATCH_RINGS local edges) of the segment ab, their triangles, and
    then only the vertices all of whose triangles are in the patch, off the domain's
    boundary, are free."""
    h = float(np.mean([np.linalg.norm(x[neighbours[v].indices] - x[v], axis=1).mean()
                       for v in (a, b)]))
    reach = max(PATCH_REACH * d, PATCH_RINGS * h)
    ab = x[b] - x[a]
    t = np.clip((x - x[a]) @ ab / max(float(ab @ ab), 1e-300), 0.0, 1.0)
    near = np.linalg.norm(x - (x[a] + t[:, None] * ab), axis=1) <= reach
    near = _component(neighbours, near, a)
    triangles = np.flatnonzero(near[cells].any(axis=1))
    return _free_vertices(cells, triangles, on_boundary), triangles


def _vertex_graph(edges, n):
    """The mesh's vertex adjacency (n, n), symmetric, from its edges (E, 2)."""
    return sp.csr_matrix((np.ones(2 * edges.shape[0]),
                          (edges.ravel(), edges[:, ::-1].ravel())), shape=(n, n))


def _component(neighbours, near, v):
    """``near`` (n,) bool restricted to its mesh-connected component that holds ``v``."""
    rows, cols = neighbours.nonzero()
    both = near[rows] & near[cols]
    sub = sp.csr_matrix((np.ones(int(both.sum())), (rows[both], cols[both])),
                        shape=neighbours.shape)
    _, label = csgraph.connected_components(sub, directed=False)
    return near & (label == label[v])


def _free_vertices(cells, triangles, on_boundary):
    """The vertices all of whose triangles are among ``triangles``, off the domain's
    boundary (``on_boundary`` (n,) bool)."""
    inside = np.zeros(on_boundary.shape[0], dtype=bool)
    inside[cells[triangles].ravel()] = True
    rest = np.ones(cells.shape[0], dtype=bool)
    rest[triangles] = False
    outside = np.zeros(on_boundary.shape[0], dtype=bool)
    outside[cells[rest].ravel()] = True
    return np.flatnonzero(inside & ~outside & ~on_boundary)


def _is_disk(cells, triangles) -> bool:
    """Whether the triangles form a disk (Euler characteristic 1, one boundary loop)."""
    used = np.unique(cells[triangles].ravel())
    local_edges, local_faces = cutting.interior_edges(cells[triangles])
    euler = used.size - local_edges.shape[0] + triangles.size
    loops = cutting._boundary_loops(local_edges, local_faces, int(cells.max()) + 1)
    return euler == 1 and len(loops) == 1


def _unusable(patch, cells, edges, faces, blocked, singular, pair):
    """Why the patch cannot take a smooth field (None where it can)."""
    free, triangles = patch
    if not pair <= set(free.tolist()):
        return "the patch does not hold both singularities"
    if blocked[cells[triangles].ravel()].any():
        return "near a corner, a model point or an interior model curve"
    others = set(np.intersect1d(singular, cells[triangles].ravel()).tolist()) - pair
    if others:
        return "another singularity in the patch"
    return None if _is_disk(cells, triangles) else "the patch is not a disk"


def _boundary_cycle(cells, triangles):
    """The patch's boundary vertices in order around it (one loop)."""
    local = cells[triangles]
    directed = np.concatenate([local[:, [0, 1]], local[:, [1, 2]], local[:, [2, 0]]])
    forward = {(int(u), int(v)) for u, v in directed}
    nxt = {u: v for u, v in forward if (v, u) not in forward}
    if len(nxt) != sum((v, u) not in forward for u, v in forward):
        return None  # a vertex twice on the rim: not a simple loop
    start = next(iter(nxt))
    cycle, v = [start], nxt[start]
    while v != start:
        cycle.append(v)
        v = nxt[v]
    return np.asarray(cycle, dtype=np.int64)


def _smooth_inside(x, cells, q, patch):
    """Replace ``q`` (in place) at the patch's free vertices by the harmonic extension
    (clipped cotangent weights) of the boundary frames' lifted angle and log lengths;
    the reason where the boundary's lifted angle does not close (None where it does)."""
    lifted = _harmonic_lift(x, cells, q, patch)
    if isinstance(lifted, str):
        return lifted
    verts, values = lifted
    free = patch[0]
    inner = values[np.searchsorted(verts, free)]
    q[free] = odeco.frames_to_q(np.exp(inner[:, 1:]), inner[:, 0])
    return None


def _harmonic_lift(x, cells, q, patch):
    """(the patch's vertices (sorted), their (angle, log l1, log l2) (nv, 3)): the rim's
    frames lifted along it (one labelling, the angle continuous), extended harmonically
    to the free vertices; or the reason where the lifted angle does not close."""
    free, triangles = patch
    loop = _boundary_cycle(cells, triangles)
    if loop is None:
        return "the patch's rim is not one loop"
    lengths, angle = odeco.q_to_frames(q[loop])
    lifted_t, lifted = [float(angle[0])], [lengths[0].copy()]
    for t, ls in zip(angle[1:], lengths[1:], strict=True):
        k = int(np.rint((lifted_t[-1] - t) / QUARTER))
        lifted_t.append(t + k * QUARTER)
        lifted.append(ls[::-1].copy() if k % 2 else ls.copy())
    if int(np.rint((lifted_t[-1] - angle[0]) / QUARTER)) != 0:  # v0 met again, turned
        return "the field turns along the patch's boundary"
    known = np.column_stack([lifted_t, np.log(np.asarray(lifted))])  # (b, 3)
    verts = np.unique(cells[triangles].ravel())
    index = -np.ones(x.shape[0], dtype=np.int64)
    index[verts] = np.arange(verts.size)
    L = _cotangent_laplacian(x, cells[triangles], index, verts.size)
    is_free = np.zeros(verts.size, dtype=bool)
    is_free[index[free]] = True
    values = np.zeros((verts.size, 3))
    fixed = index[loop]
    values[fixed] = known
    if (~is_free).sum() != loop.size:
        return "the patch's rim is not one loop"
    A = L[is_free][:, is_free].tocsc()
    rhs = -L[is_free][:, ~is_free] @ values[~is_free]
    solved = spsolve(A, rhs)
    values[is_free] = np.asarray(solved).reshape(-1, 3)
    if not np.all(np.isfinite(values)):
        return "the harmonic extension failed"
    return verts, values


def _cotangent_laplacian(x, local_cells, index, size):
    """The P1 stiffness matrix (weights clipped at 0: a maximum principle) of the
    triangles ``local_cells`` on the vertices numbered by ``index``."""
    rows, cols, vals = [], [], []
    for i in range(3):
        j, k = (i + 1) % 3, (i + 2) % 3
        u = x[local_cells[:, j]] - x[local_cells[:, i]]
        v = x[local_cells[:, k]] - x[local_cells[:, i]]
        cross = np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])
        w = np.maximum(0.5 * np.einsum("mk,mk->m", u, v) / np.maximum(cross, 1e-300), 0.0)
        a, b = index[local_cells[:, j]], index[local_cells[:, k]]
        rows += [a, b, a, b]
        cols += [b, a, a, b]
        vals += [-w, -w, w, w]
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(size, size))


#: A corner's patch reaches this many local edges beyond its −1/4 singular vertex.
CORNER_RINGS = 2


def acute_corners(x, cells) -> np.ndarray:
    """The boundary vertices whose interior angle (the sum of their triangles' angles) is
    under 45°: corners of one quarter turn that a smooth field rounds to none
    (:func:`~ufl_frames.frames2d.singularities.corner_quarter_turns`)."""
    from ufl_frames.param.seamless import angle_sums

    x = np.asarray(x, dtype=np.float64)[:, :2]
    cells = np.asarray(cells, dtype=np.int64)
    edges, faces = cutting.interior_edges(cells)
    boundary = np.unique(edges[faces[:, 1] < 0])
    angle = np.abs(angle_sums(cells, x[cells], x.shape[0]))
    return boundary[angle[boundary] < QUARTER / 2]


@dataclass(frozen=True)
class AbsorbedCorners:
    """What :func:`absorb_at_acute_corners` made of a field, for the map: ``q`` the field
    (the input where nothing changed), ``frames`` = (triangles, angle, l1, l2) the lifted
    frames of the corners' triangles to take as they are
    (:func:`~ufl_frames.param.cut.face_frames_with`; None: none), ``absorbed`` and
    ``kept`` dicts ``{"corner": [x, y], "minus": [x, y], "distance"}`` of the singular
    vertices moved into a corner and of those left (with ``"why"``)."""

    q: np.ndarray = field(repr=False)
    frames: tuple | None = field(default=None, repr=False)
    absorbed: tuple = ()
    kept: tuple = ()

    def as_dict(self) -> dict:
        """The record for ``summary.json``."""
        return {"absorbed": len(self.absorbed), "corners": list(self.absorbed),
                "kept": list(self.kept)}


def absorb_at_acute_corners(x, cells, q, features: Features | None = None) -> AbsorbedCorners:
    """The field ``q`` with the −1/4 singular vertex nearest to each corner under 45°
    moved into the corner, for the map.

    A boundary-aligned smooth field takes such a corner (its vertex cross held at one
    quarter turn, :func:`~ufl_frames.frames2d.singularities.corner_cross`) as a corner of
    none: the field between the two curves turns the short way, and the −1/4
    singularity that makes up the difference sits out in the gap (its ± partner the
    corner's triangle, which holds the quarter turn). A quad corner squeezed to the
    corner's angle needs the quarter turn at the corner and no singularity in the gap:
    on the disk of triangles around the corner within the singular vertex's distance
    (and :data:`CORNER_RINGS` edges), the field is replaced by the harmonic extension of
    its rim's lifted angle and log lengths (as :func:`remove_close_pairs` does; the rim
    runs through the corner's held cross, so it closes only where the corner holds the
    quarter turn). Near the corner the field turns by more than 45° across one triangle
    (the gap is a triangle wide), more than a triangle's three crosses can say: the
    disk's triangles keep the lifted field's frames (their vertices' mean), not those of
    their vertex crosses. Refused (the field kept) where the rim does not close, another
    singular vertex, a model point other than the corner or an interior model curve is
    in the disk, the disk is no disk, or a singular vertex is left or made.

    Args:
        x: vertex coordinates (n, 2+).
        cells: triangles (m, 3), either orientation.
        q: the P1 frame field (n, 5); not modified.
        features: the model's curves and points on this mesh.

    Returns:
        The :class:`AbsorbedCorners`.
    """
    x = np.asarray(x, dtype=np.float64)[:, :2]
    cells = np.asarray(cells, dtype=np.int64)
    q = np.asarray(q, dtype=np.float64)
    corners = acute_corners(x, cells)
    if corners.size == 0:
        return AbsorbedCorners(q=q)
    cells = cutting.counterclockwise(x, cells)
    edges, faces = cutting.interior_edges(cells)
    singular, turns = _singular(cells, q, edges, faces)
    minus_all = singular[turns == -1]
    blocked, rim = _blocked_vertices(x, cells, edges, faces, features)
    n = x.shape[0]
    neighbours = _vertex_graph(edges, n)
    length = np.linalg.norm(x[edges[:, 1]] - x[edges[:, 0]], axis=1)
    h = np.bincount(edges.ravel(), weights=np.repeat(length, 2), minlength=n) / np.maximum(
        np.bincount(edges.ravel(), minlength=n), 1)
    q_new, current, given = q, np.sort(singular), None
    absorbed, kept = [], []
    for v in corners:
        minus = current[np.isin(current, minus_all)]
        if minus.size == 0:
            break
        d = np.linalg.norm(x[minus] - x[v], axis=1)
        b = int(minus[np.argmin(d)])
        entry = {"corner": x[v].tolist(), "minus": x[b].tolist(), "distance": float(d.min())}
        patch = _corner_patch(x, cells, neighbours, int(v), b,
                              float(d.min()) + CORNER_RINGS * h[b], rim)
        why = _corner_unusable(patch, cells, blocked, current, int(v), b)
        lifted = why or _harmonic_lift(x, cells, q_new, patch)
        if isinstance(lifted, str):
            kept.append(dict(entry, why=lifted))
            continue
        verts, values = lifted
        trial = q_new.copy()
        free = patch[0]
        inner = values[np.searchsorted(verts, free)]
        trial[free] = odeco.frames_to_q(np.exp(inner[:, 1:]), inner[:, 0])
        triangles = patch[1]
        at = values[np.searchsorted(verts, cells[triangles])]  # (t, 3, 3)
        mine = (triangles, at[:, :, 0].mean(axis=1), np.exp(at[:, :, 1]).mean(axis=1),
                np.exp(at[:, :, 2]).mean(axis=1))
        trial_given = mine if given is None else tuple(
            np.concatenate([g, m]) for g, m in zip(given, mine, strict=True))
        left, _ = _singular(cells, trial, edges, faces, trial_given)
        expected = np.setdiff1d(current, [b])
        if not np.array_equal(np.sort(left), expected):
            kept.append(dict(entry, why="the smooth field inside would still be singular"))
            continue
        q_new, current, given = trial, expected, trial_given
        absorbed.append(entry)
    return AbsorbedCorners(q=q_new, frames=given, absorbed=tuple(absorbed), kept=tuple(kept))


def _corner_patch(x, cells, neighbours, v, b, reach, on_boundary):
    """(free vertices, triangles) of the disk of radius ``reach`` around corner ``v``: the
    mesh-connected component of the vertices within ``reach`` that holds ``v`` (and
    ``b``), their triangles; free are the vertices all of whose triangles are in it, off
    the domain's boundary."""
    near = _component(neighbours, np.linalg.norm(x - x[v], axis=1) <= reach, v)
    triangles = np.flatnonzero(near[cells].all(axis=1))
    return _free_vertices(cells, triangles, on_boundary), triangles


def _corner_unusable(patch, cells, blocked, singular, v, b):
    """Why the corner's patch cannot take a smooth field (None where it can)."""
    free, triangles = patch
    if b not in set(free.tolist()):
        return "the patch does not hold the singularity"
    points = np.setdiff1d(cells[triangles].ravel(), [v])
    if blocked[points].any():
        return "a model point or an interior model curve near the corner"
    if set(np.intersect1d(singular, cells[triangles].ravel()).tolist()) - {b}:
        return "another singularity in the patch"
    return None if _is_disk(cells, triangles) else "the patch is not a disk"
