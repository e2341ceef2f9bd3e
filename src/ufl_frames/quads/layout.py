r"""The T-mesh (motorcycle graph) of a seamless map, and its patches and arcs: the layout
of a quantisation that cannot fold by construction (the idea of Quantized Global
Parametrization, Campen–Bommes–Kobbelt 2015; :mod:`ufl_frames.quads.patches` gives the
arcs integer lengths and fills the patches with quads).

The seamless map (U, V) of :func:`~ufl_frames.param.seamless.integrate` is affine on every
triangle, and across a cut edge the neighbour's chart is (U, V)_g = Rot^j (U, V)_f + t. Its
iso-lines through the singular vertices and the concave boundary corners cut the domain
into rectangles of the parameter plane:

1. **exact charts** (:func:`~ufl_frames.quads.charts.fixed_point`): the wedge values
   as integers, every seam's transition and boundary curve exact;
2. **traces** (:class:`~ufl_frames.quads.motorcycles.Motorcycles`): the motorcycle
   graph, the iso-lines from the singular vertices and the concave corners traced in
   exact arithmetic until they meet;
3. **patches and arcs** (:func:`layout`): the traces and boundary curves split at their
   meeting points are the arcs (graph edges); at every node the arcs' directions in
   quarter turns (unwrapped around a vertex's fan); the faces traced by turning left. A
   face whose corners are four of 90° and the rest 180° is a rectangle in the parameter
   plane: its four sides are runs of arcs;
4. integer arc lengths and the quads of every patch: :mod:`ufl_frames.quads.patches`.

:func:`untangle` smooths the folds of a seamless map out before, where it can.

Pure NumPy (Python integers and fractions along the arcs).
"""

import math
from collections import defaultdict
from dataclasses import dataclass
from fractions import Fraction

import numpy as np

from ufl_frames.param.seamless import (
    Parametrisation,
    boundary_coordinates,
    curve_edge_ids,
    parametrisation,
    quarter_turn,
    wrong_corners,
)
from ufl_frames.quads.charts import UNIT, LayoutError
from ufl_frames.quads.motorcycles import QUARTER, Motorcycles, rot

__all__ = ["Arc", "Layout", "layout", "piece_length", "untangle"]


@dataclass
class Arc:
    """A graph edge of the layout: ``pieces`` (triangle, start, end, direction) along it
    in the triangles' charts, its end nodes, its length in the map, whether it is a piece
    of the boundary (then the domain is on its left), whether a piece of an interior curve
    of the features."""

    pieces: list
    start: int
    end: int
    length: float
    boundary: bool
    curve: bool = False


@dataclass(frozen=True)
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


def piece_length(piece):
    _, p0, p1, d = piece
    o = 0 if d[1] == 0 else 1
    return abs(p1[o] - p0[o])


def _cut_pieces(pieces, cuts):
    """The pieces between consecutive arc-length positions ``cuts`` (0 < ... < total)."""
    out, current, at = [], [], Fraction(0)
    cuts = list(cuts)
    for f, p0, p1, d in pieces:
        length = piece_length((f, p0, p1, d))
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
    """The T-mesh of the seamless map ``param``: traces
    (:class:`~ufl_frames.quads.motorcycles.Motorcycles`), arcs and rectangular patches (see
    the module text, step 3). Raises :class:`LayoutError` where a trace fails (a fold, an
    endless trace) or a face is not a rectangle."""
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
        starts = np.cumsum([Fraction(0)] + [piece_length(p) for p in t.pieces])
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
                            float(sum(piece_length(p) for p in pieces)) / UNIT, False,
                            t.stop == "curve"))
    # boundary arcs: the loops split at corners, at the features' model points and where
    # traces start or end
    for w in sorted(mc.model_nodes):
        if mc.on_boundary[w]:
            node(("v", w))
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
                            float(sum(piece_length(p) for p in pieces)) / UNIT, True))
    nodes = list(node_id)
    try:
        ends, total = _node_ends(mc, arcs, nodes)
        patches = _faces(arcs, ends, total)
    except LayoutError as e:
        wrong = wrong_corners(param)
        if not mc.folded.any() and not wrong:
            raise
        why = []
        if wrong:
            x = param.mesh.x
            why.append("the map turns " + "; ".join(
                f"{q} quarter turn{'' if abs(q) == 1 else 's'} where the domain turns {k} "
                f"at the boundary vertex "
                f"({x[v, 0]:.4g}, {x[v, 1]:.4g})" for v, q, k in wrong[:3])
                + (f" (and at {len(wrong) - 3} more)" if len(wrong) > 3 else "")
                + ": it folds there, and a concave corner it takes as convex starts no trace")
        if mc.folded.any():
            why.append(f"the seamless map folds on {int(mc.folded.sum())} triangles")
        raise LayoutError(f"{e} ({'; '.join(why)})") from e
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
        if not arc.pieces:  # its two nodes coincide in the map: no direction to leave by
            raise LayoutError(f"an arc between nodes {arc.start} and {arc.end} has no "
                              "length in the map")
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
                r = rot(kappa, d)
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
                    d = rot(mc.turn[f][i], d)
                out.append((QUARTER[d], h))
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


