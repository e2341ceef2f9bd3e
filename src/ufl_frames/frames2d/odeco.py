r"""Pointwise algebra of 2D Odeco tensors, vectorised over vertices (note §2.1).

A frame is two orthogonal branches: the unit direction :math:`\hat u = (\cos t, \sin t)`
with length :math:`l_1` and :math:`\hat v = (-\sin t, \cos t)` with length :math:`l_2`.
Its Odeco tensor (note eq. 1) is :math:`T = l_1 \hat u^{\otimes 4} + l_2 \hat v^{\otimes 4}`,
and the tensor polynomial on the unit circle :math:`x = (\cos\varphi, \sin\varphi)` is

.. math::  p(\varphi) = \tfrac{3s}{8} + \tfrac{d}{2}\cos 2(\varphi - t)
                        + \tfrac{s}{8}\cos 4(\varphi - t), \qquad s = l_1 + l_2,\ d = l_1 - l_2.

Harmonic basis (note eq. 2) and normalisation used throughout the package::

    Y = (1/sqrt(2), cos 2φ, sin 2φ, cos 4φ, sin 4φ),      p = Σ_j q_j Y_j,

orthonormal for the inner product (1/π)∫₀^{2π} f g dφ, so that |q|² = (1/π)∫ p² dφ:
the Euclidean norm of q is the L² norm of the tensor polynomial, invariant under
rotations. A frame has

    q = (3√2 s/8,  (d/2) cos 2t, (d/2) sin 2t,  (s/8) cos 4t, (s/8) sin 4t).

With a = q0/√2, B = q1 + i q2 and C = q3 + i q4 the Odeco variety (note eq. 3) is
a² = 9|C|² and aB = 3 B̄C, here written as three real quadratics q^T A_m q = 0:

    g1 = q0² − 18 (q3² + q4²)
    g2 = q0 q1 − 3√2 (q1 q3 + q2 q4)
    g3 = q0 q2 − 3√2 (q1 q4 − q2 q3)

Directions are read from C (arg C = 4t), lengths from (q0, C) and B.

Projection. For a fixed angle t the frames form the plane spanned by the orthogonal
vectors e_s(t), e_d(t) (q = s e_s + d e_d), so the best (s, d) is an orthogonal
projection, and the remaining function of θ = 4t is a trigonometric polynomial of
degree 2, maximised by safeguarded Newton iterations from the maximisers of its two
harmonics. This is the exact closest point — exact on Odeco inputs, isotropic ones
included — unlike the note's Mandel-eigenvector projection (``method="mandel"``),
which is kept for comparison and is unstable near isotropy (see note-checks §2).

No DOLFINx here: every function takes and returns NumPy arrays of shape (N, 5).
"""

import numpy as np

from ufl_frames.frames2d.aspect import ED_NORM2 as _ED_NORM2
from ufl_frames.frames2d.aspect import ES_NORM2 as _ES_NORM2
from ufl_frames.frames2d.aspect import active_bound, clamp_aspect

SQRT2 = np.sqrt(2.0)

#: Coefficients per frame: the 5 circular harmonics of a 2D fourth-order tensor (3D frames,
#: spherical harmonics, will have 15). Every (N, 5) array and 5-block of the package is this.
NUM_COEFFICIENTS = 5

#: Symmetric matrices A_m of the variety equations g_m(q) = q^T A_m q (note eq. 3).
VARIETY_MATRICES = np.zeros((3, NUM_COEFFICIENTS, NUM_COEFFICIENTS))
VARIETY_MATRICES[0, 0, 0] = 1.0
VARIETY_MATRICES[0, 3, 3] = VARIETY_MATRICES[0, 4, 4] = -18.0
# g2 = q0 q1 - 3√2 (q1 q3 + q2 q4)
for (i, j), c in {(0, 1): 1.0, (1, 3): -3 * SQRT2, (2, 4): -3 * SQRT2}.items():
    VARIETY_MATRICES[1, i, j] = VARIETY_MATRICES[1, j, i] = c / 2
# g3 = q0 q2 - 3√2 (q1 q4 - q2 q3)
for (i, j), c in {(0, 2): 1.0, (1, 4): -3 * SQRT2, (2, 3): 3 * SQRT2}.items():
    VARIETY_MATRICES[2, i, j] = VARIETY_MATRICES[2, j, i] = c / 2

