r"""The T-mesh (motorcycle graph) of a seamless map, and its patches and arcs: the layout
of a quantisation that cannot fold by construction (the idea of Quantized Global
Parametrization, Campen–Bommes–Kobbelt 2015; :mod:`ufl_frames.quads.patches` gives the
arcs integer lengths and fills the patches with quads).

The seamless map (U, V) of :func:`~ufl_frames.param.seamless.integrate` is affine on every
triangle, and across a cut edge the neighbour's chart is (U, V)_g = Rot^j (U, V)_f + t. Its
iso-lines through the singular vertices and the concave boundary corners cut the domain
into rectangles of the parameter plane:

1. **exact charts** (:func:`fixed_point`): the wedge values in fixed point (``UNIT`` per
   unit of the map) as x = T y with T the seamless constraints' elimination and y rounded,
   so that every seam's transition and every boundary curve's constant coordinate hold
   exactly in integers;
2. **traces** (:class:`Motorcycles`): from every singular vertex one trace along each of
   its 4 − turn axis directions (±U, ±V of its fan, a half-open sector rule per triangle),
   from every boundary vertex whose fan spans 270° or more one along each axis direction
   strictly inside the fan (the continuations of its boundary curves), and from one vertex
   of every boundary loop that nothing else touches one across it. Each trace is a straight
   axis-parallel line, followed triangle by triangle in exact rational arithmetic (a line
   through a vertex goes on into the fan sector that contains its direction; across a seam
   point and direction turn with the transition), and stops at the boundary, at a singular
   vertex, or where it first meets an earlier trace or itself (the motorcycle rule, one
   trace after the other). Exact coincidences are decided exactly: a trace that reaches a
   singular vertex along one of its axis directions takes that separatrix (it is not
   traced again), one that runs into an earlier trace along its line stops where they
   first touch, one that would repeat an earlier trace from its origin is empty, and
   traces that meet at a mesh vertex meet there. A folded triangle (or a singular vertex
   whose fan does not hold 4 − turn axis directions) or a trace longer than
   ``max_steps`` stops it with a failure that the layout reports;
3. **patches and arcs** (:func:`layout`): the traces and boundary curves split at their
   meeting points are the arcs (graph edges); at every node the arcs' directions in
   quarter turns (unwrapped around a vertex's fan); the faces traced by turning left. A
   face whose corners are four of 90° and the rest 180° is a rectangle in the parameter
   plane: its four sides are runs of arcs;
4. integer arc lengths and the quads of every patch: :mod:`ufl_frames.quads.patches`.

Pure NumPy/SciPy (Python integers and fractions in the tracing).
"""

import math
from collections import defaultdict
from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np
import scipy.sparse as sp

from ufl_frames.param.seamless import (
    Parametrisation,
    least_squares_system,
    parametrisation,
    quarter_turn,
)

__all__ = ["Arc", "Layout", "LayoutError", "Motorcycles", "Trace", "fixed_point", "layout",
           "untangle"]

#: Fixed-point units per unit of the map.
UNIT = 2**20

#: Rot^k as ((a, b), (c, d)), Rot(U, V) = (V, −U).
_ROT = (((1, 0), (0, 1)), ((0, 1), (-1, 0)), ((-1, 0), (0, -1)), ((0, -1), (1, 0)))
#: The axis directions counter-clockwise, and the quarter index of each.
AXES = ((1, 0), (0, 1), (-1, 0), (0, -1))
_QUARTER = {d: k for k, d in enumerate(AXES)}


class LayoutError(RuntimeError):
    """The map's traces do not give a layout of rectangles (folds, endless traces, faces
    that are not rectangles, or no integer lengths)."""


def _rot(k, v):
    (a, b), (c, d) = _ROT[k % 4]
    return (a * v[0] + b * v[1], c * v[0] + d * v[1])


def _cross(a, b):
    return a[0] * b[1] - a[1] * b[0]


def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1])


def fixed_point(param: Parametrisation, T=None, unit: int = UNIT) -> np.ndarray:
    """The wedge values as exact integers: x = T y with T the seamless constraints'
    elimination (``least_squares_system``; its entries are halves where a singular vertex
    is in them) and y the free values rounded to a multiple of T's denominator, so that
    every seam's transition and every boundary curve hold exactly.

    Args:
        param: the seamless map (its values less those of wedge 0).
        T: the elimination, if the caller has it (else built again).
        unit: fixed-point units per unit of the map.

    Returns:
        (W, 2) int64. Raises :class:`LayoutError` if the map is not seamless.
    """
    mesh = param.mesh
    if T is None:
        _, _, T = least_squares_system(mesh, param.scale, 0)
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


