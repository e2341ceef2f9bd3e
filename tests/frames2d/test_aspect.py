r"""The aspect-ratio bound of non-isotropic frames (:mod:`ufl_frames.frames2d.odeco`, pure NumPy).

At a fixed angle t the frames are q = s e_s(t) + d e_d(t) (s = l1 + l2, d = l1 − l2), and
l_max/l_min ≤ A is the cone |d| ≤ κ s, κ = (A − 1)/(A + 1). So

* :func:`aspect.clamp_aspect` must leave frames inside the cone alone (bit for bit) and
  otherwise return the least-squares fit in that cone, which is checked against a
  brute-force search over a dense grid of the cone (s, u κ s), u ∈ [−1, 1];
* :func:`odeco.project` / :func:`odeco.project_aligned` with ``max_aspect`` keep the angle
  of the unbounded projection (the closest angle, resp. the normal's) and fit the lengths
  there under the bound;
* :func:`odeco.tangent_basis` with ``max_aspect`` treats the bound as an active set: a
  frame on the bound whose gradient pushes it further out loses the e_d column and moves
  along the bound instead; an inward gradient releases it.
"""

import numpy as np
import pytest

from ufl_frames.frames2d import odeco
from ufl_frames.frames2d.aspect import active_bound, aspect_bound, clamp_aspect

ASPECTS = [1.0, 1.5, 4.0, 10.0]
ES2, ED2 = 19.0 / 64.0, 1.0 / 4.0  # |e_s|², |e_d|²
#: Where the fit in the cone is its apex s = d = 0 (an 'inverted' q), clamp_aspect returns
#: the tiny frame s = 1e-8 (|s| + |d|) instead, which is worse by about 1e-8 |q|².
FLOOR = 1e-7


def kappa(aspect):
    return (aspect - 1) / (aspect + 1)


def plane(q):
    """e_s, e_d (N, 5) of the frames at the angle of the Odeco tensors ``q`` (arg C = 4t)."""
    theta = np.arctan2(q[:, 4], q[:, 3])
    zero = np.zeros_like(theta)
    e_s = np.stack(
        [
            np.full_like(theta, 3 * odeco.SQRT2 / 8),
            zero,
            zero,
            np.cos(theta) / 8,
            np.sin(theta) / 8,
        ],
        axis=1,
    )
    e_d = np.stack([zero, np.cos(theta / 2) / 2, np.sin(theta / 2) / 2, zero, zero], axis=1)
    return e_s, e_d


def aspect_of(q):
    lengths, _ = odeco.q_to_frames(q)
    lo, hi = np.min(lengths, axis=1), np.max(lengths, axis=1)
    return lo, hi


def random_q(rng, n):
    """Gaussian q (far from the variety, many 'inverted' fits) and elongated noisy frames."""
    ratio = np.exp(rng.uniform(np.log(0.01), np.log(100.0), n))
    lengths = np.stack([np.ones(n), ratio], axis=1) * rng.uniform(0.5, 2.0, (n, 1))
    frames = odeco.frames_to_q(lengths, rng.uniform(-np.pi, np.pi, n))
    frames += 1e-3 * np.linalg.norm(frames, axis=1, keepdims=True) * rng.standard_normal((n, 5))
    return np.concatenate([rng.standard_normal((n, 5)), frames])


def brute_force(q, e_s, e_d, k, points=801):
    """min over the cone |d| <= k s of |q − s e_s − d e_d|² on a dense grid, with (s, d)."""
    s_max = 2 * np.linalg.norm(q) / np.sqrt(ES2)  # the fit has |s e_s + d e_d| <= |q|
    s = np.linspace(0.0, s_max, points)[:, None]
    d = np.linspace(-1.0, 1.0, points)[None, :] * k * s
    qs, qd = q @ e_s, q @ e_d
    f = q @ q - 2 * s * qs - 2 * d * qd + s * s * ES2 + d * d * ED2
    i, j = np.unravel_index(np.argmin(f), f.shape)
    return f[i, j], s[i, 0], d[i, j], s_max / (points - 1)


# --- clamp_aspect -----------------------------------------------------------------


