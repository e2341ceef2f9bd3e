"""Quad nodes onto the CAD curves and points (:mod:`ufl_frames.mesh.cad`): a polar grid of
quads on an annulus whose boundary nodes lie off the circles by a chord's sagitta (1e-4)
goes onto them to 1e-9 of the diameter, the nodes at model points exactly onto the points;
a move that would invert a quad is refused; a ``.msh`` keeps its nodes."""

import math

import numpy as np
import pytest

from ufl_frames.mesh.cad import snap_to_cad
from ufl_frames.mesh.domain import GeometryError
from ufl_frames.quads.measures import check_quad_mesh

# Built-in kernel: outer circle arcs 1-4 between points 2-5 (at 0, 90, 180, 270 degrees),
# inner arcs 5-8 between points 6-9.
ANNULUS_GEO = """
Point(1) = {0, 0, 0};
Point(2) = {1, 0, 0}; Point(3) = {0, 1, 0}; Point(4) = {-1, 0, 0}; Point(5) = {0, -1, 0};
Point(6) = {0.5, 0, 0}; Point(7) = {0, 0.5, 0}; Point(8) = {-0.5, 0, 0}; Point(9) = {0, -0.5, 0};
Circle(1) = {2, 1, 3}; Circle(2) = {3, 1, 4}; Circle(3) = {4, 1, 5}; Circle(4) = {5, 1, 2};
Circle(5) = {6, 1, 7}; Circle(6) = {7, 1, 8}; Circle(7) = {8, 1, 9}; Circle(8) = {9, 1, 6};
Curve Loop(1) = {1, 2, 3, 4}; Curve Loop(2) = {5, 6, 7, 8};
Plane Surface(1) = {1, 2};
"""
SAGITTA = 1e-4
NT, NR = 32, 3