class _Incidence:
    """The triangles of every vertex (``incidence[v]``, a list), from one sort."""

    def __init__(self, cells, n):
        order = np.argsort(cells.ravel(), kind="stable")
        self.faces = order // 3
        self.start = np.searchsorted(cells.ravel()[order], np.arange(n + 1))

    def __getitem__(self, v):
        return self.faces[self.start[v]:self.start[v + 1]].tolist()


@dataclass
class Trace:
    """One traced iso-line: ``pieces`` (triangle, start, end, direction) in the triangle's
    chart (exact fractions), its start and end node keys, how it ended (``stop``:
    'boundary', 'singular', 'trace', 'fold', 'limit', 'empty'), and its ``splits``
    (piece, position along the piece's line, node key) where later traces met it."""

    start: tuple
    pieces: list = field(default_factory=list)
    end: tuple | None = None
    stop: str = ""
    splits: list = field(default_factory=list)


class Motorcycles:
    """The motorcycle graph of a seamless map (see the module text, step 2).

    Args:
        param: the seamless map.
        P: its exact wedge values (:func:`fixed_point`); computed if not given.
        max_steps: the most triangles one trace may cross.
    """

    def __init__(self, param: Parametrisation, P=None, max_steps: int | None = None):
        mesh = self.mesh = param.mesh
        self.P = fixed_point(param) if P is None else P
        cells = mesh.cells
        m, n = cells.shape[0], mesh.x.shape[0]
        self.max_steps = max_steps or 20 * m + 100
        Pc = self.P[mesh.corners]
        # nested lists (tolist is fast); points taken from them become tuples
        self.pts = Pc.tolist()
        self.cells = cells.tolist()
        self.float_pts = Pc.astype(float).tolist()
        self.float_x = mesh.x[cells].tolist()
        # neighbours across local edge i (opposite corner i), and the transition there
        ends = cells[:, [[1, 2], [2, 0], [0, 1]]]
        keys = mesh.edges[:, 0] * n + mesh.edges[:, 1]
        self.edge_id = np.searchsorted(keys, ends.min(axis=2) * n + ends.max(axis=2))
        faces = mesh.faces[self.edge_id]  # (m, 3, 2)
        nb = np.where(faces[..., 0] == np.arange(m)[:, None], faces[..., 1], faces[..., 0])
        self.nb = nb.tolist()
        self.turn = np.zeros((m, 3), dtype=np.int64).tolist()
        self.shift = np.zeros((m, 3, 2), dtype=np.int64).tolist()
        in_cut = np.zeros(mesh.edges.shape[0], dtype=bool)
        in_cut[mesh.cut] = True
        for f, i in zip(*np.nonzero(in_cut[self.edge_id]), strict=True):
            f, i = int(f), int(i)
            g = self.nb[f][i]
            a = self.cells[f][(i + 1) % 3]
            k = self.cells[g].index(a)
            j = int(mesh.jump[self.edge_id[f, i]])
            if mesh.faces[self.edge_id[f, i], 0] != f:
                j = -j
            pf, pg = self.pts[f][(i + 1) % 3], self.pts[g][k]
            self.turn[f][i] = j % 4
            self.shift[f][i] = _sub(pg, _rot(j, pf))
        boundary = mesh.faces[:, 1] < 0
        self.on_boundary = np.zeros(n, dtype=bool)
        self.on_boundary[mesh.edges[boundary].ravel()] = True
        self.singular = {int(v): int(t) for v, t in zip(mesh.singular, mesh.turns, strict=True)}
        self.vertex_faces = _Incidence(cells, n)
        det = ((Pc[:, 1, 0] - Pc[:, 0, 0]) * (Pc[:, 2, 1] - Pc[:, 0, 1])
               - (Pc[:, 1, 1] - Pc[:, 0, 1]) * (Pc[:, 2, 0] - Pc[:, 0, 0]))
        self.folded = det <= 0
        self.segments = defaultdict(list)  # triangle -> registered pieces
        self.visited = defaultdict(list)  # vertex -> (trace, piece ending there)
        self.traces: list[Trace] = []
        self.taken = set()  # separatrix slots (vertex, triangle, direction) already used
        self.slots = {}  # vertex -> its slots (triangle, direction) counter-clockwise

    # ---- fans -------------------------------------------------------------------------
    def cross_edge(self, f, i, p, d):
        """Across local edge i of triangle f.

        Args:
            f, i: the triangle and its local edge (opposite corner i).
            p, d: a point and a direction in f's chart.

        Returns:
            (g, p, d, j): the neighbour (−1: boundary), p and d in its chart, and the
            quarter turns j of the transition from f's chart to g's.
        """
        g, j, t = self.nb[f][i], self.turn[f][i], self.shift[f][i]
        q = _rot(j, p)
        return g, (q[0] + t[0], q[1] + t[1]), _rot(j, d), j

    def fan(self, w, start=None):
        """The triangles around vertex w counter-clockwise: (triangle, local index of w,
        quarter turns from its chart to the first one's). A boundary vertex's fan starts
        at its forward boundary edge; an interior one's at ``start`` (or any)."""
        faces = self.vertex_faces[w]
        if self.on_boundary[w]:
            first = [f for f in faces
                     if self.nb[f][(self.cells[f].index(w) + 2) % 3] < 0]
            if len(first) != 1:
                raise LayoutError(f"boundary vertex {w} is not manifold")
            f = first[0]
        else:
            f = faces[0] if start is None else start
        out, kappa = [], 0
        for _ in range(len(faces)):
            loc = self.cells[f].index(w)
            out.append((f, loc, kappa))
            i = (loc + 1) % 3  # the edge (w, b), b the corner after a
            g = self.nb[f][i]
            if g < 0 or (g == out[0][0] and not self.on_boundary[w]):
                break
            kappa = (kappa - self.turn[f][i]) % 4
            f = g
        return out

    def sector(self, f, loc):
        """The two edge vectors (a − w, b − w) of triangle f at its corner ``loc``."""
        A = self.pts[f]
        w = A[loc]
        return _sub(A[(loc + 1) % 3], w), _sub(A[(loc + 2) % 3], w)

    def in_sector(self, f, loc, d, strict_first=False):
        """Whether direction d leaves triangle f's corner ``loc`` into the triangle: the
        half-open sector from its first edge (included, unless ``strict_first``; the
        trace then runs along that edge with the triangle on its left) to its second.

        Args:
            f, loc: the triangle and its corner.
            d: an axis direction in f's chart.
            strict_first: exclude the first edge (a boundary edge).

        Returns:
            bool.
        """
        va, vb = self.sector(f, loc)
        c = _cross(va, d)
        return (c > 0 or (c == 0 and not strict_first and va[0] * d[0] + va[1] * d[1] > 0)) \
            and _cross(d, vb) > 0

    def fan_angles(self, w, start=None):
        """Per fan triangle its start angle (radians, unwrapped, in the first triangle's
        chart turned by its quarter turns) and the total."""
        fan = self.fan(w, start)
        theta, out = None, []
        for f, loc, kappa in fan:
            va, vb = self.sector(f, loc)
            angle = math.atan2(_cross(va, vb), va[0] * vb[0] + va[1] * vb[1])
            if theta is None:
                ra = _rot(kappa, va)
                theta = math.atan2(ra[1], ra[0])
            out.append((f, loc, kappa, theta))
            theta += angle
        return out, theta - out[0][3]

    def vertex_slots(self, w):
        """The axis directions leaving vertex w (triangle, direction), counter-clockwise:
        a singular vertex's 4 − turn separatrices; a boundary vertex's directions strictly
        inside its fan."""
        slots = []
        for index, (f, loc, _) in enumerate(self.fan(w)):
            first = bool(self.on_boundary[w]) and index == 0  # not along the boundary
            slots += [(f, d) for d in AXES if self.in_sector(f, loc, d, strict_first=first)]
        return slots

    def quarters(self, w):
        """The fan angle of vertex w in quarter turns (rounded)."""
        return round(self.fan_angles(w)[1] / (math.pi / 2))

    # ---- tracing ----------------------------------------------------------------------
    def node_key(self, f, X):
        """The canonical name of the point X (fractions) of triangle f's chart: a vertex,
        (edge, t from its smaller vertex), or (triangle, X)."""
        A = self.pts[f]
        for k in range(3):
            if A[k][0] == X[0] and A[k][1] == X[1]:
                return ("v", self.cells[f][k])
        for i in range(3):
            a, b = A[(i + 1) % 3], A[(i + 2) % 3]
            if _cross(_sub(b, a), _sub(X, a)) == 0:
                va, vb = self.cells[f][(i + 1) % 3], self.cells[f][(i + 2) % 3]
                if va > vb:
                    a, b = b, a
                c = 0 if b[0] != a[0] else 1
                return ("e", int(self.edge_id[f, i]), Fraction(X[c] - a[c], b[c] - a[c]))
        return ("f", f, (Fraction(X[0]), Fraction(X[1])))

    def register(self, tid, index, f, p0, p1, d):
        """Record piece ``index`` of trace ``tid`` (p0 → p1 along d in triangle f's chart)
        for the later traces' meeting tests; a piece along an edge in the neighbour too.

        Args:
            tid, index: the trace and the piece.
            f: the triangle.
            p0, p1, d: the piece's ends and direction in f's chart.
        """
        c = 0 if d[0] == 0 else 1  # the constant coordinate
        o = 1 - c
        lo, hi = min(p0[o], p1[o]), max(p0[o], p1[o])
        self.segments[f].append((tid, index, c, p0[c], lo, hi, 0, (0, 0)))
        # a piece along an edge is in the neighbour's triangle too
        keys = (self.node_key(f, p0), self.node_key(f, p1))
        if keys[0][0] == "v" and keys[1][0] == "v":
            va, vb = keys[0][1], keys[1][1]
            tri = self.cells[f]
            if va in tri and vb in tri and va != vb:
                i = 3 - tri.index(va) - tri.index(vb)
                if self.nb[f][i] >= 0:
                    g, q0, dd, j = self.cross_edge(f, i, p0, d)
                    _, q1, _, _ = self.cross_edge(f, i, p1, d)
                    cg = 0 if dd[0] == 0 else 1
                    og = 1 - cg
                    back = ((-j) % 4, _sub((0, 0), _rot(-j, self.shift[f][i])))
                    self.segments[g].append((tid, index, cg, q0[cg], min(q0[og], q1[og]),
                                             max(q0[og], q1[og])) + back)

    def hits(self, tid, f, p0, p1, d, origin):
        """The nearest point of (p0, p1] where a recorded piece meets this one; at the
        trace's origin a collinear overlap counts (the trace repeats an earlier one: it
        is empty).

        Args:
            tid: this trace.
            f: the triangle.
            p0, p1, d: this piece's ends and direction in f's chart.
            origin: whether p0 is the trace's origin.

        Returns:
            None, or (distance, trace met, its piece, the point in that piece's chart, the
            point in f's chart).
        """
        c = 0 if d[0] == 0 else 1
        o = 1 - c
        sigma, level = d[o], p0[c]
        a0, a1 = p0[o], p1[o]
        best = None
        for tid2, index, c2, level2, lo2, hi2, k, t in self.segments[f]:
            if c2 != c:
                pos = level2
                if sigma * (pos - a0) < 0 or sigma * (a1 - pos) < 0 or not lo2 <= level <= hi2:
                    continue
                if pos == a0:
                    continue
            else:
                if level2 != level:
                    continue
                lo, hi = max(lo2, min(a0, a1)), min(hi2, max(a0, a1))
                if lo > hi:
                    continue
                pos = lo if sigma > 0 else hi
                if pos == a0 and not (lo < hi and origin):
                    continue
            distance = sigma * (pos - a0)
            if best is None or distance < best[0]:
                X = [None, None]
                X[c], X[o] = level, pos
                q = _rot(k, X)
                best = (distance, tid2, index, (q[0] + t[0], q[1] + t[1]), tuple(X))
        return best

    def trace(self, f, p, d, start_key):
        """Trace one iso-line (see the class text) and record it.

        Args:
            f: the triangle it starts into.
            p, d: its origin and axis direction in f's chart.
            start_key: the origin's node key.

        Returns:
            The :class:`Trace` (``stop`` says how it ended).
        """
        tid = len(self.traces)
        p = tuple(p)
        tr = Trace(start=start_key)
        self.traces.append(tr)
        origin = True
        for _ in range(self.max_steps):
            if self.folded[f]:
                tr.stop, tr.end = "fold", ("f", f, p)
                return tr
            A = self.pts[f]
            side = [_cross(d, _sub(A[k], p)) for k in range(3)]
            exit_edge = next((i for i in range(3)
                              if side[(i + 1) % 3] < 0 < side[(i + 2) % 3]), None)
            c = 0 if d[0] == 0 else 1
            o = 1 - c
            if exit_edge is not None:
                a, b = A[(exit_edge + 1) % 3], A[(exit_edge + 2) % 3]
                lam = Fraction(p[c] - a[c], b[c] - a[c])
                q = [None, None]
                q[c], q[o] = p[c], a[o] + lam * (b[o] - a[o])
                q, vertex = tuple(q), None
            else:
                ahead = [(d[0] * (A[k][0] - p[0]) + d[1] * (A[k][1] - p[1]), k)
                         for k in range(3) if side[k] == 0]
                ahead = [t for t in ahead if t[0] > 0]
                if not ahead:
                    tr.stop, tr.end = "fold", ("f", f, p)
                    return tr
                vertex = max(ahead)[1]
                q = tuple(A[vertex])
            hit = self.hits(tid, f, p, q, d, origin)
            if hit is not None:
                _, tid2, index, own, X = hit
                key = self.node_key(f, X)
                self.traces[tid2].splits.append((index, own, key))
                if X != tuple(p) or not origin:
                    tr.pieces.append((f, tuple(p), X, d))
                    self.register(tid, len(tr.pieces) - 1, f, p, X, d)
                tr.stop, tr.end = ("trace", key) if tr.pieces else ("empty", start_key)
                if key[0] == "v":
                    self._arrive(tr, key[1])
                return tr
            tr.pieces.append((f, tuple(p), q, d))
            self.register(tid, len(tr.pieces) - 1, f, p, q, d)
            origin = False
            if vertex is None:
                if self.nb[f][exit_edge] < 0:
                    tr.stop, tr.end = "boundary", self.node_key(f, q)
                    return tr
                f, p, d, _ = self.cross_edge(f, exit_edge, q, d)
                continue
            w = self.cells[f][vertex]
            if w in self.singular or self.on_boundary[w] or self.visited[w]:
                tr.stop = "singular" if w in self.singular else (
                    "boundary" if self.on_boundary[w] else "trace")
                tr.end = ("v", w)
                for tid2, index in self.visited[w]:
                    self.traces[tid2].splits.append((index, None, ("v", w)))
                self._arrive(tr, w)
                return tr
            self.visited[w].append((tid, len(tr.pieces) - 1))
            # on into the fan sector that holds d
            g, loc, dd = f, vertex, d
            for _ in range(len(self.vertex_faces[w]) + 1):
                i = (loc + 2) % 3  # clockwise: across the edge (w, a)
                g, _, dd, _ = self.cross_edge(g, i, (0, 0), dd)
                loc = self.cells[g].index(w)
                if self.in_sector(g, loc, dd):
                    break
            else:
                tr.stop, tr.end = "fold", ("v", w)
                return tr
            f, p, d = g, tuple(self.pts[g][loc]), dd
        tr.stop, tr.end = "limit", ("f", f, p)
        return tr

    def _arrive(self, tr, w):
        """A trace ending at singular vertex w takes the separatrix slot it runs along."""
        if w not in self.singular or not tr.pieces:
            return
        f, _, _, d = tr.pieces[-1]
        back = (-d[0], -d[1])
        loc = self.cells[f].index(w)
        g = f
        for _ in range(len(self.vertex_faces[w]) + 1):
            if self.in_sector(g, loc, back):
                self.taken.add((w, g, back))
                return
            g, _, back, _ = self.cross_edge(g, (loc + 2) % 3, (0, 0), back)
            loc = self.cells[g].index(w)

    def run(self, extra_loops=True):
        """Trace every separatrix, then every concave corner's continuations, then one
        line across every boundary loop no trace touches. Returns the traces."""
        for w in sorted(self.singular):
            slots = self.vertex_slots(w)
            if len(slots) != 4 - self.singular[w]:
                raise LayoutError(f"singular vertex {w} of turn {self.singular[w]} has "
                                  f"{len(slots)} axis directions in its fan (the map folds "
                                  "around it)")
            self.slots[w] = slots
            for f, d in slots:
                if (w, f, d) in self.taken:
                    continue
                self.taken.add((w, f, d))
                self.trace(f, self.pts[f][self.cells[f].index(w)], d, ("v", w))
        boundary = np.flatnonzero(self.on_boundary)
        for w in boundary.tolist():
            if self.quarters(w) >= 3:
                for f, d in self.vertex_slots(w):
                    self.trace(f, self.pts[f][self.cells[f].index(w)], d, ("v", w))
        if extra_loops:
            for loop in self.boundary_loops():
                if any(self._is_node(w) for w, _, _ in loop) or self._touched(loop):
                    continue
                w = loop[0][0]
                for f, d in self.vertex_slots(w):
                    self.trace(f, self.pts[f][self.cells[f].index(w)], d, ("v", w))
        return self.traces

    def _is_node(self, w):
        return self.quarters(w) != 2 or any(
            t.start == ("v", w) or t.end == ("v", w) for t in self.traces)

    def _touched(self, loop):
        edges = {int(self.edge_id[f, i]) for _, f, i in loop}
        return any(t.end and t.end[0] == "e" and t.end[1] in edges for t in self.traces)

    def boundary_loops(self):
        """The boundary loops, each a list of (vertex, triangle, local edge) of its edges
        in order (the domain on the left), starting at the edge leaving that vertex."""
        done, loops = set(), []
        for w in np.flatnonzero(self.on_boundary).tolist():
            if w in done:
                continue
            loop, v = [], w
            while v not in done:
                done.add(v)
                f, loc, _ = self.fan(v)[0]
                i = (loc + 2) % 3
                loop.append((v, f, i))
                v = self.cells[f][(loc + 1) % 3]
            loops.append(loop)
        return loops