_NEWTON_ITERATIONS = 5
_MAX_ROUNDS = 40  # of _NEWTON_ITERATIONS, in the slow path
# A Newton step below this leaves an angle error of order step² (f is concave there).
_STEP_TOL = 1e-9
#: Rows per block in the vectorised functions: the temporaries of a block stay in cache,
#: which makes ``project`` about 1.5x faster on 10⁶ rows (benchmarks/projection.py).
_CHUNK_ROWS = 65536


# --- input checking -------------------------------------------------------------


def _real(x, name: str) -> np.ndarray:
    """``x`` as float64; complex input is refused (its imaginary part would be dropped)."""
    x = np.asarray(x)
    if np.iscomplexobj(x):
        raise ValueError(f"{name} must be real, got complex values")
    return np.asarray(x, dtype=np.float64)


def _check_q(q, name="q") -> np.ndarray:
    q = _real(q, name)
    if q.ndim != 2 or q.shape[1] != 5:
        raise ValueError(f"{name} must have shape (N, 5), got {q.shape}")
    if not np.all(np.isfinite(q)):
        bad = int(np.count_nonzero(~np.all(np.isfinite(q), axis=1)))
        raise ValueError(f"{name} has {bad} row(s) with NaN or Inf")
    return q


def _check_nonzero(q: np.ndarray) -> None:
    zero = ~np.any(q != 0.0, axis=1)
    if np.any(zero):
        raise ValueError(
            f"q has {int(zero.sum())} zero tensor(s): a zero tensor has no frame to project to"
        )


def _by_chunks(func, *arrays):
    """``func`` applied to blocks of ``_CHUNK_ROWS`` rows of ``arrays``, results concatenated.

    ``func`` is row-wise and returns an array or a tuple of arrays (first axis = rows).
    """
    n = arrays[0].shape[0]
    if n <= _CHUNK_ROWS:
        return func(*arrays)
    parts = [func(*(a[i : i + _CHUNK_ROWS] for a in arrays)) for i in range(0, n, _CHUNK_ROWS)]
    if isinstance(parts[0], tuple):
        return tuple(np.concatenate(p) for p in zip(*parts, strict=True))
    return np.concatenate(parts)


# --- frames <-> coefficients ----------------------------------------------------


def _q_from_parameters(s, d, cos2t, sin2t, cos4t, sin4t) -> np.ndarray:
    """q = s e_s(t) + d e_d(t) for arrays of shape (N,)."""
    return np.stack(
        [3 * SQRT2 / 8 * s, d / 2 * cos2t, d / 2 * sin2t, s / 8 * cos4t, s / 8 * sin4t], axis=1
    )


def frames_to_q(lengths, angles) -> np.ndarray:
    """Odeco coefficients of frames (note eqs. 1–2).

    ``lengths`` (N, 2) holds (l1, l2): l1 along (cos t, sin t), l2 along (−sin t, cos t);
    ``angles`` (N,) holds t. Returns q of shape (N, 5).
    """
    lengths = _real(lengths, "lengths")
    angles = _real(angles, "angles")
    if lengths.ndim != 2 or lengths.shape[1] != 2:
        raise ValueError(f"lengths must have shape (N, 2), got {lengths.shape}")
    if angles.shape != (lengths.shape[0],):
        raise ValueError(f"angles must have shape ({lengths.shape[0]},), got {angles.shape}")
    if not (np.all(np.isfinite(lengths)) and np.all(np.isfinite(angles))):
        raise ValueError("lengths and angles must be finite")
    with np.errstate(over="ignore", invalid="ignore"):
        s = lengths[:, 0] + lengths[:, 1]
        d = lengths[:, 0] - lengths[:, 1]
        q = _q_from_parameters(
            s, d, np.cos(2 * angles), np.sin(2 * angles), np.cos(4 * angles), np.sin(4 * angles)
        )
    if not np.all(np.isfinite(q)):
        raise ValueError("lengths too large: the coefficients overflow (scale the frames down)")
    return q


