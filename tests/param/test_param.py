"""Cut graph, combing and seamless integration (``ufl_frames.param``), pure NumPy/SciPy.

Truth: fields with a known map. A constant frame on a rectangle integrates to an affine map
(exactly: misfit at rounding); the isotropic annulus field (r e_r, r e_θ) integrates to
(ln r, θ), multivalued: one cut from the inner to the outer circle, across which V jumps by
2π, and the misfit of the P1 map falls as O(h) (the targets are sampled per triangle). A
field turning by a quarter around a point has one singular vertex, cut to the boundary.
"""

import numpy as np
import pytest
from planar_meshes import annulus, annulus_field, grid

from ufl_frames.frames2d import odeco
from ufl_frames.param import cut, measures, seamless


def test_constant_field_integrates_to_an_affine_map():
    x, cells = grid(8, 6, 0, 2, 0, 1)
    t = 0.0  # aligned with the rectangle's sides (boundary alignment holds)
    q = odeco.frames_to_q(np.tile([[2.0, 1.0]], (x.shape[0], 1)), np.full(x.shape[0], t))
    mesh = cut.cut_mesh(x, cells, q)
    assert mesh.paths == 0 and mesh.cut.size == 0 and mesh.singular.size == 0
    p = seamless.integrate(mesh, scale=4.0)
    found = measures.quality(p)
    assert found["misfit"] < 1e-12 and found["flipped_triangles"] == 0
    uv = p.uv[mesh.corners[:, 0]]
    xy = x[mesh.cells[:, 0]]
    # the map is affine: (U, V) = s (x / l1, y / l2) up to a translation and a relabelling
    fit, *_ = np.linalg.lstsq(np.c_[xy, np.ones(len(xy))], uv, rcond=None)
    assert np.allclose(np.abs(fit[:2]), [[2.0, 0.0], [0.0, 4.0]], atol=1e-10) or \
        np.allclose(np.abs(fit[:2]), [[0.0, 2.0], [4.0, 0.0]], atol=1e-10)


@pytest.mark.parametrize("n", [8])
def test_annulus_is_cut_once_and_integrates_to_log_polar(n):
    misfits = []
    for refine in (1, 2, 4):
        x, cells = annulus(n * refine, 6 * n * refine)
        mesh = cut.cut_mesh(x, cells, annulus_field(x))
        assert mesh.singular.size == 0
        assert mesh.paths == 1
        assert mesh.cut_length == pytest.approx(0.5, rel=1e-9)  # a radial segment
        p = seamless.integrate(mesh)
        found = measures.quality(p)
        assert found["flipped_triangles"] == 0
        misfits.append(found["misfit"])
        # U (or V, by the labels) = ln r + c; the other coordinate advances by 2π once round
        corner_uv = p.corner_values()
        r = np.hypot(*x[mesh.cells].transpose(2, 0, 1))
        radial = [np.ptp(corner_uv[..., c] - np.log(r)) for c in range(2)]
        c = int(np.argmin(radial))
        assert radial[c] < 0.05 / refine
        span = np.ptp(corner_uv[..., 1 - c])
        assert span == pytest.approx(2 * np.pi, rel=0.02 / refine)
    rates = np.log2(np.array(misfits[:-1]) / np.array(misfits[1:]))
    assert np.all(rates > 0.9), (misfits, rates)


def test_quarter_turn_field_has_one_singular_vertex_cut_to_the_boundary():
    x, cells = grid(10, 10, -1, 1, -1, 1)
    theta = np.arctan2(x[:, 1] + 0.05, x[:, 0] + 0.03)  # centre inside a triangle-free spot
    q = odeco.frames_to_q(np.ones((x.shape[0], 2)), theta / 4)
    mesh = cut.cut_mesh(x, cells, q)
    assert mesh.singular.size == 1 and abs(int(mesh.turns[0])) == 1
    assert mesh.paths == 1
    assert np.any(mesh.jump[mesh.cut] != 0)
    # away from the cut the combing is consistent: no other edge jumps
    others = np.setdiff1d(np.flatnonzero(mesh.faces[:, 1] >= 0), mesh.cut)
    assert np.all(mesh.jump[others] == 0)
    p = seamless.integrate(mesh)
    assert np.all(np.isfinite(p.uv))


def mapped_grid(n, chart, lo=0.5, hi=1.5):
    """A structured mesh of [lo, hi]² in coordinates (a, b), mapped to the plane by ``chart``."""
    ab, cells = grid(n, n, lo, hi, lo, hi)
    return ab, chart(ab), cells


