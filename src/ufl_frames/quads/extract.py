r"""Quad extraction: the integer iso-lines of an integer-grid map, traced through the
triangles, and the quads they bound (the idea of QEx, Ebke et al. 2013).

The map (U, V) of :func:`~ufl_frames.param.quantise.quantise` is affine on every triangle
and, across a seam, related to the neighbour's by a quarter turn and an integer
translation. So the lines U = i and V = j (i, j integers) form, pulled back to the mesh, a
graph whose vertices are the integer points (i, j) and whose faces are quads:

1. exact arithmetic: the wedge values are rounded to fixed point (2⁻¹⁶ of a quad edge),
   and the seams' transitions are made exact in it, so that every decision below (does a
   line cross this edge, does it pass through this vertex, is this point inside) is the
   same seen from both sides of an edge;
2. per triangle, in its own chart: where each integer line meets the triangle's boundary
   (its vertices, and points on its edges named by the edge and the exact parameter along
   it, so that the two triangles of an edge name them alike), the integer points inside,
   and the pieces of line between consecutive points;
3. the pieces joined into chains between integer points (through the points where a line
   merely crosses an edge); around every integer point its chains sorted by direction; the
   faces traced by turning left; the bounded faces are the quads, their corners the
   integer points (the chains, curved in the mesh, become straight quad edges).

A singular vertex of the field is an integer point that 3 or 5 chains leave; a boundary
curve lies on an integer line, so its integer points are quad vertices on the boundary.
Pure NumPy (and Python's exact fractions).
"""

from collections import defaultdict
from dataclasses import dataclass
from fractions import Fraction
from math import ceil, floor

import numpy as np

from ufl_frames.param.quantise import IntegerGridMap
from ufl_frames.param.seamless import quarter_turn, wedge_of

__all__ = ["ExtractionError", "QuadMesh", "extract_quads", "fixed_point"]

#: Fixed-point units per grid step: coordinates up to 10⁴ steps keep every product of two
#: differences within int64 (and Python's integers are used where they could not).
UNIT = 2**16


class ExtractionError(RuntimeError):
    """The iso-lines do not bound quads (the map is not a valid integer-grid map)."""


@dataclass(frozen=True)
class QuadMesh:
    """A quad mesh: ``points`` (n, 2), ``quads`` (m, 4) counter-clockwise; ``grid`` (n, 2)
    the integer (U, V) of each point in the chart of one triangle it lies in (for
    pictures); ``chains`` the polyline (k, 2) under every quad edge, keyed by the sorted
    point pair; ``boundary`` the boundary edges (b, 2)."""

    points: np.ndarray
    quads: np.ndarray
    chains: dict
    boundary: np.ndarray

    @property
    def num_quads(self) -> int:
        return int(self.quads.shape[0])


def fixed_point(grid_map: IntegerGridMap) -> np.ndarray:
    """The wedge values in fixed point (W, 2) int64, ``UNIT`` per grid step, with every
    seam's transition exact: X_g = Rot^j X_f + t (t a multiple of UNIT) at both ends of
    every cut edge. Raises :class:`ExtractionError` where the seams disagree."""
    mesh = grid_map.mesh
    uv = grid_map.param.uv
    if np.abs(uv).max(initial=0.0) * UNIT > 2.0**40:
        raise ExtractionError("the map is too large for fixed point (over 16 million quads "
                              "across)")
    P = np.rint(uv * UNIT).astype(np.int64)
    # Wedge graph across cut edges: each link w_f -> w_g with X_g = R X_f + t.
    links = defaultdict(list)
    for e in mesh.cut:
        f, g = int(mesh.faces[e, 0]), int(mesh.faces[e, 1])
        rot = quarter_turn(mesh.jump[e]).astype(np.int64)
        ends = [(wedge_of(mesh, f, int(v)), wedge_of(mesh, g, int(v))) for v in mesh.edges[e]]
        wf, wg = ends[0]
        t = P[wg] - rot @ P[wf]
        t = UNIT * np.rint(t / UNIT).astype(np.int64)
        for wf, wg in ends:
            links[wf].append((wg, rot, t))
            links[wg].append((wf, rot.T, -(rot.T @ t)))  # inverse: X_f = Rᵀ (X_g − t)
    done = np.zeros(P.shape[0], dtype=bool)
    for start in list(links):
        if done[start]:
            continue
        done[start] = True
        stack = [start]
        while stack:
            w = stack.pop()
            for other, rot, t in links[w]:
                value = rot @ P[w] + t
                if not done[other]:
                    P[other] = value
                    done[other] = True
                    stack.append(other)
                elif np.any(P[other] != value):
                    raise ExtractionError("the seams' transitions do not close around a "
                                          "vertex (the map is not an integer-grid map)")
    return P


