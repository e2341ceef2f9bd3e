"""± pairs of singularities closer than a quad removed before the map
(``ufl_frames.param.pairs``), pure NumPy/SciPy.

Truth: an analytic field with a planted pair, angle ¼(arg(z − a) − arg(z − b)) plus a
smooth part, whose only singular vertices are at a (+1/4) and b (−1/4) as the
independent face-based count (:func:`ufl_frames.param.cut.cut_mesh`) finds them. Below
the threshold the pair is gone (that count finds none) and the field is bit for bit the
same outside a disk a few triangles around the pair; at or above it, or where the disk
would hold a model point, the field is returned as it was.
"""

import numpy as np
import pytest
from planar_meshes import grid

from ufl_frames.frames2d import odeco
from ufl_frames.param import cut, pairs
from ufl_frames.param.features import Features

A, B = np.array([-0.11, 0.013]), np.array([0.12, 0.007])  # 0.23 apart, off the vertices
DISTANCE = float(np.linalg.norm(B - A))


def planted(x, isotropic):
    """The planted pair's field on the points x: a smooth angle and smooth lengths beside
    the pair's ¼(arg(z − a) − arg(z − b))."""
    theta = (np.arctan2(x[:, 1] - A[1], x[:, 0] - A[0])
             - np.arctan2(x[:, 1] - B[1], x[:, 0] - B[0])) / 4 + 0.15 * x[:, 0] * x[:, 1]
    l1 = np.exp(0.2 * x[:, 0])
    l2 = l1 if isotropic else np.exp(-0.25 * x[:, 1])
    return odeco.frames_to_q(np.stack([l1, l2], axis=1), theta)


@pytest.fixture(params=[True, False], ids=["isotropic", "general"])
def field(request):
    x, cells = grid(40, 40, -1, 1, -1, 1)
    return x, cells, planted(x, request.param)


def test_the_planted_pair_is_what_the_cut_finds(field):
    x, cells, q = field
    mesh = cut.cut_mesh(x, cells, q)
    assert sorted(mesh.turns.tolist()) == [-1, 1]
    near = [np.linalg.norm(x[v] - p, axis=-1) for v, p in
            zip(mesh.singular[np.argsort(-mesh.turns)], (A, B), strict=True)]
    assert max(near) < 0.05 * np.sqrt(2)  # a vertex of the triangle that holds it (legs 0.05)


def test_a_pair_closer_than_the_threshold_is_removed_and_the_rest_kept(field):
    x, cells, q = field
    edge = np.full(x.shape[0], DISTANCE / 0.2)  # the pair 0.2 quad edges apart
    new, record = pairs.remove_close_pairs(x, cells, q, edge, within=0.3)
    assert len(record.removed) == 1 and record.kept == ()
    found = record.removed[0]  # measured between the singular vertices, not a and b
    assert found["quads"] == pytest.approx(found["distance"] / edge[0], rel=1e-12)
    assert found["quads"] < 0.3
    assert cut.cut_mesh(x, cells, new).singular.size == 0
    changed = np.flatnonzero(np.any(new != q, axis=1))
    assert np.array_equal(changed, record.changed)
    outside = np.setdiff1d(np.arange(x.shape[0]), record.changed)
    assert np.array_equal(new[outside], q[outside])
    # a disk around the segment between the two vertices, as far again as they are apart
    # (three rings of triangles at least: 0.15 here)
    middle = 0.5 * (A + B)
    assert np.linalg.norm(x[changed] - middle, axis=1).max() < 1.5 * found["distance"] + 0.05
    # the frames are frames (on the Odeco variety) and isotropic where the field was
    lengths, _ = odeco.q_to_frames(new[changed])
    assert np.allclose(odeco.frames_to_q(lengths, odeco.q_to_frames(new[changed])[1]),
                       new[changed], atol=1e-9)
    old_lengths, _ = odeco.q_to_frames(q)
    if np.allclose(old_lengths[:, 0], old_lengths[:, 1]):
        assert np.allclose(lengths[:, 0], lengths[:, 1])
    summary = record.as_dict()
    assert summary["removed"] == 1 and summary["within_quads"] == 0.3
    assert pairs.describe(summary) == "1 ± pair closer than 0.3 quad removed before the map"


