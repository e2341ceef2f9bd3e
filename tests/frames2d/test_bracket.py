"""Tests of the Lie-bracket tensor (note eq. 10, note-checks §3) (frames2d.bracket).

The gradient of q is computed exactly by the chain rule from q(s, d, t) (s = l1 + l2,
d = l1 − l2) and the gradients of the lengths and the angle; the reference bracket
:func:`~ufl_frames.frames2d.bracket.lie_bracket_direct` is itself checked against finite
differences of explicit vector fields.
"""

import importlib.util
import pathlib

import numpy as np
import pytest

from ufl_frames.frames2d import bracket, odeco

ROOT = pathlib.Path(__file__).resolve().parents[2]
SQRT2 = np.sqrt(2.0)


def q_and_gradient(lengths, angles, grad_lengths, grad_angles):
    """q (N, 5) and ∂q_j/∂x_k (N, 5, 2) by the chain rule through (s, d, t)."""
    s, d = lengths[:, 0] + lengths[:, 1], lengths[:, 0] - lengths[:, 1]
    grad_s = grad_lengths[:, 0] + grad_lengths[:, 1]
    grad_d = grad_lengths[:, 0] - grad_lengths[:, 1]
    c2, s2, c4, s4 = (f(k * angles) for k in (2, 4) for f in (np.cos, np.sin))
    zero, one = np.zeros_like(s), np.ones_like(s)
    q = np.stack([3 * SQRT2 / 8 * s, d / 2 * c2, d / 2 * s2, s / 8 * c4, s / 8 * s4], axis=1)
    dq_ds = np.stack([3 * SQRT2 / 8 * one, zero, zero, c4 / 8, s4 / 8], axis=1)
    dq_dd = np.stack([zero, c2 / 2, s2 / 2, zero, zero], axis=1)
    dq_dt = np.stack([zero, -d * s2, d * c2, -s / 2 * s4, s / 2 * c4], axis=1)
    grad_q = (
        dq_ds[:, :, None] * grad_s[:, None, :]
        + dq_dd[:, :, None] * grad_d[:, None, :]
        + dq_dt[:, :, None] * grad_angles[:, None, :]
    )
    return q, grad_q


def random_frames(rng, n, isotropic_fraction=0.25):
    lengths = np.exp(rng.uniform(np.log(0.1), np.log(10.0), (n, 2)))
    iso = rng.random(n) < isotropic_fraction
    lengths[iso, 1] = lengths[iso, 0]
    angles = rng.uniform(-np.pi, np.pi, n)
    grad_lengths = rng.standard_normal((n, 2, 2)) * rng.uniform(0.1, 10, (n, 1, 1))
    grad_angles = rng.standard_normal((n, 2)) * rng.uniform(0.1, 10, (n, 1))
    return lengths, angles, grad_lengths, grad_angles


def bracket_scale(lengths, grad_lengths, grad_angles):
    """Sum of the magnitudes of the four terms of the bracket: the scale of round-off."""
    l1, l2 = np.abs(lengths).T
    gl = np.linalg.norm(grad_lengths, axis=2)
    return l1 * gl[:, 1] + l2 * gl[:, 0] + 2 * l1 * l2 * np.linalg.norm(grad_angles, axis=1)


def null_space_tensors():
    """The 12 tensors N with N_ijkl q_l ∂_k q_j = δ_i,i0 q^T A_m ∂_k0 q (note-checks §3)."""
    out = []
    for i0 in range(2):
        for k0 in range(2):
            for a in odeco.VARIETY_MATRICES:
                n = np.zeros((2, 5, 2, 5))
                n[i0, :, k0, :] = a  # symmetric: (A_m)_jl
                out.append(n)
    return np.array(out)


# --- the table ---------------------------------------------------------------------


def test_committed_table_is_consistent():
    assert bracket.NULLITY == 12
    assert bracket.BRACKET_TENSOR.shape == (2, 5, 2, 5)
    for index, value in bracket.BRACKET_ENTRIES.items():
        assert bracket.BRACKET_TENSOR[index] == value != 0


@pytest.mark.serial
def test_regenerated_table_equals_the_committed_one(tmp_path):
    pytest.importorskip("sympy")
    spec = importlib.util.spec_from_file_location(
        "derive_bracket", ROOT / "scripts" / "derive_bracket.py"
    )
    derive_bracket = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(derive_bracket)
    path = tmp_path / "table.py"
    derive_bracket.main(path)
    spec = importlib.util.spec_from_file_location("regenerated_table", path)
    table = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(table)
    assert table.NULLITY == 12 == bracket.NULLITY
    assert table.BRACKET_ENTRIES.keys() == bracket.BRACKET_ENTRIES.keys()
    for key, value in bracket.BRACKET_ENTRIES.items():
        assert table.BRACKET_ENTRIES[key] == pytest.approx(value, rel=1e-15, abs=1e-15), key


