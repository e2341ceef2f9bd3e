r"""The geometry's model entities on a quad mesh: the region of every quad, the quad edges
on the model curves, the quad vertices at the model points — found again on the quads from
the triangles' :class:`~ufl_frames.param.features.Features`, and checked.

The map makes every model curve an integer iso-line and every model point an integer
point (:mod:`~ufl_frames.param.quantise`), so the quads' edges run along the curves and
their vertices sit on the points; here they are recognised geometrically, apart from how
the quads were made:

* a quad's region is that of the triangle under its centre;
* a quad edge lies on a curve where the middle of its traced chain (the iso-line under it,
  :attr:`~ufl_frames.quads.extract.QuadMesh.chains`) is on one of the curve's triangle
  edges, to a 10⁻⁹ share of the mesh's diameter; where there are no chains (the T-mesh's
  quads), where both its ends are on the curve to that share and its middle within
  :data:`ALONG` of its length (a chord along the curve, not across it);
* a model point's quad vertex is the one at its place, to that share.

:func:`feature_problems` checks the result against the triangles: every model point a
quad vertex, every quad's corners in its region (none straddles an interface), and per
region the quads' area and per curve the quad edges' length equal the triangles' to
:data:`RTOL`.

Pure NumPy/SciPy.
"""

from dataclasses import replace

import numpy as np
from scipy.spatial import cKDTree

from ufl_frames.param.features import Features

__all__ = ["RTOL", "TOLERANCE", "curve_lengths", "feature_problems", "locate", "quad_features",
           "region_areas"]

#: Distances below this share of the mesh's diameter count as zero.
TOLERANCE = 1e-9
#: The relative difference allowed between the quads' and the triangles' region areas and
#: curve lengths (chords of the curves, on both sides).
RTOL = 5e-3
#: Nearest triangles (by centroid) or curve edges (by midpoint) a point is tested against.
NEAREST = 12


def _diameter(x) -> float:
    return float(np.ptp(x, axis=0).max()) if x.size else 1.0


def _barycentric(x, cells, candidates, p):
    """Barycentric coordinates (k, c, 3) of points p (k, 2) in their candidate triangles
    (k, c)."""
    a, b, c = (x[cells[candidates, i]] for i in range(3))
    e1, e2, d = b - a, c - a, p[:, None, :] - a
    det = e1[..., 0] * e2[..., 1] - e1[..., 1] * e2[..., 0]
    det = np.where(det == 0, 1e-300, det)
    s = (d[..., 0] * e2[..., 1] - d[..., 1] * e2[..., 0]) / det
    t = (e1[..., 0] * d[..., 1] - e1[..., 1] * d[..., 0]) / det
    return np.stack([1 - s - t, s, t], axis=-1)


def _candidates(x, cells, p):
    """The :data:`NEAREST` triangles by centroid of every point p (k, 2), and their
    barycentric coordinates."""
    tree = cKDTree(x[cells].mean(axis=1))
    _, candidates = tree.query(p, k=min(NEAREST, cells.shape[0]))
    candidates = np.asarray(candidates).reshape(p.shape[0], -1)
    return candidates, _barycentric(x, cells, candidates, p)


#: The barycentric coordinate above which a point counts as in a triangle.
HOLDS = -1e-6


def _holding(x, cells, p):
    """Every triangle that holds each point of ``p`` (k, 2): k arrays of triangle indices
    (a point on an edge or vertex is held by each of its triangles).

    Exhaustive, unlike the :data:`NEAREST` centroids (which miss the triangle under a
    point where the triangles are slivers, such as the halves of a transfinite grid's
    graded quads): a triangle holding p has its centroid no farther from p than from its
    own farthest vertex, so the triangles whose centroid lies within the largest such
    distance of the mesh include all of them."""
    corners = x[cells]
    centroids = corners.mean(axis=1)
    reach = float(np.linalg.norm(corners - centroids[:, None], axis=2).max(initial=0.0))
    tree = cKDTree(centroids)
    out = []
    for point, near in zip(p, tree.query_ball_point(p, reach * (1 + 1e-9)), strict=True):
        near = np.asarray(near, dtype=np.int64)
        bary = _barycentric(x, cells, near[None, :], point[None, :])[0]
        out.append(near[bary.min(axis=1) >= HOLDS] if near.size else near)
    return out


