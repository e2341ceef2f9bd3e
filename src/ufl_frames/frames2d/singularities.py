r"""Singularities of a cross field given by Odeco coefficients at the vertices of triangles.

The cross direction is read from :math:`C = q_3 + i q_4 = (s/8) e^{4it}` (see
:mod:`ufl_frames.frames2d.odeco`): :math:`\theta_4 = \arg C = 4t`, which is continuous across
the fourfold symmetry of a cross. The index of a triangle is the winding of
:math:`\theta_4` around its boundary divided by 4:

.. math::  I = \frac{1}{8\pi} \sum_{\text{edges } ij} w(\theta_{4,j} - \theta_{4,i}),
           \qquad w(\delta) \in (-\pi, \pi],

counted counter-clockwise, so a multiple of 1/4: a +1/4 singularity is one where
the cross turns by +90° around a small loop. Each edge's wrapped step is taken once and
negated the other way (a step of exactly ±π, as between a junction's held boundary cross
and an interface's cross 45° off it, would otherwise count +π on both sides), so the sum
over all triangles equals the winding of θ₄ along the mesh boundary exactly (a discrete
index theorem): with the boundary rows held, the boundary's corners alone fix it.

:func:`triangle_indices` and :func:`find_singularities` are pure NumPy;
:func:`locate_singularities` works on a DOLFINx function and imports DOLFINx only
when called.
"""

import numpy as np

from ufl_frames.frames2d.odeco import NUM_COEFFICIENTS

__all__ = [
    "corner_cross",
    "corner_quarter_turns",
    "find_singularities",
    "index_theorem",
    "locate_singularities",
    "poincare_hopf_sum",
    "triangle_indices",
]


def _wrap(delta: np.ndarray) -> np.ndarray:
    """Angle differences wrapped into (−π, π]."""
    return np.pi - np.mod(np.pi - delta, 2 * np.pi)


def _check(cells, q, coords=None):
    cells = np.asarray(cells)
    if cells.ndim != 2 or cells.shape[1] != 3:
        raise ValueError(f"cells must have shape (M, 3), got {cells.shape}")
    if cells.size and not np.issubdtype(cells.dtype, np.integer):
        raise ValueError(f"cells must hold integer vertex indices, got dtype {cells.dtype}")
    q = np.asarray(q, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != NUM_COEFFICIENTS:
        raise ValueError(f"q must have shape (N, {NUM_COEFFICIENTS}), got {q.shape}")
    if cells.size and (cells.min() < 0 or cells.max() >= q.shape[0]):
        raise ValueError(f"cells index vertices outside 0..{q.shape[0] - 1}")
    if not np.all(np.isfinite(q[:, 3:5])):
        raise ValueError("q has NaN or Inf in its C = (q3, q4) components")
    if coords is not None:
        coords = np.asarray(coords, dtype=np.float64)
        if coords.ndim != 2 or coords.shape[0] != q.shape[0] or coords.shape[1] < 2:
            raise ValueError(f"coords must have shape ({q.shape[0]}, 2 or 3), got {coords.shape}")
    return cells.astype(np.int64, copy=False), q, coords


def triangle_indices(cells, q, coords=None) -> np.ndarray:
    """Index (a multiple of 1/4) of every triangle, shape (M,).

    ``cells`` (M, 3) holds vertex indices into ``q`` (N, 5). Triangles are taken as
    counter-clockwise; pass ``coords`` (N, 2 or 3) to orient each one by its signed
    area instead (DOLFINx cells have no fixed orientation).

    Args:
        cells: vertex indices (M, 3) into ``q``.
        q: coefficients (N, 5); the angle is read from (q3, q4).
        coords: vertex coordinates (N, 2 or 3) (None: every triangle counter-clockwise).

    Returns:
        The indices (M,), multiples of 1/4.

    Raises:
        ValueError: a shape is wrong, ``cells`` are not integers or index outside ``q``,
            or (q3, q4) is not finite.
    """
    cells, q, coords = _check(cells, q, coords)
    theta4 = np.arctan2(q[:, 4], q[:, 3])
    tail, head = cells, cells[:, [1, 2, 0]]  # edges 0→1, 1→2, 2→0
    # Each edge's step is wrapped once, from its first end to its second in an order of
    # the vertices that does not depend on the triangle, and negated for the other way:
    # a step of exactly ±π (a held cross 45° off its neighbour's, at a junction) then
    # counts +π in one triangle and −π in the other, and the sum over the triangles stays
    # the winding along the boundary.
    forward = _before(tail, head, coords)
    first, second = np.where(forward, tail, head), np.where(forward, head, tail)
    steps = _wrap(theta4[second] - theta4[first])
    steps = np.where(forward, steps, -steps)
    turns = np.rint(steps.sum(axis=1) / (2 * np.pi))  # an integer up to rounding
    if coords is not None:
        x = coords[cells, :2]
        e1, e2 = x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]
        area2 = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        turns = np.where(area2 < 0, -turns, turns)
    return turns / 4.0 + 0.0  # + 0.0 turns −0.0 into 0.0


