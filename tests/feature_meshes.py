"""Planar triangle meshes with model features (regions, interfaces, embedded curves and
points) and their :class:`~ufl_frames.param.features.Features`, for the pure NumPy tests
of the map and the quads with features (``tests/param``, ``tests/quads``).

Every mesh is a tensor grid whose lines include the feature lines, split into triangles
with alternating diagonals, and its vertices off the features moved at random (a fifth of
the local spacing at most), so that only the features' edges are straight lines.
"""

import numpy as np
from planar_meshes import tensor_grid

from ufl_frames.param.features import Features


def pieces(*stops, h=0.05):
    """Sorted coordinates from stops[0] to stops[-1] through every stop, about ``h`` apart."""
    out = [stops[0]]
    for a, b in zip(stops[:-1], stops[1:], strict=True):
        k = max(1, int(round((b - a) / h)))
        out += list(np.linspace(a, b, k + 1)[1:])
    return np.array(out)


def perturb(x, keep, amount, seed=0):
    """``x`` with the points not in ``keep`` (bool mask) moved at random by up to
    ``amount`` in each coordinate."""
    rng = np.random.default_rng(seed)
    moved = x + rng.uniform(-amount, amount, x.shape)
    return np.where(keep[:, None], x, moved)


def features_of(x, cells, region, curves, points):
    """The :class:`Features` of a mesh: ``region`` (m,) per triangle; ``curves`` a list of
    (tag, mask over the points): an edge is on the curve if both its ends are; ``points``
    a list of (tag, (x, y)): the mesh point there (exactly)."""
    local = cells[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2)
    edges = np.unique(np.sort(local, axis=1), axis=0)
    curve_edges, edge_curve = [], []
    for tag, on in curves:
        chosen = edges[on[edges[:, 0]] & on[edges[:, 1]]]
        curve_edges.append(chosen)
        edge_curve.append(np.full(chosen.shape[0], tag, dtype=np.int64))
    point_nodes, point_tag = [], []
    for tag, p in points:
        distance = np.linalg.norm(x - np.asarray(p), axis=1)
        assert distance.min() < 1e-12, f"no mesh point at {p}"
        point_nodes.append(int(np.argmin(distance)))
        point_tag.append(tag)
    return Features(cell_region=np.asarray(region, dtype=np.int64),
                    curve_edges=np.concatenate(curve_edges).astype(np.int64),
                    edge_curve=np.concatenate(edge_curve),
                    point_nodes=np.array(point_nodes, dtype=np.int64),
                    point_tag=np.array(point_tag, dtype=np.int64))


def _near(a, b):
    return np.abs(a - b) < 1e-12


def _centroids(x, cells):
    return x[cells].mean(axis=1)


def _box_boundary(x, width, height, xsplits=(), ysplits=()):
    """Curves of the box's sides split at ``xsplits`` (bottom and top) and ``ysplits``
    (right side), tags from 1; their model points (corners and splits), tags from 1."""
    X, Y = x[:, 0], x[:, 1]
    xs, ys = [0.0, *xsplits, width], [0.0, *ysplits, height]
    curves, points, tag = [], [], 1
    for a, b in zip(xs[:-1], xs[1:], strict=True):  # bottom
        curves.append((tag, _near(Y, 0) & (X >= a - 1e-12) & (X <= b + 1e-12)))
        tag += 1
    for a, b in zip(ys[:-1], ys[1:], strict=True):  # right
        curves.append((tag, _near(X, width) & (Y >= a - 1e-12) & (Y <= b + 1e-12)))
        tag += 1
    for a, b in zip(xs[:-1], xs[1:], strict=True):  # top
        curves.append((tag, _near(Y, height) & (X >= a - 1e-12) & (X <= b + 1e-12)))
        tag += 1
    curves.append((tag, _near(X, 0)))  # left
    corners = [(u, 0.0) for u in xs] + [(width, v) for v in ys[1:]] \
        + [(u, height) for u in xs[:-1]]
    points = [(k + 1, p) for k, p in enumerate(dict.fromkeys(corners))]
    return curves, points


def interface_box(interface=0.43, width=1.0, height=0.7, h=0.05, seed=0):
    """The box [0, width] × [0, height], regions 1 (x < interface) and 2, the interface
    x = ``interface`` (curve 7); boundary curves 1..6, points at the corners and the
    interface's ends. Returns (x, cells, features)."""
    xs = pieces(0.0, interface, width, h=h)
    ys = pieces(0.0, height, h=h)
    x, cells = tensor_grid(xs, ys)
    on = _near(x[:, 0], interface)
    boundary = _near(x[:, 0], 0) | _near(x[:, 0], width) | _near(x[:, 1], 0) \
        | _near(x[:, 1], height)
    x = perturb(x, on | boundary, 0.2 * h, seed)
    curves, points = _box_boundary(x, width, height, xsplits=(interface,))
    curves.append((7, on))
    region = np.where(_centroids(x, cells)[:, 0] < interface, 1, 2)
    return x, cells, features_of(x, cells, region, curves, points)


