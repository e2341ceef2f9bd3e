"""3D Odeco algebra (pure NumPy): the harmonic basis against quadrature on the sphere, the
27 variety equations against frames and random tensors, and the projections against
their optimality conditions."""

import numpy as np
import pytest

from ufl_frames.frames3d import harmonics, odeco


def rotations(n, seed=0):
    """Uniformly random rotations (n, 3, 3) from unit quaternions."""
    q = np.random.default_rng(seed).normal(size=(n, 4))
    a, b, c, d = (q / np.linalg.norm(q, axis=1)[:, None]).T
    return np.stack([
        np.stack([a * a + b * b - c * c - d * d, 2 * (b * c - a * d), 2 * (b * d + a * c)], -1),
        np.stack([2 * (b * c + a * d), a * a - b * b + c * c - d * d, 2 * (c * d - a * b)], -1),
        np.stack([2 * (b * d - a * c), 2 * (c * d + a * b), a * a - b * b - c * c + d * d], -1),
    ], axis=1)


def sphere_quadrature(n_theta=12, n_phi=24):
    """Points (k, 3) and weights (k,) exact for polynomials of degree ≤ 2·n_theta − 1 on
    the unit sphere: Gauss-Legendre in cos θ, the trapezoidal rule in φ."""
    z, wz = np.polynomial.legendre.leggauss(n_theta)
    phi = 2 * np.pi * np.arange(n_phi) / n_phi
    Z, P = np.meshgrid(z, phi, indexing="ij")
    r = np.sqrt(1 - Z**2)
    x = np.stack([r * np.cos(P), r * np.sin(P), Z], axis=-1).reshape(-1, 3)
    w = (wz[:, None] * np.full(n_phi, 2 * np.pi / n_phi)[None, :]).ravel()
    return x, w


def evaluate(q, x):
    """The quartic of coefficients q (N, 15) at the points x (k, 3): (N, k)."""
    monomials = np.stack([x[:, 0] ** a * x[:, 1] ** b * x[:, 2] ** c
                          for a, b, c in harmonics.MONOMIALS], axis=1)
    return (q @ harmonics.FROM_Q.T) @ monomials.T


def frames(n, seed=0, lengths=None):
    R = rotations(n, seed)
    lam = (np.random.default_rng(seed + 1).uniform(0.5, 2.0, (n, 3)) if lengths is None
           else np.broadcast_to(np.asarray(lengths, float), (n, 3)).copy())
    return odeco.frames_to_q(lam, R), lam, R


# --- the basis ------------------------------------------------------------------------


def test_harmonics_are_orthonormal_on_the_sphere():
    x, w = sphere_quadrature()
    Y = evaluate(np.eye(15), x)
    assert np.abs((Y * w) @ Y.T - np.eye(15)).max() < 1e-13


def test_harmonics_have_their_degree():
    """Each basis function is a spherical harmonic of its degree l: for a quartic
    f = r⁴ g(ω), Δf = r² (20 g + Δ_S g), so Δ_S g = −l(l+1) g reads Δf = (20 − l(l+1)) f
    on the unit sphere."""
    for j, degree in enumerate(harmonics.DEGREES):
        c = harmonics.FROM_Q[:, j]
        lap = {}
        for (a, b, e), coef in zip(harmonics.MONOMIALS, c, strict=True):
            for p, dec in ((a, (2, 0, 0)), (b, (0, 2, 0)), (e, (0, 0, 2))):
                if p >= 2:
                    key = (a - dec[0], b - dec[1], e - dec[2])
                    lap[key] = lap.get(key, 0.0) + coef * p * (p - 1)
        # Δ f is a quadratic; on the sphere multiply by r² = 1: compare pointwise
        x, _ = sphere_quadrature()
        lap_f = sum(v * x[:, 0] ** k[0] * x[:, 1] ** k[1] * x[:, 2] ** k[2] for k, v in lap.items())
        f = evaluate(np.eye(15)[j:j + 1], x)[0]
        assert np.abs(lap_f - 12 * f - 8 * f + degree * (degree + 1) * f).max() < 1e-10


def test_coefficients_are_the_quartic_and_rotation_invariant():
    x, _ = sphere_quadrature()
    u = rotations(5)[:, :, 0]
    q = harmonics.q_of_powers(u)
    assert np.abs(evaluate(q, x) - (u @ x.T) ** 4).max() < 1e-13
    # |q|² = ∫ (u·x)⁸ dA = 4π/9 for every unit u, and per degree the same for all u
    assert np.allclose(np.sum(q**2, axis=1), 4 * np.pi / 9, rtol=1e-13)
    for degree in (0, 2, 4):
        part = np.sum(q[:, harmonics.DEGREES == degree] ** 2, axis=1)
        assert np.ptp(part) < 1e-13


def test_mandel_matrix_of_a_branch_is_its_outer_square():
    u = rotations(4, seed=3)[:, :, 1]
    m = np.stack([u[:, 0] ** 2, u[:, 1] ** 2, u[:, 2] ** 2, np.sqrt(2) * u[:, 1] * u[:, 2],
                  np.sqrt(2) * u[:, 0] * u[:, 2], np.sqrt(2) * u[:, 0] * u[:, 1]], axis=1)
    M = harmonics.mandel(harmonics.q_of_powers(u))
    assert np.abs(M - m[:, :, None] * m[:, None, :]).max() < 1e-14