def parabolic(ab):
    s, t = ab[:, 0], ab[:, 1]
    return np.stack([s * t, (t**2 - s**2) / 2], axis=1)


def elliptic(ab):
    mu, nu = ab[:, 0], ab[:, 1]
    return np.stack([np.cosh(mu) * np.cos(nu), np.sinh(mu) * np.sin(nu)], axis=1)


def chart_field(ab, chart, eps=1e-6):
    """The frame (∂x/∂a, ∂x/∂b) of an orthogonal chart: integrable, its map is (a, b)."""
    da = (chart(ab + [eps, 0]) - chart(ab - [eps, 0])) / (2 * eps)
    db = (chart(ab + [0, eps]) - chart(ab - [0, eps])) / (2 * eps)
    lengths = np.stack([np.linalg.norm(da, axis=1), np.linalg.norm(db, axis=1)], axis=1)
    return odeco.frames_to_q(lengths, np.arctan2(da[:, 1], da[:, 0]))


@pytest.mark.parametrize("chart", [parabolic, elliptic], ids=["parabolic", "elliptic"])
def test_orthogonal_coordinates_integrate_with_first_order_misfit(chart):
    """Parabolic and elliptic coordinates on a coordinate rectangle: the map is (a, b) up
    to relabelling and translation, the misfit falls at rate ≥ 1, nothing flips."""
    misfits = []
    for n in (8, 16, 32):
        ab, x, cells = mapped_grid(n, chart)
        mesh = cut.cut_mesh(x, cells, chart_field(ab, chart))
        assert mesh.cut.size == 0 and mesh.singular.size == 0
        p = seamless.integrate(mesh)
        found = measures.quality(p)
        assert found["flipped_triangles"] == 0
        misfits.append(found["misfit"])
        uv = np.zeros((mesh.num_wedges, 2))
        uv[mesh.corners.ravel()] = ab[mesh.cells.ravel()]  # the exact map at the wedges
        error = [min(np.ptp(p.uv[:, i] - sign * uv[:, j]) for sign in (1, -1))
                 for i, j in ((0, 0), (1, 1))]
        swapped = [min(np.ptp(p.uv[:, i] - sign * uv[:, j]) for sign in (1, -1))
                   for i, j in ((0, 1), (1, 0))]
        assert min(max(error), max(swapped)) < 2.0 / n
    rates = np.log2(np.array(misfits[:-1]) / np.array(misfits[1:]))
    assert np.all(rates >= 0.9), (misfits, rates)


def test_a_field_with_many_singularities_still_gives_a_map():
    """Random frames: dozens of singular vertices, each cut to the boundary; the map exists
    (finite, seams and boundary constraints consistent) and is judged by its measures."""
    rng = np.random.default_rng(7)
    x, cells = grid(12, 12)
    q = odeco.frames_to_q(rng.uniform(0.5, 2.0, (x.shape[0], 2)),
                          rng.uniform(0, 2 * np.pi, x.shape[0]))
    mesh = cut.cut_mesh(x, cells, q)
    assert mesh.singular.size > 20 and 0 < mesh.paths <= mesh.singular.size
    assert np.isin(mesh.singular, mesh.edges[mesh.cut]).all()  # every one on the cut
    others = np.setdiff1d(np.flatnonzero(mesh.faces[:, 1] >= 0), mesh.cut)
    assert np.all(mesh.jump[others] == 0)  # the combing is consistent off the cut
    found = measures.quality(seamless.integrate(mesh))
    assert np.isfinite(found["misfit"]) and found["misfit"] > 0.3  # far from integrable


def test_bad_input_is_refused():
    x, cells = grid(2, 2)
    q = odeco.frames_to_q(np.ones((x.shape[0], 2)), np.zeros(x.shape[0]))
    with pytest.raises(ValueError, match="more than two triangles"):
        cut.cut_mesh(x, np.concatenate([cells, cells[:1]]), q)


def test_a_singularity_on_the_boundary_still_gives_a_map():
    """A field turning by a quarter around a boundary point: no interior singular vertex
    to cut to, so the turn shows up as boundary edges whose constant coordinate
    conflicts; the map still exists, finite, and its misfit says it is poor."""
    x, cells = grid(10, 10, -1, 1, 0, 1)
    theta = np.arctan2(x[:, 1] + 1e-3, x[:, 0] + 0.05)
    q = odeco.frames_to_q(np.ones((x.shape[0], 2)), theta / 4)
    mesh = cut.cut_mesh(x, cells, q)
    assert mesh.singular.size == 0 and mesh.paths == 0
    found = measures.quality(seamless.integrate(mesh))
    assert np.isfinite(found["misfit"]) and found["misfit"] > 0.05
