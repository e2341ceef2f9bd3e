r"""Integer arc lengths of a T-mesh layout and the quads of its patches: the quantisation
of a seamless map that cannot fold (Quantized Global Parametrization, Campen–Bommes–
Kobbelt 2015), on the layout of :func:`ufl_frames.quads.layout.layout`.

1. **integer arc lengths** (:func:`integer_lengths`): n_a ≥ 0 per arc with, per patch, the
   arcs of opposite sides summing to the same integer, minimising Σ w_a |n_a − L_a| (L_a
   the arc's length in the map, w_a = 1), a small integer program (SciPy's HiGHS
   ``milp``). An arc shorter than ``collapse_below`` may get 0: a thin patch between two
   nearly collinear traces then collapses, its long sides glued point by point, which
   lines the two traces up (the separatrices of nearby singularities join). Other arcs
   get at least 1. Where a collapse would put two singular vertices on one point inside,
   glue two parts of the boundary (or a patch between two boundary sides) together, leave
   a kept patch with two corners on one point, or glue singular vertices to the boundary
   where the quads left there would not make a valid fan (:meth:`_Points.valid_fan`: the
   domain's angle there shared by the quads, each within :data:`FAN_ANGLES`), the arcs
   collapsed there get at least 1 and the program is solved again (until none does).
   An arc at a model point may collapse (a trace passing a fraction of a quad from a
   corner, the airfoil's trailing edge say, goes through it), the model point staying
   where it is, but not so as to glue it to another model or curve point or to another
   boundary point (:meth:`_Points.bad_merges`); an interior curve's arcs shorter than
   :data:`CURVE_COLLAPSE_BELOW` may collapse too, gluing points along the curve (two traces
   from its two sides landing a hair apart, or a hair from a model point on it, end at one
   point), but not two model points (the longest zero arc between them gets 1). So a
   valence-5 singular vertex (turn −1) a fraction of a quad from a straight boundary
   goes onto it, a boundary vertex in three quads of about 60° (the thin patches between
   its separatrices and the boundary collapse: no sliver layer); a valence-3 one (turn
   +1) does not (one quad with a 180° corner); two valence-5 ones next to a 240° corner
   (a sharp leading edge) go onto the corner, five quads of 48°.
   With every arc at least 1 (``collapse_below=0``) a solution always exists: the real
   lengths solve the equalities, so the rational cone they span holds integer points.
   An arc along a curved boundary or interior curve gets at least as many quad edges as
   keep each edge's chord within ``sagitta`` (:data:`CHORD_SAGITTA`) of the quad size off
   the curve (:func:`min_curve_lengths`): an arc that turns by θ with map length L (so a
   quad size ℓ/L for its plane length ℓ, on a radius ℓ/θ) needs n edges with
   (ℓ/θ)(1 − cos(θ/2n)) ≤ sagitta · ℓ/L, i.e. n ≥ θ / (2 arccos(1 − sagitta · θ/L)); the
   extra edges go on across the patches (opposite sides stay equal), a sheet of narrower
   quads from the curve to wherever the program closes it. A small hole a few quads
   round would otherwise be a polygon of a few chords;
2. **quads** (:func:`patch_quads`): per patch a W × H grid, its boundary points at the
   integer positions along each arc (uniform in the map; an arc that is a side by itself of
   a patch thinner than :data:`FACING_BELOW` quads has its points across from the opposite
   side's, :func:`_facing_fractions`, so that a thin patch is not sheared), the inside by
   transfinite (Coons) blending in the patch's rectangle of the parameter plane, and every
   point mapped back to the plane by walking the triangles of the map from the patch's
   corner (straight segments in the patch's chart, across seams). Arc points are computed
   once, so the patches that share an arc share its points: the quads are conforming;
   points glued by a collapse become one (a boundary corner's, else the boundary's, else
   the singular vertex's, else their mean). Where that point has no one place on the
   boundary (singular vertices glued to it, or several boundary points or corners glued,
   none a model or curve point), it goes on the boundary between its two boundary
   neighbours where its two quad edges follow it best
   (:func:`~ufl_frames.quads.improve.onto_boundary`): at a round nose a fraction of a quad
   wide, whose thin patches collapse and glue its −1/4 singular vertices to it, the nose's
   tip.

Pure NumPy/SciPy. :func:`quads_of_map` runs the whole chain on a seamless map (of one or
more connected components: each has its own patches).
"""

import math
from dataclasses import replace

import numpy as np
import scipy.sparse as sp
from scipy.optimize import Bounds, LinearConstraint, milp

from ufl_frames.param.seamless import Parametrisation, folded
from ufl_frames.quads.charts import UNIT, LayoutError
from ufl_frames.quads.extract import QuadMesh, with_features
from ufl_frames.quads.improve import onto_boundary
from ufl_frames.quads.layout import Layout, layout, piece_length, untangle
from ufl_frames.quads.motorcycles import rot