# ---- patches and arcs ---------------------------------------------------------------------
@dataclass
class Arc:
    """A graph edge of the layout: ``pieces`` (triangle, start, end, direction) along it
    in the triangles' charts, its end nodes, its length in the map, whether it is a piece
    of the boundary (then the domain is on its left)."""

    pieces: list
    start: int
    end: int
    length: float
    boundary: bool


@dataclass
class Layout:
    """The T-mesh: ``arcs``; ``nodes`` (their keys); ``patches``, each its four sides
    counter-clockwise, a side a list of half-arcs (2 a: arc a forwards, 2 a + 1
    backwards); the ``traces``; ``motorcycles`` the tracer (charts and topology);
    ``folded`` the triangles where the map folds (no trace crosses them, but the quads
    of their patch may be poor there); ``unlocated`` how many quad points
    :func:`~ufl_frames.quads.patches.patch_quads` could not find in the map (lost in a
    fold: placed approximately); ``untangled`` how many triangles folded before
    :func:`untangle` (:func:`~ufl_frames.quads.patches.quads_of_map` does it first)."""

    arcs: list
    nodes: list
    patches: list
    traces: list
    motorcycles: Motorcycles
    folded: np.ndarray
    unlocated: int = 0
    untangled: int = 0

    def lengths(self) -> np.ndarray:
        return np.array([a.length for a in self.arcs])