def _before(a: np.ndarray, b: np.ndarray, coords) -> np.ndarray:
    """Whether vertex ``a`` comes before ``b``: by (x, y) where ``coords`` are given (the
    same order on every rank), ties and no coordinates by index."""
    if coords is None:
        return a < b
    xa, xb = coords[a, 0], coords[b, 0]
    ya, yb = coords[a, 1], coords[b, 1]
    return (xa < xb) | ((xa == xb) & ((ya < yb) | ((ya == yb) & (a < b))))


def find_singularities(cells, coords, q) -> list[dict]:
    """Triangles of nonzero index as ``{"index", "x", "y"}`` (barycentres), sorted by (x, y).

    Args:
        cells: vertex indices (M, 3) into ``q`` and ``coords``.
        coords: vertex coordinates (N, 2 or 3); the triangles are oriented by them.
        q: coefficients (N, 5).

    Returns:
        One dict a singular triangle: ``index`` (a multiple of 1/4) and its barycentre's
        ``x``, ``y`` (floats).

    Raises:
        ValueError: as :func:`triangle_indices`, or ``coords`` is None.
    """
    cells, q, coords = _check(cells, q, coords)
    if coords is None:
        raise ValueError("coords are required")
    index = triangle_indices(cells, q, coords)
    hit = np.flatnonzero(index != 0)
    centre = coords[cells[hit], :2].mean(axis=1)
    found = [
        {"index": float(index[k]), "x": float(c[0]), "y": float(c[1])}
        for k, c in zip(hit, centre, strict=True)
    ]
    return sorted(found, key=lambda s: (s["x"], s["y"], s["index"]))


def locate_singularities(q_function) -> list[dict]:
    """:func:`find_singularities` for a DOLFINx P1 function with value shape (5,).

    Collective: each rank scans the cells it owns, and every rank returns the same
    list of all singularities, sorted by (x, y). Updates the ghost values of
    ``q_function`` (``scatter_forward``) first.
    """
    from ufl_frames.bootstrap import init_petsc

    init_petsc()
    import dolfinx  # noqa: F401  (only to fail early and clearly without DOLFINx)

    V = q_function.function_space
    mesh = V.mesh
    tdim = mesh.topology.dim
    bs = V.dofmap.index_map_bs
    cell_dofs = V.dofmap.list
    if tdim != 2 or bs != NUM_COEFFICIENTS or cell_dofs.shape[1] != 3:
        raise ValueError(
            "locate_singularities needs a P1 function with value shape (5,) on a triangle "
            f"mesh; got tdim={tdim}, block size={bs}, {cell_dofs.shape[1]} dofs per cell"
        )
    q_function.x.scatter_forward()
    q = q_function.x.array.reshape(-1, bs)
    coords = V.tabulate_dof_coordinates()
    owned = mesh.topology.index_map(tdim).size_local
    local = find_singularities(cell_dofs[:owned], coords[: q.shape[0]], q)
    found = [s for part in mesh.comm.allgather(local) for s in part]
    return sorted(found, key=lambda s: (s["x"], s["y"], s["index"]))