__all__ = ["CHORD_SAGITTA", "COLLAPSE_BELOW", "CURVE_COLLAPSE_BELOW", "FACING_BELOW",
           "arc_turning", "integer_lengths", "min_curve_lengths", "patch_quads",
           "quads_of_map"]

#: Arcs shorter than this (in quads) may get length 0 (:func:`integer_lengths`).
COLLAPSE_BELOW = 0.5
#: An interior curve's arc may get length 0 only if shorter than this (in quads): its
#: collapse glues two points along the curve and shears the quads on both sides by its
#: length. The rotor sector's (trace ends a hair from a model point) are under 0.01 of a
#: quad; deal.II step-49's one of 0.38 at 400 quads took its min SJ from 0.71 to 0.43.
CURVE_COLLAPSE_BELOW = 0.1
#: A patch side that is one arc gets its points across from the opposite side's only where
#: the patch is thinner than this (in quads, :func:`_facing_fractions`); thicker patches
#: keep them uniform in the map (the gear, vnotch_plate: patches 2.4–12 quads thick whose
#: points moved by up to a quad).
FACING_BELOW = 1.0
#: A quad edge along a curved boundary or interior curve stays within this share of the
#: quad size of its curve (its chord's sagitta; :func:`min_curve_lengths`). With 0.04 a
#: hole 4, 6, 10, 16 quads round in the map gets at least 9, 11, 14, 18 edges (its polygon
#: 7.9, 5.3, 3.3, 2.0 % short of the hole's area instead of 36, 17, 6.5, 2.6 %); 20 quads
#: round and more keep their count. Chosen so that ``plate_holes`` at 200 quads is within
#: 0.5 % of its area (benchmarks/README.md, "Quads on the CAD curves").
CHORD_SAGITTA = 0.04

#: The angles (degrees) the quads at a singular vertex glued to the boundary may have on
#: average (:meth:`_Points.valid_fan`): three at 60° on a straight boundary, five at 48°
#: in a 240° corner; not one at 180°.
FAN_ANGLES = (40.0, 135.0)