def q_to_frames(q) -> tuple[np.ndarray, np.ndarray]:
    """Lengths (N, 2) and angles (N,) in (−π/4, π/4] of the frames nearest to q.

    Exact (up to rounding) when q lies on the Odeco variety. The frame symmetries
    (t → t + π/2 with l1 ↔ l2, and t → t + π) are resolved by returning t in
    (−π/4, π/4]; l1 is the length along (cos t, sin t).
    """
    q = _check_q(q)
    _check_nonzero(q)
    s, d, c4, s4 = _by_chunks(lambda block: _closest_parameters(block, isotropic=False), q)
    lengths = np.stack([(s + d) / 2, (s - d) / 2], axis=1)
    return lengths, np.arctan2(s4, c4) / 4


def branch_vectors(q) -> tuple[np.ndarray, np.ndarray]:
    """Scaled branches u = l1 û and v = l2 v̂ (each (N, 2)) of the frames nearest to q."""
    lengths, t = q_to_frames(q)
    uhat = np.stack([np.cos(t), np.sin(t)], axis=1)
    vhat = np.stack([-np.sin(t), np.cos(t)], axis=1)
    return lengths[:, :1] * uhat, lengths[:, 1:] * vhat


# --- the variety ----------------------------------------------------------------


def variety_residual(q) -> np.ndarray:
    """The three variety equations g_m(q) = q^T A_m q (note eq. 3), shape (N, 3)."""
    q = _check_q(q)
    with np.errstate(over="ignore", invalid="ignore"):
        residual = np.einsum("ni,mij,nj->nm", q, VARIETY_MATRICES, q)
    if not np.all(np.isfinite(residual)):
        raise ValueError("q too large: its variety residual overflows (scale q down)")
    return residual


def tangent_project(q, dq) -> np.ndarray:
    """Project steps ``dq`` onto the tangent spaces of the variety at ``q`` (note §3, step 2).

    The normal space at q is spanned by the gradients A_m q of the three equations,
    which have rank 2 only (the variety is 3-dimensional in R⁵, note-checks §1), so the
    normals are orthonormalised by a singular value decomposition (singular values
    below a relative 1e-5 are discarded) before they are removed.
    """
    q = _check_q(q)
    dq = _check_q(dq, "dq")
    if dq.shape != q.shape:
        raise ValueError(f"dq must have the shape of q {q.shape}, got {dq.shape}")
    return _by_chunks(_tangent_project_rows, q, dq)


def _tangent_project_rows(q, dq):
    # The normals are homogeneous in q: scale rows to max |q_j| = 1 (no under/overflow).
    scale = np.max(np.abs(q), axis=1, keepdims=True)
    q = q / np.where(scale > 0, scale, 1.0)
    normals = np.einsum("mij,nj->nim", VARIETY_MATRICES, q)  # (N, 5, 3)
    # Orthonormalise by SVD of the normals themselves (error ~ ε κ, where the Gram
    # matrix would square the condition number κ); rank is 2 on the variety.
    u, sigma, _ = np.linalg.svd(normals, full_matrices=False)
    keep = sigma > 1e-5 * sigma[:, :1]
    basis = u * keep[:, None, :]
    return dq - np.einsum("nik,nk->ni", basis, np.einsum("nik,ni->nk", basis, dq))


def tangent_basis(
    q, max_aspect: float | None = None, gradient=None, on_variety: bool = False, held=None,
    only_held: bool = False,
) -> np.ndarray:
    """Orthonormal basis (N, 5, 3) of the tangent space of the variety at the frames nearest q.

    Columns: e_s (total length), e_d (length difference) and ∂q/∂t (rotation), which
    are mutually orthogonal for every frame. Used to reduce second-order methods
    to the 3 tangent degrees of freedom per vertex.

    With ``max_aspect`` A, frames at the aspect bound l_max/l_min = A (see
    :func:`clamp_aspect`) whose ``gradient`` (N, 5; default: none given) pushes the
    aspect further out lose their e_d column, and e_s becomes the direction along the
    bound (an active set: a gradient pointing inwards releases the frame).
    ``held`` (N,) bool: frames on the bound that stay active whatever the gradient (see
    :func:`ufl_frames.frames2d.aspect.active_bound`); with ``only_held`` they are the
    active set (on the bound), whatever the gradient. ``on_variety`` promises that q lies
    on the variety: the frame is then read off q directly (about 3x faster) instead of by
    the closest-point search.

    Args:
        q: coefficients (N, 5), none zero.
        max_aspect: the aspect bound A (None: no bound, every frame keeps e_d).
        gradient: (N, 5), decides which frames on the bound are active (None: zero, no
            frame is pushed outwards).
        on_variety: q lies on the variety (read off directly).
        held: (N,) bool, frames kept active while on the bound (None: none).
        only_held: the ``held`` frames on the bound are the active set; ``gradient``
            decides nothing.

    Returns:
        The basis (N, 5, 3); a column absent is zero.

    Raises:
        ValueError: ``q`` or ``gradient`` is not (N, 5) and finite, or a row of ``q`` is
            zero.
    """
    q = _check_q(q)
    _check_nonzero(q)
    if gradient is None:
        gradient = np.zeros_like(q)
    gradient = _check_q(gradient, "gradient")
    held = np.zeros(q.shape[0], bool) if held is None else np.asarray(held, dtype=bool)
    return _by_chunks(
        lambda a, g, k: _tangent_basis_rows(a, max_aspect, g, on_variety, k, only_held),
        q, gradient, held,
    )


