"""The quad stage with the geometry's features (pipeline.stages._quad_mesh on rank 0's cut
mesh): regions, interfaces, embedded curves and points pass through to the quads, and the
stage's checks refuse quads that ignore them.

Truth: the synthetic meshes of ``tests/feature_meshes.py`` (a box split at x = 0.43, an
embedded segment and point): the interface's quad nodes at x = 0.43, the model points quad
vertices, the regions' areas; the stage's own checks (:func:`_problems`) are tested to
fail on quads made without the features. The same on every rank (rank-local work).
"""

import numpy as np
import pytest
from feature_meshes import embedded_box, interface_box

from ufl_frames.frames2d import odeco
from ufl_frames.param import cut
from ufl_frames.param.features import Features
from ufl_frames.pipeline.stages import RootField, _problems, _quad_mesh, _quad_mesh_or_advice
from ufl_frames.quads.extract import with_features
from ufl_frames.quads.features import region_areas


def constant_field(x):
    return odeco.frames_to_q(np.ones((x.shape[0], 2)), np.zeros(x.shape[0]))


def test_stage_keeps_the_interface_and_the_regions():
    x, cells, features = interface_box()
    mesh = cut.cut_mesh(x, cells, constant_field(x), features=features)
    quads, record = _quad_mesh_or_advice(mesh, 0.1)
    assert record["quantisation"] == "layout" and record["fallback_reason"] is None
    assert record["valid"] and record["problems"] == []
    assert record["features"] == {"regions": 2, "curve_edges": len(quads.curve_edges),
                                  "point_nodes": 6}
    interface = quads.curve_edges[quads.edge_curve == 7]
    assert np.abs(quads.points[interface.ravel(), 0] - 0.43).max() < 1e-9  # improve kept them
    area = region_areas(quads.points, quads.quads, quads.quad_region)
    assert area == pytest.approx({1: 0.43 * 0.7, 2: 0.57 * 0.7}, rel=5e-3)
    assert _problems(mesh, quads) == []


def test_stage_with_embedded_segment_and_point():
    x, cells, features = embedded_box()
    mesh = cut.cut_mesh(x, cells, constant_field(x), features=features)
    for methods in (("layout",), ("greedy rounding",)):
        quads, record = _quad_mesh(mesh, 0.1, methods=methods)
        assert record["valid"] and record["features"]["point_nodes"] == 7
        assert np.min(np.linalg.norm(quads.points - [0.81, 0.18], axis=1)) < 1e-12


def test_checks_refuse_quads_without_the_features():
    x, cells, features = interface_box()
    bare = cut.cut_mesh(x, cells, constant_field(x))
    quads, record = _quad_mesh(bare, 0.1)
    assert record["quantisation"] == "layout"
    mesh = cut.cut_mesh(x, cells, constant_field(x), features=features)
    assert _problems(mesh, quads) == ["the quads do not carry the features"]
    problems = _problems(mesh, with_features(quads, mesh))
    assert any("curve 7" in line for line in problems)


def test_a_boundary_point_at_180_degrees_is_a_layout_node():
    """One region, the sides split at x = 0.43 (two boundary curves meeting at 180°): the
    split points are nodes of the T-mesh, so quad vertices."""
    x, cells, full = interface_box()
    kept = full.edge_curve != 7
    features = Features(cell_region=np.ones(cells.shape[0], dtype=np.int64),
                        curve_edges=full.curve_edges[kept], edge_curve=full.edge_curve[kept],
                        point_nodes=full.point_nodes, point_tag=full.point_tag)
    mesh = cut.cut_mesh(x, cells, constant_field(x), features=features)
    quads, record = _quad_mesh(mesh, 0.1)
    assert record["valid"]
    for point in ((0.43, 0.0), (0.43, 0.7)):
        assert np.min(np.linalg.norm(quads.points - point, axis=1)) < 1e-12
    assert record["quantisation"] == "layout" and record["fallback_reason"] is None


def test_root_field_cuts_with_its_features():
    x, cells, features = interface_box()
    root = RootField.__new__(RootField)  # the gathered arrays alone, no distributed field
    root._arrays, root._cuts, root.features = (x, cells, constant_field(x)), {}, features
    mesh, removed = root._cut_mesh()
    assert mesh.features is features and removed.removed == ()


@pytest.mark.parametrize("size", [0.07])
def test_stage_at_a_finer_size(size):
    x, cells, features = interface_box()
    mesh = cut.cut_mesh(x, cells, constant_field(x), features=features)
    quads, record = _quad_mesh(mesh, size)
    assert record["valid"]
    interface = quads.curve_edges[quads.edge_curve == 7]
    assert np.abs(quads.points[interface.ravel(), 0] - 0.43).max() < 1e-9


def test_a_size_too_coarse_is_adapted_where_asked(monkeypatch):
    """The annulus (0.5 wide) at quad size 2: the chords' bound puts enough edges round
    the circles for one ring of valid quads. Without that bound no quad fits across:
    without ``adapt`` the refusal names the smaller size that works; with it that size's
    mesh is returned, and its measures say which size was asked, which was used and why."""
    from planar_meshes import annulus, annulus_field

    from ufl_frames.quads import patches

    x, cells = annulus(8, 64)
    mesh = cut.cut_mesh(x, cells, annulus_field(x))
    quads, quality = _quad_mesh_or_advice(mesh, 2.0)
    assert quality["valid"] and "adapted_size" not in quality
    assert quads.num_quads == 7  # 1.6 quads round the inner circle in the map
    monkeypatch.setattr(patches, "CHORD_SAGITTA", 0.0)
    with pytest.raises(ValueError, match=r"\(quad size 1\.4 works\)"):
        _quad_mesh_or_advice(mesh, 2.0)
    quads, quality = _quad_mesh_or_advice(mesh, 2.0, adapt=True)
    adapted = quality["adapted_size"]
    assert adapted["asked"] == 2.0 and adapted["used"] == pytest.approx(1.4)
    assert "quad size 2" in adapted["why"]
    assert quality["valid"] and quads.num_quads > 0