def corner_quarter_turns(angles):
    """The quarter turns k of boundary corners of interior angle α (radians): round(α/(π/2)),
    but at least 1 — the corner rule of every stage (field, Poincaré–Hopf, map, quads).

    A corner under 45° would round to 0 quarter turns: the cross would turn by α along
    the boundary there and the map would flatten the corner to 0°, which no quad has.
    Taken as one quarter turn (the cross turns by α − 90°) it is a quad corner squeezed
    to α (scaled Jacobian sin α); equivalently a 0-turn corner with a −1/4 singularity
    at its tip. Integers of ``angles``' shape (an int for a scalar)."""
    k = np.maximum(1, np.rint(np.asarray(angles, dtype=np.float64) / (np.pi / 2)))
    k = k.astype(np.int64)
    return int(k) if k.ndim == 0 else k


def corner_cross(bisector: float, angle: float) -> float:
    """The cross angle ψ (mod π/2) at a corner of interior angle ``angle`` whose interior
    bisector has the direction ``bisector`` (radians): the cross half-way between the two
    curves' crosses along the turn of α − k π/2 (k = :func:`corner_quarter_turns`), so
    ψ = bisector − k π/4. Where k = round(α/(π/2)) this is the cross nearest to both
    curves' (their 4-fold average); under 45° it is that average turned by 45°."""
    return float(bisector - corner_quarter_turns(angle) * np.pi / 4)


def poincare_hopf_sum(euler_characteristic: int, corner_angles) -> float:
    """χ − Σ_c (2 − k_c)/4, k_c = :func:`corner_quarter_turns` (round(α_c / (π/2)), at
    least 1): what the interior indices of a boundary-aligned cross field sum to (module
    docstring); α_c in radians."""
    angles = np.asarray(corner_angles, dtype=np.float64).ravel()
    if not np.all(np.isfinite(angles)) or np.any(angles <= 0) or np.any(angles >= 2 * np.pi):
        raise ValueError("corner angles must lie in (0, 2π)")
    return float(euler_characteristic - np.sum(2 - corner_quarter_turns(angles)) / 4) + 0.0


#: Corners within this of an odd multiple of 45° (radians) are ambiguous: the two curves'
#: crosses differ by 45°, so the boundary cross there may turn either way.
AMBIGUOUS_CORNER_TOL = np.radians(2.0)


def index_theorem(singularities: list[dict], euler_characteristic: int, corner_angles) -> dict:
    """The index sum of ``singularities`` against :func:`poincare_hopf_sum`.

    Returns ``{"index_sum", "expected", "agrees", "euler_characteristic", "corners",
    "ambiguous_corners"}``. ``corners`` counts the corners that contribute (angle not
    180° rounded); ``ambiguous_corners`` those near an odd multiple of 45° above 90°
    (135°, 225°, 315°; 45° is one quarter turn either way), where either rounding is
    right: ``expected`` is the lower sum (their k rounded down) and each widens the
    agreement by 1/4 above it. Indices are multiples
    of 1/4, so sums are compared exactly after rounding.

    Args:
        singularities: dicts with an ``index`` (e.g. :func:`find_singularities`).
        euler_characteristic: χ of the domain.
        corner_angles: the interior angles of the boundary corners, in radians.

    Returns:
        The dict above: ``index_sum`` and ``expected`` floats, ``agrees`` a bool, the
        others ints.
    """
    angles = np.asarray(corner_angles, dtype=np.float64).ravel()
    index_sum = float(np.rint(4 * sum(float(s["index"]) for s in singularities)) / 4) + 0.0
    quarter = np.pi / 2
    ambiguous = np.abs(angles / quarter - np.floor(angles / quarter) - 0.5) * quarter
    # 45° is not: one quarter turn rounded either way (corner_quarter_turns).
    ambiguous = (ambiguous < AMBIGUOUS_CORNER_TOL) & (angles > quarter)
    # The ambiguous ones rounded down (k smaller: (2 − k)/4 larger, the lower sum).
    rounded = np.where(ambiguous, np.floor(angles / quarter), corner_quarter_turns(angles))
    low = float(euler_characteristic - np.sum(2 - rounded) / 4) + 0.0
    high = low + np.count_nonzero(ambiguous) / 4
    return {
        "index_sum": index_sum,
        "expected": low,
        "agrees": bool(low <= index_sum <= high),
        "euler_characteristic": int(euler_characteristic),
        "corners": int(np.count_nonzero(np.rint(angles / quarter) != 2)),
        "ambiguous_corners": int(np.count_nonzero(ambiguous)),
    }