def test_table_is_the_minimum_norm_solution_of_sampled_equations():
    """Independent of sympy: sample the defining equations and solve by least squares."""
    rng = np.random.default_rng(1)
    frames = random_frames(rng, 100)
    q, grad_q = q_and_gradient(*frames)
    target = bracket.lie_bracket_direct(*frames)  # (N, 2)
    # [u, v]_i = C_ijkl q_l ∂_k q_j: for each component i the same N x 50 matrix of
    # products q_l ∂_k q_j multiplies the 50 unknowns C_i···. (Kept small: LAPACK on
    # larger matrices goes multithreaded and crawls on a loaded machine.)
    matrix = np.einsum("nl,njk->njkl", q, grad_q).reshape(len(q), 50)
    sv = np.linalg.svd(matrix, compute_uv=False)
    rank = int(np.sum(sv > 1e-10 * sv[0]))
    assert 2 * (50 - rank) == bracket.NULLITY == 12
    c, *_ = np.linalg.lstsq(matrix, target, rcond=1e-10)  # minimum norm, (50, 2)
    np.testing.assert_allclose(c.T.reshape(2, 5, 2, 5), bracket.BRACKET_TENSOR, atol=1e-10)


# --- the bracket ----------------------------------------------------------------------


def test_lie_bracket_matches_the_direct_formula():
    rng = np.random.default_rng(2)
    lengths, angles, grad_lengths, grad_angles = frames = random_frames(rng, 1000)
    q, grad_q = q_and_gradient(*frames)
    np.testing.assert_allclose(q, odeco.frames_to_q(lengths, angles), atol=1e-14)
    got = bracket.lie_bracket(q, grad_q)
    want = bracket.lie_bracket_direct(*frames)
    error = np.linalg.norm(got - want, axis=1) / bracket_scale(lengths, grad_lengths, grad_angles)
    assert error.max() < 1e-12, error.max()


def test_direct_formula_matches_finite_differences():
    """[u, v] = (∇v) u − (∇u) v for explicit smooth fields, by central differences."""

    def l1(x, y):
        return 1.5 + 0.4 * np.sin(x + 2 * y)

    def l2(x, y):
        return 0.8 + 0.3 * np.cos(3 * x - y)

    def t(x, y):
        return 0.7 * x * y + 0.5 * np.sin(y)

    def fields(x, y):
        a, b, angle = l1(x, y), l2(x, y), t(x, y)
        u = a[:, None] * np.stack([np.cos(angle), np.sin(angle)], axis=-1)
        v = b[:, None] * np.stack([-np.sin(angle), np.cos(angle)], axis=-1)
        return u, v

    rng = np.random.default_rng(3)
    x, y = rng.uniform(-1, 1, (2, 100))
    h = 1e-5
    (ux1, vx1), (ux0, vx0) = fields(x + h, y), fields(x - h, y)
    (uy1, vy1), (uy0, vy0) = fields(x, y + h), fields(x, y - h)
    jac_u = np.stack([(ux1 - ux0) / (2 * h), (uy1 - uy0) / (2 * h)], axis=2)  # ∂u_i/∂x_k
    jac_v = np.stack([(vx1 - vx0) / (2 * h), (vy1 - vy0) / (2 * h)], axis=2)
    u, v = fields(x, y)
    fd = np.einsum("nik,nk->ni", jac_v, u) - np.einsum("nik,nk->ni", jac_u, v)

    def grad(f):
        return np.stack(
            [(f(x + h, y) - f(x - h, y)) / (2 * h), (f(x, y + h) - f(x, y - h)) / (2 * h)], axis=1
        )

    direct = bracket.lie_bracket_direct(
        np.stack([l1(x, y), l2(x, y)], axis=1),
        t(x, y),
        np.stack([grad(l1), grad(l2)], axis=1),
        grad(t),
    )
    np.testing.assert_allclose(direct, fd, atol=1e-8)


@pytest.mark.parametrize("integrable", [True, False])
def test_annulus_fields(integrable):
    """note-checks §4: u = g(r) e_r, v = f(r) e_θ: [u, v] = g (f' − f/r) e_θ, zero iff f = c r."""
    rng = np.random.default_rng(4)
    r = rng.uniform(0.5, 2.0, 300)
    theta = rng.uniform(-np.pi, np.pi, 300)
    e_r = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    e_t = np.stack([-np.sin(theta), np.cos(theta)], axis=1)
    g, dg = 1 + r**2, 2 * r
    f, df = (0.7 * r, 0.7 * np.ones_like(r)) if integrable else (r**2, 2 * r)
    lengths = np.stack([g, f], axis=1)
    grad_lengths = np.stack([dg[:, None] * e_r, df[:, None] * e_r], axis=1)
    grad_angles = e_t / r[:, None]  # t = θ
    q, grad_q = q_and_gradient(lengths, theta, grad_lengths, grad_angles)
    got = bracket.lie_bracket(q, grad_q)
    want = (g * (df - f / r))[:, None] * e_t
    np.testing.assert_allclose(got, want, atol=1e-12 * np.abs(q).max() * np.abs(grad_q).max())
    if integrable:
        assert np.abs(got).max() < 1e-12