def _parameters_on_variety(q):
    """(s, d, cos 4t, sin 4t) of a q on the variety: s from q0, 4t from arg C, d from B."""
    s = q[:, 0] * (8 / (3 * SQRT2))
    c4, s4 = _unit(q[:, 3], q[:, 4])
    flip = s < 0  # C = (s/8) e^{4it}: arg C is 4t + π for s < 0
    c4, s4 = np.where(flip, -c4, c4), np.where(flip, -s4, s4)
    c2, s2 = _half_angle(c4, s4)
    return s, 2 * (q[:, 1] * c2 + q[:, 2] * s2), c4, s4


def _length_directions(c4, s4):
    """e_s(t), e_d(t) (N, 5), the directions of s = l1 + l2 and d = l1 − l2 at the frames'
    angle t (from cos 4t, sin 4t), unnormalised, and cos 2t, sin 2t."""
    c2, s2 = _half_angle(c4, s4)
    zero = np.zeros_like(c4)
    e_s = np.stack([np.full_like(c4, 3 * SQRT2 / 8), zero, zero, c4 / 8, s4 / 8], axis=1)
    e_d = np.stack([zero, c2 / 2, s2 / 2, zero, zero], axis=1)
    return e_s, e_d, c2, s2


def _tangent_basis_rows(q, max_aspect, gradient, on_variety=False, held=None,
                        only_held=False):
    if on_variety:
        s, d, c4, s4 = _parameters_on_variety(q)
    else:
        s, d, c4, s4 = _closest_parameters(q, isotropic=False)
    e_s, e_d, c2, s2 = _length_directions(c4, s4)
    zero = np.zeros_like(s)
    dq_dt = np.stack([zero, -d * s2, d * c2, -s * s4 / 2, s * c4 / 2], axis=1)
    if max_aspect is not None:
        active, sign, kappa = active_bound(s, d, gradient, e_s, e_d, max_aspect, held,
                                           only_held)
        active = active[:, None]
        e_s = np.where(active, e_s + (sign * kappa)[:, None] * e_d, e_s)
        e_d = np.where(active, 0.0, e_d)
    basis = np.stack([e_s, e_d, dq_dt], axis=2)
    norm = np.linalg.norm(basis, axis=1, keepdims=True)
    return basis / np.where(norm > 0, norm, 1.0)


def pushed_off_bound(q, direction, max_aspect: float) -> np.ndarray:
    """Frames on the aspect bound that a step along ``direction`` (N, 5) pushes outwards,
    to first order (N,) bool; ``q`` on the variety.

    The test of :func:`ufl_frames.frames2d.aspect.active_bound` with the step in place of
    the descent direction −g: the retraction would clamp these frames back onto the
    bound, bending the step (see ``GaussNewtonModel._consistent_active_set``).

    Args:
        q: coefficients (N, 5) on the variety.
        direction: the step (N, 5).
        max_aspect: the aspect bound A (finite, ≥ 1).

    Returns:
        (N,) bool, the frames on the bound that the step pushes outwards.
    """
    q = _check_q(q)
    direction = _check_q(direction, "direction")
    s, d, c4, s4 = _parameters_on_variety(q)
    e_s, e_d, _, _ = _length_directions(c4, s4)
    return active_bound(s, d, -direction, e_s, e_d, max_aspect)[0]