def _is_grid(value) -> bool:
    return value % UNIT == 0


def extract_quads(grid_map: IntegerGridMap) -> QuadMesh:
    """The quad mesh of the integer-grid map ``grid_map`` (see the module text).

    Raises :class:`ExtractionError` if the traced lines do not bound quads only.
    """
    mesh = grid_map.mesh
    P = fixed_point(grid_map)
    x, cells, corners = mesh.x, mesh.cells, mesh.corners
    C = P[corners]
    det = ((C[:, 1, 0] - C[:, 0, 0]) * (C[:, 2, 1] - C[:, 0, 1])
           - (C[:, 1, 1] - C[:, 0, 1]) * (C[:, 2, 0] - C[:, 0, 0]))
    if np.any(det <= 0):
        raise ExtractionError(f"{int(np.count_nonzero(det <= 0))} triangles fold or collapse "
                              "in the integer-grid map")
    edge_of = {}
    for e, (a, b) in enumerate(mesh.edges):
        edge_of[(int(a), int(b))] = e
    keys: dict = {}  # node key -> id
    position: list = []
    grid_point: list = []

    def node(key, where, is_grid):
        i = keys.get(key)
        if i is None:
            i = keys[key] = len(position)
            position.append(where)
            grid_point.append(is_grid)
        return i

    segments: dict = {}  # (i, j) sorted -> physical direction from i to j
    exterior: set = set()  # directed pieces along the boundary with the outside on the left

    def link(i, j, direction):
        if i == j:
            return
        if i < j:
            segments.setdefault((i, j), direction)
        else:
            segments.setdefault((j, i), -direction)

    for f in range(cells.shape[0]):
        verts = [int(v) for v in cells[f]]
        X = [tuple(int(c) for c in P[corners[f, i]]) for i in range(3)]
        xf = x[cells[f]]
        # the affine map of this triangle: physical = xf[0] + M (param − X0)
        dp = np.array([[X[1][0] - X[0][0], X[2][0] - X[0][0]],
                       [X[1][1] - X[0][1], X[2][1] - X[0][1]]], dtype=float)
        dx = np.stack([xf[1] - xf[0], xf[2] - xf[0]], axis=1)
        M = dx @ np.linalg.inv(dp)
        # boundary nodes of this triangle: (id, (U, V) exact)
        boundary_nodes = []
        for i in range(3):
            if _is_grid(X[i][0]) or _is_grid(X[i][1]):
                gid = node(("v", verts[i]), x[verts[i]],
                           _is_grid(X[i][0]) and _is_grid(X[i][1]))
                boundary_nodes.append((gid, (Fraction(X[i][0]), Fraction(X[i][1]))))
        for i in range(3):
            ia, ib = (i + 1) % 3, (i + 2) % 3
            a, b = verts[ia], verts[ib]
            if a > b:
                ia, ib, a, b = ib, ia, b, a
            e = edge_of[(a, b)]
            A, B = X[ia], X[ib]
            found = {}
            for c in range(2):
                lo, hi = sorted((A[c], B[c]))
                for k in range(floor(lo / UNIT) + 1, ceil(hi / UNIT)):
                    t = Fraction(k * UNIT - A[c], B[c] - A[c])
                    found[t] = None
            for t in found:
                U = A[0] + t * (B[0] - A[0])
                V = A[1] + t * (B[1] - A[1])
                where = x[a] + float(t) * (x[b] - x[a])
                gid = node(("e", e, t), where,
                           U.denominator == 1 and V.denominator == 1 and _is_grid(int(U))
                           and _is_grid(int(V)))
                boundary_nodes.append((gid, (U, V)))
        # the integer lines through the closed triangle
        for c in range(2):
            o = 1 - c
            values = [X[i][c] for i in range(3)]
            for k in range(ceil(min(values) / UNIT), floor(max(values) / UNIT) + 1):
                level = k * UNIT
                on = [(gid, X_) for gid, X_ in boundary_nodes if X_[c] == level]
                if len(on) < 2:
                    continue
                on.sort(key=lambda item: item[1][o])
                along = [i for i in range(3)
                         if values[(i + 1) % 3] == level and values[(i + 2) % 3] == level]
                step = np.zeros(2)
                step[o] = 1.0
                direction = M @ step  # physical direction of increasing other coordinate
                if along:
                    chain = [gid for gid, _ in on]
                    i = along[0]
                    a, b = verts[(i + 1) % 3], verts[(i + 2) % 3]
                    if mesh.faces[edge_of[(min(a, b), max(a, b))], 1] < 0:
                        # a boundary edge: the domain is left of (i+1) -> (i+2) (cells are
                        # counter-clockwise); mark the pieces that have the outside on
                        # their left
                        ascending = X[(i + 1) % 3][o] < X[(i + 2) % 3][o]
                        for p, q in zip(chain[:-1], chain[1:], strict=True):
                            exterior.add((q, p) if ascending else (p, q))
                else:
                    lo, hi = on[0][1][o], on[-1][1][o]
                    inner = []
                    for m in range(floor(lo / UNIT) + 1, ceil(hi / UNIT)):
                        if not lo < m * UNIT < hi:
                            continue
                        point = [0, 0]
                        point[c], point[o] = level, m * UNIT
                        where = xf[0] + M @ (np.array(point, dtype=float) - X[0])
                        inner.append(node(("f", f, point[0], point[1]), where, True))
                    chain = [on[0][0]] + inner + [on[-1][0]]
                for p, q in zip(chain[:-1], chain[1:], strict=True):
                    link(p, q, direction)
    points_all = np.array(position)
    is_grid = np.array(grid_point, dtype=bool)
    return _faces(points_all, is_grid, segments, exterior)


