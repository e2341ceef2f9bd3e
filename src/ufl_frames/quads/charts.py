r"""Exact charts of a seamless map: its wedge values as integers, so that every decision of
the T-mesh layout (:mod:`ufl_frames.quads.layout`, its step 1) is exact.

The seamless map (U, V) of :func:`~ufl_frames.param.seamless.integrate` is affine on every
triangle, and across a cut edge the neighbour's chart is (U, V)_g = Rot^j (U, V)_f + t.
:func:`fixed_point` gives the wedge values in fixed point (``UNIT`` per unit of the map) as
x = T y with T the seamless constraints' elimination and y rounded, so that every seam's
transition and every boundary curve's constant coordinate hold exactly in integers; the
traces of :mod:`ufl_frames.quads.motorcycles` run in these charts. :class:`LayoutError` is
the error of the whole chain (charts, traces, patches, integer lengths).

Pure NumPy/SciPy.
"""

import numpy as np
import scipy.sparse as sp

from ufl_frames.param.seamless import Parametrisation, elimination

__all__ = ["UNIT", "LayoutError", "fixed_point"]

#: Fixed-point units per unit of the map.
UNIT = 2**20


class LayoutError(RuntimeError):
    """The map's traces do not give a layout of rectangles (folds, endless traces, faces
    that are not rectangles, or no integer lengths)."""


def fixed_point(param: Parametrisation, T=None, unit: int = UNIT) -> np.ndarray:
    """The wedge values as exact integers: x = T y with T the seamless constraints'
    elimination (:func:`~ufl_frames.param.seamless.elimination`; its entries are halves
    where a singular vertex is in them) and y the free values rounded to a multiple of T's
    denominator, so that every seam's transition and every boundary curve hold exactly.

    Args:
        param: the seamless map (its values less those of wedge 0).
        T: the elimination, if the caller has it (else built again).
        unit: fixed-point units per unit of the map.

    Returns:
        (W, 2) int64. Raises :class:`LayoutError` if the map is not seamless.
    """
    mesh = param.mesh
    if T is None:
        T = elimination(mesh, 0)
    Tr = T.tocsr()
    Tr.sum_duplicates()
    x0 = (param.uv - param.uv[0]).ravel()
    denominator = 1
    while not np.allclose(Tr.data * denominator, np.rint(Tr.data * denominator), atol=1e-9):
        denominator *= 2
        if denominator > 2**10:
            raise LayoutError("the seamless constraints are not integer (no exact charts)")
    y = np.zeros(Tr.shape[1])
    count = np.diff(Tr.indptr)
    rows = np.flatnonzero(count == 1)
    rows = rows[np.isclose(Tr.data[Tr.indptr[rows]], 1.0)]
    cols = Tr.indices[Tr.indptr[rows]]
    y[cols[::-1]] = x0[rows[::-1]]  # a free variable's own row (the first one wins)
    Ti = sp.csr_matrix((np.rint(Tr.data * denominator).astype(np.int64), Tr.indices,
                        Tr.indptr), shape=Tr.shape)
    yi = np.rint(y * unit / denominator).astype(np.int64)
    P = (Ti @ yi).reshape(-1, 2)
    if np.abs(P / unit - (param.uv - param.uv[0])).max(initial=0.0) > 1e-3:
        raise LayoutError("the map does not satisfy its seamless constraints")
    return P