def tangent_curvature(
    q, gradient, max_aspect: float | None = None, isotropic: bool = False, active_gradient=None,
    active=None,
) -> np.ndarray:
    """Second-order term of the chart: Σ_k g_k ∂²q_k in the basis of :func:`tangent_basis`.

    With q = s e_s(t) + d e_d(t) on the variety (q on it: read off directly) and a
    gradient g of the energy in q, the Hessian of the energy in the chart (s, d, t) is
    Jᵀ ∇²E J + W, W_ab = g · ∂²q/∂p_a∂p_b: here W (N, 3, 3), rescaled to the orthonormal
    columns of ``tangent_basis(q, max_aspect, gradient, on_variety=True)``. Only the
    rotation couples: ∂²q/∂s∂t = e_s', ∂²q/∂d∂t = e_d', ∂²q/∂t² = s e_s'' + d e_d''.
    With the normal part of g this is the second fundamental form of the variety. The
    aspect-bound active set is decided by ``active_gradient`` (default ``gradient``), as
    in :func:`tangent_basis`, or given as ``active`` (N,) bool (frames on the bound only
    count), which is how a basis with a held set is matched.

    Args:
        q: coefficients (N, 5) on the variety.
        gradient: g, the energy's gradient in q (N, 5).
        max_aspect: the aspect bound A (None: no bound).
        isotropic: frames with l1 = l2 (no e_d column: its rows and columns are zero).
        active_gradient: (N, 5), decides the active set on the bound (None: ``gradient``).
        active: (N,) bool, the active set given (frames on the bound only count);
            None: decided by ``active_gradient``.

    Returns:
        W (N, 3, 3), symmetric, in the orthonormal columns of :func:`tangent_basis`.
    """
    q = _check_q(q)
    gradient = _check_q(gradient, "gradient")
    active_gradient = gradient if active_gradient is None else active_gradient
    s, d, c4, s4 = _parameters_on_variety(q)
    e_s, e_d, c2, s2 = _length_directions(c4, s4)
    zero = np.zeros_like(s)
    e_s1 = np.stack([zero, zero, zero, -s4 / 2, c4 / 2], axis=1)
    e_d1 = np.stack([zero, -s2, c2, zero, zero], axis=1)
    e_s2 = np.stack([zero, zero, zero, -2 * c4, -2 * s4], axis=1)
    e_d2 = np.stack([zero, -2 * c2, -2 * s2, zero, zero], axis=1)
    mixed_s, keep_d = e_s1, ~np.full(s.shape, isotropic)
    col0 = e_s
    if max_aspect is not None and not isotropic:
        active, sign, kappa = active_bound(s, d, active_gradient, e_s, e_d, max_aspect,
                                           held=active, only_held=active is not None)
        col0 = np.where(active[:, None], e_s + (sign * kappa)[:, None] * e_d, e_s)
        mixed_s = np.where(active[:, None], e_s1 + (sign * kappa)[:, None] * e_d1, e_s1)
        keep_d &= ~active
    dq_dt = s[:, None] * e_s1 + d[:, None] * e_d1
    n0, n2 = np.linalg.norm(col0, axis=1), np.linalg.norm(dq_dt, axis=1)
    n2 = np.where(n2 > 0, n2, 1.0)
    dot = lambda a, b: np.einsum("ni,ni->n", a, b)  # noqa: E731
    curvature = np.zeros((q.shape[0], 3, 3))
    curvature[:, 0, 2] = curvature[:, 2, 0] = dot(gradient, mixed_s) / (n0 * n2)
    cross = np.where(keep_d, dot(gradient, e_d1) / (0.5 * n2), 0.0)
    curvature[:, 1, 2] = curvature[:, 2, 1] = cross
    curvature[:, 2, 2] = dot(gradient, s[:, None] * e_s2 + d[:, None] * e_d2) / n2**2
    return curvature


# --- projections ----------------------------------------------------------------


def _half_angle(c, s):
    """cos and sin of θ/2 ∈ (−π/2, π/2] from cos θ, sin θ, without cancellation."""
    right = c >= 0
    big = np.sqrt(np.clip((1 + np.abs(c)) / 2, 0.0, None))  # the larger of |cos|, |sin| of θ/2
    small = s / (2 * big)
    ch = np.where(right, big, np.abs(small))
    sh = np.where(right, small, np.where(s < 0, -big, big))
    return ch, sh