def three_region_box(xi=0.43, yi=0.33, width=1.0, height=0.7, h=0.05, seed=1):
    """The box with region 1 (x < xi), 2 (x > xi, y < yi) and 3 (x > xi, y > yi): the
    interfaces x = xi below yi (curve 8), above (curve 9), y = yi right of xi (curve 10),
    meeting at the T-junction (xi, yi) (a model point). Returns (x, cells, features)."""
    xs = pieces(0.0, xi, width, h=h)
    ys = pieces(0.0, yi, height, h=h)
    x, cells = tensor_grid(xs, ys)
    X, Y = x[:, 0], x[:, 1]
    vertical = _near(X, xi)
    horizontal = _near(Y, yi) & (X >= xi - 1e-12)
    boundary = _near(X, 0) | _near(X, width) | _near(Y, 0) | _near(Y, height)
    x = perturb(x, vertical | horizontal | boundary, 0.2 * h, seed)
    curves, points = _box_boundary(x, width, height, xsplits=(xi,), ysplits=(yi,))
    curves += [(8, vertical & (Y <= yi + 1e-12)), (9, vertical & (Y >= yi - 1e-12)),
               (10, horizontal)]
    points.append((len(points) + 1, (xi, yi)))
    c = _centroids(x, cells)
    region = np.where(c[:, 0] < xi, 1, np.where(c[:, 1] < yi, 2, 3))
    return x, cells, features_of(x, cells, region, curves, points)


def embedded_box(segment=((0.25, 0.37), (0.64, 0.37)), point=(0.81, 0.18), width=1.0,
                 height=0.7, h=0.05, seed=2):
    """The box (one region, 1) with an embedded horizontal segment (curve 5) ending inside
    and an embedded point (a model point); boundary curves 1..4 and the corners. Returns
    (x, cells, features)."""
    (ax, ay), (bx, _) = segment
    px, py = point
    xs = pieces(*sorted({0.0, ax, bx, px, width}), h=h)
    ys = pieces(*sorted({0.0, ay, py, height}), h=h)
    x, cells = tensor_grid(xs, ys)
    X, Y = x[:, 0], x[:, 1]
    on = _near(Y, ay) & (X >= ax - 1e-12) & (X <= bx + 1e-12)
    at = _near(X, px) & _near(Y, py)
    boundary = _near(X, 0) | _near(X, width) | _near(Y, 0) | _near(Y, height)
    x = perturb(x, on | at | boundary, 0.2 * h, seed)
    curves, points = _box_boundary(x, width, height)
    curves.append((5, on))
    points += [(5, (ax, ay)), (6, (bx, ay)), (7, (px, py))]
    region = np.ones(cells.shape[0], dtype=np.int64)
    return x, cells, features_of(x, cells, region, curves, points)


def interface_annulus(r0=0.5, ri=0.71, r1=1.0, nt=48, h=0.05, seed=3):
    """The annulus r0 ≤ r ≤ r1 as a polar grid through the circle r = ``ri``: regions 1
    (r < ri) and 2, curves 1 (inner circle), 2 (the interface), 3 (outer), one model
    point on each at θ = 0; the vertices off the circles moved at random. Returns (x,
    cells, features)."""
    r = pieces(r0, ri, r1, h=h)
    t = np.linspace(0, 2 * np.pi, nt, endpoint=False)
    R, T = np.meshgrid(r, t, indexing="ij")
    x = np.stack([(R * np.cos(T)).ravel(), (R * np.sin(T)).ravel()], axis=1)
    idx = np.arange(x.shape[0]).reshape(r.size, nt)
    a, b = idx[:-1], idx[1:]
    c, d = np.roll(b, -1, axis=1), np.roll(a, -1, axis=1)
    cells = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3),
                            np.stack([a, c, d], -1).reshape(-1, 3)])
    radius = np.hypot(x[:, 0], x[:, 1])
    circles = [_near(radius, s) for s in (r0, ri, r1)]
    x = perturb(x, circles[0] | circles[1] | circles[2], 0.15 * min(h, 2 * np.pi * r0 / nt),
                seed)
    region = np.where(np.hypot(*_centroids(x, cells).T) < ri, 1, 2)
    curves = [(k + 1, on) for k, on in enumerate(circles)]
    points = [(k + 1, (s, 0.0)) for k, s in enumerate((r0, ri, r1))]
    return x, cells, features_of(x, cells, region, curves, points)


def embedded_corner_box(corner=(0.64, 0.37), start=0.25, top=0.58, width=1.0, height=0.7,
                        h=0.05, seed=4):
    """The box (one region, 1) with an embedded curve that turns by 90° inside: from
    (start, y) to the corner (x, y) (curve 5), then up to (x, top) (curve 6), both ends and
    the corner model points. Returns (x, cells, features)."""
    cx, cy = corner
    xs = pieces(*sorted({0.0, start, cx, width}), h=h)
    ys = pieces(*sorted({0.0, cy, top, height}), h=h)
    x, cells = tensor_grid(xs, ys)
    X, Y = x[:, 0], x[:, 1]
    across = _near(Y, cy) & (X >= start - 1e-12) & (X <= cx + 1e-12)
    up = _near(X, cx) & (Y >= cy - 1e-12) & (Y <= top + 1e-12)
    boundary = _near(X, 0) | _near(X, width) | _near(Y, 0) | _near(Y, height)
    x = perturb(x, across | up | boundary, 0.2 * h, seed)
    curves, points = _box_boundary(x, width, height)
    curves += [(5, across), (6, up)]
    points += [(5, (start, cy)), (6, (cx, cy)), (7, (cx, top))]
    region = np.ones(cells.shape[0], dtype=np.int64)
    return x, cells, features_of(x, cells, region, curves, points)
