"""How good a parametrisation is: misfit to the field, flipped triangles, distortion.

All per-triangle quantities of :class:`~ufl_frames.param.seamless.Parametrisation`, reduced
with the triangles' areas as weights. Pure NumPy.
"""

import numpy as np

from ufl_frames.param.seamless import Parametrisation

__all__ = ["quality"]


def quality(p: Parametrisation) -> dict:
    """The measures as a JSON-ready dict:

    * ``misfit``: ‖∇(U, V) − s (u/|u|², v/|v|²)‖ / ‖s (u/|u|², v/|v|²)‖ in L² (both
      components together; 0 for an integrable field and an exact map);
    * ``misfit_u``, ``misfit_v``: the same per component;
    * ``flipped_triangles``: triangles where det [∇U; ∇V] ≤ 0 (the map folds);
    * ``angle_distortion_deg`` (mean, max): |angle(∇U, ∇V) − 90°|;
    * ``area_distortion`` (mean): |log(det J / det J_target)|, area weighted;
    * ``cuts``, ``cut_length``, ``singular_vertices``: of the cut mesh.
    """
    w = p.area / p.area.sum()
    ru, rv = p.grad_u - p.target_u, p.grad_v - p.target_v

    def norm2(a):
        return float(np.dot(w, np.einsum("mk,mk->m", a, a)))

    det = p.grad_u[:, 0] * p.grad_v[:, 1] - p.grad_u[:, 1] * p.grad_v[:, 0]
    det_target = p.target_u[:, 0] * p.target_v[:, 1] - p.target_u[:, 1] * p.target_v[:, 0]
    cos = np.einsum("mk,mk->m", p.grad_u, p.grad_v) / np.maximum(
        np.linalg.norm(p.grad_u, axis=1) * np.linalg.norm(p.grad_v, axis=1), 1e-300)
    angle_error = np.degrees(np.abs(np.arccos(np.clip(cos, -1, 1)) - np.pi / 2))
    ok = det > 0
    log_area = np.abs(np.log(np.where(ok, det, 1.0) / det_target))
    return {
        "misfit": float(np.sqrt((norm2(ru) + norm2(rv)) / (norm2(p.target_u) + norm2(p.target_v)))),
        "misfit_u": float(np.sqrt(norm2(ru) / norm2(p.target_u))),
        "misfit_v": float(np.sqrt(norm2(rv) / norm2(p.target_v))),
        "flipped_triangles": int(np.count_nonzero(~ok)),
        "angle_distortion_deg": {"mean": float(np.dot(w, angle_error)),
                                 "max": float(angle_error.max(initial=0.0))},
        "area_distortion": float(np.dot(w[ok], log_area[ok]) / max(w[ok].sum(), 1e-300)),
        "cuts": int(p.mesh.paths),
        "cut_length": p.mesh.cut_length,
        "singular_vertices": int(p.mesh.singular.size),
        "scale": float(p.scale),
    }