def _unit(x, y):
    """(x, y) normalised; (1, 0) where both vanish."""
    r = np.hypot(x, y)
    ok = r > 0
    safe = np.where(ok, r, 1.0)
    return np.where(ok, x / safe, 1.0), np.where(ok, y / safe, 0.0)


def _harmonics(coeffs, c, s):
    """f(θ) − const = A1 cos θ + B1 sin θ + A2 cos 2θ + B2 sin 2θ."""
    a1, b1, a2, b2 = coeffs
    return a1 * c + b1 * s + a2 * (c * c - s * s) + b2 * 2 * s * c


def _newton(coeffs, c, s, iterations, escape=False):
    """Safeguarded Newton ascent on f(θ), carried as (cos θ, sin θ); returns the last step.

    Newton steps where f is concave, elsewhere gradient steps f'/L (L ≥ |f''|: they
    ascend). Near a minimum those crawl; with ``escape`` the reflected Newton step
    f'/|f''| (at most 1) is taken instead when it ascends more: it doubles the distance
    to the minimum per iteration.
    """
    a1, b1, a2, b2 = coeffs
    lipschitz = np.abs(a1) + np.abs(b1) + 4 * (np.abs(a2) + np.abs(b2)) + 1e-300
    step = np.zeros_like(c)
    for _ in range(iterations):
        c2, s2 = c * c - s * s, 2 * s * c
        df = b1 * c - a1 * s + 2 * (b2 * c2 - a2 * s2)
        d2f = -(a1 * c + b1 * s) - 4 * (a2 * c2 + b2 * s2)
        concave = d2f < -1e-3 * lipschitz
        step = df / np.where(concave, -d2f, lipschitz)
        if escape:
            reflected = np.clip(df / np.maximum(np.abs(d2f), 1e-3 * lipschitz), -1.0, 1.0)
            gain = [_harmonics(coeffs, *_rotate(c, s, h)) for h in (step, reflected)]
            step = np.where(~concave & (gain[1] > gain[0]), reflected, step)
        c, s = _rotate(c, s, step)
    return c, s, step


def _rotate(c, s, step):
    """(cos, sin) of θ + atan(step): no trigonometric calls."""
    scale = 1.0 / np.sqrt(1.0 + step * step)
    return (c - step * s) * scale, (s + step * c) * scale


def _ascend(coeffs, c, s):
    """Newton ascent from each start (c, s) until its step is below ``_STEP_TOL``.

    Rounds of ``_NEWTON_ITERATIONS`` iterations on the starts that have not converged
    yet; starts in convex regions crawl (gradient steps) and may need several rounds.
    """
    c, s = c.copy(), s.copy()
    active = np.arange(c.size)
    for _ in range(_MAX_ROUNDS):
        sub = tuple(x[active] for x in coeffs)
        c_a, s_a, step = _newton(sub, c[active], s[active], _NEWTON_ITERATIONS, escape=True)
        c[active], s[active] = c_a, s_a
        active = active[np.abs(step) > _STEP_TOL]
        if active.size == 0:
            break
    return c, s


def _best_lengths(q, c4, s4, isotropic):
    """Least-squares (s, d) for the angle θ = 4t given by (cos θ, sin θ)."""
    c2, s2 = _half_angle(c4, s4)
    s = (3 * SQRT2 / 8 * q[:, 0] + (q[:, 3] * c4 + q[:, 4] * s4) / 8) / _ES_NORM2
    if isotropic:
        return s, np.zeros_like(s), c2, s2
    d = (q[:, 1] * c2 + q[:, 2] * s2) / 2 / _ED_NORM2
    return s, d, c2, s2


