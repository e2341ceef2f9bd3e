"""The 2D frame algebra as one object (:mod:`ufl_frames.frames2d.algebra`): a thin face
over :mod:`~ufl_frames.frames2d.odeco`, :mod:`~ufl_frames.frames2d.aspect` and the
bracket table, with the sizes the FEM layer and the kernels read. Pure NumPy.

Truth: the module functions it wraps (the same arrays, bit for bit) and the frames'
definitions (unit isotropic frames along given directions).
"""

import numpy as np
import pytest

from ufl_frames.frames2d import aspect, odeco
from ufl_frames.frames2d.algebra import ALGEBRA, FrameAlgebra2D
from ufl_frames.frames2d.bracket import BRACKET_ENTRIES


def _frames(n=50, seed=3):
    rng = np.random.default_rng(seed)
    lengths = rng.uniform(0.3, 2.0, (n, 2))
    angles = rng.uniform(-np.pi, np.pi, n)
    return lengths, angles, rng


def test_sizes_and_table():
    assert ALGEBRA.count == odeco.NUM_COEFFICIENTS == 5
    assert (ALGEBRA.dim, ALGEBRA.cell, ALGEBRA.cell_vertices) == (2, "triangle", 3)
    assert ALGEBRA.bracket_components == 2
    assert dict(ALGEBRA.bracket_entries) == BRACKET_ENTRIES
    assert [k for k, _ in ALGEBRA.bracket_entries] == list(BRACKET_ENTRIES)  # the order
    assert {i for (i, _, _, _), _ in ALGEBRA.bracket_entries} == set(range(2))
    assert ALGEBRA == FrameAlgebra2D() and hash(ALGEBRA) == hash(FrameAlgebra2D())


def test_methods_are_the_module_functions():
    lengths, angles, rng = _frames()
    q = odeco.frames_to_q(lengths, angles)
    noisy = q + 0.1 * rng.standard_normal(q.shape)
    gradient = rng.standard_normal(q.shape)
    normals = rng.standard_normal((q.shape[0], 2))
    same = np.testing.assert_array_equal
    same(ALGEBRA.frames_to_q(lengths, angles), q)
    for got, want in zip(ALGEBRA.q_to_frames(noisy), odeco.q_to_frames(noisy), strict=True):
        same(got, want)
    same(ALGEBRA.project(noisy, max_aspect=3.0), odeco.project(noisy, max_aspect=3.0))
    same(ALGEBRA.project(noisy, isotropic=True), odeco.project(noisy, isotropic=True))
    same(ALGEBRA.project_aligned(noisy, normals, max_aspect=3.0),
         odeco.project_aligned(noisy, normals, max_aspect=3.0))
    same(ALGEBRA.variety_residual(noisy), odeco.variety_residual(noisy))
    same(ALGEBRA.tangent_basis(q, 3.0, gradient, on_variety=True),
         odeco.tangent_basis(q, 3.0, gradient, on_variety=True))
    same(ALGEBRA.tangent_project(q, gradient), odeco.tangent_project(q, gradient))
    same(ALGEBRA.tangent_curvature(q, gradient, 3.0), odeco.tangent_curvature(q, gradient, 3.0))
    same(ALGEBRA.pushed_off_bound(q, gradient, 3.0), odeco.pushed_off_bound(q, gradient, 3.0))
    assert ALGEBRA.aspect_bound(False, 3.0) == aspect.aspect_bound(False, 3.0) == 3.0
    assert ALGEBRA.aspect_bound(True, 3.0) is None


def test_orientation_and_unit_frames():
    """``orientation`` is the first branch's direction; ``unit_frames`` of it is the unit
    isotropic frame of the same cross; ``closest_unit_isotropic`` keeps the cross."""
    lengths, angles, _ = _frames()
    q = odeco.frames_to_q(lengths, angles)
    directions = ALGEBRA.orientation(q)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0, atol=1e-15)
    unit = ALGEBRA.unit_frames(directions)
    np.testing.assert_allclose(unit, odeco.frames_to_q(np.ones((q.shape[0], 2)), angles),
                               atol=1e-14)
    np.testing.assert_allclose(ALGEBRA.closest_unit_isotropic(q), unit, atol=1e-12)
    np.testing.assert_allclose(ALGEBRA.project_aligned(q, directions), q, atol=1e-12)


def test_tangent_columns():
    """The rotation column moves the angle only, the anisotropy column the difference of
    the lengths only (the columns the manifold drops at fixed rows and isotropic frames)."""
    lengths, angles, _ = _frames(20)
    q = odeco.frames_to_q(lengths, angles)
    basis = ALGEBRA.tangent_basis(q)
    assert basis.shape == (20, ALGEBRA.count, ALGEBRA.tangent_columns)
    (rotation,), (anisotropy,) = ALGEBRA.rotation_columns, ALGEBRA.anisotropy_columns
    eps = 1e-6
    turn = (odeco.frames_to_q(lengths, angles + eps) - odeco.frames_to_q(lengths, angles - eps))
    stretch = (odeco.frames_to_q(lengths + [eps, -eps], angles)
               - odeco.frames_to_q(lengths - [eps, -eps], angles))
    for step, column in ((turn, rotation), (stretch, anisotropy)):
        unit = step / np.linalg.norm(step, axis=1, keepdims=True)
        np.testing.assert_allclose(np.abs(np.einsum("ni,ni->n", unit, basis[:, :, column])),
                                   1.0, atol=1e-8)


@pytest.mark.parametrize("bad", [np.ones((2, 4)), np.ones(5)])
def test_shapes_are_checked(bad):
    with pytest.raises(ValueError, match="shape"):
        ALGEBRA.project(bad)