# --- the variety ------------------------------------------------------------------------


def test_27_equations_vanish_on_frames_and_not_on_tensors():
    q, _, _ = frames(500)
    scale = np.sum(q**2, axis=1)
    assert np.abs(odeco.variety_residual(q)).max() < 1e-14 * scale.max()
    t = np.random.default_rng(7).normal(size=(500, 15))
    res = np.linalg.norm(odeco.variety_residual(t), axis=1) / np.sum(t**2, axis=1)
    assert res.min() > 1e-3
    assert odeco.VARIETY_MATRICES.shape == (27, 15, 15)


def test_variety_has_dimension_6():
    """The normals of the 27 equations have rank 9 at frames (15 − 9 = 6 = 3 rotations +
    3 lengths), and they annihilate the tangent directions the frames move in."""
    q, _, _ = frames(40, seed=2)
    normals = odeco.variety_normals(q)
    assert {int(np.linalg.matrix_rank(n, tol=1e-9 * np.abs(n).max())) for n in normals} == {9}
    T = odeco.tangent_basis(q)
    assert np.abs(normals @ T).max() < 1e-11


def test_frames_round_trip():
    q, lam, R = frames(1000, seed=4)
    lam2, R2 = odeco.q_to_frames(q)
    assert np.abs(odeco.frames_to_q(lam2, R2) - q).max() < 1e-12
    # the same branches up to order and sign: |R2ᵀ R| is a permutation matching the lengths
    P = np.abs(np.einsum("nji,njk->nik", R2, R))
    perm = np.argmax(P, axis=2)
    assert np.abs(np.take_along_axis(P, perm[:, :, None], 2) - 1).max() < 1e-12
    assert np.abs(lam2 - np.take_along_axis(lam, perm, 1)).max() < 1e-12


# --- projections ----------------------------------------------------------------------


@pytest.mark.parametrize("lengths", [None, (1.0, 1.0, 1.0), (1.0, 1 + 1e-7, 1 - 1e-7),
                                     (2.0, 1.0, 1.0), (1.0, 0.0, 0.0)])
def test_projection_is_exact_on_frames(lengths):
    q, _, _ = frames(300, seed=5, lengths=lengths)
    assert np.abs(odeco.project(q) - q).max() < 1e-12 * np.abs(q).max()


@pytest.mark.parametrize("lengths", [None, (1.0, 1.0, 1.0), (1.0, 1 + 1e-7, 1 - 1e-7)])
@pytest.mark.parametrize("eps", [1e-3, 1e-6])
def test_projection_of_perturbed_frames_is_the_closest_point(lengths, eps):
    """Within O(ε) of the frame, on the variety, and the residual orthogonal to the
    variety's tangent space there (first-order optimality)."""
    q, _, _ = frames(300, seed=6, lengths=lengths)
    d = np.random.default_rng(8).normal(size=q.shape)
    d *= eps / np.linalg.norm(d, axis=1)[:, None]
    p = odeco.project(q + d)
    assert np.linalg.norm(p - q, axis=1).max() <= 2 * eps
    assert np.abs(odeco.variety_residual(p)).max() < 1e-13
    T = odeco.tangent_basis(p)
    r = q + d - p
    # the iteration stops after a step under 1e-8 rad; at a residual of size ε its linear
    # rate leaves a tangential residual of order 1e-8 · ε · (curvature), not of order ε
    # (small steps are taken without comparing distances, which are flat to rounding there)
    assert np.abs(np.einsum("nka,nk->na", T, r)).max() < 1e-7 * eps
    assert np.abs(odeco.project(p) - p).max() < 1e-12


def test_isotropic_projection_has_equal_lengths():
    q, _, R = frames(200, seed=9)
    p = odeco.project(q, isotropic=True)
    lam, _ = odeco.q_to_frames(p)
    assert np.ptp(lam, axis=1).max() < 1e-10
    qi = odeco.frames_to_q(np.ones((200, 3)), R)
    assert np.abs(odeco.project(qi, isotropic=True) - qi).max() < 1e-12


def test_aligned_projection_keeps_the_normal_and_is_exact_on_aligned_frames():
    q, _, R = frames(200, seed=10)
    n = R[:, :, 1] * np.where(np.arange(200) % 2, 1.0, -1.0)[:, None]
    assert np.abs(odeco.project_aligned(q, n) - q).max() < 1e-12
    normals = np.random.default_rng(11).normal(size=(200, 3))
    p = odeco.project_aligned(q, normals)
    lam, R2 = odeco.q_to_frames(p)
    unit = normals / np.linalg.norm(normals, axis=1)[:, None]
    assert (1 - np.abs(np.einsum("nij,ni->nj", R2, unit)).max(axis=1)).max() < 1e-12
    assert np.abs(odeco.variety_residual(p)).max() < 1e-13
    # no closer than the unconstrained projection
    assert np.all(np.linalg.norm(q - p, axis=1)
                  >= np.linalg.norm(q - odeco.project(q), axis=1) - 1e-12)


@pytest.mark.parametrize("bad", [np.zeros((3, 14)), np.full((2, 15), np.nan),
                                 np.ones((2, 15)) * 1j])
def test_bad_coefficients_are_refused(bad):
    with pytest.raises(ValueError):
        odeco.project(bad)
