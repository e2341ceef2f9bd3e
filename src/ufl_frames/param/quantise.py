r"""Quantisation: from the seamless map to an integer-grid map.

A quad mesh is the pull-back of the integer grid Z² by (U, V) only if the grid is the same
seen from every side of every seam and fits the boundary. So, on top of the seamless
constraints (:mod:`~ufl_frames.param.seamless`), these quantities become integers:

* the translation t of every seam, (U, V)_g = Rot^j (U, V)_f + t;
* the constant coordinate of every boundary curve (U = i or V = j along it), and of every
  interior curve of the mesh's features (interfaces, embedded curves) alike;
* both coordinates of every model point of the features (corners, curve ends, embedded
  points, points between two curves) and of every vertex where curves meet or end
  (:func:`model_points`): quad vertices, so that no quad edge straddles two curves;
* both coordinates of every singular vertex (it becomes a grid vertex of valence 4 − turns)
  and of every boundary cusp (a boundary turning back by 180°: :func:`cusps`).

They are linear functionals F x of the wedge values, F y in the free unknowns y of the
least-squares problem. With N = (AT)ᵀ(AT) its normal matrix, fixing a set S of them to the
integers d moves the minimiser to y = y₀ − N⁻¹ F_Sᵀ (F_S N⁻¹ F_Sᵀ)⁻¹ (F_S y₀ − d) and raises
the misfit energy by (F_S y₀ − d)ᵀ (F_S N⁻¹ F_Sᵀ)⁻¹ (F_S y₀ − d). Greedy rounding (as in
mixed-integer quadrangulation) fixes one functional at a time, re-solving after each: here
the re-solve is exact and cheap, a rank-one update of the functionals' mean and covariance
G = F N⁻¹ Fᵀ (one sparse factorisation and one back-substitution per functional), and the
next one fixed is the one whose rounding costs the least energy. Functionals that the fixed
ones already determine (the same curve seen from two edges, the anchor's) are not rounded
again; they come out integer by themselves.

The translation of every connected component is removed by anchoring one of its wedges
that is integer anyway: a singular vertex, else a boundary corner (both coordinates
constant), else a boundary vertex.
Pure NumPy/SciPy.
"""

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ufl_frames.param.cut import CutMesh, triangle_components
from ufl_frames.param.seamless import (
    Parametrisation,
    SeamlessSystem,
    boundary_coordinates,
    curve_edge_ids,
    first_wedges,
    interior_curve_coordinates,
    invalid,
    quarter_turn,
    wedge_of,
)

__all__ = ["IntegerGridMap", "QuantisationError", "integer_functionals", "model_points",
           "quantise"]

#: A functional is determined by those fixed when its conditional variance falls below
#: this share of its own (it then equals an integer combination of integers).
DETERMINED = 1e-9
#: A functional the fixed ones determine is taken to be off its integer beyond this.
PARITY_TOLERANCE = 1e-4
#: Rounds of fold repair (:func:`_repair`), and the quantities tried in each.
REPAIRS, REPAIR_CANDIDATES = 4, 10
#: CPU seconds the fold repair may take in all: a trial whose re-weighted rows are many
#: costs a factorisation, and a map that folds in many places would crawl through them.
REPAIR_SECONDS = 20.0
#: Largest distance to an integer an integer functional may keep after the final solve.
INTEGER_TOLERANCE = 1e-6


#: The order of rounding. Singular vertices first: a seam's translation around a singular
#: vertex s of turn j is t = (1 − Rot^j) s, and det(1 − Rot) = 2, so an integer t alone
#: would leave s at half-integers; an integer s makes t integer by itself.
_PHASE = {"singular": 0, "boundary": 1, "curve": 1, "point": 1, "seam": 2}


class QuantisationError(ValueError):
    """No valid integer-grid map at this scale (the rounding folds the map)."""


@dataclass(frozen=True)
class IntegerGridMap:
    """The quantised map ``param`` (its ``uv`` integer on every seam, boundary curve and
    singular vertex), the seamless map it was rounded from, and what the rounding did:
    ``functionals`` (F, (K, 2W)) and their integer ``values``; ``rounded`` how many were
    fixed by the greedy (the others followed); ``max_shift`` the largest rounding distance;
    ``energy_increase`` the misfit energy the rounding added, relative to the target's;
    ``repaired`` how many were rounded the other way to undo a fold."""

    param: Parametrisation
    seamless: Parametrisation
    functionals: sp.csr_matrix
    values: np.ndarray
    kinds: np.ndarray
    rounded: int
    max_shift: float
    energy_increase: float
    repaired: int = 0

    @property
    def mesh(self) -> CutMesh:
        return self.param.mesh


