"""Regions, interfaces, embedded curves and points through the map and the quads
(``ufl_frames.param.quantise`` with features, ``ufl_frames.quads.features``), pure
NumPy/SciPy.

Truth: the geometry. A box 1 × 0.7 split at x = 0.43 (not a multiple of the quad size 0.1:
the map must stretch to put the interface on a grid line), three regions meeting at a
T-junction, an embedded segment ending inside and an embedded point, an annulus with a
circular interface under the polar field. The quads' nodes on the interface lines (to
1e-9), the regions' areas and the curves' lengths (analytic, or the triangles' where the
curve is a circle: both are its chords) within 0.5 %, the model points quad vertices (to
1e-12), every quad on one side of every interface; validity by
:func:`ufl_frames.quads.measures.check_quad_mesh`, written apart from the extraction.
"""

import numpy as np
import pytest
from feature_meshes import (
    embedded_box,
    embedded_corner_box,
    interface_annulus,
    interface_box,
    three_region_box,
)

from ufl_frames.frames2d import odeco
from ufl_frames.param import cut, quantise, seamless
from ufl_frames.param.features import Features
from ufl_frames.quads import extract, patches
from ufl_frames.quads.features import (
    chord_allowances,
    curve_lengths,
    feature_problems,
    locate,
    region_areas,
)
from ufl_frames.quads.measures import check_quad_mesh, quad_quality

RTOL = 5e-3


def constant_field(x):
    return odeco.frames_to_q(np.ones((x.shape[0], 2)), np.zeros(x.shape[0]))


def polar_field(x):
    r, theta = np.hypot(x[:, 0], x[:, 1]), np.arctan2(x[:, 1], x[:, 0])
    return odeco.frames_to_q(np.stack([r, r], axis=1), theta)


def quads_of(x, cells, q, features, size=0.1, method="greedy"):
    """(cut mesh, integer-grid map or None, quads) by greedy rounding or the T-mesh."""
    mesh = cut.cut_mesh(x, cells, q, features=features)
    scale = seamless.scale_for_quad_size(mesh, size)
    if method == "layout":
        quads, _, _ = patches.quads_of_map(seamless.integrate(mesh, scale))
        return mesh, None, quads
    grid_map = quantise.quantise(mesh, scale)
    return mesh, grid_map, extract.extract_quads(grid_map)


METHODS = pytest.mark.parametrize("method", ["greedy", "layout"])


def distance_to_curve(x, features, tag, points):
    """The distance of every point to the triangle edges of curve ``tag``."""
    e = features.curve_edges[features.edge_curve == tag]
    a, d = x[e[:, 0]], x[e[:, 1]] - x[e[:, 0]]
    w = points[:, None, :] - a[None]
    t = np.clip(np.einsum("pej,ej->pe", w, d) / np.einsum("ej,ej->e", d, d), 0.0, 1.0)
    return np.linalg.norm(w - t[..., None] * d[None], axis=2).min(axis=1)


def assert_valid(quads, area):
    assert check_quad_mesh(quads.points, quads.quads, area=area, rtol=RTOL) == []
    assert quads.quad_region.shape == (quads.num_quads,)


@METHODS
def test_interface_at_an_off_grid_place_is_a_line_of_quad_edges(method):
    x, cells, features = interface_box()
    _, _, quads = quads_of(x, cells, constant_field(x), features, method=method)
    assert_valid(quads, 0.7)
    p = quads.points
    on = np.abs(p[:, 0] - 0.43) < 1e-9
    assert on.sum() >= 8  # 0.7 / 0.1 + 1 nodes up the interface
    interface = quads.curve_edges[quads.edge_curve == 7]
    assert np.abs(p[interface.ravel(), 0] - 0.43).max() < 1e-9
    assert np.linalg.norm(p[interface[:, 1]] - p[interface[:, 0]], axis=1).sum() \
        == pytest.approx(0.7, rel=1e-9)
    # every quad on one side: its corners all left of or all right of the interface
    corner_x = p[quads.quads, 0]
    left = (corner_x <= 0.43 + 1e-9).all(axis=1)
    right = (corner_x >= 0.43 - 1e-9).all(axis=1)
    assert np.all(left ^ right)
    np.testing.assert_array_equal(quads.quad_region, np.where(left, 1, 2))
    areas = region_areas(p, quads.quads, quads.quad_region)
    assert areas[1] == pytest.approx(0.43 * 0.7, rel=RTOL)
    assert areas[2] == pytest.approx(0.57 * 0.7, rel=RTOL)
    lengths = curve_lengths(p, quads.curve_edges, quads.edge_curve)
    expected = {1: 0.43, 2: 0.57, 3: 0.7, 4: 0.43, 5: 0.57, 6: 0.7, 7: 0.7}
    assert lengths == pytest.approx(expected, rel=RTOL)
    # the interface's ends on the boundary (points between two boundary curves) are quad
    # vertices, and every model point is one
    at = {tuple(np.round(p[v], 9)) for v in quads.point_nodes}
    assert {(0.43, 0.0), (0.43, 0.7), (0.0, 0.0), (1.0, 0.7)} <= at
    assert sorted(quads.point_tag.tolist()) == sorted(features.point_tag.tolist())
    assert feature_problems(quads, x, cells, features) == []


