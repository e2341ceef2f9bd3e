r"""How good a quad mesh is, and whether it is a valid one. Pure NumPy (and SciPy).

A quad mesh is ``points`` (n, 2) and ``quads`` (m, 4): rows of point indices, corners in
counter-clockwise order. The measures (:func:`quad_quality`):

* **valence** of a vertex: the number of mesh edges at it. A regular interior vertex has
  4; a regular boundary vertex with interior angle θ (of the mesh's boundary polygon)
  has :math:`\max(1, \mathrm{round}(θ/(π/2))) + 1`: 3 on a straight or smooth part of
  the boundary, 2 at a 90° corner, 4 at a 270° concave one (2 also at corners sharper
  than 45°, a trailing edge, say, where no fewer edges can meet). Other vertices are
  *irregular*;
* **scaled Jacobian** (SJ) of a quad: the smallest over its four corners of
  :math:`e_\text{next} \times e_\text{prev} / (|e_\text{next}|\,|e_\text{prev}|)`, the
  sine of the corner angle (1 for a rectangle, ≤ 0 at a reflex or folded corner), as
  Verdict/ParaView define it. Gmsh calls this number ``minSIGE`` for valid linear quads
  (equal to rounding, checked in the tests); Gmsh's ``minSJ`` of a linear quad is another
  measure, the smallest corner Jacobian over the Jacobian at the centre (1 for every
  parallelogram);
* **edge length ratio** of a quad: longest over shortest of its four edges.

:func:`check_quad_mesh` lists what makes a mesh invalid (conformity, orientation,
manifold vertices, unused or duplicate points, total area).
"""

import math

import numpy as np

__all__ = [
    "QUALITY_KEYS",
    "boundary_length",
    "check_quad_mesh",
    "euler_characteristic",
    "quad_quality",
    "scaled_jacobians",
    "vertex_valence",
]

#: The keys of :func:`quad_quality`'s dict, in its order.
QUALITY_KEYS = (
    "quads",
    "vertices",
    "irregular_vertices",
    "irregular_interior",
    "irregular_boundary",
    "interior_valence",
    "min_sj",
    "mean_sj",
    "sj_at_least_0_8",
    "edge_length_ratio",
    "mean_edge_length",
    "area",
)

#: Relative tolerance of :func:`check_quad_mesh`: points closer than this times the
#: bounding box's larger side are duplicates; a point this close (relative to the edge's
#: length) to the inside of a boundary edge is a T-junction; a quad whose area is below
#: this times its longest edge squared is degenerate.
GEOMETRIC_TOLERANCE = 1e-9