def _solve(lay: Layout, lower: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """min Σ w |n − L| over integers n ≥ ``lower`` with equal opposite sides per patch.

    Args:
        lay: the layout (L its arc lengths).
        lower: per arc its lower bound (0 or 1).
        weights: per arc w.

    Returns:
        n (A,) int64; raises :class:`LayoutError` where there is none.
    """
    L = lay.lengths()
    A = L.size
    rows, cols, vals, count = [], [], [], 0
    for sides in lay.patches:
        for s in (0, 1):
            for side, sign in ((sides[s], 1.0), (sides[s + 2], -1.0)):
                for h in side:
                    rows.append(count)
                    cols.append(h // 2)
                    vals.append(sign)
            count += 1
    eye = sp.identity(A, format="csr")
    blocks = [LinearConstraint(sp.hstack([eye, -eye]), -np.inf, L),
              LinearConstraint(sp.hstack([-eye, -eye]), -np.inf, -L)]
    if count:
        E = sp.csr_matrix((vals, (rows, cols)), shape=(count, A))
        E.sum_duplicates()
        blocks.append(LinearConstraint(sp.hstack([E, sp.csr_matrix((count, A))]), 0, 0))
    result = milp(np.concatenate([np.zeros(A), weights]), constraints=blocks,
                  integrality=np.concatenate([np.ones(A), np.zeros(A)]),
                  bounds=Bounds(np.concatenate([lower, np.zeros(A)]), np.inf))
    if result.status != 0 or result.x is None:
        raise LayoutError("no integer arc lengths with equal opposite sides in every patch "
                          f"({result.message})")
    return np.rint(result.x[:A]).astype(np.int64)


def arc_turning(mc, arc) -> tuple[float, float]:
    """How far ``arc`` turns in the plane (radians, ≥ 0) and its plane length.

    The arc's pieces are straight in the plane (one triangle each); the turns between
    consecutive pieces are summed and spread over the whole arc as a constant curvature
    (the turns at its two ends, shared with the next arcs, are not seen: the sum is scaled
    by the arc's length over the length between its first and last pieces' middles). One
    piece alone: 0.
    """
    points = [_physical(mc, arc.pieces[0][0], arc.pieces[0][1])]
    points += [_physical(mc, f, p1) for f, _, p1, _ in arc.pieces]
    step = np.diff(np.asarray(points), axis=0)
    length = np.linalg.norm(step, axis=1)
    step, length = step[length > 1e-14], length[length > 1e-14]
    total = float(length.sum())
    if length.size < 2:
        return 0.0, total
    heading = np.arctan2(step[:, 1], step[:, 0])
    turns = np.angle(np.exp(1j * np.diff(heading)))
    inner = total - 0.5 * (length[0] + length[-1])
    return abs(float(turns.sum())) * total / float(inner), total


def min_curve_lengths(lay: Layout, sagitta: float | None = None) -> np.ndarray:
    """Per arc of ``lay`` the fewest quad edges that keep every edge of a boundary or
    curve arc within ``sagitta`` of the quad size off its curve (the module text, step 1):
    n ≥ θ / (2 arccos(1 − sagitta · θ/L)), θ the arc's turn (:func:`arc_turning`), L its
    map length; 0 for the other arcs and where ``sagitta`` is not positive (None:
    :data:`CHORD_SAGITTA`)."""
    sagitta = CHORD_SAGITTA if sagitta is None else sagitta
    need = np.zeros(len(lay.arcs), dtype=np.int64)
    if sagitta <= 0:
        return need
    for a, arc in enumerate(lay.arcs):
        if not (arc.boundary or arc.curve) or arc.length <= 0 or not arc.pieces:
            continue
        theta, _ = arc_turning(lay.motorcycles, arc)
        half = math.acos(max(-1.0, 1.0 - sagitta * theta / float(arc.length)))
        if half > 0:  # else straight (to rounding): no bound
            need[a] = math.ceil(theta / (2 * half) - 1e-9)
    return need


def integer_lengths(lay: Layout, weights=None,
                    collapse_below: float = COLLAPSE_BELOW,
                    sagitta: float | None = None) -> np.ndarray:
    """Integer lengths n (one per arc of ``lay``) with equal opposite sides per patch,
    closest to the arcs' lengths (see the module text, step 1).

    Args:
        lay: the layout.
        weights: w_a per arc (default 1).
        collapse_below: arcs shorter than this may get 0 (0: every arc at least 1).
        sagitta: a curved boundary or curve arc gets at least the edges that keep their
            chords within this share of the quad size off the curve
            (:func:`min_curve_lengths`; None: :data:`CHORD_SAGITTA`; 0: none asked).

    Returns:
        n (A,) int64. Raises :class:`~ufl_frames.quads.charts.LayoutError` where there is
        no solution.
    """
    L = lay.lengths()
    w = np.ones(L.size) if weights is None else np.asarray(weights, dtype=float)
    # an interior curve's arcs may collapse too, if shorter than CURVE_COLLAPSE_BELOW
    # (two trace ends on it a hair apart become one); bad_merges keeps its model points
    # and its pieces apart
    lower = np.where(L < collapse_below, 0.0, 1.0)
    lower[[a for a, arc in enumerate(lay.arcs)
           if arc.curve and L[a] >= min(collapse_below, CURVE_COLLAPSE_BELOW)]] = 1.0
    need = min_curve_lengths(lay, CHORD_SAGITTA if sagitta is None else sagitta)
    lower = np.where(need >= 2, np.maximum(lower, need), lower)  # 1: as before (collapses)
    for _ in range(L.size + 1):
        n = _solve(lay, lower, w)
        points = _Points(lay, n)
        bad = points.bad_merges()
        if not bad:
            return n
        lower[bad] = np.maximum(lower[bad], 1.0)
    raise LayoutError("the collapses of thin patches keep merging singular vertices")


class _Points:
    """The points of the quads of ``lay`` at lengths ``n`` before any is placed: the
    nodes (ids 0 … N − 1), then each arc's inner points; per arc its n + 1 ids (one for a
    zero arc, whose ends are glued); the glue (union–find) of zero arcs and collapsed
    patches; per patch its four sides as runs of ids."""

    def __init__(self, lay: Layout, n: np.ndarray):
        self.lay, self.n = lay, n
        count = len(lay.nodes)
        self.arc_ids = []
        for arc, k in zip(lay.arcs, n.tolist(), strict=True):
            inner = list(range(count, count + max(k - 1, 0)))
            count += len(inner)
            self.arc_ids.append([arc.start] + inner + ([arc.end] if k > 0 else []))
        self.count = count
        self.parent = list(range(count))
        self.events = []  # (zero arcs, point pairs they glue)
        self.lost = []  # zero arcs of patches collapsed between two boundary sides
        for a, (arc, k) in enumerate(zip(lay.arcs, n.tolist(), strict=True)):
            if k == 0:
                self.events.append(([a], [(arc.start, arc.end)]))
        self.runs = []
        for sides in lay.patches:
            runs = []
            for side in sides:
                ids = []
                for h in side:
                    seq = self.arc_ids[h // 2]
                    seq = seq if h % 2 == 0 else seq[::-1]
                    ids += seq if not ids else seq[1:]
                runs.append(ids)
            W, H = len(runs[0]) - 1, len(runs[1]) - 1
            if len(runs[2]) - 1 != W or len(runs[3]) - 1 != H:
                raise LayoutError("a patch's opposite sides have different integer lengths")
            for s, width in ((0, W), (1, H)):  # collapsed: two sides become one
                if width:
                    continue
                across = [h // 2 for h in sides[s] + sides[s + 2]]
                self.events.append((across, list(zip(runs[s + 1], runs[(s + 3) % 4][::-1],
                                                     strict=True))))
                glued = sides[s + 1] + sides[(s + 3) % 4]
                if all(lay.arcs[h // 2].boundary for h in glued):
                    self.lost += across  # boundary onto boundary: the patch is lost
            self.runs.append(runs)
        for _, pairs in self.events:
            for a, b in pairs:
                self.union(a, b)

    def find(self, a):
        root = a
        while self.parent[root] != root:
            root = self.parent[root]
        while self.parent[a] != root:
            self.parent[a], a = root, self.parent[a]
        return root

    def union(self, a, b):
        a, b = self.find(a), self.find(b)
        if a != b:
            self.parent[max(a, b)] = min(a, b)

    def _ids_on(self, kind: str) -> set:
        """The points of the arcs whose flag ``kind`` ('boundary' or 'curve') is set."""
        return {i for arc, ids in zip(self.lay.arcs, self.arc_ids, strict=True)
                if getattr(arc, kind) for i in ids}

    def boundary_ids(self) -> set:
        """The points on the boundary's arcs."""
        return self._ids_on("boundary")

    def curve_ids(self) -> set:
        """The points on the features' interior curves (their arcs' points and ends)."""
        return self._ids_on("curve")

    def model_ids(self) -> set:
        """The nodes at the features' model points."""
        mc = self.lay.motorcycles
        return {i for i, key in enumerate(self.lay.nodes)
                if key[0] == "v" and key[1] in mc.model_nodes}

    def bad_merges(self) -> list:
        """The zero arcs of the glues that put on one point two singular vertices inside,
        singular vertices and the boundary where the fan left is not valid
        (:meth:`valid_fan`), two boundary points not joined along the boundary by zero
        arcs (a part of the domain collapsed), or two neighbouring points of a patch that
        keeps its quads; and those of a patch collapsed between two sides on the boundary
        (the patch would be lost)."""
        mc = self.lay.motorcycles
        along = list(range(self.count))  # union–find of the zero boundary arcs alone

        def find(a):
            while along[a] != a:
                along[a] = along[along[a]]
                a = along[a]
            return a

        for arc, k in zip(self.lay.arcs, self.n.tolist(), strict=True):
            if k == 0 and arc.boundary:
                along[max(find(arc.start), find(arc.end))] = min(find(arc.start),
                                                                 find(arc.end))
        pieces: dict = {}
        members: dict = {}
        for i in self.boundary_ids():
            pieces.setdefault(self.find(i), set()).add(find(i))
            members.setdefault(self.find(i), []).append(i)
        bad = {root for root, parts in pieces.items() if len(parts) > 1}
        # an interior curve keeps its points apart: a glue may pull a trace, or a
        # valence-5 singular vertex (turn −1: quads of 90° and 60° on the two sides), onto
        # it (the curve's point stays, :func:`patch_quads`), not two of its points
        # together, nor one onto the boundary or a valence-3 singular vertex (a quad with a
        # 180° corner on one side); but points joined along the curve by its zero arcs
        # (trace ends a fraction of a quad apart, at most one model point) may be one
        on_curve = list(range(self.count))  # union–find of the zero curve arcs alone

        def follow(a):
            while on_curve[a] != a:
                on_curve[a] = on_curve[on_curve[a]]
                a = on_curve[a]
            return a

        for arc, k in zip(self.lay.arcs, self.n.tolist(), strict=True):
            if k == 0 and arc.curve:
                on_curve[max(follow(arc.start), follow(arc.end))] = min(follow(arc.start),
                                                                        follow(arc.end))
        models = self.model_ids()
        special: dict = {}
        for i in self.curve_ids() | self.model_ids():
            special.setdefault(self.find(i), set()).add(i)
        others = self.boundary_ids() | {i for i, key in enumerate(self.lay.nodes)
                                        if key[0] == "v" and mc.singular.get(key[1], -1) != -1}
        for i in others:
            ids = special.get(self.find(i))
            if ids is not None and i not in ids:
                bad.add(self.find(i))
        bad.update(root for root, ids in special.items() if len(ids & models) > 1)
        along: dict = {}  # model points glued along a curve by its zero arcs
        for i in models:
            along[follow(i)] = along.get(follow(i), 0) + 1
        clash = {c for c, count in along.items() if count > 1}
        bad.update(root for root, ids in special.items() if len({follow(i) for i in ids}) > 1)
        for runs in self.runs:  # a patch left with quads whose two corners are one point
            if len(runs[0]) > 1 and len(runs[1]) > 1:
                for ids in runs:
                    bad.update(self.find(u) for u, v in zip(ids, ids[1:], strict=False)
                               if self.find(u) == self.find(v))
        seen, fans, quads = set(), {}, None
        for i, key in enumerate(self.lay.nodes):
            if key[0] == "v" and key[1] in mc.singular:
                root = self.find(i)
                if root in pieces:  # onto the boundary: where the fan left there is valid
                    if root not in fans:
                        quads = self.quads_at() if quads is None else quads
                        fans[root] = self.valid_fan(members[root], quads.get(root, 0))
                    if not fans[root]:
                        bad.add(root)
                elif root in seen:  # two singular vertices inside
                    bad.add(root)
                seen.add(root)
        blamed = {a for arcs, pairs in self.events
                  if any(self.find(p) in bad for p, _ in pairs) for a in arcs}
        # a zero curve arc glues two points along its curve, which is bad only where two
        # model points become one along it, and then the longest zero arc between them is
        # kept: the others keep length 0 (a whole quad between a trace end and a model
        # point, or the end of a trace from the other side, it passes a fraction of a
        # quad from, would fold the quads between them); the glues they are part of are
        # undone by their other arcs
        longest: dict = {}
        for a, (arc, k) in enumerate(zip(self.lay.arcs, self.n.tolist(), strict=True)):
            c = follow(arc.start)
            if k == 0 and arc.curve and c in clash and (
                    c not in longest or arc.length > self.lay.arcs[longest[c]].length):
                longest[c] = a
        innocent = {a for a, (arc, k) in enumerate(zip(self.lay.arcs, self.n.tolist(),
                                                       strict=True))
                    if k == 0 and arc.curve and a not in longest.values()}
        kept = blamed - innocent
        return sorted((kept if kept or self.lost else blamed) | set(self.lost))

    def quads_at(self) -> dict:
        """Per glued point (root) the number of quads of the kept patches at it: one at a
        patch's corner, two at a point inside a side."""
        out: dict = {}
        for runs in self.runs:
            if len(runs[0]) > 1 and len(runs[1]) > 1:
                for ids in runs:
                    out[self.find(ids[0])] = out.get(self.find(ids[0]), 0) + 1
                    for u in ids[1:-1]:
                        out[self.find(u)] = out.get(self.find(u), 0) + 2
        return out

    def valid_fan(self, ids, quads: int) -> bool:
        """Whether ``quads`` quads at the boundary points ``ids`` glued into one (with
        singular vertices) make a valid fan: the domain's angle there (each point's angle in
        the triangles, π inside a boundary edge; the glued points' angles together, less π
        per glue along the boundary) shared by the quads within [:data:`FAN_ANGLES`]. A
        valence-5 singular vertex (turn −1) on a straight boundary: three quads at 60°,
        valid; a valence-3 one (turn +1): one quad with a 180° corner, not."""
        mc = self.lay.motorcycles
        nodes = len(self.lay.nodes)
        total = 0.0
        for i in ids:
            key = self.lay.nodes[i] if i < nodes else None
            total += _angle(mc, key[1]) if key is not None and key[0] == "v" else math.pi
        total -= math.pi * (len(ids) - 1)
        low, high = FAN_ANGLES
        return quads >= 1 and math.radians(low) <= total / quads <= math.radians(high)


def _angle(mc, w) -> float:
    """The angle of the domain at vertex w in the plane (its triangles' angles at w)."""
    x = mc.mesh.x
    total = 0.0
    for f, loc, _ in mc.fan(w):
        c = mc.cells[f]
        a, b = x[c[(loc + 1) % 3]] - x[c[loc]], x[c[(loc + 2) % 3]] - x[c[loc]]
        total += math.atan2(a[0] * b[1] - a[1] * b[0], a @ b)
    return total


def _physical(mc, f, X):
    """The plane point of a chart point.

    Args:
        mc: the tracer (charts).
        f: the triangle.
        X: the point in f's chart (floats, fixed-point units).

    Returns:
        (2,) array.
    """
    A = np.array(mc.pts[f], dtype=float)
    T = np.array([A[1] - A[0], A[2] - A[0]]).T
    b = np.linalg.solve(T, np.asarray(X, dtype=float) - A[0])
    lam = np.array([1 - b.sum(), b[0], b[1]])
    return lam @ mc.mesh.x[mc.cells[f]]
def _arc_points(mc, arc, n, fractions=None):
    """The inner points of an arc at its lengths k/n, k = 1 … n − 1 (uniform in the map),
    or at the given ``fractions`` of its length.

    Args:
        mc: the tracer (charts).
        arc: the arc.
        n: its integer length.
        fractions: n − 1 increasing numbers in (0, 1), or None (k/n).

    Returns:
        A list of n − 1 plane points.
    """
    lengths = [float(piece_length(p)) for p in arc.pieces]
    total = sum(lengths)
    fractions = np.arange(1, n) / n if fractions is None else fractions
    out, j, at = [], 0, 0.0
    for k in range(1, n):
        s = total * float(fractions[k - 1])
        while j < len(lengths) - 1 and at + lengths[j] < s:
            at += lengths[j]
            j += 1
        f, p0, _, d = arc.pieces[j]
        out.append(_physical(mc, f, (float(p0[0]) + (s - at) * d[0],
                                     float(p0[1]) + (s - at) * d[1])))
    return out


def _bary(A, X):
    """Barycentric coordinates of X in the triangle A (three float pairs)."""
    (a0, a1), (b0, b1), (c0, c1) = A
    det = (b0 - a0) * (c1 - a1) - (b1 - a1) * (c0 - a0)
    x0, x1 = X
    l0 = ((c0 - b0) * (x1 - b1) - (c1 - b1) * (x0 - b0)) / det
    l1 = ((a0 - c0) * (x1 - c1) - (a1 - c1) * (x0 - c0)) / det
    return (l0, l1, 1.0 - l0 - l1)


def _turned(k, t, pts):
    """The triangle's chart points ``pts`` (three float pairs) in the walking frame: Rot^k
    then the shift t, as six floats (a0, a1, b0, b1, c0, c1) — :func:`~ufl_frames.quads.
    motorcycles.rot` written out (a quarter turn only swaps and negates: the same floats)."""
    (u0, v0), (u1, v1), (u2, v2) = pts
    t0, t1 = t
    if k == 0:
        return u0 + t0, v0 + t1, u1 + t0, v1 + t1, u2 + t0, v2 + t1
    if k == 1:
        return v0 + t0, t1 - u0, v1 + t0, t1 - u1, v2 + t0, t1 - u2
    if k == 2:
        return t0 - u0, t1 - v0, t0 - u1, t1 - v1, t0 - u2, t1 - v2
    return t0 - v0, u0 + t1, t0 - v1, u1 + t1, t0 - v2, u2 + t1


def _walk(mc, state, q, max_steps):
    """Walk straight from the state's point to q across triangles (and seams), in pure
    Python floats (the inner loop of the quads; :func:`_bary` written out).

    Args:
        mc: the tracer (charts, neighbours, transitions).
        state: (triangle, quarter turns and shift from its chart to the walking frame,
            point in the walking frame).
        q: the target in the walking frame.
        max_steps: the most triangles to cross.

    Returns:
        (state at q, plane point of q), or (None, None) if the walk got lost (in a fold).
    """
    f, k, t, p = state
    entry = -1
    fpts, nb, xs = mc.float_pts, mc.nb, mc.float_x
    x0, x1 = q
    for _ in range(max_steps):
        a0, a1, b0, b1, c0, c1 = _turned(k, t, fpts[f])
        det = (b0 - a0) * (c1 - a1) - (b1 - a1) * (c0 - a0)
        l0 = ((c0 - b0) * (x1 - b1) - (c1 - b1) * (x0 - b0)) / det
        l1 = ((a0 - c0) * (x1 - c1) - (a1 - c1) * (x0 - c0)) / det
        l2 = 1.0 - l0 - l1
        if l0 >= -1e-12 and l1 >= -1e-12 and l2 >= -1e-12:
            x = xs[f]
            return (f, k, t, q), (l0 * x[0][0] + l1 * x[1][0] + l2 * x[2][0],
                                  l0 * x[0][1] + l1 * x[1][1] + l2 * x[2][1])
        lq = (l0, l1, l2)
        A = ((a0, a1), (b0, b1), (c0, c1))
        lp = _bary(A, p)
        best, i_best = math.inf, -1
        for i in range(3):
            if lq[i] < 0 and i != entry:
                s = lp[i] / (lp[i] - lq[i])
                if s < best:
                    best, i_best = s, i
        if i_best < 0:
            i_best, best = min(range(3), key=lambda i: lq[i]), 0.0
        best = max(best, 0.0)
        p = (p[0] + best * (x0 - p[0]), p[1] + best * (x1 - p[1]))
        g = nb[f][i_best]
        if g < 0:  # q is outside (round-off on the boundary): stop where the walk left
            lp = [max(v, 0.0) for v in _bary(A, p)]
            total = sum(lp)
            x = xs[f]
            return (f, k, t, p), tuple(sum(lp[i] * x[i][c] for i in range(3)) / total
                                       for c in range(2))
        j, e = mc.turn[f][i_best], mc.shift[f][i_best]
        if j or e[0] or e[1]:  # a seam: the walking frame's transition changes
            k2 = (k - j) % 4
            e = rot(k2, e)
            t = (t[0] - e[0], t[1] - e[1])
            k = k2
        entry = nb[g].index(f) if nb[g].count(f) == 1 else -1
        f = g
    return None, None  # lost (in a fold): the caller tries another way


def _walk_point(mc, state):
    """The plane point of a walk's state (its point clamped into its triangle)."""
    f, k, t, p = state
    A = [rot(k, c) for c in mc.float_pts[f]]
    lam = [max(v, 0.0) for v in _bary([(a[0] + t[0], a[1] + t[1]) for a in A], p)]
    x = mc.float_x[f]
    return tuple(sum(lam[i] * x[i][c] for i in range(3)) / sum(lam) for c in range(2))


def patch_quads(lay: Layout, n: np.ndarray) -> tuple[QuadMesh, int]:
    """The quads of every patch of ``lay`` for the integer arc lengths ``n``
    (:func:`integer_lengths`; see the module text, step 2), and how many points could not
    be located: a point whose walk gets lost in a fold of the map (one that no trace
    crosses) is walked to again from the patch's corner, else placed where the walk was."""
    mc = lay.motorcycles
    pts = _Points(lay, n)
    position = [None] * pts.count
    for arc in lay.arcs:
        for node, (f, X) in ((arc.start, arc.pieces[0][:2]),
                             (arc.end, (arc.pieces[-1][0], arc.pieces[-1][2]))):
            if position[node] is None:
                position[node] = _physical(mc, f, (float(X[0]), float(X[1])))
    fractions = _facing_fractions(lay, n)
    for a, arc in enumerate(lay.arcs):
        for i, p in zip(pts.arc_ids[a][1:-1], _arc_points(mc, arc, int(n[a]), fractions[a]),
                        strict=True):
            position[i] = p
    quads, lost = [], 0
    steps = 50 * int(math.sqrt(len(mc.cells))) + 1000  # a walk longer than this is lost
    for sides, runs in zip(lay.patches, pts.runs, strict=True):
        W, H = len(runs[0]) - 1, len(runs[1]) - 1
        if W == 0 or H == 0:
            continue
        lengths = [_side_positions(lay, n, side, fractions) for side in sides]
        Lw, Lh = lengths[0][-1], lengths[1][-1]
        bottom = np.stack([lengths[0], np.zeros(W + 1)], axis=1)
        right = np.stack([np.full(H + 1, Lw), lengths[1]], axis=1)
        top = np.stack([Lw - lengths[2], np.full(W + 1, Lh)], axis=1)[::-1]
        left = np.stack([np.zeros(H + 1), Lh - lengths[3]], axis=1)[::-1]
        grid = np.full((W + 1, H + 1), -1, dtype=np.int64)
        grid[:, 0], grid[W, :] = runs[0], runs[1]
        grid[:, H], grid[0, :] = runs[2][::-1], runs[3][::-1]
        # the walking frame: the chart of the first piece at corner (0, 0)
        h = sides[0][0]
        arc = lay.arcs[h // 2]
        if h % 2 == 0:
            f, X0, _, d = arc.pieces[0]
        else:
            f, _, X0, d = arc.pieces[-1]
            d = (-d[0], -d[1])
        origin = (float(X0[0]), float(X0[1]))
        state = start = (f, 0, (0.0, 0.0), origin)
        # the Coons blend of the whole grid at once (inner points (W − 1, H − 1, 2))
        u = (np.arange(1, W) / W)[:, None, None]
        v = (np.arange(1, H) / H)[None, :, None]
        xy = ((1 - v) * bottom[1:W, None] + v * top[1:W, None] + (1 - u) * left[None, 1:H]
              + u * right[None, 1:H]
              - ((1 - u) * (1 - v) * bottom[0] + u * (1 - v) * bottom[W]
                 + (1 - u) * v * top[0] + u * v * top[W])).tolist()
        for j in range(1, H):
            for i in (range(1, W) if j % 2 else range(W - 1, 0, -1)):
                x, y = xy[i - 1][j - 1]
                q = (origin[0] + UNIT * (x * d[0] - y * d[1]),
                     origin[1] + UNIT * (x * d[1] + y * d[0]))
                moved, point = _walk(mc, state, q, steps)
                if moved is None:  # lost in a fold: from the corner instead, else approximate
                    moved, point = _walk(mc, start, q, steps)
                if moved is None:
                    lost += 1
                    moved, point = state, _walk_point(mc, state)
                state = moved
                grid[i, j] = len(position)
                position.append(point)
        g = grid
        quads.append(np.stack([g[:-1, :-1], g[1:, :-1], g[1:, 1:], g[:-1, 1:]],
                              axis=-1).reshape(-1, 4))
    if not quads:
        raise LayoutError("no quads at this size (every patch collapses): take a smaller "
                          "quad size")
    quads = np.concatenate(quads)
    # glued points: one point each, a corner's, else the boundary's (a singular vertex
    # glued to the boundary goes there), else a model point's, else an interior curve's
    # (a trace glued to an interface goes onto it; trace ends glued along the curve, the
    # mean of theirs), else the singular vertex's, else the mean
    total = len(position)
    root = np.array([pts.find(i) if i < pts.count else i for i in range(total)])
    rank = np.full(total, 5)
    rank[[i for i, key in enumerate(lay.nodes) if key[0] == "v" and key[1] in mc.singular]] = 4
    rank[list(pts.curve_ids())] = 3
    rank[list(pts.model_ids())] = 2
    rank[list(pts.boundary_ids())] = 1
    rank[[i for i, key in enumerate(lay.nodes)
          if key[0] == "v" and mc.on_boundary[key[1]] and mc.quarters(key[1]) != 2]] = 0
    xy = np.array([np.asarray(p, dtype=float) for p in position])
    used, quads = np.unique(root[quads], return_inverse=True)
    quads = quads.reshape(-1, 4)
    best = np.full(total, 6)
    np.minimum.at(best, root, rank)
    chosen = rank == best[root]
    sums = np.zeros((total, 2))
    np.add.at(sums, root[chosen], xy[chosen])
    counts = np.bincount(root[chosen], minlength=total)
    points = sums[used] / counts[used, None]
    # singular vertices glued to the boundary (no corner there), or boundary points
    # (corners) glued together, with no model point or curve point: the boundary point
    # they make has no one place in the map (the mean of the boundary points is off a
    # curved boundary): it goes where its edges follow the boundary best
    special = np.zeros(total, dtype=bool)
    special[list(pts.curve_ids() | pts.model_ids())] = True
    pinned, fan = np.zeros(total, dtype=bool), np.zeros(total, dtype=bool)
    np.logical_or.at(pinned, root, special)
    np.logical_or.at(fan, root, rank == 4)
    free = (((best[used] == 1) & fan[used]) | ((best[used] <= 1) & (counts[used] > 1))) \
        & ~pinned[used]
    points = onto_boundary(points, quads, np.flatnonzero(free), mc.mesh.x, mc.mesh.cells)
    a, b = quads.ravel(), np.roll(quads, -1, axis=1).ravel()
    m = points.shape[0]
    pairs, counts = np.unique(np.minimum(a, b) * m + np.maximum(a, b), return_counts=True)
    once = pairs[counts == 1]
    return QuadMesh(points=points, quads=quads, chains={},
                    boundary=np.stack([once // m, once % m], axis=1)), lost


def _fractions(k: int, h: int, fractions) -> np.ndarray:
    """The positions (fractions of its length, 0 and 1 included) of the k + 1 points of
    half-arc h along its own direction: uniform, or ``fractions[h // 2]`` (of the arc)."""
    inner = fractions[h // 2]
    inner = np.arange(1, k) / k if inner is None else np.asarray(inner, dtype=float)
    f = np.concatenate([[0.0], inner, [1.0]]) if k else np.zeros(1)
    return f if h % 2 == 0 else (1.0 - f)[::-1]


def _side_positions(lay: Layout, n: np.ndarray, side, fractions) -> np.ndarray:
    """The map lengths from a patch side's start of its points (its arcs' points at
    their :func:`_facing_fractions`, else uniform)."""
    pos = [0.0]
    for h in side:
        k = int(n[h // 2])
        at = pos[-1]
        pos += (at + lay.arcs[h // 2].length * _fractions(k, h, fractions)[1:]).tolist()
    return np.array(pos)


def _facing_fractions(lay: Layout, n: np.ndarray) -> list:
    """Per arc the fractions of its length where its inner points go, or None (uniform,
    k/n). An arc that is a whole side by itself (but for zero arcs) of a patch thinner than
    :data:`FACING_BELOW` quads has them across from the opposite side's points (at their
    lengths along that side, scaled to this one), not uniform; of the patches it is such a
    side of (a boundary arc has one, a trace or a curve two), the thinnest (the least
    length across, in the map) sets them, the thinnest patches first (so that a patch whose
    two sides are single arcs passes on the points its thinner neighbour gave one of them).
    A thin patch (one quad across an air gap between the boundary and an interface, or
    between an interface and a trace passing close to it) whose other side is split
    unevenly (the interface's model points, the ends of traces from the other side) would
    otherwise have its quads sheared by up to a quad's length across their thickness. A
    thicker patch keeps them uniform: even spacing in the map is what the map's
    conformality wants there, and points moved by up to a quad along a side several quads
    from the uneven one skewed the quads at it."""
    fractions: list = [None] * len(lay.arcs)
    candidates = []
    for p, sides in enumerate(lay.patches):
        for s, side in enumerate(sides):
            kept = [h for h in side if n[h // 2] > 0]  # zero arcs have no points
            if len(kept) == 1 and n[kept[0] // 2] >= 2:
                thickness = sum(lay.arcs[g // 2].length for g in sides[(s + 1) % 4])
                if thickness < FACING_BELOW:
                    candidates.append((thickness, p, s, kept[0]))
    for _, p, s, h in sorted(candidates):
        sides = lay.patches[p]
        if fractions[h // 2] is not None:
            continue
        across = _side_positions(lay, n, sides[(s + 2) % 4], fractions)
        if across[-1] <= 0:
            continue
        inner = (1.0 - across[::-1] / across[-1])[1:-1]  # along this side, from its start
        fractions[h // 2] = inner if h % 2 == 0 else (1.0 - inner)[::-1]
    return fractions


def quads_of_map(param: Parametrisation,
                 collapse_below: float = COLLAPSE_BELOW) -> tuple[QuadMesh, Layout, np.ndarray]:
    """The quad mesh of the seamless map ``param`` by its T-mesh: its folds smoothed out
    where they can be (:func:`~ufl_frames.quads.layout.untangle`), :func:`~ufl_frames.
    quads.layout.layout`, :func:`integer_lengths` (arcs shorter than ``collapse_below``
    may collapse), :func:`patch_quads`. Returns the quads, the layout and the arc
    lengths."""
    folds = int(np.count_nonzero(folded(param)))
    if folds:
        param, _ = untangle(param)
    lay = layout(param)
    n = integer_lengths(lay, collapse_below=collapse_below)
    quad_mesh, lost = patch_quads(lay, n)
    return (with_features(quad_mesh, param.mesh), replace(lay, untangled=folds, unlocated=lost),
            n)
