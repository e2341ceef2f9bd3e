r"""The Lie bracket of a 2D frame field in terms of its Odeco coefficients (note §2.2).

    [u, v]_i = C_ijkl q_l ∂q_j/∂x_k                                   (note eq. 10)

for the scaled branches u = l1 û, v = l2 v̂ with v̂ = û rotated by +90°. The tensor
C is derived symbolically by ``scripts/derive_bracket.py`` and stored, entry by
entry, in :mod:`ufl_frames.frames2d._bracket_table`.

Which C. The defining equations leave a 12-dimensional family (the derivatives of
the three variety equations, q^T A_m ∂_k q, for 2 components × 2 directions). We
use the minimum-Frobenius-norm member: the one solution orthogonal to that family,
defined without any further choice. All members agree on the variety and converge
at the same O(h²) rate; off the variety (inside P1 elements) they differ. Measured
on the integrable annulus fields at h = 0.05 (tests/test_energy.py): adding a random
null-space element of half the norm of C raised the residual discrete H in 7 of 8
trials, but a null-space element fitted to those fields lowered it by 1.6–7x — the
minimum-norm C is canonical, not optimal; choosing C for accuracy is open.

Pure NumPy; the UFL form of the same formula is :func:`ufl_frames.fem.energy.lie_bracket`.
"""

import numpy as np

from ufl_frames.frames2d._bracket_table import BRACKET_ENTRIES, NULLITY
from ufl_frames.frames2d.odeco import NUM_COEFFICIENTS

#: The dimension: [u, v] and the derivatives ∂_k have this many components.
_DIM = 2

__all__ = ["BRACKET_ENTRIES", "BRACKET_TENSOR", "NULLITY", "lie_bracket", "lie_bracket_direct"]


def _dense(entries) -> np.ndarray:
    tensor = np.zeros((_DIM, NUM_COEFFICIENTS, _DIM, NUM_COEFFICIENTS))
    for index, value in entries.items():
        tensor[index] = value
    return tensor


#: C_ijkl as a dense (2, 5, 2, 5) array.
BRACKET_TENSOR = _dense(BRACKET_ENTRIES)


def lie_bracket(q, grad_q) -> np.ndarray:
    """[u, v] (N, 2) from q (N, 5) and its gradient ∂q_j/∂x_k (N, 5, 2) (note eq. 10)."""
    q = np.asarray(q, dtype=np.float64)
    grad_q = np.asarray(grad_q, dtype=np.float64)
    n = NUM_COEFFICIENTS
    if q.ndim != 2 or q.shape[1] != n or grad_q.shape != (q.shape[0], n, _DIM):
        raise ValueError(f"need q (N, 5) and grad_q (N, 5, 2), got {q.shape} and {grad_q.shape}")
    return np.einsum("ijkl,nl,njk->ni", BRACKET_TENSOR, q, grad_q)


def lie_bracket_direct(lengths, angles, grad_lengths, grad_angles) -> np.ndarray:
    """[u, v] (N, 2) from the explicit frame and its gradients (independent reference).

    u = l1 (cos t, sin t), v = l2 (−sin t, cos t); ``grad_lengths`` (N, 2, 2) holds
    ∇l1, ∇l2 and ``grad_angles`` (N, 2) holds ∇t. From [u, v] = ∇_u v − ∇_v u:
    [u,v] = l1 (û·∇l2) v̂ − l1 l2 (û·∇t) û − l2 (v̂·∇l1) û − l1 l2 (v̂·∇t) v̂.

    Args:
        lengths: l1, l2 (N, 2).
        angles: t, the angle of u (N,).
        grad_lengths: ∇l1, ∇l2 (N, 2, 2), ``grad_lengths[:, i]`` the gradient of l_(i+1).
        grad_angles: ∇t (N, 2).

    Returns:
        [u, v] (N, 2).
    """
    l1, l2 = np.asarray(lengths, dtype=np.float64).T
    t = np.asarray(angles, dtype=np.float64)
    grad_l = np.asarray(grad_lengths, dtype=np.float64)
    grad_t = np.asarray(grad_angles, dtype=np.float64)
    uhat = np.stack([np.cos(t), np.sin(t)], axis=1)
    vhat = np.stack([-np.sin(t), np.cos(t)], axis=1)
    dot = lambda a, b: np.einsum("ni,ni->n", a, b)[:, None]  # noqa: E731
    return (
        l1[:, None] * dot(uhat, grad_l[:, 1]) * vhat
        - (l1 * l2)[:, None] * dot(uhat, grad_t) * uhat
        - l2[:, None] * dot(vhat, grad_l[:, 0]) * uhat
        - (l1 * l2)[:, None] * dot(vhat, grad_t) * vhat
    )