def _boundary_sliders(mesh, chosen):
    """(wedge, one boundary neighbour's wedge, the other's, the constant coordinate) of
    each vertex of ``chosen`` that can slide along the boundary: one wedge (no cut
    through it), two boundary edges that keep the same coordinate constant, and both
    neighbours' wedges in its chart (the edges' own triangles)."""
    boundary, constant = boundary_coordinates(mesh)
    ends = mesh.edges[boundary]
    owners = defaultdict(set)
    for v, w in zip(mesh.cells.ravel().tolist(), mesh.corners.ravel().tolist(), strict=True):
        owners[v].add(w)
    touching = defaultdict(list)
    for e, (u, v) in enumerate(ends.tolist()):
        touching[u].append(e)
        touching[v].append(e)
    sliders = []
    for v in np.flatnonzero(chosen).tolist():
        if len(owners[v]) != 1 or len(touching[v]) != 2:
            continue
        (w,), (e1, e2) = owners[v], touching[v]
        if constant[e1] != constant[e2]:
            continue
        neighbours = []
        for e in (e1, e2):
            f = int(mesh.faces[boundary[e], 0])
            other = int(ends[e, 1] if ends[e, 0] == v else ends[e, 0])
            local = int(np.flatnonzero(mesh.cells[f] == other)[0])
            neighbours.append(int(mesh.corners[f, local]))
        sliders.append((w, neighbours[0], neighbours[1], int(constant[e1])))
    return sliders


def untangle(param: Parametrisation, rounds: int = 200, rings: int = 3):
    """The seamless map with its folds smoothed out where it can: every interior vertex
    (not singular) within ``rings`` rings of a folded triangle moved, ``rounds`` times at
    most, to the mean of its neighbours in its own chart (all its wedges together, each
    by its transition, so the map stays seamless; the singular vertices and the model's
    points stay): a Tutte-like relaxation of the folded region. A boundary vertex there
    (one wedge, both its boundary edges keeping the same coordinate constant) slides
    along its iso-line: its other coordinate goes to the mean of its two boundary
    neighbours' (a boundary whose map runs backwards for a stretch, as next to the
    airfoil's trailing edge, is folded there and only moving along it unfolds it).

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
    region[mesh.singular] = False
    region[list(mc.model_nodes)] = False
    sliders = _boundary_sliders(mesh, region & mc.on_boundary)
    region &= ~mc.on_boundary
    curves, _ = curve_edge_ids(mesh)  # the features' curves and points stay: iso-lines
    region[mesh.edges[curves].ravel()] = False
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
        for w, a, b, c in sliders:  # along the boundary: the free coordinate 1 - c
            uv[w, 1 - c] = 0.5 * (uv[a, 1 - c] + uv[b, 1 - c])
        if sweep % 10 == 9 and not folded_now().any():
            break
    return parametrisation(mesh, uv, param.scale), int(np.count_nonzero(folded_now()))