@pytest.mark.parametrize("aspect", ASPECTS)
def test_clamp_leaves_frames_inside_the_bound_unchanged(aspect):
    rng = np.random.default_rng(1)
    s = rng.uniform(0.1, 3.0, 1000)
    d = rng.uniform(-1.0, 1.0, 1000) * kappa(aspect) * s
    d[:10] = kappa(aspect) * s[:10]  # exactly on the bound
    s_out, d_out = clamp_aspect(s, d, aspect)
    assert np.array_equal(s_out, s) and np.array_equal(d_out, d)


@pytest.mark.parametrize("aspect", ASPECTS)
def test_clamp_is_the_least_squares_fit_in_the_cone(aspect):
    """Outside the cone: the projection on the nearer ray in the metric (|e_s|², |e_d|²)."""
    rng = np.random.default_rng(2)
    s = rng.uniform(-2.0, 3.0, 500)
    d = rng.uniform(-6.0, 6.0, 500)
    k = kappa(aspect)
    s_out, d_out = clamp_aspect(s, d, aspect)
    assert np.all(np.abs(d_out) <= k * s_out * (1 + 1e-12))
    assert np.all(s_out > 0)
    # The fit minimises ES2 (s' − s)² + ED2 (d' − d)² over the cone: compare with the
    # best of 2001 points on each ray and the unconstrained point where it is inside.
    t = np.linspace(0.0, 4.0, 2001)[None, :] * (np.abs(s) + np.abs(d))[:, None]
    cost = np.inf * np.ones(s.size)
    for sign in (-1.0, 1.0):
        ray = ES2 * (t - s[:, None]) ** 2 + ED2 * (sign * k * t - d[:, None]) ** 2
        cost = np.minimum(cost, ray.min(axis=1))
    inside = np.abs(d) <= k * s
    cost[inside] = 0.0
    got = ES2 * (s_out - s) ** 2 + ED2 * (d_out - d) ** 2
    spacing = 4.0 / 2000 * (np.abs(s) + np.abs(d))
    # got <= grid optimum (it is the exact optimum), up to the tiny-frame floor 1e-8 (|s|+|d|)
    assert np.all(got <= cost + 1e-12 * (s * s + d * d) + 1e-7 * (np.abs(s) + np.abs(d)) ** 2)
    # ... and the grid gets within its resolution of it
    assert np.all(cost <= got + 4 * spacing * (np.abs(s) + np.abs(d)) + 1e-12)


def test_clamp_rejects_bad_bounds():
    for bad in (0.5, 0.0, -2.0, np.nan, np.inf):
        with pytest.raises(ValueError, match="max_aspect"):
            clamp_aspect(np.ones(3), np.zeros(3), bad)


# --- project with max_aspect ------------------------------------------------------


@pytest.mark.parametrize("aspect", ASPECTS)
def test_project_bounds_the_aspect_ratio(aspect):
    rng = np.random.default_rng(3)
    q = random_q(rng, 2000)
    out = odeco.project(q, max_aspect=aspect)
    lo, hi = aspect_of(out)
    assert np.all(lo > 0)
    worst = np.max(hi / lo)
    print(f"\nmax_aspect {aspect}: largest l_max/l_min of the projections {worst!r}")
    assert worst <= aspect * (1 + 1e-12)
    assert np.max(np.abs(odeco.variety_residual(out))) <= 1e-12 * np.max(np.sum(out**2, axis=1))


