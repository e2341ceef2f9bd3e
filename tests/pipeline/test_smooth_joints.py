"""Smooth joints (param.features.with_smooth_joints): which model points a quad edge may span
(here beside the pipeline tests: the records it reads, mesh.domain.PhysicalGroup, need DOLFINx).

Truth: a unit square of 2 × 2 cells cut into triangles, its bottom side made of two
collinear curves that meet at (0.5, 0), a 90° corner at each of the four corners. The
point between the collinear curves is a joint (straight there, 180°); the corners are not;
nor is the point where the curves belong to different physical groups, or where it is a
physical point itself. And a fan of triangles round a boundary point where two curves meet
at a known angle: a joint only where the boundary turns by less than SMOOTH_TURN (25°), so
not at 135° or 225° (which the field rounds to two quarter turns, straight; deal.II
step-49's notch corners, cut off by a quad edge); where the CAD's corners are given, their
angle counts, not the triangles' (a circle's end point on coarse chords). The same fan's
point is a tie corner (with_tie_corners: no cross fits both curves) at 135° and 225° only.
"""

import math

import numpy as np
import pytest

from ufl_frames.mesh.domain import Corner, PhysicalGroup
from ufl_frames.param.features import Features, with_smooth_joints, with_tie_corners


def _square():
    x = np.array([[i / 2, j / 2] for j in range(3) for i in range(3)])
    cells = []
    for j in range(2):
        for i in range(2):
            a, b, c, d = 3 * j + i, 3 * j + i + 1, 3 * j + i + 4, 3 * j + i + 3
            cells += [[a, b, c], [a, c, d]]
    # curves: bottom left 1, bottom right 2, right 3, top 4, left 5
    edges = [[0, 1], [1, 2], [2, 5], [5, 8], [8, 7], [7, 6], [6, 3], [3, 0]]
    curve = [1, 2, 3, 3, 4, 4, 5, 5]
    points = [0, 1, 2, 8, 6]  # the four corners and the bottom side's middle
    features = Features(cell_region=np.zeros(len(cells), dtype=np.int64),
                        curve_edges=np.array(edges), edge_curve=np.array(curve),
                        point_nodes=np.array(points), point_tag=np.array([10, 11, 12, 13, 14]))
    return x, np.array(cells), features


def test_the_straight_point_between_two_curves_is_a_joint():
    x, cells, features = _square()
    joined = with_smooth_joints(features, x, cells)
    assert joined.joints.tolist() == [1]
    assert sorted(joined.required_points.tolist()) == [0, 2, 6, 8]
    chains = joined.curve_chains()
    assert chains[1] == chains[2] == 1 and len({chains[c] for c in (3, 4, 5)}) == 3
    assert len(features.joints) == 0 and len(features.required_points) == 5  # default: none


def test_named_points_and_curves_of_other_groups_stay_quad_vertices():
    x, cells, features = _square()
    groups = (PhysicalGroup(1, 7, "inlet", (1,)), PhysicalGroup(1, 8, "wall", (2, 3, 4, 5)))
    assert with_smooth_joints(features, x, cells, groups).joints.size == 0
    same = (PhysicalGroup(1, 8, "wall", (1, 2, 3, 4, 5)),)
    assert with_smooth_joints(features, x, cells, same).joints.tolist() == [1]
    named = (PhysicalGroup(0, 9, "probe", (11,)),)
    assert with_smooth_joints(features, x, cells, named).joints.size == 0


def _fan(degrees):
    """Triangles round node 0 on the boundary, filling the domain's angle ``degrees`` there
    (rim nodes 1…5 at radius 1); curve 1 from node 0 along +x, curve 2 back to node 0 along
    the last ray, curve 3 the rim; model points at node 0 and the curves' rim ends."""
    rays = np.radians(np.linspace(0.0, degrees, 5))
    x = np.vstack([[0.0, 0.0], np.c_[np.cos(rays), np.sin(rays)]])
    cells = np.array([[0, i, i + 1] for i in range(1, 5)])
    edges = [[0, 1], [1, 2], [2, 3], [3, 4], [4, 5], [5, 0]]
    features = Features(cell_region=np.zeros(4, dtype=np.int64), curve_edges=np.array(edges),
                        edge_curve=np.array([1, 3, 3, 3, 3, 2]),
                        point_nodes=np.array([0, 1, 5]), point_tag=np.array([10, 11, 12]))
    return x, cells, features


@pytest.mark.parametrize("degrees, joint", [(180, True), (160, True), (204, True),
                                            (150, False), (135, False), (225, False),
                                            (210, False), (90, False)])
def test_a_joint_is_where_the_boundary_turns_little(degrees, joint):
    x, cells, features = _fan(degrees)
    assert with_smooth_joints(features, x, cells).joints.tolist() == ([0] if joint else [])


def test_the_cad_angle_decides_where_the_corners_are_given():
    x, cells, features = _fan(150)  # the triangles turn by 30° at node 0
    assert with_smooth_joints(features, x, cells).joints.size == 0
    rim = tuple(Corner(*x[v], math.radians(90)) for v in (1, 5))  # the rim's ends
    # a circle's end point: the CAD has no corner there, its chords turn
    assert with_smooth_joints(features, x, cells, corners=rim).joints.tolist() == [0]
    x, cells, _ = _fan(180)
    rim = tuple(Corner(*x[v], math.radians(90)) for v in (1, 5))
    assert with_smooth_joints(features, x, cells, corners=rim).joints.tolist() == [0]
    corner = (Corner(0.0, 0.0, math.radians(135)),)  # a 135° corner the triangles round off
    assert with_smooth_joints(features, x, cells, corners=rim + corner).joints.size == 0


@pytest.mark.parametrize("degrees, tie", [(135, True), (225, True), (90, False), (150, False),
                                          (180, False), (270, False)])
def test_tie_corners_are_the_135_and_225_degree_corners(degrees, tie):
    x, cells, features = _fan(degrees)
    found = with_tie_corners(features, x, cells).tie_corners.tolist()
    assert (0 in found) == tie
    rim = tuple(Corner(*x[v], math.radians(90)) for v in (1, 5))  # the CAD says the same
    here = (Corner(0.0, 0.0, math.radians(degrees)),) if degrees != 180 else ()
    assert with_tie_corners(features, x, cells, rim + here).tie_corners.tolist() == \
        ([0] if tie else [])
    assert len(features.tie_corners) == 0  # none by default
