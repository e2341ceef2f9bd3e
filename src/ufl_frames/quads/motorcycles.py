r"""The motorcycle graph of a seamless map: the iso-lines through its singular vertices and
its concave boundary corners, traced until they meet (step 2 of the T-mesh layout,
:mod:`ufl_frames.quads.layout`).

From every singular vertex one trace along each of its 4 − turn axis directions (±U, ±V of
its fan, a half-open sector rule per triangle), from every boundary vertex whose fan spans
270° or more one along each axis direction strictly inside the fan (the continuations of
its boundary curves), and from one vertex of every boundary loop that nothing else touches
one across it. Before all of them, the interior curves of the mesh's features
(interfaces, embedded curves: iso-lines of the map) are laid down as traces along their
edges, split at their nodes (model points, ends, junctions), and every node inside the
domain that would leave a face no rectangle (a curve's end, a turn, an embedded point)
launches the traces that continue it (:meth:`Motorcycles.curves`). Each trace is a
straight axis-parallel line in the exact charts of
:func:`~ufl_frames.quads.charts.fixed_point`, followed triangle by triangle in exact
rational arithmetic (a line through a vertex goes on into the fan sector that contains its
direction; across a seam point and direction turn with the transition), and stops at the
boundary, at a singular vertex, or where it first meets an earlier trace or itself (the
motorcycle rule, one trace after the other). Exact coincidences are decided exactly: a
trace that reaches a singular vertex along one of its axis directions takes that
separatrix (it is not traced again), one that runs into an earlier trace along its line
stops where they first touch, one that would repeat an earlier trace from its origin is
empty, and traces that meet at a mesh vertex meet there. A folded triangle (or a singular
vertex whose fan does not hold 4 − turn axis directions) or a trace longer than
``max_steps`` stops it with a failure that the layout reports.

Pure Python integers and fractions in the tracing, NumPy for the topology.
"""

import math
from collections import defaultdict
from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np

from ufl_frames.param.quantise import model_points
from ufl_frames.param.seamless import Parametrisation, curve_edge_ids
from ufl_frames.quads.charts import LayoutError, fixed_point

__all__ = ["AXES", "QUARTER", "Motorcycles", "Trace", "rot"]

#: Rot^k as ((a, b), (c, d)), Rot(U, V) = (V, −U).
_ROT = (((1, 0), (0, 1)), ((0, 1), (-1, 0)), ((-1, 0), (0, -1)), ((0, -1), (1, 0)))
#: The axis directions counter-clockwise, and the quarter index of each.
AXES = ((1, 0), (0, 1), (-1, 0), (0, -1))
QUARTER = {d: k for k, d in enumerate(AXES)}


def rot(k, v):
    (a, b), (c, d) = _ROT[k % 4]
    return (a * v[0] + b * v[1], c * v[0] + d * v[1])


def _cross(a, b):
    return a[0] * b[1] - a[1] * b[0]