def test_the_check_finds_an_interface_the_quads_ignore():
    """The same mesh quantised without its features: the grid lines fall at multiples of
    0.1, the interface at 0.43 lies inside quads, and the check says so."""
    x, cells, features = interface_box()
    _, _, quads = quads_of(x, cells, constant_field(x), None)
    assert quads.quad_region is None
    mesh = cut.cut_mesh(x, cells, constant_field(x), features=features)
    found = extract.with_features(quads, mesh)
    problems = feature_problems(found, x, cells, features)
    assert any("curve 7" in line for line in problems)
    assert any("straddles" in line for line in problems)


@METHODS
def test_three_regions_meet_at_a_t_junction(method):
    x, cells, features = three_region_box()
    _, _, quads = quads_of(x, cells, constant_field(x), features, method=method)
    assert_valid(quads, 0.7)
    p = quads.points
    for tag, coordinate, level in ((8, 0, 0.43), (9, 0, 0.43), (10, 1, 0.33)):
        e = quads.curve_edges[quads.edge_curve == tag]
        assert e.size and np.abs(p[e.ravel(), coordinate] - level).max() < 1e-9
    assert np.min(np.linalg.norm(p - [0.43, 0.33], axis=1)) < 1e-12
    centre = p[quads.quads].mean(axis=1)
    truth = np.where(centre[:, 0] < 0.43, 1, np.where(centre[:, 1] < 0.33, 2, 3))
    np.testing.assert_array_equal(quads.quad_region, truth)
    corners = p[quads.quads]
    side_x = np.sign(np.round(corners[..., 0] - 0.43, 9))
    assert np.all(side_x.min(axis=1) * side_x.max(axis=1) >= 0)  # none across x = 0.43
    right = truth > 1
    side_y = np.sign(np.round(corners[right, :, 1] - 0.33, 9))
    assert np.all(side_y.min(axis=1) * side_y.max(axis=1) >= 0)  # none across y = 0.33
    areas = region_areas(p, quads.quads, quads.quad_region)
    expected = {1: 0.43 * 0.7, 2: 0.57 * 0.33, 3: 0.57 * 0.37}
    assert areas == pytest.approx(expected, rel=RTOL)
    lengths = curve_lengths(p, quads.curve_edges, quads.edge_curve)
    assert {k: lengths[k] for k in (8, 9, 10)} == pytest.approx({8: 0.33, 9: 0.37, 10: 0.57},
                                                                rel=RTOL)
    assert feature_problems(quads, x, cells, features) == []


@METHODS
def test_embedded_segment_and_point(method):
    x, cells, features = embedded_box()
    _, _, quads = quads_of(x, cells, constant_field(x), features, method=method)
    assert_valid(quads, 0.7)
    p = quads.points
    segment = quads.curve_edges[quads.edge_curve == 5]
    assert np.abs(p[segment.ravel(), 1] - 0.37).max() < 1e-9
    assert p[segment.ravel(), 0].min() == pytest.approx(0.25, abs=1e-9)
    assert p[segment.ravel(), 0].max() == pytest.approx(0.64, abs=1e-9)
    assert curve_lengths(p, quads.curve_edges, quads.edge_curve)[5] == pytest.approx(0.39,
                                                                                     rel=1e-9)
    for point in ((0.25, 0.37), (0.64, 0.37), (0.81, 0.18)):
        assert np.min(np.linalg.norm(p - point, axis=1)) < 1e-12
    # no quad edge crosses the segment: none has its ends on the two sides of y = 0.37
    # and meets that line strictly between the segment's ends
    a, b = p[quads.quads], p[np.roll(quads.quads, -1, axis=1)]
    below, above = a[..., 1] - 0.37, b[..., 1] - 0.37
    across = below * above < -1e-18
    t = np.where(across, below / np.where(across, below - above, 1.0), 0.0)
    at = a[..., 0] + t * (b[..., 0] - a[..., 0])
    assert not np.any(across & (at > 0.25 + 1e-9) & (at < 0.64 - 1e-9))
    assert np.all(quads.quad_region == 1)
    tags = dict(zip(quads.point_tag.tolist(), quads.point_nodes.tolist(), strict=True))
    np.testing.assert_allclose(p[tags[7]], (0.81, 0.18), atol=1e-12)
    assert feature_problems(quads, x, cells, features) == []