def _faces(points_all, is_grid, segments, exterior) -> QuadMesh:
    """Chains between integer points, their cyclic order, the faces; the quads."""
    n = points_all.shape[0]
    neighbours = defaultdict(list)  # node -> [(other, direction)]
    for (i, j), d in segments.items():
        neighbours[i].append((j, d))
        neighbours[j].append((i, -d))
    through = [v for v in neighbours if not is_grid[v]]
    bad = [v for v in through if len(neighbours[v]) != 2]
    if bad:
        raise ExtractionError(f"{len(bad)} points where an iso-line crosses an edge are not "
                              "on exactly one line (the map folds or the grid is broken)")
    grid_ids = np.flatnonzero(is_grid & np.array([len(neighbours[v]) > 0 for v in range(n)]))
    number = np.full(n, -1, dtype=np.int64)
    number[grid_ids] = np.arange(grid_ids.size)
    # half-edges: from each grid node, along each segment, to the next grid node
    half = []  # (start grid, end grid, angle at start, polyline)
    for g in grid_ids:
        for first, d in neighbours[g]:
            path, prev, cur = [g, first], g, first
            while not is_grid[cur]:
                a, b = neighbours[cur]
                nxt = a[0] if a[0] != prev else b[0]
                prev, cur = cur, nxt
                path.append(cur)
                if len(path) > n + 1:
                    raise ExtractionError("an iso-line closes on itself without an integer "
                                          "point")
            half.append((number[g], number[cur], float(np.arctan2(d[1], d[0])), path))
    out = defaultdict(list)  # grid node -> half-edge ids sorted counter-clockwise
    for h, (s, _, angle, _) in enumerate(half):
        out[s].append((angle, h))
    position_in = {}
    for s in out:
        out[s].sort()
        for rank, (_, h) in enumerate(out[s]):
            position_in[h] = (s, rank)
    # the twin of a half-edge: the one tracing the same path backwards
    by_path = {tuple(path): h for h, (_, _, _, path) in enumerate(half)}
    twin = [by_path[tuple(reversed(path))] for (_, _, _, path) in half]
    used = np.zeros(len(half), dtype=bool)
    quads, other_faces = [], 0
    points = points_all[grid_ids]
    for h0 in range(len(half)):
        if used[h0]:
            continue
        face, polyline, h = [], [], h0
        while not used[h]:
            used[h] = True
            face.append(half[h][0])
            polyline.extend(half[h][3][:-1])
            t = twin[h]
            s, rank = position_in[t]
            h = out[s][(rank - 1) % len(out[s])][1]  # the next clockwise from the twin
        if any((p, q) in exterior for p, q in zip(polyline, polyline[1:] + polyline[:1],
                                                   strict=True)):
            continue  # a boundary loop: the outside (or a hole) on its left
        ring = points_all[polyline]
        area = 0.5 * np.sum(ring[:, 0] * np.roll(ring[:, 1], -1)
                            - np.roll(ring[:, 0], -1) * ring[:, 1])
        if len(face) != 4 or area <= 0:
            other_faces += 1
            continue
        quads.append(face)
    if other_faces:
        raise ExtractionError(f"{other_faces} faces of the traced iso-lines are not quads")
    chains = {}
    boundary_edges = []
    for h, (s, e, _, path) in enumerate(half):
        if s < e:
            chains[(int(s), int(e))] = points_all[path]
        del h
    quads = np.array(quads, dtype=np.int64).reshape(-1, 4)
    edge_count = defaultdict(int)
    for quad in quads:
        for i in range(4):
            a, b = int(quad[i]), int(quad[(i + 1) % 4])
            edge_count[(min(a, b), max(a, b))] += 1
    boundary_edges = [pair for pair, count in edge_count.items() if count == 1]
    return QuadMesh(points=points, quads=quads, chains=chains,
                    boundary=np.array(boundary_edges, dtype=np.int64).reshape(-1, 2))
