"""Smooth joints (param.features.with_smooth_joints): which model points a quad edge may span
(here beside the pipeline tests: the records it reads, mesh.domain.PhysicalGroup, need DOLFINx).

Truth: a unit square of 2 × 2 cells cut into triangles, its bottom side made of two
collinear curves that meet at (0.5, 0), a 90° corner at each of the four corners. The
point between the collinear curves is a joint (straight there, 180°); the corners are not;
nor is the point where the curves belong to different physical groups, or where it is a
physical point itself.
"""

import numpy as np

from ufl_frames.mesh.domain import PhysicalGroup
from ufl_frames.param.features import Features, with_smooth_joints


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