def _boundary_wedges(mesh: CutMesh):
    """Per boundary edge its (wedge at the first vertex, wedge at the second, constant
    coordinate)."""
    boundary, coordinate = boundary_coordinates(mesh)
    f = mesh.faces[boundary, 0]
    wa = [wedge_of(mesh, int(fi), int(a)) for fi, a in zip(f, mesh.edges[boundary, 0],
                                                           strict=True)]
    wb = [wedge_of(mesh, int(fi), int(b)) for fi, b in zip(f, mesh.edges[boundary, 1],
                                                           strict=True)]
    return np.array(wa, dtype=np.int64), np.array(wb, dtype=np.int64), coordinate


def anchor_wedges(mesh: CutMesh) -> np.ndarray:
    """Per connected component of the mesh a wedge whose (U, V) the integer grid fixes
    anyway: a singular vertex's, else a boundary corner's, else a boundary vertex's (else
    the component's first wedge)."""
    count, label = triangle_components(mesh.faces, mesh.cells.shape[0])
    wedge_component = np.empty(mesh.num_wedges, dtype=np.int64)
    wedge_component[mesh.corners] = label[:, None]
    candidates = []
    for v in mesh.singular:
        face = int(np.flatnonzero(np.any(mesh.cells == v, axis=1))[0])
        candidates.append(wedge_of(mesh, face, int(v)))
    wa, wb, coordinate = _boundary_wedges(mesh)
    constrained = np.zeros((mesh.num_wedges, 2), dtype=bool)
    constrained[wa, coordinate] = True
    constrained[wb, coordinate] = True
    candidates += list(np.flatnonzero(constrained.all(axis=1))) + list(wa)
    candidates += list(first_wedges(mesh))
    anchors = {}
    for w in candidates:
        anchors.setdefault(int(wedge_component[w]), int(w))
    return np.array([anchors[c] for c in range(count)], dtype=np.int64)


def interior_angles(mesh: CutMesh) -> np.ndarray:
    """The angle of the domain at every vertex (n,): the sum of its triangles' angles
    (2π inside, the corner angle on the boundary)."""
    p = mesh.x[mesh.cells]  # (m, 3, 2)
    angle = np.zeros(mesh.x.shape[0])
    for i in range(3):
        a, b = p[:, (i + 1) % 3] - p[:, i], p[:, (i + 2) % 3] - p[:, i]
        cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
        np.add.at(angle, mesh.cells[:, i], np.arctan2(np.abs(cross), np.einsum("mk,mk->m", a, b)))
    return angle


def cusps(mesh: CutMesh) -> np.ndarray:
    """Boundary vertices where the boundary turns back on itself (the domain's angle
    under 45° or over 315°, a trailing edge, a slit's end): the same coordinate is constant
    on both sides, yet the vertex must be a grid point (the boundary turns by 180°)."""
    boundary = np.unique(mesh.edges[mesh.faces[:, 1] < 0])
    angle = interior_angles(mesh)[boundary]
    return boundary[(angle < np.pi / 4) | (angle > 7 * np.pi / 4)]


def model_points(mesh: CutMesh) -> np.ndarray:
    """The vertices that must be quad vertices because of the features (empty without):
    the model points, and every vertex on the model curves (boundary and interior) where
    two curve tags meet or where the curve edges at it are not two (a curve's end inside,
    a junction of three); not the smooth joints
    (:func:`~ufl_frames.param.features.with_smooth_joints`)."""
    if mesh.features is None:
        return np.zeros(0, dtype=np.int64)
    points = [mesh.features.required_points]
    ids, tags = curve_edge_ids(mesh)
    if ids.size:
        ends = mesh.edges[ids].ravel()
        both = np.repeat(tags, 2)
        degree = np.bincount(ends, minlength=mesh.x.shape[0])
        pairs = np.unique(np.stack([ends, both], axis=1), axis=0)
        kinds = np.bincount(pairs[:, 0], minlength=mesh.x.shape[0])
        meet = np.flatnonzero((degree > 0) & ((degree != 2) | (kinds > 1)))
        points.append(meet[~np.isin(meet, mesh.features.joints)])
    return np.unique(np.concatenate(points))