@pytest.mark.parametrize("aspect", ASPECTS[1:])  # A = 1: only exact l1 = l2 is inside
def test_project_leaves_frames_inside_the_bound_unchanged(aspect):
    """Exactly: the bound changes nothing where the unbounded fit satisfies it."""
    rng = np.random.default_rng(4)
    n = 1000
    ratio = np.exp(rng.uniform(-1.0, 1.0, n) * np.log(aspect))
    lengths = np.stack([np.ones(n), ratio], axis=1) * rng.uniform(0.5, 2.0, (n, 1))
    q = odeco.frames_to_q(lengths, rng.uniform(-np.pi, np.pi, n))
    q[n // 2 :] += 1e-6 * rng.standard_normal((n - n // 2, 5))  # near-Odeco too
    free = odeco.project(q)
    lo, hi = aspect_of(free)
    inside = hi <= aspect * lo * (1 - 1e-9)
    assert inside.sum() > n // 2
    bounded = odeco.project(q, max_aspect=aspect)
    assert np.array_equal(bounded[inside], free[inside])
    exact = np.flatnonzero(inside[: n // 2])  # exact Odeco inputs are recovered
    assert np.allclose(bounded[exact], q[exact], rtol=0, atol=1e-13)


@pytest.mark.parametrize("aspect", [1.5, 4.0])
def test_project_is_the_constrained_fit_at_the_closest_angle(aspect):
    """Same angle as the unbounded projection; lengths = brute-force optimum in the cone."""
    rng = np.random.default_rng(5)
    q = random_q(rng, 20)
    out = odeco.project(q, max_aspect=aspect)
    free = odeco.project(q)
    # the angle: C = (s/8) e^{4it} of both have the same argument modulo π (the free fit
    # of a Gaussian q may be 'inverted', s < 0; the bounded one has s > 0)
    arg = np.angle((out[:, 3] + 1j * out[:, 4]) / (free[:, 3] + 1j * free[:, 4]))
    assert np.max(np.abs(np.sin(arg))) < 1e-12
    e_s, e_d = plane(out)
    for k in range(q.shape[0]):
        f_grid, s_grid, d_grid, ds = brute_force(q[k], e_s[k], e_d[k], kappa(aspect))
        f_out = np.sum((q[k] - out[k]) ** 2)
        scale = q[k] @ q[k]
        assert f_out <= f_grid + FLOOR * scale
        assert f_grid - f_out <= 1e-4 * scale  # the grid resolves the optimum
        s_out, d_out = out[k] @ e_s[k] / ES2, out[k] @ e_d[k] / ED2
        assert abs(s_out - s_grid) <= 2 * ds and abs(abs(d_out) - abs(d_grid)) <= 2 * ds


@pytest.mark.parametrize("aspect", ASPECTS)
def test_project_with_bound_is_idempotent(aspect):
    rng = np.random.default_rng(6)
    q = random_q(rng, 1000)
    once = odeco.project(q, max_aspect=aspect)
    twice = odeco.project(once, max_aspect=aspect)
    scale = np.linalg.norm(once, axis=1, keepdims=True)
    assert np.max(np.abs(twice - once) / scale) < 1e-12


def test_isotropic_projection_ignores_the_bound():
    rng = np.random.default_rng(7)
    q = random_q(rng, 200)
    assert np.array_equal(
        odeco.project(q, isotropic=True, max_aspect=2.0), odeco.project(q, isotropic=True)
    )


def test_project_rejects_bad_bounds():
    q = random_q(np.random.default_rng(8), 5)
    for bad in (0.99, np.nan):
        with pytest.raises(ValueError, match="max_aspect"):
            odeco.project(q, max_aspect=bad)
        with pytest.raises(ValueError, match="max_aspect"):
            odeco.project_aligned(q, np.ones((q.shape[0], 2)), max_aspect=bad)


# --- project_aligned with max_aspect ----------------------------------------------


@pytest.mark.parametrize("aspect", [1.0, 1.5, 4.0])
def test_project_aligned_with_bound(aspect):
    rng = np.random.default_rng(9)
    q = random_q(rng, 30)
    psi = rng.uniform(-np.pi, np.pi, q.shape[0])
    normals = np.stack([np.cos(psi), np.sin(psi)], axis=1) * rng.uniform(0.5, 2, (q.shape[0], 1))
    out = odeco.project_aligned(q, normals, max_aspect=aspect)
    free = odeco.project_aligned(q, normals)
    # orientation: arg C = 4 psi
    arg = np.angle((out[:, 3] + 1j * out[:, 4]) * np.exp(-4j * psi))
    assert np.max(np.abs(arg)) < 1e-12
    lo, hi = aspect_of(out)
    assert np.all(lo > 0) and np.all(hi <= aspect * lo * (1 + 1e-12))
    # inside the bound: unchanged, bit for bit
    lo_f, hi_f = aspect_of(free)
    inside = (lo_f > 0) & (hi_f <= aspect * lo_f * (1 - 1e-9))
    assert np.array_equal(out[inside], free[inside])
    # the constrained least-squares fit at the normal's angle
    e_s, e_d = plane(out)
    for k in range(q.shape[0]):
        f_grid, _, _, _ = brute_force(q[k], e_s[k], e_d[k], kappa(aspect))
        f_out = np.sum((q[k] - out[k]) ** 2)
        assert f_out <= f_grid + FLOOR * (q[k] @ q[k])
        assert f_grid - f_out <= 1e-4 * (q[k] @ q[k])
    # idempotent
    again = odeco.project_aligned(out, normals, max_aspect=aspect)
    assert np.max(np.abs(again - out)) < 1e-12 * np.max(np.abs(out))


# --- tangent_basis with max_aspect ------------------------------------------------


def frames_on_bound(rng, n, aspect):
    """Frames with l_max/l_min = aspect, half with d > 0 (l1 long), half with d < 0."""
    lengths = np.ones((n, 2))
    lengths[: n // 2, 0] = aspect
    lengths[n // 2 :, 1] = aspect
    lengths *= rng.uniform(0.5, 2.0, (n, 1))
    return odeco.frames_to_q(lengths, rng.uniform(-np.pi, np.pi, n))


def unit_e_d(q):
    """Unit e_d, oriented along increasing d = l1 − l2 of :func:`odeco.q_to_frames`."""
    return odeco.tangent_basis(q)[:, :, 1]


def length_gradient(q, outward):
    """A gradient along e_d whose descent pushes the frames of ``outward`` (N,) bool further
    out of the bound (|d| grows) and the others back in."""
    d_sign = np.where(odeco.q_to_frames(q)[0] @ np.array([1.0, -1.0]) < 0, -1.0, 1.0)
    return (np.where(outward, -1.0, 1.0) * d_sign)[:, None] * unit_e_d(q)


def check_orthonormal(basis):
    gram = np.einsum("nik,nil->nkl", basis, basis)
    nonzero = np.linalg.norm(basis, axis=1) > 0
    expected = np.zeros_like(gram)
    idx = np.arange(3)
    expected[:, idx, idx] = nonzero
    assert np.max(np.abs(gram - expected)) < 1e-12


@pytest.mark.parametrize("aspect", [1.5, 4.0])
def test_tangent_basis_outward_gradient_activates_the_bound(aspect):
    rng = np.random.default_rng(10)
    q = frames_on_bound(rng, 200, aspect)
    d_sign = np.where(odeco.q_to_frames(q)[0] @ np.array([1.0, -1.0]) < 0, -1.0, 1.0)
    e_d = unit_e_d(q)
    free = odeco.tangent_basis(q)
    # descent (−g) increasing |d|: g = −sign(d) e_d
    gradient = -d_sign[:, None] * e_d + 0.3 * free[:, :, 2]
    basis = odeco.tangent_basis(q, max_aspect=aspect, gradient=gradient)
    check_orthonormal(basis)
    assert np.all(basis[:, :, 1] == 0.0)  # e_d lost
    assert np.allclose(basis[:, :, 2], free[:, :, 2], atol=1e-14)  # rotation kept
    # column 0 runs along the bound: q + ε b0 has the same aspect ratio, and is tangent
    step = 1e-3 * np.linalg.norm(q, axis=1, keepdims=True) * basis[:, :, 0]
    lo, hi = aspect_of(q + step)
    assert np.allclose(hi / lo, aspect, rtol=1e-10)
    assert np.allclose(odeco.tangent_project(q, basis[:, :, 0]), basis[:, :, 0], atol=1e-12)
    # and it is (e_s + sign κ e_d) normalised
    k = kappa(aspect)
    along = free[:, :, 0] * np.sqrt(ES2) + (d_sign * k)[:, None] * e_d * np.sqrt(ED2)
    along /= np.linalg.norm(along, axis=1, keepdims=True)
    assert np.allclose(basis[:, :, 0], along, atol=1e-12)


@pytest.mark.parametrize("aspect", [1.5, 4.0])
def test_tangent_basis_inward_gradient_releases_the_bound(aspect):
    rng = np.random.default_rng(11)
    q = frames_on_bound(rng, 200, aspect)
    d_sign = np.where(odeco.q_to_frames(q)[0] @ np.array([1.0, -1.0]) < 0, -1.0, 1.0)
    e_d = unit_e_d(q)
    free = odeco.tangent_basis(q)
    gradient = d_sign[:, None] * e_d - 0.7 * free[:, :, 0]  # descent decreases |d|
    basis = odeco.tangent_basis(q, max_aspect=aspect, gradient=gradient)
    assert np.array_equal(basis, free)
    check_orthonormal(basis)


def test_tangent_basis_ignores_the_bound_inside():
    rng = np.random.default_rng(12)
    n = 200
    lengths = np.stack([np.ones(n), rng.uniform(0.3, 3.0, n)], axis=1)
    q = odeco.frames_to_q(lengths, rng.uniform(-np.pi, np.pi, n))
    gradient = rng.standard_normal((n, 5))
    basis = odeco.tangent_basis(q, max_aspect=4.0, gradient=gradient)
    assert np.array_equal(basis, odeco.tangent_basis(q))
    check_orthonormal(basis)


def test_tangent_basis_mixed_rows():
    """Active and released rows side by side: each row only depends on its own gradient."""
    rng = np.random.default_rng(13)
    q = frames_on_bound(rng, 100, 4.0)
    outward = rng.random(100) < 0.5
    gradient = length_gradient(q, outward)
    basis = odeco.tangent_basis(q, max_aspect=4.0, gradient=gradient)
    check_orthonormal(basis)
    assert np.all(basis[outward, :, 1] == 0.0)
    assert np.array_equal(basis[~outward], odeco.tangent_basis(q[~outward]))


@pytest.mark.parametrize("aspect", [1.5, 4.0])
def test_tangent_basis_active_set_is_first_order_feasibility(aspect):
    """A frame at the bound is active iff the steepest-descent step −εg leaves the cone.

    Checked geometrically: fit (s', d') of q − εg at the frame's angle (ε small) and test
    |d'| > κ s', for gradients mixing e_s, e_d and rotation: shrinking s at fixed d leaves
    the cone just as growing |d| does, so the s-component matters too.
    """
    rng = np.random.default_rng(15)
    n = 400
    q = frames_on_bound(rng, n, aspect)
    free = odeco.tangent_basis(q)
    gradient = np.einsum("nik,nk->ni", free, rng.standard_normal((n, 3)))
    e_s, e_d = free[:, :, 0] * np.sqrt(ES2), free[:, :, 1] * np.sqrt(ED2)  # unnormalised
    eps = (
        1e-7 * np.linalg.norm(q, axis=1, keepdims=True) / np.linalg.norm(gradient, axis=1)[:, None]
    )
    step = q - eps * gradient
    s_new = np.einsum("ni,ni->n", step, e_s) / ES2
    d_new = np.einsum("ni,ni->n", step, e_d) / ED2
    leaves = np.abs(d_new) - kappa(aspect) * s_new
    clear = np.abs(leaves) > 1e-3 * eps[:, 0] * np.linalg.norm(gradient, axis=1)
    assert clear.mean() > 0.95
    basis = odeco.tangent_basis(q, max_aspect=aspect, gradient=gradient)
    active = np.all(basis[:, :, 1] == 0.0, axis=1)
    assert np.array_equal(active[clear], leaves[clear] > 0)
    assert 0.2 < active.mean() < 0.8  # both cases are exercised
    check_orthonormal(basis)


def test_tangent_basis_only_held_is_the_given_set():
    """With ``only_held`` the held rows on the bound are the active set whatever the
    gradient: a held frame keeps the bound's basis under an inward gradient, an unheld one
    keeps e_d under an outward gradient, and a held frame inside the bound is free."""
    rng = np.random.default_rng(17)
    n = 100
    q = frames_on_bound(rng, n, 4.0)
    outward = rng.random(n) < 0.5
    gradient = length_gradient(q, outward)
    held = rng.random(n) < 0.5
    assert (held & ~outward).any() and (~held & outward).any()
    basis = odeco.tangent_basis(q, max_aspect=4.0, gradient=gradient, held=held,
                                only_held=True)
    check_orthonormal(basis)
    bound = odeco.tangent_basis(q, max_aspect=4.0, gradient=length_gradient(q, True))
    assert np.array_equal(basis[held], bound[held])  # the bound's basis, as if pushed out
    assert np.array_equal(basis[~held], odeco.tangent_basis(q[~held]))
    # the union semantics (the default) would have made the outward unheld frames active
    union = odeco.tangent_basis(q, max_aspect=4.0, gradient=gradient, held=held)
    assert np.all(union[~held & outward, :, 1] == 0.0)
    inside = odeco.frames_to_q(np.stack([np.ones(n), np.full(n, 2.0)], axis=1),
                               rng.uniform(-np.pi, np.pi, n))
    free = odeco.tangent_basis(inside, max_aspect=4.0, gradient=gradient,
                               held=np.ones(n, bool), only_held=True)
    assert np.array_equal(free, odeco.tangent_basis(inside))
    with pytest.raises(ValueError, match="held"):
        s_, d_ = np.ones(n), np.ones(n)
        active_bound(s_, d_, gradient, gradient, gradient, 4.0, held=None, only_held=True)


def test_tangent_curvature_follows_a_given_active_set():
    """``tangent_curvature(..., active=mask)`` is the curvature in the columns of the basis
    with that active set: equal to the one whose gradient decides the same set."""
    rng = np.random.default_rng(18)
    n = 100
    q = frames_on_bound(rng, n, 4.0)
    mask = rng.random(n) < 0.5
    deciding = length_gradient(q, mask)  # outward where mask
    gradient = rng.standard_normal((n, 5))
    expected = odeco.tangent_curvature(q, gradient, 4.0, active_gradient=deciding)
    given = odeco.tangent_curvature(q, gradient, 4.0, active_gradient=-deciding, active=mask)
    assert np.array_equal(given, expected)
    assert not np.array_equal(
        odeco.tangent_curvature(q, gradient, 4.0, active_gradient=-deciding), expected)


def test_tangent_basis_rejects_bad_bounds():
    q = frames_on_bound(np.random.default_rng(14), 4, 2.0)
    for bad in (0.5, np.nan):
        with pytest.raises(ValueError, match="max_aspect"):
            odeco.tangent_basis(q, max_aspect=bad, gradient=np.zeros_like(q))


def test_aspect_bound_rule():
    """One rule: no bound for isotropic frames or an infinite/missing A, else A (checked)."""
    assert aspect_bound(True, 4.0) is None
    assert aspect_bound(False, float("inf")) is None
    assert aspect_bound(False, None) is None
    assert aspect_bound(False, 4) == 4.0
    with pytest.raises(ValueError, match="max_aspect"):
        aspect_bound(False, 0.5)


@pytest.mark.parametrize("aspect", [1.5, 4.0, 10.0])
def test_pushed_off_bound_is_what_the_projection_clamps(aspect):
    """A frame on the bound is pushed off by a step iff the projection of q + ε·step (the
    retraction) has to clamp it: checked against :func:`odeco.project` without and with
    the bound, for random steps; frames inside the bound are never pushed off."""
    rng = np.random.default_rng(16)
    n = 400
    q = frames_on_bound(rng, n, aspect)
    step = rng.standard_normal((n, 5))
    eps = 1e-6 * np.linalg.norm(q, axis=1, keepdims=True) / np.linalg.norm(step, axis=1)[:, None]
    trial = q + eps * step
    clamped = np.linalg.norm(odeco.project(trial, max_aspect=aspect) - odeco.project(trial),
                             axis=1)
    clear = (clamped > 1e-4 * eps[:, 0] * np.linalg.norm(step, axis=1)) | (clamped == 0.0)
    assert clear.mean() > 0.95
    pushed = odeco.pushed_off_bound(q, step, aspect)
    assert np.array_equal(pushed[clear], clamped[clear] > 0)
    assert 0.2 < pushed.mean() < 0.8  # both cases are exercised
    inside = odeco.frames_to_q(np.stack([np.ones(n), np.full(n, 0.5 * (1 + aspect))], axis=1),
                               rng.uniform(-np.pi, np.pi, n))
    assert not odeco.pushed_off_bound(inside, step, aspect).any()
