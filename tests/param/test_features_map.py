"""The map with the geometry's features (``ufl_frames.param.cut``, ``seamless``,
``quantise`` given a :class:`~ufl_frames.param.features.Features`), pure NumPy/SciPy.

Truth: a constant frame field (angle 0) on a box split at x = 0.43 and on a box of three
regions: the interface x = 0.43 is crossed by the first branch, so U is the coordinate
constant along it. A field that turns inside the regions (aligned on the sides and the
interface, not a gradient): without the features its map's U varies along the interface,
with them it is constant (to round-off), and integer once quantised; the model points
the quantisation makes grid points are the geometry's: the corners, the interface's ends,
the T-junction.
"""

import numpy as np
import pytest
from feature_meshes import interface_box, three_region_box

from ufl_frames.frames2d import odeco
from ufl_frames.param import cut, quantise, seamless
from ufl_frames.param.features import Features


def constant_field(x):
    return odeco.frames_to_q(np.ones((x.shape[0], 2)), np.zeros(x.shape[0]))


def wavy_field(x, interface=0.43, width=1.0, height=0.7, amount=0.25):
    """A frame field turned by up to ``amount`` radians inside each region of the split
    box, aligned to the box's sides and to the interface x = ``interface`` (angle 0 on
    them): not a gradient, so its map bends unless held straight."""
    left = x[:, 0] < interface
    s = np.where(left, x[:, 0] / interface, (x[:, 0] - interface) / (width - interface))
    angle = amount * np.sin(np.pi * s) * np.sin(np.pi * x[:, 1] / height)
    return odeco.frames_to_q(np.ones((x.shape[0], 2)), angle)


def wedges(mesh, edges, end):
    return np.array([seamless.wedge_of(mesh, int(f), int(v))
                     for f, v in zip(mesh.faces[edges, 0], mesh.edges[edges, end], strict=True)])


def test_cut_mesh_keeps_the_features():
    x, cells, features = interface_box()
    assert cut.cut_mesh(x, cells, constant_field(x), features=features).features is features
    assert cut.cut_mesh(x, cells, constant_field(x)).features is None
    short = Features(features.cell_region[:-1], features.curve_edges, features.edge_curve,
                     features.point_nodes, features.point_tag)
    with pytest.raises(ValueError, match="regions for"):
        cut.cut_mesh(x, cells, constant_field(x), features=short)


def test_the_interface_is_crossed_by_u():
    x, cells, features = interface_box()
    mesh = cut.cut_mesh(x, cells, constant_field(x), features=features)
    edges, coordinate, tags = seamless.interior_curve_coordinates(mesh)
    assert np.all(tags == 7)
    assert edges.size == np.count_nonzero(features.edge_curve == 7)  # 0.7 / 0.05 edges
    np.testing.assert_allclose(mesh.x[mesh.edges[edges].ravel(), 0], 0.43, atol=1e-15)
    # in every triangle's combed chart the branch across x = const is U or V, as combed
    u_across = np.abs(np.cos(mesh.angle[mesh.faces[edges, 0]])) > 0.5
    np.testing.assert_array_equal(coordinate, np.where(u_across, 0, 1))


def test_map_is_constant_and_then_integer_along_the_interface():
    x, cells, features = interface_box()
    mesh = cut.cut_mesh(x, cells, wavy_field(x), features=features)
    scale = seamless.scale_for_quad_size(mesh, 0.1)
    edges, coordinate, _ = seamless.interior_curve_coordinates(mesh)
    wa, wb = wedges(mesh, edges, 0), wedges(mesh, edges, 1)
    smooth = seamless.integrate(mesh, scale)
    np.testing.assert_allclose(smooth.uv[wa, coordinate], smooth.uv[wb, coordinate],
                               atol=1e-9)
    bare = seamless.integrate(cut.cut_mesh(x, cells, wavy_field(x)), scale)
    spread = np.ptp(bare.uv[wa, coordinate])  # without the features U varies along x = 0.43
    assert spread > 1e-2
    grid_map = quantise.quantise(mesh, scale)
    value = grid_map.param.uv[wa, coordinate]
    np.testing.assert_allclose(value, grid_map.param.uv[wb, coordinate], atol=1e-9)
    assert np.abs(value - np.rint(value)).max() < 1e-6
    assert {"curve", "point"} <= set(grid_map.kinds.tolist())
    values = grid_map.functionals @ grid_map.param.uv.ravel()
    assert np.abs(values - np.rint(values)).max() < 1e-6


def test_model_points_are_the_geometrys():
    x, cells, features = three_region_box()
    mesh = cut.cut_mesh(x, cells, constant_field(x), features=features)
    expected = {(0.0, 0.0), (0.43, 0.0), (1.0, 0.0), (1.0, 0.33), (1.0, 0.7), (0.43, 0.7),
                (0.0, 0.7), (0.43, 0.33)}
    found = {tuple(np.round(p, 12)) for p in x[quantise.model_points(mesh)]}
    assert found == expected
    # without the point list, where curve tags change or curves meet give the same points
    bare = Features(features.cell_region, features.curve_edges, features.edge_curve,
                    np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
    mesh = cut.cut_mesh(x, cells, constant_field(x), features=bare)
    found = {tuple(np.round(p, 12)) for p in x[quantise.model_points(mesh)]}
    assert found == expected


def test_a_junctions_triangles_take_their_other_vertices_frames():
    """A fan at a junction (vertex 0) whose cross is held at 45°, as at a 300° slit tip:
    the triangle between a vertex of cross 60° and one of 0° (a 60° sector of one
    triangle) takes 75°, the short way between those two (face_frames gives the three's
    mean, which the 45° pulls off); a triangle with one other vertex takes its frame;
    the given triangle keeps its given frame."""
    cells = np.array([[0, 2, 1], [0, 3, 2]])
    angles = np.radians([45.0, 60.0, 0.0, 0.0])
    lengths = np.ones((4, 2))
    given = cut.junction_frames(cells, np.array([0]), (lengths, angles))
    assert given[0].tolist() == [0, 1]
    assert np.degrees(given[1]) % 90 == pytest.approx([75.0, 0.0], abs=1e-12)
    kept = (np.array([1]), np.array([0.3]), np.array([2.0]), np.array([1.0]))
    both = cut.junction_frames(cells, np.array([0]), (lengths, angles), kept)
    assert both[0].tolist() == [1, 0] and both[1][0] == 0.3
    assert np.degrees(both[1][1]) % 90 == pytest.approx(75.0, abs=1e-12)
    q = odeco.frames_to_q(lengths, angles)
    plain, _, _ = cut.face_frames(cells, q)
    assert abs(np.degrees(plain[0]) % 90 - 75.0) > 10  # what the junction's cross did