def _closest_parameters(q, isotropic):
    r"""(s, d, cos 4t, sin 4t) of the Odeco tensor closest to q.

    Maximises f(θ) = (α + q3 cos θ + q4 sin θ)²/19 + (q1 cos θ/2 + q2 sin θ/2)², α = 3√2 q0,
    which is |q|² minus the squared distance to the best frame at angle t = θ/4.
    Expanded: f = const + A1 cos θ + B1 sin θ + A2 cos 2θ + B2 sin 2θ.
    """
    # The maximiser is invariant under scaling q: rows scaled to max |q_j| = 1 keep the
    # quadratic coefficients A1 ... B2 clear of underflow and overflow (|q| ~ 1e±160).
    scale = np.max(np.abs(q), axis=1)
    q0, q1, q2, q3, q4 = q.T / np.where(scale > 0, scale, 1.0)
    alpha = 3 * SQRT2 * q0
    if isotropic:
        # Only the first term: θ = arg C, or arg C + π when that makes α + |C| cos larger.
        c, s = _unit(q3, q4)
        flip = alpha < 0
        c, s = np.where(flip, -c, c), np.where(flip, -s, s)
        s_len, d_len, _, _ = _best_lengths(q, c, s, isotropic=True)
        return s_len, d_len, c, s

    a1 = 2 * alpha * q3 / 19 + (q1**2 - q2**2) / 2
    b1 = 2 * alpha * q4 / 19 + q1 * q2
    a2 = (q3**2 - q4**2) / 38
    b2 = q3 * q4 / 19
    coeffs = (a1, b1, a2, b2)

    # Fast path: Newton from the maximiser of the first harmonic. When its amplitude
    # R1 exceeds 5 R2 (R2 that of the second harmonic) f has a single local maximum,
    # in the arc |sin(θ − arg)| < 2 R2/R1 where f'' < 0: Newton converges to it.
    c, s = _unit(a1, b1)
    c, s, step = _newton(coeffs, c, s, _NEWTON_ITERATIONS)
    unsure = (a1 * a1 + b1 * b1 <= 25 * (a2 * a2 + b2 * b2)) | (np.abs(step) > _STEP_TOL)
    if np.any(unsure):
        # Slow path: up to two local maxima. Start also from both maximisers of the
        # second harmonic, iterate each start until it converges, keep the best.
        sub = tuple(x[unsure] for x in coeffs)
        c2, s2 = _half_angle(*_unit(sub[2], sub[3]))
        starts_c = np.concatenate([c[unsure], c2, -c2])
        starts_s = np.concatenate([s[unsure], s2, -s2])
        cs, ss = _ascend(tuple(np.tile(x, 3) for x in sub), starts_c, starts_s)
        cs, ss = cs.reshape(3, -1), ss.reshape(3, -1)
        best = np.argmax(_harmonics(sub, cs, ss), axis=0)
        cols = np.arange(best.size)
        c[unsure], s[unsure] = cs[best, cols], ss[best, cols]
    s_len, d_len, _, _ = _best_lengths(q, c, s, isotropic=False)
    return s_len, d_len, c, s


def _project_mandel(q, isotropic):
    """The note's geometric projection (§2.1, eqs. 4–5) through Mandel eigentensors."""
    tensors = tensor_components(q)
    t1111, t1112, t1122, t1222, t2222 = tensors.T
    r2 = SQRT2
    mandel = np.stack(
        [
            np.stack([t1111, t1122, r2 * t1112], axis=-1),
            np.stack([t1122, t2222, r2 * t1222], axis=-1),
            np.stack([r2 * t1112, r2 * t1222, 2 * t1122], axis=-1),
        ],
        axis=1,
    )
    w, v = np.linalg.eigh(mandel)  # ascending: keep the two largest
    dmat = np.zeros((q.shape[0], 2, 2))
    for k in (1, 2):
        # Eigenvectors have arbitrary signs; D_k = û⊗û has trace +1, so orient each
        # eigentensor to a non-negative trace (otherwise lengths come out negated).
        vk = v[:, :, k] * np.where(v[:, 0, k] + v[:, 1, k] < 0, -1.0, 1.0)[:, None]
        dk = np.stack(
            [np.stack([vk[:, 0], vk[:, 2] / r2], -1), np.stack([vk[:, 2] / r2, vk[:, 1]], -1)],
            axis=1,
        )
        dmat += w[:, k, None, None] * dk
    lam, vec = np.linalg.eigh(dmat)
    angles = np.arctan2(vec[:, 1, 0], vec[:, 0, 0])  # direction of lam[:, 0]
    if isotropic:
        lam = np.repeat(lam.mean(axis=1, keepdims=True), 2, axis=1)
    return frames_to_q(lam, angles)