@METHODS
def test_embedded_curve_turning_inside(method):
    """An embedded curve along y = 0.37 from x = 0.25 to the corner (0.64, 0.37), then up
    to y = 0.58: both legs lines of quad edges, the corner and the ends quad vertices."""
    x, cells, features = embedded_corner_box()
    _, _, quads = quads_of(x, cells, constant_field(x), features, method=method)
    assert_valid(quads, 0.7)
    p = quads.points
    for tag, coordinate, level, length in ((5, 1, 0.37, 0.39), (6, 0, 0.64, 0.21)):
        e = quads.curve_edges[quads.edge_curve == tag]
        assert e.size and np.abs(p[e.ravel(), coordinate] - level).max() < 1e-9
        assert np.linalg.norm(p[e[:, 1]] - p[e[:, 0]], axis=1).sum() == pytest.approx(
            length, rel=1e-9)
    for point in ((0.25, 0.37), (0.64, 0.37), (0.64, 0.58)):
        assert np.min(np.linalg.norm(p - point, axis=1)) < 1e-12
    assert feature_problems(quads, x, cells, features) == []


@METHODS
def test_annulus_with_a_circular_interface(method):
    x, cells, features = interface_annulus()
    _, _, quads = quads_of(x, cells, polar_field(x), features, method=method)
    p = quads.points
    e1, e2 = x[cells[:, 1]] - x[cells[:, 0]], x[cells[:, 2]] - x[cells[:, 0]]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    assert_valid(quads, area.sum())
    assert quad_quality(quads.points, quads.quads)["irregular_vertices"] == 0
    r = np.hypot(p[:, 0], p[:, 1])
    for tag in (1, 2, 3):  # on the triangles' polygon of the circle (its chords)
        e = quads.curve_edges[quads.edge_curve == tag]
        assert e.size and distance_to_curve(x, features, tag, p[np.unique(e)]).max() < 1e-9
    centre_r = np.hypot(*p[quads.quads].mean(axis=1).T)
    np.testing.assert_array_equal(quads.quad_region, np.where(centre_r < 0.71, 1, 2))
    on = distance_to_curve(x, features, 2, p)[quads.quads] < 1e-9
    corner_r = r[quads.quads]
    inside = (on | (corner_r < 0.71)).all(axis=1)
    outside = (on | (corner_r > 0.71)).all(axis=1)
    assert np.all(inside ^ outside)
    region = features.cell_region
    areas = region_areas(p, quads.quads, quads.quad_region)
    for k in (1, 2):  # chords of the circles on both sides
        assert areas[k] == pytest.approx(area[region == k].sum(), rel=RTOL)
    lengths = curve_lengths(p, quads.curve_edges, quads.edge_curve)
    for tag, radius in ((1, 0.5), (2, 0.71), (3, 1.0)):
        assert lengths[tag] == pytest.approx(2 * np.pi * radius, rel=RTOL)
    assert feature_problems(quads, x, cells, features) == []


@METHODS
def test_a_point_between_two_boundary_curves_is_a_quad_vertex(method):
    """One region, the bottom side split at x = 0.43 (two curves meeting at 180°): the
    split is a quad vertex, though no interface reaches it."""
    x, cells, full = interface_box()
    kept = full.edge_curve != 7
    features = Features(cell_region=np.ones(cells.shape[0], dtype=np.int64),
                        curve_edges=full.curve_edges[kept], edge_curve=full.edge_curve[kept],
                        point_nodes=full.point_nodes, point_tag=full.point_tag)
    _, _, quads = quads_of(x, cells, constant_field(x), features, method=method)
    assert_valid(quads, 0.7)
    for point in ((0.43, 0.0), (0.43, 0.7)):
        assert np.min(np.linalg.norm(quads.points - point, axis=1)) < 1e-12
    lengths = curve_lengths(quads.points, quads.curve_edges, quads.edge_curve)
    assert lengths[1] == pytest.approx(0.43, rel=1e-9)
    assert lengths[2] == pytest.approx(0.57, rel=1e-9)
    assert feature_problems(quads, x, cells, features) == []