def _piece_length(piece):
    _, p0, p1, d = piece
    o = 0 if d[1] == 0 else 1
    return abs(p1[o] - p0[o])


def _cut_pieces(pieces, cuts):
    """The pieces between consecutive arc-length positions ``cuts`` (0 < ... < total)."""
    out, current, at = [], [], Fraction(0)
    cuts = list(cuts)
    for f, p0, p1, d in pieces:
        length = _piece_length((f, p0, p1, d))
        start = p0
        while cuts and cuts[0] <= at + length:  # no piece of length 0 at a cut
            s = cuts.pop(0) - at
            X = (p0[0] + s * d[0], p0[1] + s * d[1])
            if X != start:
                current.append((f, start, X, d))
            out.append(current)
            current, start = [], X
        if start != p1:
            current.append((f, start, p1, d))
        at += length
    out.append(current)
    return out


def layout(param: Parametrisation, motorcycles: Motorcycles | None = None) -> Layout:
    """The T-mesh of the seamless map ``param``: traces (:class:`Motorcycles`), arcs and
    rectangular patches (see the module text, step 3). Raises :class:`LayoutError` where a
    trace fails (a fold, an endless trace) or a face is not a rectangle."""
    mc = motorcycles or Motorcycles(param)
    traces = mc.traces if mc.traces else mc.run()
    failed = [t for t in traces if t.stop in ("fold", "limit")]
    if failed:
        x = mc.mesh.x
        where = [x[t.end[1]] if t.end[0] == "v" else x[mc.cells[t.end[1]]].mean(axis=0)
                 for t in failed]
        what = "; ".join(
            ("one enters a folded triangle" if t.stop == "fold" else
             f"one does not end within {mc.max_steps} triangles")
            + f" near ({p[0]:.4g}, {p[1]:.4g})" for t, p in zip(failed[:3], where, strict=False))
        raise LayoutError(f"{len(failed)} of {len(traces)} traces failed ({what}); the "
                          f"seamless map folds on {int(mc.folded.sum())} triangles")
    node_id: dict = {}

    def node(key):
        return node_id.setdefault(key, len(node_id))

    arcs = []
    for t in traces:
        if not t.pieces:
            continue
        starts = np.cumsum([Fraction(0)] + [_piece_length(p) for p in t.pieces])
        total = starts[-1]
        positions = {}
        for index, own, key in t.splits:
            _, p0, p1, d = t.pieces[index]
            if own is None:
                s = starts[index + 1]
            else:
                o = 0 if d[1] == 0 else 1
                s = starts[index] + abs(own[o] - p0[o])
            if 0 < s < total:
                positions[s] = key
        cuts = sorted(positions)
        keys = [t.start] + [positions[s] for s in cuts] + [t.end]
        for k, pieces in enumerate(_cut_pieces(t.pieces, cuts)):
            arcs.append(Arc(pieces, node(keys[k]), node(keys[k + 1]),
                            float(sum(_piece_length(p) for p in pieces)) / UNIT, False))
    # boundary arcs: the loops split at corners and where traces start or end
    ends_on = defaultdict(list)
    for key in node_id:
        if key[0] == "e":
            ends_on[key[1]].append(key[2])
    for loop in mc.boundary_loops():
        events = []  # (position in loop, key)
        for index, (v, f, i) in enumerate(loop):
            if ("v", v) in node_id or mc.quarters(v) != 2:
                events.append((index, Fraction(0), ("v", v)))
            e = int(mc.edge_id[f, i])
            forward = mc.cells[f][(i + 1) % 3] < mc.cells[f][(i + 2) % 3]
            for t in sorted(s if forward else 1 - s for s in ends_on.get(e, ())):
                events.append((index, t, ("e", e, t if forward else 1 - t)))
        if not events:
            raise LayoutError("a boundary loop has no corner and no trace")
        for k, (index, s, key) in enumerate(events):
            index2, s2, key2 = events[(k + 1) % len(events)]
            pieces, at, stop = [], (index, s), (index2, s2)
            first = True
            while first or at != stop:
                first = False
                j, s0 = at
                _, f, i = loop[j]
                a, b = mc.pts[f][(i + 1) % 3], mc.pts[f][(i + 2) % 3]
                if a[0] != b[0] and a[1] != b[1]:
                    raise LayoutError("a boundary edge is not on an iso-line of the map")
                d = (int(np.sign(b[0] - a[0])), int(np.sign(b[1] - a[1])))
                if j == index2 and s0 < s2:  # the next event is on this edge
                    s1, at = s2, stop
                else:
                    s1, at = Fraction(1), ((j + 1) % len(loop), Fraction(0))
                X0 = (a[0] + s0 * (b[0] - a[0]), a[1] + s0 * (b[1] - a[1]))
                X1 = (a[0] + s1 * (b[0] - a[0]), a[1] + s1 * (b[1] - a[1]))
                if X0 != X1:
                    pieces.append((f, X0, X1, d))
            arcs.append(Arc(pieces, node(key), node(key2),
                            float(sum(_piece_length(p) for p in pieces)) / UNIT, True))
    nodes = list(node_id)
    try:
        ends, total = _node_ends(mc, arcs, nodes)
        patches = _faces(arcs, ends, total)
    except LayoutError as e:
        if not mc.folded.any():
            raise
        raise LayoutError(f"{e} (the seamless map folds on {int(mc.folded.sum())} "
                          "triangles)") from e
    return Layout(arcs=arcs, nodes=nodes, patches=patches, traces=traces, motorcycles=mc,
                  folded=np.flatnonzero(mc.folded))