def test_a_pair_at_or_beyond_the_threshold_is_kept(field):
    x, cells, q = field
    for quads in (0.35, 1.0):
        edge = np.full(x.shape[0], DISTANCE / quads)
        new, record = pairs.remove_close_pairs(x, cells, q, edge, within=0.3)
        assert new is q and record.removed == () and record.kept == ()
        assert pairs.describe(record.as_dict()) is None


def test_the_threshold_follows_the_local_quad_edge(field):
    """:func:`local_quad_edge` at a quad size: (l1 + l2)/(2s), its mean over the quads
    the size asked; a quad size of 2 d gives the pair 0.5 quad apart (kept at 0.3),
    one of 5 d 0.2 (removed)."""
    x, cells, q = field
    for size, removed in ((2 * DISTANCE, 0), (5 * DISTANCE, 1)):
        edge = pairs.local_quad_edge(x, cells, q, quad_size=size)
        assert np.median(edge) == pytest.approx(size, rel=0.3)
        _, record = pairs.remove_close_pairs(x, cells, q, edge, within=0.3)
        assert len(record.removed) == removed


def test_a_pair_around_a_model_point_is_kept(field):
    """A point the user placed between the two (a model point) is never smoothed over."""
    x, cells, q = field
    point = int(np.argmin(np.linalg.norm(x - 0.5 * (A + B), axis=1)))
    features = Features(cell_region=np.zeros(cells.shape[0], dtype=np.int64),
                        curve_edges=np.zeros((0, 2), dtype=np.int64),
                        edge_curve=np.zeros(0, dtype=np.int64),
                        point_nodes=np.array([point]), point_tag=np.array([7]))
    edge = np.full(x.shape[0], DISTANCE / 0.2)
    new, record = pairs.remove_close_pairs(x, cells, q, edge, within=0.3, features=features)
    assert new is q and record.removed == ()
    assert len(record.kept) == 1 and "model point" in record.kept[0]["why"]
    assert "1 kept" in pairs.describe(record.as_dict())


def test_a_pair_at_the_boundary_keeps_the_boundary_frames():
    """A pair two triangles from the boundary: the patch reaches it, the boundary's frames
    stay as they were (its rim), and no singular vertex is left."""
    x, cells = grid(40, 40, -1, 1, -1, 1)
    shift = np.array([0.0, -0.89])
    theta = (np.arctan2(x[:, 1] - A[1] - shift[1], x[:, 0] - A[0])
             - np.arctan2(x[:, 1] - B[1] - shift[1], x[:, 0] - B[0])) / 4
    q = odeco.frames_to_q(np.ones((x.shape[0], 2)), theta)
    assert cut.cut_mesh(x, cells, q).singular.size == 2
    new, record = pairs.remove_close_pairs(x, cells, q, np.full(x.shape[0], 2.0), within=0.3)
    assert len(record.removed) == 1
    boundary = np.flatnonzero(np.isclose(np.abs(x), 1.0).any(axis=1))
    assert np.array_equal(new[boundary], q[boundary])
    assert not np.isin(record.changed, boundary).any()
    assert cut.cut_mesh(x, cells, new).singular.size == 0


def test_two_pairs_apart_are_both_removed_and_a_far_singularity_stays():
    """Two planted pairs and a lone +1/4 far from both: both pairs go, the lone one stays
    where it was."""
    x, cells = grid(40, 40, -1, 1, -1, 1)
    arg = lambda p: np.arctan2(x[:, 1] - p[1], x[:, 0] - p[0])  # noqa: E731
    lone = (0.013, 0.61)
    theta = (arg(A - [0.5, 0.4]) - arg(B - [0.5, 0.4]) + arg(A + [0.5, -0.4])
             - arg(B + [0.5, -0.4]) + arg(lone)) / 4
    q = odeco.frames_to_q(np.ones((x.shape[0], 2)), theta)
    before = cut.cut_mesh(x, cells, q)
    assert sorted(before.turns.tolist()) == [-1, -1, 1, 1, 1]
    new, record = pairs.remove_close_pairs(x, cells, q, np.full(x.shape[0], 2.0), within=0.3)
    assert len(record.removed) == 2 and record.kept == ()
    after = cut.cut_mesh(x, cells, new)
    assert after.turns.tolist() == [1]
    assert np.linalg.norm(x[after.singular[0]] - lone) < 0.05 * np.sqrt(2)