def integer_functionals(mesh: CutMesh) -> tuple[sp.csr_matrix, np.ndarray]:
    """F (K, 2W): the rows of every quantity that must be an integer, and their kinds
    ('boundary', 'curve', 'point', 'singular', 'seam'). Unknown 2w + c is coordinate c of
    wedge w."""
    rows, cols, vals, kinds = [], [], [], []

    def add(entries, kind):
        k = len(kinds)
        for var, coef in entries:
            rows.append(k)
            cols.append(var)
            vals.append(coef)
        kinds.append(kind)

    wa, _, coordinate = _boundary_wedges(mesh)
    for w, c in zip(wa, coordinate, strict=True):
        add([(2 * w + c, 1.0)], "boundary")
    for v in cusps(mesh):  # both coordinates: the vertex is a corner of the grid
        face = int(np.flatnonzero(np.any(mesh.cells == v, axis=1))[0])
        w = wedge_of(mesh, face, int(v))
        for c in range(2):
            add([(2 * w + c, 1.0)], "boundary")
    inner, inner_coordinate, _ = interior_curve_coordinates(mesh)
    for e, c in zip(inner, inner_coordinate, strict=True):
        w = wedge_of(mesh, int(mesh.faces[e, 0]), int(mesh.edges[e, 0]))
        add([(2 * w + int(c), 1.0)], "curve")
    used = np.zeros(mesh.x.shape[0], dtype=bool)
    used[mesh.cells.ravel()] = True
    for v in model_points(mesh):
        if not used[v]:
            continue
        face = int(np.flatnonzero(np.any(mesh.cells == v, axis=1))[0])
        w = wedge_of(mesh, face, int(v))
        for c in range(2):
            add([(2 * w + c, 1.0)], "point")
    for v in mesh.singular:
        face = int(np.flatnonzero(np.any(mesh.cells == v, axis=1))[0])
        w = wedge_of(mesh, face, int(v))
        for c in range(2):
            add([(2 * w + c, 1.0)], "singular")
    for e in mesh.cut:
        f, g = int(mesh.faces[e, 0]), int(mesh.faces[e, 1])
        a = int(mesh.edges[e, 0])
        wf, wg = wedge_of(mesh, f, a), wedge_of(mesh, g, a)
        rot = quarter_turn(mesh.jump[e])
        for c in range(2):  # t_c = X_g(a)_c − (Rot X_f(a))_c
            add([(2 * wg + c, 1.0)] + [(2 * wf + d, -rot[c, d]) for d in range(2) if rot[c, d]],
                "seam")
    F = sp.csr_matrix((vals, (rows, cols)), shape=(len(kinds), 2 * mesh.num_wedges))
    return F, np.array(kinds)


def _distinct_rows(M: sp.csr_matrix) -> np.ndarray:
    """Indices of the nonzero rows of ``M`` that differ from every earlier row."""
    seen, keep = set(), []
    M = M.tocsr()
    M.sum_duplicates()
    for i in range(M.shape[0]):
        start, stop = M.indptr[i], M.indptr[i + 1]
        data = np.round(M.data[start:stop], 9)
        nonzero = data != 0
        if not nonzero.any():
            continue
        key = (tuple(M.indices[start:stop][nonzero]), tuple(data[nonzero]))
        if key not in seen:
            seen.add(key)
            keep.append(i)
    return np.array(keep, dtype=np.int64)


def _covariance(lu, Fy: sp.csr_matrix, block: int = 256) -> np.ndarray:
    """G = F N⁻¹ Fᵀ from the factorised N, ``block`` right-hand sides at a time."""
    K = Fy.shape[0]
    G = np.empty((K, K))
    FyT = Fy.T.tocsc()
    for start in range(0, K, block):
        stop = min(K, start + block)
        Z = lu.solve(FyT[:, start:stop].toarray())
        G[:, start:stop] = Fy @ Z
    return 0.5 * (G + G.T)