def polar_quads():
    """A polar grid on 0.5 <= r <= 1 (NT angles, NR layers), boundary nodes SAGITTA
    inside the circles (and the node at angle 0 also moved along the circle); the curve
    edges and point nodes of ANNULUS_GEO."""
    t = 2 * np.pi * np.arange(NT) / NT
    r = np.linspace(0.5, 1.0, NR + 1)
    R, T = np.meshgrid(r, t, indexing="ij")
    R = R.copy()
    R[0] += SAGITTA
    R[-1] -= SAGITTA
    x = np.stack([R * np.cos(T), R * np.sin(T)], axis=-1).reshape(-1, 2)
    x[NR * NT] += (0.0, 2 * SAGITTA)  # the outer node at angle 0, off point 2
    x[NR * NT + NT // 4] = (0.0, 1.0 + 1e-12)  # the node at point 3, up to rounding
    idx = np.arange(x.shape[0]).reshape(NR + 1, NT)
    nxt = np.roll(idx, -1, axis=1)
    q = np.stack([idx[:-1], idx[1:], nxt[1:], nxt[:-1]], -1).reshape(-1, 4)
    quarter = np.arange(NT) // (NT // 4)
    edges = np.concatenate([np.stack([idx[-1], nxt[-1]], 1), np.stack([idx[0], nxt[0]], 1)])
    curves = np.concatenate([1 + quarter, 5 + quarter])
    corners = np.arange(0, NT, NT // 4)
    point_nodes = np.concatenate([idx[-1, corners], idx[0, corners]])
    point_tag = np.concatenate([2 + np.arange(4), 6 + np.arange(4)])
    return x, q, edges, curves, point_nodes, point_tag


def radial_offset(x, nodes):
    """Distance of the nodes to the nearer circle, r = 0.5 or 1."""
    r = np.linalg.norm(x[nodes], axis=1)
    return np.minimum(abs(r - 1.0), abs(r - 0.5))


@pytest.fixture
def geo(tmp_path):
    path = tmp_path / "annulus.geo"
    path.write_text(ANNULUS_GEO)
    return path


@pytest.mark.parametrize("named", [True, False], ids=["curve-edges", "nearest-curve"])
def test_nodes_onto_the_circles_and_points(geo, named):
    x, q, edges, curves, point_nodes, point_tag = polar_quads()
    boundary = np.unique(edges)
    assert radial_offset(x, boundary).max() == pytest.approx(SAGITTA, rel=1e-6)  # before
    given = dict(curve_edges=edges, edge_curve=curves, point_nodes=point_nodes,
                 point_tag=point_tag) if named else {}
    snap = snap_to_cad(str(geo), x, q, **given)
    diameter = 2.0
    assert radial_offset(snap.points, boundary).max() < 1e-9 * diameter
    assert snap.refused == 0 and snap.moved == boundary.size
    # named: the node off point 2 goes onto it; else onto the circle, SAGITTA away
    farthest = math.hypot(SAGITTA, 2 * SAGITTA) if named else SAGITTA
    assert snap.max_offset_before == pytest.approx(farthest, rel=0.01)
    corners = np.array([(1, 0), (0, 1), (-1, 0), (0, -1), (0.5, 0), (0, 0.5), (-0.5, 0),
                        (0, -0.5)], dtype=float)
    # named point nodes go onto their points; without names only those already there up to
    # rounding (point 3's): the node 2e-4 off point 2 goes onto the circle, not the point
    exact = np.ones(8, bool) if named else np.arange(8) == 1
    assert np.array_equal(snap.points[point_nodes[exact]], corners[exact])
    assert np.linalg.norm(snap.points[point_nodes] - corners, axis=1).max() < 3 * SAGITTA
    inside = np.setdiff1d(np.arange(len(x)), boundary)
    assert np.array_equal(snap.points[inside], x[inside])
    assert check_quad_mesh(snap.points, q) == []


def test_a_move_to_another_curve_is_refused(geo):
    x, q, edges, curves, point_nodes, point_tag = polar_quads()
    outer_node = edges[0, 1]  # edge 0's first node is point 2's, placed on the point anyway
    wrong = curves.copy()
    wrong[0] = 5  # an outer edge named as on the inner circle: its other edge is outer
    snap = snap_to_cad(str(geo), x, q, curve_edges=edges, edge_curve=wrong,
                       point_nodes=point_nodes, point_tag=point_tag, time_limit=60.0)
    assert snap.refused == 0  # a node named on two curves goes to the nearer one
    assert np.linalg.norm(snap.points[outer_node]) == pytest.approx(1.0, abs=1e-9)
    # named on the inner circle alone (both its edges): the move across the ring is refused
    wrong[(edges == outer_node).any(axis=1)] = 5
    snap = snap_to_cad(str(geo), x, q, curve_edges=edges, edge_curve=wrong,
                       point_nodes=point_nodes, point_tag=point_tag, time_limit=60.0)
    assert snap.refused == 1
    assert np.array_equal(snap.points[outer_node], x[outer_node])
    assert snap.max_offset_after == pytest.approx(0.5, abs=2 * SAGITTA)
    assert check_quad_mesh(snap.points, q) == []


def test_a_move_that_inverts_a_quad_is_refused(geo):
    """The outer ring of quads lies outside the circle, 1e-4 thick: every outer node's move
    onto the circle (2e-4 inwards) would turn its quads inside out."""
    x, q, edges, curves, point_nodes, point_tag = polar_quads()
    r = np.linalg.norm(x, axis=1)
    outer, ring = np.isclose(r, 1.0, atol=3 * SAGITTA), np.isclose(r, 1.0 - 0.5 / NR)
    x[outer] *= ((1 + 2 * SAGITTA) / r[outer])[:, None]
    x[ring] *= ((1 + SAGITTA) / r[ring])[:, None]
    assert check_quad_mesh(x, q) == []
    snap = snap_to_cad(str(geo), x, q, curve_edges=edges, edge_curve=curves,
                       point_nodes=point_nodes, point_tag=point_tag)
    assert snap.refused == NT and snap.moved == NT  # the inner circle's nodes move
    assert np.array_equal(snap.points[outer], x[outer])
    # the farthest: the node that was also 2e-4 off point 2 along the circle
    assert snap.max_offset_after == pytest.approx(math.hypot(2 * SAGITTA, 2 * SAGITTA), rel=0.02)
    assert check_quad_mesh(snap.points, q) == []


def test_a_mesh_file_keeps_its_nodes(tmp_path):
    x, q, *_ = polar_quads()
    snap = snap_to_cad(str(tmp_path / "annulus.msh"), x, q)
    assert snap.moved == 0 and np.array_equal(snap.points, x)
    assert "without CAD model" in snap.note


def test_unknown_curve_is_refused(geo):
    x, q, edges, curves, *_ = polar_quads()
    with pytest.raises(GeometryError, match="model curve 42"):
        snap_to_cad(str(geo), x, q, curve_edges=edges, edge_curve=curves + 41)


def test_builtin_annulus_onto_its_circles():
    x, q, edges, *_ = polar_quads()
    snap = snap_to_cad("annulus", x, q)
    assert radial_offset(snap.points, np.unique(edges)).max() < 2e-9