# --- symmetries and the null space ------------------------------------------------------


def test_bracket_is_invariant_under_relabelling_and_flips_under_reflection():
    rng = np.random.default_rng(5)
    lengths, angles, grad_lengths, grad_angles = random_frames(rng, 400)
    reference = bracket.lie_bracket_direct(lengths, angles, grad_lengths, grad_angles)
    scale = bracket_scale(lengths, grad_lengths, grad_angles)[:, None]
    # (u, v) → (v, −u): t → t + π/2 with l1 ↔ l2. Same q, same gradient, same bracket.
    relabelled = (lengths[:, ::-1], angles + np.pi / 2, grad_lengths[:, ::-1], grad_angles)
    np.testing.assert_allclose(
        bracket.lie_bracket_direct(*relabelled) / scale, reference / scale, atol=1e-13
    )
    q, grad_q = q_and_gradient(lengths, angles, grad_lengths, grad_angles)
    q_r, grad_q_r = q_and_gradient(*relabelled)
    np.testing.assert_allclose(q_r, q, atol=1e-13)
    np.testing.assert_allclose(grad_q_r, grad_q, atol=1e-12)
    # (u, v) → (−u, −v): t → t + π.
    turned = (lengths, angles + np.pi, grad_lengths, grad_angles)
    np.testing.assert_allclose(
        bracket.lie_bracket_direct(*turned) / scale, reference / scale, atol=1e-13
    )
    # Reflection of the labels, u → −u (negatively oriented): the bracket changes sign,
    # which is why eq. 10 needs positively oriented frames.
    sign = np.array([-1.0, 1.0])
    reflected = (lengths * sign, angles, grad_lengths * sign[:, None], grad_angles)
    np.testing.assert_allclose(
        bracket.lie_bracket_direct(*reflected) / scale, -reference / scale, atol=1e-13
    )


def test_null_space_terms_vanish_on_the_variety():
    rng = np.random.default_rng(6)
    frames = random_frames(rng, 500)
    q, grad_q = q_and_gradient(*frames)
    scale = (
        np.linalg.norm(q, axis=1)[:, None, None]
        * np.linalg.norm(grad_q, axis=(1, 2))[:, None, None]
    )
    # q^T A_m ∂_k q = ½ ∂_k g_m(q) = 0 along the variety.
    terms = np.einsum("nl,mlj,njk->nmk", q, odeco.VARIETY_MATRICES, grad_q)
    assert np.all(np.abs(terms) <= 1e-14 * scale)
    null = null_space_tensors()
    flat = null.reshape(12, -1)
    assert np.linalg.matrix_rank(flat) == 12
    # The committed C is the minimum-norm member: orthogonal to the null space.
    assert np.abs(flat @ bracket.BRACKET_TENSOR.ravel()).max() < 1e-14
    for n_tensor in null:
        values = np.einsum("ijkl,nl,njk->ni", n_tensor, q, grad_q)
        assert np.all(np.abs(values) <= 1e-14 * scale[:, :, 0])
    # Any other member of the family gives the same bracket on the variety ...
    other = bracket.BRACKET_TENSOR + np.tensordot(rng.standard_normal(12), null, axes=1)
    got = np.einsum("ijkl,nl,njk->ni", other, q, grad_q)
    want = bracket.lie_bracket(q, grad_q)
    assert np.all(np.abs(got - want) <= 1e-12 * scale[:, :, 0])
    # ... but not off it (note-checks §3: the choice matters inside elements).
    q_off = q + 0.1 * np.linalg.norm(q, axis=1, keepdims=True) * rng.standard_normal(q.shape)
    off = np.einsum("ijkl,nl,njk->ni", other, q_off, grad_q) - bracket.lie_bracket(q_off, grad_q)
    assert np.abs(off).max() > 1e-3 * scale.max()


# --- bad input ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("q", "grad_q"),
    [
        (np.ones(5), np.ones((5, 2))),
        (np.ones((3, 5)), np.ones((3, 2, 5))),
        (np.ones((3, 5)), np.ones((2, 5, 2))),
        (np.ones((3, 4)), np.ones((3, 4, 2))),
    ],
)
def test_lie_bracket_rejects_bad_shapes(q, grad_q):
    with pytest.raises(ValueError, match=r"need q \(N, 5\) and grad_q \(N, 5, 2\)"):
        bracket.lie_bracket(q, grad_q)