def _greedy(mean: np.ndarray, G: np.ndarray, phase: np.ndarray,
            forced=()) -> tuple[np.ndarray, np.ndarray]:
    """Fix the functionals one at a time, cheapest rounding first within the lowest open
    ``phase`` (after the ``forced`` (index, integer) pairs, in their order); return the
    fixed ones (indices, in order) and the integer of every one.

    A rounding that would leave a functional it determines at a non-integer (a parity:
    around a boundary loop whose seams flip a coordinate's sign, 2 a = an integer
    combination of the singular vertices) is replaced by the other neighbouring integer,
    or, if that fails too, postponed until the other functionals are fixed.
    """
    mean, C = mean.copy(), G.copy()
    own = np.maximum(np.diag(G).copy(), 1e-300)
    open_ = np.ones(mean.size, dtype=bool)
    fixed = []

    def trial(i, value):
        column = C[:, i].copy()
        new_mean = mean + column * ((value - mean[i]) / C[i, i])
        new_var = np.diag(C) - column**2 / C[i, i]
        follows = open_ & (new_var <= DETERMINED * own)
        follows[i] = False
        fractional = np.abs(new_mean[follows] - np.rint(new_mean[follows]))
        return column, new_mean, not np.any(fractional > PARITY_TOLERANCE)

    for i, value in forced:
        if C[i, i] <= DETERMINED * own[i]:
            continue  # the earlier ones determine it
        column, mean, _ = trial(i, value)
        C -= np.outer(column, column) / C[i, i]
        mean[i] = value
        open_[i] = False
        fixed.append(int(i))
    while open_.any():
        idx = np.flatnonzero(open_)
        var = np.diag(C)[idx]
        determined = var <= DETERMINED * own[idx]
        open_[idx[determined]] = False
        idx = np.flatnonzero(open_)
        if idx.size == 0:
            break
        lowest = phase[idx].min()
        order = sorted(idx, key=lambda i: (phase[i] != lowest,
                                           (np.rint(mean[i]) - mean[i]) ** 2 / C[i, i]))
        for i in order:
            nearest = np.rint(mean[i])
            other = nearest + (1.0 if mean[i] > nearest else -1.0)
            for value in (nearest, other):
                column, new_mean, consistent = trial(i, value)
                if consistent:
                    break
            if consistent:
                break
        else:
            raise QuantisationError(
                "no rounding of the seams, boundary curves and singular vertices is "
                "consistent (every choice leaves a determined quantity at a half-integer)")
        mean = new_mean
        C -= np.outer(column, column) / C[i, i]
        mean[i] = value
        open_[i] = False
        fixed.append(int(i))
    return np.array(fixed, dtype=np.int64), np.rint(mean)


def quantise(mesh: CutMesh, scale: float) -> IntegerGridMap:
    """The integer-grid map of ``mesh``'s combed field at scale ``scale`` (quads of edge
    |u|/s): seamless least squares with the integer functionals rounded greedily.

    Where the rounded map folds (a triangle with det ∇(U, V) ≤ 0), the folded triangles
    and their neighbours are weighted up and the map solved again with the same integers
    (:meth:`~ufl_frames.param.seamless.SeamlessSystem.unfold`); where it still folds, or
    winds a full turn wrong around a vertex (:func:`~ufl_frames.param.seamless.invalid`),
    quantities are rounded the other way (:func:`_repair`). All with one factorisation
    (:class:`~ufl_frames.param.seamless.SeamlessSystem`). Raises
    :class:`QuantisationError` if it stays invalid: the grid is too coarse for the
    field's singularities or its narrow parts at this scale.
    """
    system = SeamlessSystem(mesh, scale, anchor_wedges(mesh))
    seamless = system.param(system.y0)
    F, kinds = integer_functionals(mesh)
    Fy = (F @ system.T).tocsr()
    keep = _distinct_rows(Fy)
    Fk = Fy[keep]
    rounded, max_shift, repaired, stopped = 0, 0.0, 0, False
    fixed = np.zeros(0, dtype=np.int64)
    if keep.size:
        G = _covariance(system.lu, Fk)
        mean = Fk @ system.y0
        phase = np.array([_PHASE[kind] for kind in kinds[keep]])
        fixed, target = _greedy(mean, G, phase)
        rounded = int(fixed.size)
    if fixed.size:
        max_shift = float(np.abs(Fk[fixed] @ system.y0 - target[fixed]).max())
        param = system.unfold(Fk[fixed], G[np.ix_(fixed, fixed)], target[fixed])
        if invalid(param).any():
            param, repaired, stopped = _repair(system, F, (Fk, mean, G, phase), fixed,
                                               target, param)
    else:
        param = system.unfold()
    values = F @ param.uv.ravel()
    off = np.abs(values - np.rint(values))
    if off.size and off.max() > INTEGER_TOLERANCE:
        worst = int(np.argmax(off))
        raise QuantisationError(
            f"the rounding left a {kinds[worst]} quantity {off.max():.2g} away from an integer "
            "(the integer constraints conflict)")
    values = np.rint(values)
    bad = int(np.count_nonzero(invalid(param)))
    if bad:
        raise QuantisationError(
            f"the integer-grid map folds, collapses or winds wrong around {bad} of "
            f"{mesh.cells.shape[0]} triangles at this quad size"
            + (f" (the fold repair stopped after {REPAIR_SECONDS:g} CPU seconds)" if stopped
               else "")
            + ": the grid is too coarse for the field's singularities or narrow parts; take "
            "a smaller quad size")
    increase = ((_misfit_energy(param) - _misfit_energy(seamless))
                / max(float(system.b @ system.b), 1e-300))
    return IntegerGridMap(param=param, seamless=seamless, functionals=F, values=values,
                          kinds=kinds, rounded=rounded, max_shift=max_shift,
                          energy_increase=increase, repaired=repaired)