def _node_ends(mc, arcs, nodes):
    """The ends of the arcs at every node, ordered counter-clockwise.

    Args:
        mc: the tracer.
        arcs: the arcs.
        nodes: the node keys.

    Returns:
        (ends, total): per node its [(quarter turns, half-arc leaving it)] sorted (turns
        unwrapped around a vertex's fan), and its cyclic total in quarter turns (None on
        the boundary: no turning past the outside).
    """
    leaving = defaultdict(list)  # node -> (triangle, direction, half-arc)
    for a, arc in enumerate(arcs):
        f0, _, _, d0 = arc.pieces[0]
        f1, _, _, d1 = arc.pieces[-1]
        leaving[arc.start].append((f0, d0, 2 * a))
        leaving[arc.end].append((f1, (-d1[0], -d1[1]), 2 * a + 1))
    ends, total = {}, {}
    for n, key in enumerate(nodes):
        items = leaving[n]
        if key[0] == "v":
            w = key[1]
            fan, angle = mc.fan_angles(w)
            where = {f: (kappa, theta) for f, _, kappa, theta in fan}
            out = []
            for f, d, h in items:
                kappa, theta = where[f]
                r = _rot(kappa, d)
                phi = math.atan2(r[1], r[0])
                phi += 2 * math.pi * math.ceil((theta - 1e-9 - phi) / (2 * math.pi))
                out.append((round(phi / (math.pi / 2)), h))
            total[n] = None if mc.on_boundary[w] else round(angle / (math.pi / 2))
        else:
            if key[0] == "e":
                e = key[1]
                ref = int(mc.mesh.faces[e, 0])
            else:
                ref = key[1]
            out = []
            for f, d, h in items:
                if f != ref:
                    i = [int(x) for x in mc.edge_id[f]].index(key[1])
                    d = _rot(mc.turn[f][i], d)
                out.append((_QUARTER[d], h))
            total[n] = 4
            if key[0] == "e" and mc.mesh.faces[key[1], 1] < 0:
                # a boundary point: forward boundary direction first, no wrap
                forward = next(k for k, h in out if h % 2 == 0 and arcs[h // 2].boundary)
                out = [((k - forward) % 4, h) for k, h in out]
                out = [(2 if (h % 2 == 1 and arcs[h // 2].boundary) else k, h)
                       for k, h in out]
                total[n] = None
        ends[n] = sorted(out)
    return ends, total


def _faces(arcs, ends, total):
    """The faces, traced by turning left at every node; each must be a rectangle: four
    corners of a quarter turn, the others straight.

    Args:
        arcs: the arcs (boundary arcs are walked forwards only).
        ends, total: of :func:`_node_ends`.

    Returns:
        Per patch its four sides (lists of half-arcs), counter-clockwise. Raises
        :class:`LayoutError` where a face is not a rectangle.
    """
    where = {}
    for n, items in ends.items():
        for rank, (_, h) in enumerate(items):
            where[h] = (n, rank)
    seen, patches, bad = set(), [], []
    for h0 in range(2 * len(arcs)):
        if h0 in seen or (h0 % 2 == 1 and arcs[h0 // 2].boundary):
            continue
        cycle, h = [], h0
        while h not in seen:
            seen.add(h)
            n, rank = where[h ^ 1]  # arriving at n along h: its twin leaves n
            items = ends[n]
            if total[n] is None and rank == 0:
                raise LayoutError("a face turns past the outside of the domain")
            k_in = items[rank][0]
            k_out, nxt = items[rank - 1]
            angle = (k_in - k_out) if total[n] is None else (k_in - k_out) % total[n]
            if angle == 0 and total[n] is not None:
                angle = total[n]
            cycle.append((h, angle))
            h = nxt
        if h != h0:
            raise LayoutError("the faces of the traces do not close")
        corners = [k for k, (_, angle) in enumerate(cycle) if angle == 1]
        if len(corners) != 4 or any(angle not in (1, 2) for _, angle in cycle):
            bad.append([angle for _, angle in cycle])
            continue
        start = (corners[-1] + 1) % len(cycle)
        cycle = cycle[start:] + cycle[:start]
        sides, side = [], []
        for h, angle in cycle:
            side.append(h)
            if angle == 1:
                sides.append(side)
                side = []
        patches.append(sides)
    if bad:
        raise LayoutError(f"{len(bad)} faces of the traces are not rectangles (corner "
                          f"quarter turns {bad[:3]})")
    return patches


def untangle(param: Parametrisation, rounds: int = 200, rings: int = 3):
    """The seamless map with its folds smoothed out where it can: every interior vertex
    (not singular) within ``rings`` rings of a folded triangle moved, ``rounds`` times at
    most, to the mean of its neighbours in its own chart (all its wedges together, each
    by its transition, so the map stays seamless; the boundary and the singular vertices
    stay): a Tutte-like relaxation of the folded region.

    Args:
        param: the seamless map.
        rounds: the most relaxation sweeps.
        rings: how far around the folded triangles vertices move.

    Returns:
        (the new map, the number of triangles still folded).
    """
    mesh = param.mesh
    cells, corners = mesh.cells, mesh.corners
    uv = param.uv.copy()

    def folded_now():
        C = uv[corners]
        return ((C[:, 1, 0] - C[:, 0, 0]) * (C[:, 2, 1] - C[:, 0, 1])
                - (C[:, 1, 1] - C[:, 0, 1]) * (C[:, 2, 0] - C[:, 0, 0])) <= 0

    bad = folded_now()
    if not bad.any():
        return param, 0
    mc = Motorcycles(param, P=np.zeros((mesh.num_wedges, 2), dtype=np.int64))
    region = np.zeros(mesh.x.shape[0], dtype=bool)
    region[cells[bad].ravel()] = True
    for _ in range(rings):
        region[cells[region[cells].any(axis=1)].ravel()] = True
    region &= ~mc.on_boundary
    region[mesh.singular] = False
    # per vertex: (its wedge, the other two corners' wedges, rotation to the fan's first)
    fans = [(v, [(int(corners[f, loc]), int(corners[f, (loc + 1) % 3]),
                  int(corners[f, (loc + 2) % 3]), quarter_turn(kappa))
                 for f, loc, kappa in mc.fan(v)]) for v in np.flatnonzero(region).tolist()]
    for sweep in range(rounds):
        for _, fan in fans:
            ref = uv[fan[0][0]]
            total, shifts = np.zeros(2), {}
            for w, a, b, R in fan:
                t = ref - R @ uv[w]  # the transition of this wedge's chart to the first's
                shifts[w] = (R, t)
                total += R @ (uv[a] + uv[b]) + 2 * t
            mean = total / (2 * len(fan))
            for w, (R, t) in shifts.items():
                uv[w] = R.T @ (mean - t)
        if sweep % 10 == 9 and not folded_now().any():
            break
    return parametrisation(mesh, uv, param.scale), int(np.count_nonzero(folded_now()))