def tensor_components(q) -> np.ndarray:
    """Independent components (T1111, T1112, T1122, T1222, T2222) of the tensor of q."""
    q = _check_q(q)
    # Each harmonic as a quartic form in the monomials x⁴, x³y, x²y², xy³, y⁴.
    forms = np.array(
        [
            [1 / SQRT2, 0, 2 / SQRT2, 0, 1 / SQRT2],  # (x² + y²)² / √2
            [1, 0, 0, 0, -1],  # cos 2φ = x⁴ − y⁴ on the circle
            [0, 2, 0, 2, 0],  # sin 2φ
            [1, 0, -6, 0, 1],  # cos 4φ
            [0, 4, 0, -4, 0],  # sin 4φ
        ]
    )
    monomial = q @ forms
    return monomial / np.array([1.0, 4.0, 6.0, 4.0, 1.0])


def project(
    q, isotropic: bool = False, method: str = "closest", max_aspect: float | None = None
) -> np.ndarray:
    """Nearest Odeco tensors (note §2.1, §3 step 4); with ``isotropic`` the nearest with l1 = l2.

    ``method="closest"`` (default) is the exact Euclidean closest point in q (see
    module docstring); ``method="mandel"`` is the note's eigentensor projection,
    kept for comparison only. ``max_aspect`` bounds l_max/l_min: the lengths at the
    closest angle are then fitted under the bound (:func:`clamp_aspect`).

    Args:
        q: coefficients (N, 5), none zero.
        isotropic: the nearest frames with l1 = l2.
        method: ``"closest"`` or ``"mandel"``.
        max_aspect: the aspect bound A (None: no bound; ignored by ``"mandel"`` and for
            isotropic frames).

    Returns:
        The projected coefficients (N, 5).

    Raises:
        ValueError: ``q`` is not (N, 5) and finite, a row is zero, or ``method`` is
            unknown.
    """
    q = _check_q(q)
    _check_nonzero(q)
    if method == "mandel":
        return _by_chunks(lambda block: _project_mandel(block, isotropic), q)
    if method != "closest":
        raise ValueError(f"unknown projection method {method!r}: use 'closest' or 'mandel'")
    return _by_chunks(lambda block: _project_closest(block, isotropic, max_aspect), q)


def _project_closest(q, isotropic, max_aspect=None):
    s, d, c4, s4 = _closest_parameters(q, isotropic)
    if max_aspect is not None and not isotropic:
        s, d = clamp_aspect(s, d, max_aspect)
    c2, s2 = _half_angle(c4, s4)
    return _q_from_parameters(s, d, c2, s2, c4, s4)


def project_aligned(
    q, normals, isotropic: bool = False, max_aspect: float | None = None
) -> np.ndarray:
    """Boundary projection (note §3): orientation fixed by ``normals`` (N, 2), lengths free.

    One branch is aligned with the normal (the other with the tangent); the lengths
    are the least-squares fit of q at that orientation.

    Args:
        q: coefficients (N, 5).
        normals: the direction of one branch at each frame (N, 2), finite and non-zero
            (need not be unit).
        isotropic: the lengths fitted with l1 = l2.
        max_aspect: the aspect bound A on the fitted lengths (None: no bound).

    Returns:
        The projected coefficients (N, 5).

    Raises:
        ValueError: ``q`` is not (N, 5) and finite, or ``normals`` is not (N, 2), finite
            and non-zero.
    """
    q = _check_q(q)
    normals = np.asarray(normals, dtype=np.float64)
    if normals.shape != (q.shape[0], 2):
        raise ValueError(f"normals must have shape ({q.shape[0]}, 2), got {normals.shape}")
    norm = np.linalg.norm(normals, axis=1)
    if not np.all(np.isfinite(norm)) or np.any(norm == 0):
        raise ValueError("normals must be finite and non-zero")
    c1, s1 = normals[:, 0] / norm, normals[:, 1] / norm
    c2, s2 = c1 * c1 - s1 * s1, 2 * s1 * c1
    c4, s4 = c2 * c2 - s2 * s2, 2 * s2 * c2
    s, d, c2, s2 = _best_lengths(q, c4, s4, isotropic)
    if max_aspect is not None and not isotropic:
        s, d = clamp_aspect(s, d, max_aspect)
    return _q_from_parameters(s, d, c2, s2, c4, s4)