def _repair(system: SeamlessSystem, F, rounding, fixed, target, param):
    """Move by one, to the other neighbouring integer and then away from it, each of the
    :data:`REPAIR_CANDIDATES` fixed quantities the invalid triangles (folded, or around a
    vertex the map winds wrong: :func:`~ufl_frames.param.seamless.invalid`) depend on most
    (a boundary curve and a singular vertex rounded onto one line, say), alone and with
    those the greedy fixed after it rounded again (a boundary curve across a moved
    singular vertex's seam moves with it): at most :data:`REPAIRS` times, each keeping the
    best trial if it has fewer invalid triangles and leaves every quantity an integer;
    no trial begins after :data:`REPAIR_SECONDS` of CPU time.
    Returns the map, the number of rounds that moved one, and whether the time ran out."""
    Fk, mean, G, phase = rounding
    repaired = 0
    deadline = time.process_time() + REPAIR_SECONDS
    for _ in range(REPAIRS):
        bad = invalid(param)
        if not bad.any() or time.process_time() > deadline:
            break
        influence = system.influence(Fk[fixed], G[np.ix_(fixed, fixed)], np.flatnonzero(bad))
        trials = []
        for k in np.argsort(-influence, kind="stable")[:REPAIR_CANDIDATES]:
            i = fixed[k]
            toward = 1.0 if mean[i] >= target[i] else -1.0  # the other neighbour first
            kept = [(j, target[j]) for j in fixed[:k]]
            for step in (toward, -toward):
                alone = target.copy()
                alone[i] += step
                trials += [("alone", (fixed, alone)),
                           ("regreedy", kept + [(i, target[i] + step)])]
        best = None
        for kind, trial in trials:
            if time.process_time() > deadline:
                break
            if kind == "alone":  # the quantity alone, every other one kept
                trial_fixed, trial_target = trial
            else:  # the quantity and those the greedy fixed after it, rounded again
                try:
                    trial_fixed, trial_target = _greedy(mean, G, phase, trial)
                except QuantisationError:
                    continue
            candidate = system.unfold(Fk[trial_fixed], G[np.ix_(trial_fixed, trial_fixed)],
                                      trial_target[trial_fixed])
            values = F @ candidate.uv.ravel()
            if np.abs(values - np.rint(values)).max(initial=0.0) > INTEGER_TOLERANCE:
                continue
            count = int(np.count_nonzero(invalid(candidate)))
            if count < int(np.count_nonzero(bad)) and (best is None or count < best[0]):
                best = (count, trial_fixed, trial_target, candidate)
                if count == 0:
                    break
        if best is None:
            break
        _, fixed, target, param = best
        repaired += 1
    return param, repaired, time.process_time() > deadline


def _misfit_energy(p: Parametrisation) -> float:
    """Σ_f |f| (|∇U − s ũ|² + |∇V − s ṽ|²): the least squares' objective."""
    return float(np.dot(p.area, np.sum((p.grad_u - p.target_u) ** 2, axis=1)
                        + np.sum((p.grad_v - p.target_v) ** 2, axis=1)))
