r"""The aspect bound of non-isotropic frames: l_max / l_min ≤ A, in the lengths (s, d).

A frame of angle t is q = s e_s(t) + d e_d(t), s = l1 + l2, d = l1 − l2 (see
:mod:`ufl_frames.frames2d.odeco`), so l_max/l_min ≤ A is the cone |d| ≤ κ s with
κ = (A − 1)/(A + 1). Without a bound the non-isotropic energy has degenerate
minimisers: one branch collapses (l → 0, or turns negative) and the bracket vanishes
trivially (note-checks §5), so the library, like the CLI, bounds it by
:data:`DEFAULT_MAX_ASPECT` unless told otherwise. Isotropic frames (d = 0) have no bound.

This is the one place of the rule: the projection clamps (s, d) onto the cone
(:func:`clamp_aspect`), and the tangent basis and curvature drop the e_d direction of
frames on the cone's surface that the energy pushes outwards (:func:`active_bound`).
Pure NumPy.
"""

import math

import numpy as np

__all__ = ["DEFAULT_MAX_ASPECT", "ES_NORM2", "ED_NORM2", "active_bound", "aspect_bound",
           "clamp_aspect", "kappa"]

#: The bound l_max/l_min ≤ A of non-isotropic frames used unless one is given.
DEFAULT_MAX_ASPECT = 4.0

#: |e_s(t)|² and |e_d(t)|², independent of t: the metric of the plane (s, d) of frames.
ES_NORM2 = 19.0 / 64.0
ED_NORM2 = 1.0 / 4.0

#: Frames with |d| ≥ (1 − this) κ s count as on the bound.
_ON_BOUND_RTOL = 1e-9


def aspect_bound(isotropic: bool, max_aspect: float | None) -> float | None:
    """The bound A the projection and solver get: None for isotropic frames (l1 = l2
    already) and for an infinite or missing A; otherwise A (checked: finite, ≥ 1)."""
    if isotropic or max_aspect is None or math.isinf(max_aspect):
        return None
    kappa(max_aspect)
    return float(max_aspect)


def kappa(max_aspect: float) -> float:
    """κ = (A − 1)/(A + 1), the slope of the cone |d| ≤ κ s; A must be finite and ≥ 1."""
    if not (np.isfinite(max_aspect) and max_aspect >= 1):
        raise ValueError(f"max_aspect must be a finite number >= 1, got {max_aspect}")
    return (max_aspect - 1) / (max_aspect + 1)


def clamp_aspect(s, d, max_aspect: float):
    """Least-squares (s, d) with l_max/l_min ≤ ``max_aspect``, i.e. |d| ≤ κ s.

    For a fixed angle the frames are s e_s + d e_d with |e_s|² = 19/64, |e_d|² = 1/4,
    so the constrained fit projects (s, d) onto the ray d = ±κ s in that metric.
    Frames inside the bound are returned unchanged.

    Args:
        s: total lengths l1 + l2, (N,) or a scalar.
        d: length differences l1 − l2, as ``s``.
        max_aspect: the bound A (finite, ≥ 1).

    Returns:
        (s, d), arrays shaped as the inputs, with |d| ≤ κ s.

    Raises:
        ValueError: ``max_aspect`` is not finite or below 1.
    """
    k = kappa(max_aspect)
    s = np.asarray(s, dtype=np.float64)
    d = np.asarray(d, dtype=np.float64)
    sign = np.where(d < 0, -1.0, 1.0)
    outside = np.abs(d) > k * s
    s_ray = (ES_NORM2 * s + ED_NORM2 * k * sign * d) / (ES_NORM2 + ED_NORM2 * k**2)
    # A fit with s ≤ 0 (an inverted frame, only at wild trial points) stays a tiny frame.
    s_ray = np.maximum(s_ray, 1e-8 * (np.abs(s) + np.abs(d)))
    return np.where(outside, s_ray, s), np.where(outside, sign * k * s_ray, d)


def active_bound(s, d, gradient, e_s, e_d, max_aspect: float, held=None,
                 only_held: bool = False):
    """Frames held on the bound: on it (|d| = κ s) and pushed outwards by ``gradient``.

    Along the steepest descent −g, Δs = −g·e_s/|e_s|² and Δd = −g·e_d/|e_d|² (e_s, e_d
    unnormalised, (N, 5)); the bound sign·d − κ s ≤ 0 is violated to first order when
    sign·Δd − κ Δs ≥ 0. A gradient pointing inwards releases the frame (an active set).
    ``held`` (N,) marks frames kept on the bound whatever the gradient says, while they
    are on it (the solver's anti-zigzag rule); with ``only_held`` they are the active set
    itself (where on the bound) and the gradient decides nothing (the rule that decides
    the set with the Newton step, ``GaussNewtonModel._consistent_active_set``).

    Args:
        s: total lengths l1 + l2 (N,).
        d: length differences l1 − l2 (N,).
        gradient: g (N, 5), the gradient whose descent −g decides.
        e_s: the unnormalised direction of s at each frame (N, 5).
        e_d: the unnormalised direction of d at each frame (N, 5).
        max_aspect: the bound A (finite, ≥ 1).
        held: (N,) bool, frames kept on the bound while on it (None: none).
        only_held: the ``held`` frames on the bound are the active set.

    Returns:
        ``(active, sign, κ)``: the mask (N,), the sign of d (N,) and the slope, with which
        the direction along the bound is e_s + sign κ e_d.

    Raises:
        ValueError: ``only_held`` without ``held``, or ``max_aspect`` not finite or
            below 1.
    """
    k = kappa(max_aspect)
    sign = np.where(d < 0, -1.0, 1.0)
    on_bound = np.abs(d) >= k * s * (1 - _ON_BOUND_RTOL)
    if only_held:
        if held is None:
            raise ValueError("only_held needs the held mask")
        return on_bound & np.asarray(held, dtype=bool), sign, k
    ds = -np.einsum("ni,ni->n", gradient, e_s) / ES_NORM2
    dd = -np.einsum("ni,ni->n", gradient, e_d) / ED_NORM2
    outward = sign * dd - k * ds >= 0
    if held is not None:
        outward = outward | held
    return on_bound & outward, sign, k
