"""The boundary's tightest bend (param.bends.bend_size) on hand-made meshes.

Truth: on a circle of radius R an arc of length w turns by w / R, so the largest quad edge
that turns by at most MAX_BEND is MAX_BEND · R, whether the circle bounds a disk or a hole;
a polygon whose vertices are all corners does not bend at all; the unit square with no
corner given has its quarter turns spread over the half sides beside them, π/2 per unit
length, as the circle of its perimeter (R = 2/π).
"""

import numpy as np
import pytest

from ufl_frames.param.bends import MAX_BEND, bend_size, boundary_loops


def _ring(r_in: float, r_out: float, n: int):
    """Two circles of n points, triangulated counter-clockwise (r_in = 0: a fan)."""
    t = 2 * np.pi * np.arange(n) / n
    circle = np.stack([np.cos(t), np.sin(t)], axis=1)
    i, j = np.arange(n), (np.arange(n) + 1) % n
    if r_in == 0:
        x = np.vstack([[[0.0, 0.0]], r_out * circle])
        return x, np.stack([np.zeros(n, int), 1 + i, 1 + j], axis=1)
    x = np.vstack([r_in * circle, r_out * circle])
    cells = np.concatenate([np.stack([i, n + i, n + j], axis=1),
                            np.stack([i, n + j, j], axis=1)])
    return x, cells


def test_a_disk_bends_at_its_radius():
    x, cells = _ring(0, 0.3, 400)
    bend = bend_size(x, cells)
    assert bend.size == pytest.approx(MAX_BEND * 0.3, rel=0.02)
    assert bend.radius == pytest.approx(0.3, rel=0.02)
    assert np.hypot(*bend.at) == pytest.approx(0.3)


def test_a_hole_bends_at_its_radius_and_the_loops_keep_the_domain_on_their_left():
    x, cells = _ring(0.1, 2.0, 600)
    loops = boundary_loops(x, cells)
    assert sorted(len(loop) for loop in loops) == [600, 600]
    for loop in loops:  # outer loop counter-clockwise, the hole's clockwise
        p = x[loop]
        signed = 0.5 * np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1])
        assert signed > 0 if np.hypot(*p[0]) > 1 else signed < 0
    bend = bend_size(x, cells)
    assert bend.radius == pytest.approx(0.1, rel=0.02)  # the tighter of the two circles
    assert np.hypot(*bend.at) == pytest.approx(0.1)


def test_corners_are_not_bends_unless_they_are_not_corners():
    x = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.5]], dtype=float)
    cells = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    assert bend_size(x, cells).size == np.inf  # every vertex may be a corner
    assert bend_size(x, cells, corners=np.arange(4)).size == np.inf
    no_corner = bend_size(x, cells, corners=np.zeros(0, dtype=int))
    # each quarter turn spread over the half sides beside it: π/2 per unit length, the
    # curvature of the circle of the same perimeter, R = 2/π
    assert no_corner.size == pytest.approx(MAX_BEND * 2 / np.pi, rel=0.02)
    with pytest.raises(ValueError, match="max_bend"):
        bend_size(x, cells, max_bend=0)