def locate(x, cells, p) -> np.ndarray:
    """The triangle of ``cells`` on ``x`` that holds each point of ``p`` (k, 2): the one
    among the nearest whose smallest barycentric coordinate is largest, or where none of
    them holds it, any that does (:func:`_holding`); −1 where none holds it (smallest
    coordinate under −10⁻⁶: outside the mesh)."""
    p = np.asarray(p, dtype=np.float64)
    candidates, bary = _candidates(x, cells, p)
    worst = bary.min(axis=2)
    best = worst.argmax(axis=1)
    found = candidates[np.arange(candidates.shape[0]), best]
    found = np.where(worst[np.arange(best.size), best] >= HOLDS, found, -1)
    missed = np.flatnonzero(found < 0)
    for i, held in zip(missed, _holding(x, cells, p[missed]), strict=True):
        if held.size:
            found[i] = held[0]
    return found


def _quad_edges(quads):
    """The distinct edges (e, 2) of the quads, sorted pairs."""
    q = np.asarray(quads, dtype=np.int64)
    pairs = np.sort(np.stack([q, np.roll(q, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
    return np.unique(pairs, axis=0)


def _polyline_middle(polyline) -> np.ndarray:
    """The point halfway along a polyline (k, 2) by length."""
    step = np.linalg.norm(np.diff(polyline, axis=0), axis=1)
    total = step.sum()
    if total == 0:
        return polyline[0]
    along = np.concatenate([[0.0], np.cumsum(step)])
    i = int(np.clip(np.searchsorted(along, 0.5 * total) - 1, 0, step.size - 1))
    t = (0.5 * total - along[i]) / step[i] if step[i] else 0.0
    return polyline[i] + t * (polyline[i + 1] - polyline[i])


def _on_curve(x, curve_edges, p, tol, within=None):
    """The curve edge (index into ``curve_edges``) that each point of ``p`` lies on
    within ``tol`` (or within ``within`` (k,) per point; −1 for none)."""
    if curve_edges.shape[0] == 0 or p.shape[0] == 0:
        return np.full(p.shape[0], -1, dtype=np.int64)
    a, b = x[curve_edges[:, 0]], x[curve_edges[:, 1]]
    tree = cKDTree(0.5 * (a + b))
    _, near = tree.query(p, k=min(NEAREST, curve_edges.shape[0]))
    near = np.asarray(near).reshape(p.shape[0], -1)
    d = b[near] - a[near]
    w = p[:, None, :] - a[near]
    t = np.clip(np.einsum("kcj,kcj->kc", w, d) / np.maximum(np.einsum("kcj,kcj->kc", d, d),
                                                             1e-300), 0.0, 1.0)
    distance = np.linalg.norm(w - t[..., None] * d, axis=2)
    best = distance.argmin(axis=1)
    found = near[np.arange(p.shape[0]), best]
    limit = np.broadcast_to(tol if within is None else np.maximum(within, tol), p.shape[0])
    found = np.where(distance[np.arange(p.shape[0]), best] <= limit, found, -1)
    # The nearest midpoints miss a long edge beside short ones: every edge within the
    # limit of p has its midpoint within the limit plus its half length.
    half = 0.5 * float(np.linalg.norm(b - a, axis=1).max())
    missed = np.flatnonzero(found < 0)
    for i, near in zip(missed, tree.query_ball_point(p[missed], limit[missed] + half), strict=True):
        near = np.asarray(near, dtype=np.int64)
        if near.size:
            d, w = b[near] - a[near], p[i] - a[near]
            t = np.clip(np.einsum("cj,cj->c", w, d)
                        / np.maximum(np.einsum("cj,cj->c", d, d), 1e-300), 0.0, 1.0)
            distance = np.linalg.norm(w - t[:, None] * d, axis=1)
            if distance.min() <= limit[i]:
                found[i] = near[distance.argmin()]
    return found


#: A straight quad edge (no chain under it) with both ends on a curve lies along it where
#: its middle is closer to the curve than this share of its length (the sagitta of a
#: chord of a circle is under a tenth of the chord up to a 45° arc).
ALONG = 0.25


def _straight_on_curve(x, curve_edges, edge_curve, points, edges, tol):
    """Per quad edge (straight, no chain) a curve edge of the curve it lies along (−1 for
    none): both its ends on that curve within ``tol``, its middle within :data:`ALONG` of
    its length."""
    out = np.full(edges.shape[0], -1, dtype=np.int64)
    length = np.linalg.norm(points[edges[:, 1]] - points[edges[:, 0]], axis=1)
    middle = 0.5 * (points[edges[:, 0]] + points[edges[:, 1]])
    for tag in np.unique(edge_curve):
        mine = np.flatnonzero(edge_curve == tag)
        ends = [_on_curve(x, curve_edges[mine], points[edges[:, k]], tol) for k in (0, 1)]
        near = _on_curve(x, curve_edges[mine], middle, 0.0, within=ALONG * length)
        found = (ends[0] >= 0) & (ends[1] >= 0) & (near >= 0) & (out < 0)
        out[found] = mine[near[found]]
    return out


def quad_features(quad_mesh, x, cells, features: Features):
    """``quad_mesh`` (:class:`~ufl_frames.quads.extract.QuadMesh`) with its
    ``quad_region``, ``curve_edges``/``edge_curve`` and ``point_nodes``/``point_tag``
    found from the triangle mesh ``x``, ``cells`` and its ``features`` (see the module
    text). Model points with no quad vertex at their place are left out (the check,
    :func:`feature_problems`, names them)."""
    x = np.asarray(x, dtype=np.float64)[:, :2]
    cells = np.asarray(cells, dtype=np.int64)
    points, quads = quad_mesh.points[:, :2], np.asarray(quad_mesh.quads, dtype=np.int64)
    tol = TOLERANCE * _diameter(x)
    region = np.asarray(features.cell_region)
    inside = locate(x, cells, points[quads].mean(axis=1))
    quad_region = np.where(inside >= 0, region[np.maximum(inside, 0)], -1)
    curve_edges = np.asarray(features.curve_edges, dtype=np.int64).reshape(-1, 2)
    edge_curve = np.asarray(features.edge_curve, dtype=np.int64)
    edges = _quad_edges(quads)
    on_some = _on_curve(x, curve_edges, points, tol) >= 0
    edges = edges[on_some[edges].all(axis=1)]  # only these can lie along a curve
    chains = quad_mesh.chains or {}
    if chains:
        middle = np.array([_polyline_middle(np.asarray(chains[(int(i), int(j))]))
                           if (int(i), int(j)) in chains else 0.5 * (points[i] + points[j])
                           for i, j in edges]).reshape(-1, 2)
        on = _on_curve(x, curve_edges, middle, tol)
    else:  # straight edges: both ends on one curve, the middle near it (not across)
        on = _straight_on_curve(x, curve_edges, edge_curve, points, edges, tol)
        chains = features.curve_chains()
        if len(features.joints) and chains:  # an edge across joints: the curve under its middle
            chain = np.array([chains[int(c)] for c in edge_curve], dtype=np.int64)
            across = _straight_on_curve(x, curve_edges, chain, points, edges, tol)
            on = np.where(on >= 0, on, across)
    kept = on >= 0
    point_nodes, point_tag = [], []
    if len(features.point_nodes):
        distance, nearest = cKDTree(points).query(x[np.asarray(features.point_nodes)])
        found = distance <= tol
        point_nodes, point_tag = nearest[found], np.asarray(features.point_tag)[found]
    return replace(quad_mesh, quad_region=quad_region.astype(np.int64),
                   curve_edges=edges[kept], edge_curve=edge_curve[on[kept]],
                   point_nodes=np.asarray(point_nodes, dtype=np.int64),
                   point_tag=np.asarray(point_tag, dtype=np.int64))


def region_areas(points, quads, quad_region) -> dict:
    """{region: the area of its quads}."""
    p = np.asarray(points)[:, :2][np.asarray(quads)]
    area = 0.5 * np.sum(p[..., 0] * np.roll(p[..., 1], -1, axis=1)
                        - np.roll(p[..., 0], -1, axis=1) * p[..., 1], axis=1)
    return {int(r): float(area[quad_region == r].sum()) for r in np.unique(quad_region)}


def curve_lengths(points, curve_edges, edge_curve) -> dict:
    """{curve: the length of its edges}."""
    p = np.asarray(points)[:, :2]
    e = np.asarray(curve_edges, dtype=np.int64).reshape(-1, 2)
    length = np.linalg.norm(p[e[:, 1]] - p[e[:, 0]], axis=1)
    return {int(c): float(length[edge_curve == c].sum()) for c in np.unique(edge_curve)}


def feature_problems(quad_mesh, x, cells, features: Features) -> list[str]:
    """What breaks the features on the quads of :func:`quad_features`, one line each (an
    empty list where nothing does): a model point (but a smooth joint,
    :attr:`~ufl_frames.param.features.Features.required_points`) with no quad vertex; a
    quad outside the mesh or with a corner outside its region's triangles (straddling an
    interface); a region whose quads' area, or a curve whose quad edges' length, differs from the
    triangles' by more than :data:`RTOL` plus what the quad edges' chords of the curved
    parts explain (:func:`chord_allowances`); curves joined by smooth joints count as one
    (:meth:`~ufl_frames.param.features.Features.curve_chains`)."""
    x = np.asarray(x, dtype=np.float64)[:, :2]
    cells = np.asarray(cells, dtype=np.int64)
    problems = []
    required = np.isin(features.point_nodes, features.required_points)
    missing = len(set(np.asarray(features.point_tag)[required].tolist())
                  - set(np.asarray(quad_mesh.point_tag).tolist()))
    if missing:
        problems.append(f"{missing} model points are not quad vertices")
    region = np.asarray(features.cell_region)
    quad_region = quad_mesh.quad_region
    if np.any(quad_region < 0):
        problems.append(f"{int(np.count_nonzero(quad_region < 0))} quads have their centre "
                        "outside the triangles")
    points = quad_mesh.points[:, :2]
    quads = np.asarray(quad_mesh.quads, dtype=np.int64)
    candidates, bary = _candidates(x, cells, points)
    holds = bary.min(axis=2) >= HOLDS  # (points, candidates): the point in the triangle
    corner_regions = region[candidates]
    straddle = 0
    for k in range(4):
        c = quads[:, k]
        ok = np.any(holds[c] & (corner_regions[c] == quad_region[:, None]), axis=1)
        doubt = np.flatnonzero(~ok & (quad_region >= 0))  # the nearest may miss slivers
        held = _holding(x, cells, points[c[doubt]])
        straddle += sum(int(not np.any(region[h] == quad_region[q]))
                        for q, h in zip(doubt, held, strict=True))
    if straddle:
        problems.append(f"{straddle} quad corners lie outside their quad's region (a quad "
                        "straddles an interface)")
    area, _ = _triangle_areas(x, cells)
    quad_areas = region_areas(points, quads, quad_region)
    area_slack, length_slack = chord_allowances(quad_mesh, x, features)
    for r in np.unique(region):
        expected = float(area[region == r].sum())
        got = quad_areas.get(int(r), 0.0)
        if abs(got - expected) > RTOL * expected + area_slack.get(int(r), 0.0):
            problems.append(f"region {int(r)}: the quads' area {got:.6g} differs from the "
                            f"triangles' {expected:.6g} by {abs(got / expected - 1):.2%}")
    expected_lengths = curve_lengths(x, features.curve_edges, np.asarray(features.edge_curve))
    got_lengths = curve_lengths(points, quad_mesh.curve_edges, quad_mesh.edge_curve)
    chains = features.curve_chains()
    if len(features.joints):  # curves joined by joints, which quad edges span: as one
        def by_chain(lengths):
            out = {}
            for c, value in lengths.items():
                out[chains.get(c, c)] = out.get(chains.get(c, c), 0.0) + value
            return out

        expected_lengths, got_lengths, length_slack = (
            by_chain(d) for d in (expected_lengths, got_lengths, length_slack))
    for c, expected in expected_lengths.items():
        got = got_lengths.get(c, 0.0)
        if abs(got - expected) > RTOL * expected + length_slack.get(c, 0.0):
            problems.append(f"curve {c}: the quad edges on it are {got:.6g} long, the "
                            f"triangles' {expected:.6g} ({abs(got / expected - 1):.2%} off)")
    return problems


def chord_allowances(quad_mesh, x, features: Features) -> tuple[dict, dict]:
    """How much the quads' area per region and their length per curve may differ from the
    triangles' because a quad edge on a curve is a chord of the triangles' polyline there:
    twice the area ℓ²θ/12 and the length ℓθ²/24 of a circular arc of chord ℓ turning by θ,
    θ the angle between the triangle edges under the quad edge's two ends. Curves joined
    by smooth joints count as one (a quad edge across a joint has its ends on two of them):
    their lengths under the chain's smallest tag
    (:meth:`~ufl_frames.param.features.Features.curve_chains`). Returns
    ({region: area}, {curve: length})."""
    points = np.asarray(quad_mesh.points)[:, :2]
    edges = np.asarray(quad_mesh.curve_edges, dtype=np.int64).reshape(-1, 2)
    curve_of = np.asarray(quad_mesh.edge_curve, dtype=np.int64)
    tri_edges = np.asarray(features.curve_edges, dtype=np.int64).reshape(-1, 2)
    tri_curve = np.asarray(features.edge_curve, dtype=np.int64)
    if len(features.joints):
        chains = features.curve_chains()
        curve_of, tri_curve = (np.array([chains.get(int(c), int(c)) for c in tags],
                                        dtype=np.int64) for tags in (curve_of, tri_curve))
    areas: dict[int, float] = {}
    lengths: dict[int, float] = {}
    if edges.size == 0:
        return areas, lengths
    # the quads on each side of a quad edge
    quads = np.asarray(quad_mesh.quads, dtype=np.int64)
    n = points.shape[0]
    sides: dict[int, list[int]] = {}
    for k in range(4):
        a, b = quads[:, k], quads[:, (k + 1) % 4]
        for q, key in enumerate(np.minimum(a, b) * n + np.maximum(a, b)):
            sides.setdefault(int(key), []).append(q)
    for c in np.unique(curve_of):
        on = edges[curve_of == c]
        mine = tri_edges[tri_curve == c]
        if mine.size == 0:
            continue
        a, b = x[mine[:, 0]], x[mine[:, 1]]
        direction = b - a
        direction /= np.linalg.norm(direction, axis=1)[:, None]

        def under(p, a=a, b=b):  # the triangle edge nearest to each point
            ab = b - a
            t = np.clip(np.einsum("pkj,kj->pk", p[:, None, :] - a[None], ab)
                        / np.einsum("kj,kj->k", ab, ab)[None], 0.0, 1.0)
            d = np.linalg.norm(p[:, None, :] - (a[None] + t[..., None] * ab[None]), axis=2)
            return np.argmin(d, axis=1)

        da, db = direction[under(points[on[:, 0]])], direction[under(points[on[:, 1]])]
        theta = np.arccos(np.clip(np.abs(np.einsum("ij,ij->i", da, db)), 0.0, 1.0))
        ell = np.linalg.norm(points[on[:, 1]] - points[on[:, 0]], axis=1)
        lengths[int(c)] = float(np.sum(2 * ell * theta**2 / 24))
        for (i, j), sag in zip(on, 2 * ell**2 * theta / 12, strict=True):
            for q in sides.get(int(min(i, j) * n + max(i, j)), []):
                r = int(quad_mesh.quad_region[q])
                areas[r] = areas.get(r, 0.0) + float(sag)
    return areas, lengths


def _triangle_areas(x, cells):
    p = x[cells]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    return 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]), p