def test_without_features_nothing_changes():
    x, cells, _ = interface_box()
    mesh, _, quads = quads_of(x, cells, constant_field(x), None)
    assert mesh.features is None
    assert quads.quad_region is None and quads.curve_edges is None
    assert quads.num_quads == 70  # the 10 × 7 grid


def test_a_chord_across_smooth_joints_is_allowed_the_turn_of_the_curves_under_it():
    """A quad edge from angle 0 to 60° on the unit circle, over a polyline of five 12°
    segments, each its own curve, joined by smooth joints (a polyline's vertices): its
    allowance is that of a chord of length ℓ = 1 whose ends' segments turn by
    θ = 54° − 6° = 48° (``chord_allowances``: twice ℓθ²/24 for the curve, twice ℓ²θ/12
    for the quad's region), counted for the chain (the smallest tag), not 0 as the one
    segment under the edge's middle alone would give."""
    t = np.radians(12.0) * np.arange(6)
    x = np.stack([np.cos(t), np.sin(t)], axis=1)
    features = Features(cell_region=np.zeros(1, dtype=np.int64),
                        curve_edges=np.stack([np.arange(5), np.arange(1, 6)], axis=1),
                        edge_curve=np.arange(1, 6), point_nodes=np.arange(6),
                        point_tag=np.arange(1, 7), joints=np.arange(1, 5))
    points = np.array([x[0], x[5], 0.5 * x[5], 0.5 * x[0]])
    quad_mesh = extract.QuadMesh(points=points, quads=np.array([[3, 0, 1, 2]]), chains={},
                                 boundary=np.zeros((0, 2), dtype=np.int64),
                                 quad_region=np.array([7]), curve_edges=np.array([[0, 1]]),
                                 edge_curve=np.array([3]))
    areas, lengths = chord_allowances(quad_mesh, x, features)
    theta = np.radians(48.0)
    assert lengths == pytest.approx({1: 2 * theta**2 / 24})
    assert areas == pytest.approx({7: 2 * theta / 12})


def sliver_row_under_a_big_triangle():
    """80 small triangles in a row, 1 × 0.025, under one triangle 1 wide and 0.975 tall
    (region 2; the row region 1): just above the row, the 12 nearest centroids are all
    the small triangles', not the big one's (0.3 away), which holds the point."""
    n = 40
    bottom = np.column_stack([np.arange(n + 1) / n, np.zeros(n + 1)])
    top = np.column_stack([np.arange(n + 1) / n, np.full(n + 1, 0.025)])
    x = np.vstack([bottom, top, [[0.5, 1.0]]])
    cells = [[i, i + 1, n + 2 + i] for i in range(n)]
    cells += [[i, n + 2 + i, n + 1 + i] for i in range(n)]
    cells.append([n + 1, 2 * n + 1, 2 * n + 2])
    return x, np.array(cells, dtype=np.int64)


def test_a_point_in_a_triangle_far_beyond_its_nearest_centroids_is_located():
    """The big triangle holds (0.5, 0.03) and (0.2, 0.026) though 80 centroids are
    nearer; (0.3, 0.01) lies on the row's edge x = 0.3 (either triangle beside it);
    (0.5, -0.01) and (0.02, 0.5) are outside."""
    x, cells = sliver_row_under_a_big_triangle()
    p = np.array([[0.5, 0.03], [0.2, 0.026], [0.3, 0.01], [0.5, -0.01], [0.02, 0.5]])
    found = locate(x, cells, p)
    assert found[:2].tolist() == [len(cells) - 1] * 2
    assert found[2] >= 0 and np.isclose(np.abs(x[cells[found[2]], 0] - 0.3).min(), 0.0)
    assert found[3:].tolist() == [-1, -1]


def test_a_point_on_a_long_curve_edge_beyond_its_nearest_midpoints_is_found():
    """A point on the long edge (0, 0)–(1, 0), whose midpoint is 0.4 away, with 30 short
    edges of another curve nearer (x = 0.95, y in 0.01..0.31): it lies on the long one; a
    point off both lies on none."""
    from ufl_frames.quads.features import _on_curve

    x = np.array([[0.0, 0.0], [1.0, 0.0]] + [[0.95, 0.01 * (k + 1)] for k in range(31)])
    edges = np.array([[0, 1]] + [[k + 2, k + 3] for k in range(30)], dtype=np.int64)
    found = _on_curve(x, edges, np.array([[0.9, 0.0], [0.9, 0.05]]), 1e-9)
    assert found.tolist() == [0, -1]