def _arrays(points, quads) -> tuple[np.ndarray, np.ndarray]:
    """``points`` as float (n, 2) and ``quads`` as int64 (m, 4), or ValueError."""
    x = np.asarray(points, dtype=float)
    q = np.asarray(quads)
    if x.ndim != 2 or x.shape[1] != 2:
        raise ValueError(f"points must have shape (n, 2), got {x.shape}")
    if q.ndim != 2 or q.shape[1] != 4:
        raise ValueError(f"quads must have shape (m, 4), got {q.shape}")
    if q.size and not np.issubdtype(q.dtype, np.integer):
        raise ValueError(f"quads must hold integer point indices, got dtype {q.dtype}")
    q = q.astype(np.int64, copy=False)
    if q.size and (q.min() < 0 or q.max() >= x.shape[0]):
        raise ValueError(f"quads index points outside 0..{x.shape[0] - 1}")
    return x, q


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _corner_vectors(x: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Edge vectors (m, 4, 2) from every corner to the next and to the previous corner."""
    p = x[q]
    return np.roll(p, -1, axis=1) - p, np.roll(p, 1, axis=1) - p


def _edges(q: np.ndarray, n: int):
    """Undirected edges: (directed edges (4m, 2) in quad order, key of each, unique keys,
    index of each directed edge's key, number of quads at each unique edge)."""
    directed = np.stack([q, np.roll(q, -1, axis=1)], axis=-1).reshape(-1, 2)
    keys = np.minimum(directed[:, 0], directed[:, 1]) * n + np.maximum(directed[:, 0],
                                                                        directed[:, 1])
    unique, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
    return directed, keys, unique, inverse, counts


def scaled_jacobians(points, quads) -> np.ndarray:
    """The scaled Jacobian of every quad (m,): min over corners of sin(corner angle),
    signed (counter-clockwise positive); 0 where a corner has a zero-length edge."""
    x, q = _arrays(points, quads)
    nxt, prv = _corner_vectors(x, q)
    length = np.linalg.norm(nxt, axis=-1) * np.linalg.norm(prv, axis=-1)
    cross = _cross(nxt, prv)
    sj = np.divide(cross, length, out=np.zeros_like(cross), where=length > 0)
    return sj.min(axis=1) if q.shape[0] else np.zeros(0)


def _corner_angles(x: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Interior angle (m, 4) in [0, 2π) at every corner of counter-clockwise quads: the
    turn from the next edge to the previous one (> π at a reflex corner)."""
    nxt, prv = _corner_vectors(x, q)
    return np.mod(np.arctan2(_cross(nxt, prv), np.einsum("mkd,mkd->mk", nxt, prv)),
                  2 * np.pi)


def euler_characteristic(quads) -> int:
    """χ = V − E + F of the quad mesh (the points its quads use, their distinct edges, the
    quads): 1 for a disk, 1 − h with h holes, summed over components."""
    q = np.asarray(quads, dtype=np.int64).reshape(-1, 4)
    edges = np.sort(np.stack([q, np.roll(q, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
    return int(np.unique(q).size - np.unique(edges, axis=0).shape[0] + q.shape[0])


def boundary_length(points, quads) -> float:
    """The length of the quad mesh's boundary: its edges that lie in one quad."""
    x = np.asarray(points, dtype=np.float64)[:, :2]
    q = np.asarray(quads, dtype=np.int64).reshape(-1, 4)
    edges = np.sort(np.stack([q, np.roll(q, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    once = unique[counts == 1]
    return float(np.linalg.norm(x[once[:, 1]] - x[once[:, 0]], axis=1).sum())


def vertex_valence(points, quads) -> dict:
    """Per point: ``valence`` (edges at it), ``expected`` (its regular valence, module
    docstring; 0 where no quad uses it), ``boundary`` (bool: on an edge of one quad) and
    ``angle`` (sum of the quad corner angles at it: 2π inside, the interior angle of the
    boundary polygon on the boundary)."""
    x, q = _arrays(points, quads)
    n = x.shape[0]
    directed, _, unique, inverse, counts = _edges(q, n)
    valence = np.bincount(np.concatenate([unique // n, unique % n]), minlength=n)
    boundary = np.zeros(n, dtype=bool)
    boundary[directed[counts[inverse] == 1].ravel()] = True
    angle = np.bincount(q.ravel(), weights=_corner_angles(x, q).ravel(), minlength=n)
    quarter_turns = np.maximum(1, np.rint(angle / (np.pi / 2))).astype(np.int64)
    used = np.bincount(q.ravel(), minlength=n) > 0
    expected = np.where(boundary, quarter_turns + 1, 4) * used
    return {"valence": valence, "expected": expected, "boundary": boundary, "angle": angle}


def quad_quality(points, quads) -> dict:
    """The measures of a quad mesh (module docstring) as a JSON-ready dict, keys
    :data:`QUALITY_KEYS`:

    * ``quads``, ``vertices`` (used by a quad);
    * ``irregular_vertices`` = ``irregular_interior`` + ``irregular_boundary``;
    * ``interior_valence``: ``{"3": count, "4": ..., ...}`` over interior vertices;
    * ``min_sj``, ``mean_sj``, ``sj_at_least_0_8`` (share of quads with SJ ≥ 0.8);
    * ``edge_length_ratio``: ``{"mean", "max"}`` over quads of longest / shortest edge;
    * ``mean_edge_length`` (each edge once), ``area`` (sum of signed areas).
    """
    x, q = _arrays(points, quads)
    if q.shape[0] == 0:
        raise ValueError("no quads")
    v = vertex_valence(x, q)
    used = v["expected"] > 0
    irregular = used & (v["valence"] != v["expected"])
    interior = used & ~v["boundary"]
    values, counts = np.unique(v["valence"][interior], return_counts=True)
    sj = scaled_jacobians(x, q)
    nxt, _ = _corner_vectors(x, q)
    lengths = np.linalg.norm(nxt, axis=-1)
    shortest = lengths.min(axis=1)
    ratio = np.divide(lengths.max(axis=1), shortest, out=np.full(q.shape[0], np.inf),
                      where=shortest > 0)
    n = x.shape[0]
    _, _, unique, _, _ = _edges(q, n)
    edge_lengths = np.linalg.norm(x[unique // n] - x[unique % n], axis=1)
    return {
        "quads": int(q.shape[0]),
        "vertices": int(used.sum()),
        "irregular_vertices": int(irregular.sum()),
        "irregular_interior": int((irregular & ~v["boundary"]).sum()),
        "irregular_boundary": int((irregular & v["boundary"]).sum()),
        "interior_valence": {str(int(k)): int(c) for k, c in zip(values, counts, strict=True)},
        "min_sj": float(sj.min()),
        "mean_sj": float(sj.mean()),
        "sj_at_least_0_8": float(np.mean(sj >= 0.8)),
        "edge_length_ratio": {"mean": float(ratio.mean()), "max": float(ratio.max())},
        "mean_edge_length": float(edge_lengths.mean()),
        "area": float(_signed_areas(x, q).sum()),
    }


def _signed_areas(x: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Shoelace area of every quad (positive when counter-clockwise)."""
    p = x[q]
    return 0.5 * _cross(p, np.roll(p, -1, axis=1)).sum(axis=1)


def _some(indices, fmt, limit: int = 3) -> str:
    """The first ``limit`` items formatted, and how many more."""
    items = [fmt(i) for i in indices[:limit]]
    more = len(indices) - limit
    return ", ".join(items) + (f" and {more} more" if more > 0 else "")


def check_quad_mesh(points, quads, area: float | None = None, rtol: float = 1e-9,
                    slits: bool = False) -> list[str]:
    """What makes the quad mesh invalid, one line each; an empty list for a valid mesh.

    Checked: finite coordinates; distinct corners in every quad; every edge in one quad
    (boundary) or two (interior), and never a point inside a boundary edge (T-junction);
    every quad counter-clockwise with positive area and a positive SJ at each corner
    (not inverted, not degenerate, not reflex), and the two quads at an interior edge
    crossing it in opposite directions (consistent orientation; also finds duplicated
    quads); the quads at every vertex one fan (manifold); no point unused, none
    duplicated (with ``slits``, two boundary points may coincide: the two sides of a
    slit, a domain cut open along a curve); the total area within ``rtol`` of ``area``
    when given.

    Args:
        points: the points (n, 2).
        quads: point indices (m, 4).
        area: the domain's area (None: not checked).
        rtol: the relative tolerance of the area check.
        slits: allow two boundary points at one place.

    Returns:
        The problems found, one line each (the arrays' wrong shapes or indices too).
    """
    try:
        x, q = _arrays(points, quads)
    except ValueError as e:
        return [str(e)]
    if q.shape[0] == 0:
        return ["no quads"]
    problems = []
    if not np.all(np.isfinite(x)):
        return [f"{int((~np.isfinite(x)).any(axis=1).sum())} points have NaN or infinite "
                "coordinates"]
    n = x.shape[0]
    ordered = np.sort(q, axis=1)
    repeated = np.flatnonzero((ordered[:, 1:] == ordered[:, :-1]).any(axis=1))
    if repeated.size:
        problems.append(f"{repeated.size} quads repeat a corner: "
                        + _some(repeated, lambda i: f"quad {i} {q[i].tolist()}"))
    directed, keys, unique, inverse, counts = _edges(q, n)
    over = np.flatnonzero(counts > 2)
    if over.size:
        problems.append(f"{over.size} edges lie in more than two quads: " + _some(
            over, lambda i: f"({unique[i] // n}, {unique[i] % n}) in {counts[i]}"))
    # Consistent orientation: an interior edge crossed once each way.
    forward = directed[:, 0] < directed[:, 1]
    same_way = np.flatnonzero(
        (counts == 2) & (np.bincount(inverse, weights=forward, minlength=unique.size) != 1))
    if same_way.size:
        problems.append(f"{same_way.size} interior edges are crossed the same way by both "
                        "their quads (inconsistent orientation or a duplicated quad): "
                        + _some(same_way, lambda i: f"({unique[i] // n}, {unique[i] % n})"))
    area_q = _signed_areas(x, q)
    nxt, _ = _corner_vectors(x, q)
    tiny = GEOMETRIC_TOLERANCE * np.einsum("mkd,mkd->mk", nxt, nxt).max(axis=1)
    nonpositive = np.flatnonzero(area_q <= tiny)
    if nonpositive.size:
        problems.append(f"{nonpositive.size} quads have a non-positive area (clockwise or "
                        "degenerate): " + _some(nonpositive, lambda i: f"quad {i}"))
    sj = scaled_jacobians(x, q)
    bad_corner = np.flatnonzero((sj <= 0) & (area_q > tiny))
    if bad_corner.size:
        problems.append(f"{bad_corner.size} quads of positive area have a corner with "
                        "SJ <= 0 (reflex, folded or degenerate): "
                        + _some(bad_corner, lambda i: f"quad {i} (SJ {sj[i]:.3g})"))
    problems += _t_junctions(x, directed[counts[inverse] == 1])
    problems += _non_manifold(q, n)
    unused = np.flatnonzero(np.bincount(q.ravel(), minlength=n) == 0)
    if unused.size:
        problems.append(f"{unused.size} points are in no quad: "
                        + _some(unused, lambda i: f"point {i}"))
    twins = np.zeros(n, dtype=bool)  # points that may have a twin: a slit's sides
    if slits:
        twins[directed[counts[inverse] == 1].ravel()] = True
    problems += _duplicates(x, float(np.ptp(x, axis=0).max()), twins)
    if area is not None:
        total = float(area_q.sum())
        if not abs(total - area) <= rtol * abs(area):
            problems.append(f"the quads' area {total:.12g} differs from {area:.12g} by "
                            f"{abs(total - area) / max(abs(area), 1e-300):.3g} (relative), "
                            f"more than {rtol:g}")
    return problems


def _t_junctions(x: np.ndarray, boundary: np.ndarray) -> list[str]:
    """Points that lie inside a boundary edge (a quad's edge meets two quads' edges)."""
    from scipy.spatial import cKDTree

    if boundary.size == 0:
        return []
    a, b = x[boundary[:, 0]], x[boundary[:, 1]]
    mid, half = 0.5 * (a + b), 0.5 * np.linalg.norm(b - a, axis=1)
    tree = cKDTree(x)
    found = []
    for e, near in enumerate(tree.query_ball_point(mid, half * (1 + 1e-12))):
        near = [p for p in near if p not in (boundary[e, 0], boundary[e, 1])]
        if not near:
            continue
        d = b[e] - a[e]
        length2 = float(d @ d)
        if length2 == 0:
            continue
        rel = x[near] - a[e]
        t = rel @ d / length2
        off = np.abs(_cross(np.broadcast_to(d, rel.shape), rel)) / math.sqrt(length2)
        tol = GEOMETRIC_TOLERANCE * math.sqrt(length2)
        hit = (t > 1e-9) & (t < 1 - 1e-9) & (off <= tol)
        found += [(int(p), e) for p in np.asarray(near)[hit]]
    if not found:
        return []
    return [f"{len(found)} points lie inside an edge of another quad (T-junction): " + _some(
        found, lambda f: f"point {f[0]} on edge {boundary[f[1]].tolist()}")]


def _non_manifold(q: np.ndarray, n: int) -> list[str]:
    """Vertices whose quads form more than one fan (joined through shared edges)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    m = q.shape[0]
    corner_vertex = q.ravel()
    # Each corner touches two half-edges at its vertex: (v, next) and (v, previous).
    ends = np.stack([np.roll(q, -1, axis=1).ravel(), np.roll(q, 1, axis=1).ravel()], axis=1)
    half_keys = corner_vertex[:, None] * n + ends
    _, half_id = np.unique(half_keys.ravel(), return_inverse=True)
    corners = 4 * m
    rows = np.repeat(np.arange(corners), 2)
    graph = coo_matrix((np.ones(rows.size), (rows, corners + half_id)),
                       shape=(corners + half_id.max() + 1,) * 2)
    _, label = connected_components(graph, directed=False)
    fans = np.unique(np.stack([corner_vertex, label[:corners]], axis=1), axis=0)
    per_vertex = np.bincount(fans[:, 0], minlength=n)
    bad = np.flatnonzero(per_vertex > 1)
    if not bad.size:
        return []
    return [f"{bad.size} vertices are not manifold (their quads form separate fans): "
            + _some(bad, lambda i: f"point {i} ({per_vertex[i]} fans)")]


def _duplicates(x: np.ndarray, scale: float, twins: np.ndarray) -> list[str]:
    """Distinct points at the same place, but for two ``twins`` (the boundary points of
    the two sides of a slit)."""
    from scipy.spatial import cKDTree

    pairs = cKDTree(x).query_pairs(GEOMETRIC_TOLERANCE * max(scale, 1e-300),
                                   output_type="ndarray")
    if len(pairs):
        pairs = pairs[~(twins[pairs[:, 0]] & twins[pairs[:, 1]])]
    if not len(pairs):
        return []
    return [f"{len(pairs)} pairs of points coincide: "
            + _some(pairs, lambda p: f"points {p[0]} and {p[1]}")]