def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1])


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
        P: its exact wedge values (:func:`~ufl_frames.quads.charts.fixed_point`); computed
            if not given.
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
            self.shift[f][i] = _sub(pg, rot(j, pf))
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
        self.curve_vertices = set()  # vertices on the features' interior curves: traces stop
        used = np.zeros(n, dtype=bool)
        used[cells.ravel()] = True
        self.model_nodes = {int(v) for v in model_points(mesh) if used[v]}  # layout nodes

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
        q = rot(j, p)
        return g, (q[0] + t[0], q[1] + t[1]), rot(j, d), j

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
                ra = rot(kappa, va)
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
                    back = ((-j) % 4, _sub((0, 0), rot(-j, self.shift[f][i])))
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
                q = rot(k, X)
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
            if (w in self.singular or self.on_boundary[w] or self.visited[w]
                    or w in self.curve_vertices):
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
        """Lay the features' interior curves down as traces (:meth:`curves`), trace every
        separatrix, then every concave corner's continuations, then one line across every
        boundary loop no trace touches. Returns the traces."""
        self.curves()
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

    def curves(self):
        """The interior curves of the mesh's features (interfaces, embedded curves) as
        traces that were there first: every run of curve edges between two nodes (model
        points, ends, junctions, the boundary) one trace along the edges, which later
        traces stop on; then, from every node inside the domain, traces that keep its
        faces rectangles: the continuation of a curve that ends there, of both curves at
        a turn, and a line through an embedded point (two opposite directions)."""
        ids, _ = curve_edge_ids(self.mesh)
        if ids.size == 0 and not self.model_nodes:
            return
        inner = ids[self.mesh.faces[ids, 1] >= 0]
        edges = self.mesh.edges[inner]
        neighbours = defaultdict(list)
        for (a, b), e in zip(edges.tolist(), inner.tolist(), strict=True):
            neighbours[a].append((b, e))
            neighbours[b].append((a, e))
        nodes = {w for w in neighbours if len(neighbours[w]) != 2 or self.on_boundary[w]
                 or w in self.model_nodes or w in self.singular}
        used = set()
        leaving = defaultdict(list)  # node -> (triangle, direction) of the curves leaving it
        starts = sorted(nodes) + sorted(neighbours)  # closed loops: any vertex of theirs
        for w in starts:
            for b, e in neighbours[w]:
                if e in used:
                    continue
                nodes.add(w)
                chain = [w]
                while True:
                    used.add(e)
                    chain.append(b)
                    if b in nodes:
                        break
                    b, e = next(item for item in neighbours[b] if item[1] not in used)
                self._curve_trace(chain, leaving)
        for w in sorted(nodes | (self.model_nodes - set(np.flatnonzero(self.on_boundary)))):
            if self.on_boundary[w] or w in self.singular:
                continue
            self._fill(w, leaving[w])

    def _curve_trace(self, chain, leaving):
        """A trace along the vertices ``chain`` (a run of curve edges), registered."""
        tid = len(self.traces)
        tr = Trace(start=("v", chain[0]), end=("v", chain[-1]), stop="curve")
        self.traces.append(tr)
        for a, b in zip(chain[:-1], chain[1:], strict=True):
            f = next(g for g in self.vertex_faces[a] if b in self.cells[g])
            p0, p1 = tuple(self.pts[f][self.cells[f].index(a)]), \
                tuple(self.pts[f][self.cells[f].index(b)])
            if p0[0] != p1[0] and p0[1] != p1[1]:
                raise LayoutError(f"an interior curve is not an iso-line of the map (edge "
                                  f"{a}–{b})")
            d = (int(np.sign(p1[0] - p0[0])), int(np.sign(p1[1] - p0[1])))
            tr.pieces.append((f, p0, p1, d))
            self.register(tid, len(tr.pieces) - 1, f, p0, p1, d)
            if b != chain[-1]:
                self.visited[b].append((tid, len(tr.pieces) - 1))
                self.curve_vertices.add(b)
        self.curve_vertices.update((chain[0], chain[-1]))
        f0, _, _, d0 = tr.pieces[0]
        f1, _, _, d1 = tr.pieces[-1]
        leaving[chain[0]].append((f0, d0))
        leaving[chain[-1]].append((f1, (-d1[0], -d1[1])))

    def _fill(self, w, leaving):
        """Traces from the inside node w so that the curves leaving it (``leaving``,
        (triangle, direction)) and they leave no gap of more than a half turn: none at a
        straight run or a junction of three, the continuation at an end, both at a turn,
        two opposite at an embedded point."""
        fan = {f: kappa for f, _, kappa in self.fan(w)}
        slots = self.vertex_slots(w)
        if len(slots) != 4:
            raise LayoutError(f"a model vertex {w} has {len(slots)} axis directions in its "
                              "fan (the map folds around it)")
        quarter = [QUARTER[rot(fan[f], d)] for f, d in slots]
        taken = {QUARTER[rot(fan[f], d)] for f, d in leaving}
        if not taken:
            wanted = {quarter[0], (quarter[0] + 2) % 4}
        elif len(taken) == 1:
            wanted = {(q + 2) % 4 for q in taken}
        elif len(taken) == 2 and (max(taken) - min(taken)) % 2 == 1:
            wanted = {(q + 2) % 4 for q in taken}
        else:
            wanted = set()
        for (f, d), q in zip(slots, quarter, strict=True):
            if q in wanted:
                self.trace(f, self.pts[f][self.cells[f].index(w)], d, ("v", w))

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
