r"""Seamless integration of a combed frame field: the P1 map (U, V) on the cut mesh.

On the cut mesh (:class:`~ufl_frames.param.cut.CutMesh`) the combed frame of triangle f has
branches u_f (angle t_f, length l1) and v_f (t_f + 90°, length l2); an integrable field is
the gradient of a map, ∇U = u/|u|², ∇V = v/|v|². So (U, V), P1 on the cut mesh's vertices
(the wedges), minimises

    Σ_f |f| ( |∇U_f − s u_f/|u_f|²|² + |∇V_f − s v_f/|v_f|²|² )

(s the global scale: U and V advance by 1 per quad edge of length |u|/s) subject to

* seams: across a cut edge with jump j (g's frame is f's turned by j quarter turns) the two
  sides are related by (U, V)_g = Rot^j (U, V)_f + t, Rot(U, V) = (V, −U), with one
  translation t along each seam — imposed without t as equal differences at the two ends
  of every cut edge;
* boundary alignment: along a boundary edge the coordinate whose branch crosses the edge
  (the branch more normal to it) is constant; likewise along the interior curves of the
  mesh's features (interfaces between regions, embedded curves: one coordinate constant
  along each piece, seen from the edge's first triangle);
* U = V = 0 at one wedge of every connected component (the map is defined up to a
  translation of each).

The equality constraints are eliminated (sparse Gaussian elimination with substitution:
every constraint has four or two ±1 terms, and redundant ones — around a closed loop of
seams, say — reduce to 0 = 0 and are dropped), leaving a sparse SPD system for the free
unknowns, solved directly (SciPy's SuperLU, :func:`factorise`). Pure NumPy/SciPy.
"""

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ufl_frames.param.cut import CutMesh, triangle_components

__all__ = ["Parametrisation", "SeamlessSystem", "angle_sums", "boundary_coordinates",
           "boundary_steps", "curve_edge_ids", "elimination", "factorise", "first_wedges", "folded",
           "gradients", "integrate", "interior_curve_coordinates", "invalid",
           "least_squares_system", "miswound", "parametrisation", "quarter_turn",
           "scale_for_quad_count", "scale_for_quad_size", "targets", "wedge_of",
           "weighted_solve", "wrong_corners"]


def gradients(x: np.ndarray, cells: np.ndarray):
    """Per triangle its area (m,) and the gradients of its three P1 hat functions (m, 3, 2)."""
    p = x[cells]  # (m, 3, 2)
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    # ∇φ_i = rot(opposite edge) / (2 area): opposite edges p2−p1, p0−p2, p1−p0
    opposite = np.stack([p[:, 2] - p[:, 1], p[:, 0] - p[:, 2], p[:, 1] - p[:, 0]], axis=1)
    grad = np.stack([-opposite[..., 1], opposite[..., 0]], axis=-1) / det[:, None, None]
    return 0.5 * det, grad


def targets(mesh: CutMesh, scale: float):
    """s u/|u|² and s v/|v|² per triangle, (m, 2) each."""
    c, s = np.cos(mesh.angle), np.sin(mesh.angle)
    target_u = scale * np.stack([c, s], axis=1) / mesh.l1[:, None]
    target_v = scale * np.stack([-s, c], axis=1) / mesh.l2[:, None]
    return target_u, target_v


def quarter_turn(j: int) -> np.ndarray:
    """Rot^j as a 2 × 2 matrix, Rot(U, V) = (V, −U)."""
    return np.linalg.matrix_power(np.array([[0.0, 1.0], [-1.0, 0.0]]), int(j) % 4)


def boundary_coordinates(mesh: CutMesh) -> tuple[np.ndarray, np.ndarray]:
    """The boundary edges and, per edge, the coordinate (0: U, 1: V) that is constant
    along it: that of the branch that crosses it (the more normal), with the frame of the
    edge's two vertices (held aligned with the boundary by the solver) in the labels of
    its triangle's combed frame — the triangle's own frame, which its third vertex pulls
    off the boundary's direction (by up to 45° next to a singularity), decides only where
    the vertex frames are not known."""
    boundary = np.flatnonzero(mesh.faces[:, 1] < 0)
    return boundary, _constant_coordinate(mesh, boundary)


def curve_edge_ids(mesh: CutMesh) -> tuple[np.ndarray, np.ndarray]:
    """The mesh edges (ids into ``mesh.edges``) on the model curves of ``mesh.features``
    and the curve tag of each (empty without features).

    Raises:
        ValueError: a curve edge is no edge of the mesh.
    """
    if mesh.features is None or mesh.features.curve_edges.size == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    e = np.asarray(mesh.features.curve_edges, dtype=np.int64).reshape(-1, 2)
    n = int(max(mesh.edges.max(initial=0), e.max(initial=0))) + 1
    keys = mesh.edges[:, 0] * n + mesh.edges[:, 1]
    wanted = np.minimum(e[:, 0], e[:, 1]) * n + np.maximum(e[:, 0], e[:, 1])
    ids = np.minimum(np.searchsorted(keys, wanted), keys.size - 1)
    if np.any(keys[ids] != wanted):
        raise ValueError(f"{int(np.count_nonzero(keys[ids] != wanted))} curve edges of the "
                         "features are not edges of the triangle mesh")
    return ids, np.asarray(mesh.features.edge_curve, dtype=np.int64)


def interior_curve_coordinates(mesh: CutMesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The interior curve edges (interfaces and embedded curves: two triangles), per edge
    the coordinate (0: U, 1: V) constant along it in its first triangle's chart (chosen as
    on the boundary, :func:`boundary_coordinates`), and its curve tag."""
    ids, tags = curve_edge_ids(mesh)
    inner = mesh.faces[ids, 1] >= 0
    ids, tags = ids[inner], tags[inner]
    return ids, _constant_coordinate(mesh, ids), tags


def _constant_coordinate(mesh: CutMesh, edge_ids: np.ndarray) -> np.ndarray:
    """Per edge of ``edge_ids`` the coordinate of its first triangle's combed frame whose
    branch crosses it (see :func:`boundary_coordinates`)."""
    f = mesh.faces[edge_ids, 0]
    angle = mesh.angle[f]
    if mesh.vertex_angle is not None:
        quarter = np.pi / 2
        ends = mesh.vertex_angle[mesh.edges[edge_ids]] - angle[:, None]  # (k, 2)
        angle = angle + np.mean(np.mod(ends + quarter / 2, quarter) - quarter / 2, axis=1)
    direction = mesh.x[mesh.edges[edge_ids, 1]] - mesh.x[mesh.edges[edge_ids, 0]]
    along_u = np.abs(np.cos(angle) * direction[:, 0] + np.sin(angle) * direction[:, 1])
    along_v = np.abs(-np.sin(angle) * direction[:, 0] + np.cos(angle) * direction[:, 1])
    return np.where(along_u < along_v, 0, 1).astype(np.int64)


def wedge_of(mesh: CutMesh, face: int, vertex: int) -> int:
    """The cut-mesh vertex (wedge) of triangle ``face`` at mesh vertex ``vertex``.

    Args:
        mesh: the cut mesh.
        face: a triangle's index.
        vertex: a mesh vertex of that triangle.

    Returns:
        The wedge's index.
    """
    return int(mesh.corners[face, int(np.flatnonzero(mesh.cells[face] == vertex)[0])])


def scale_for_quad_count(mesh: CutMesh, quads: float) -> float:
    """The scale s at which the grid has about ``quads`` cells: a cell of the field's
    grid has area l1 l2 / s², so their number is s² ∫ 1/(l1 l2)."""
    area, _ = gradients(mesh.x, mesh.cells)
    return float(np.sqrt(quads / np.dot(area, 1.0 / (mesh.l1 * mesh.l2))))


def scale_for_quad_size(mesh: CutMesh, quad_size: float) -> float:
    """The scale s at which the grid's cells have mean edge length ``quad_size``: cells
    of edges l1/s, l2/s with density s²/(l1 l2), so the mean over cells is
    (1/s) ∫ (l1 + l2)/(2 l1 l2) / ∫ 1/(l1 l2)."""
    area, _ = gradients(mesh.x, mesh.cells)
    density = area / (mesh.l1 * mesh.l2)
    return float(np.dot(density, 0.5 * (mesh.l1 + mesh.l2)) / density.sum() / quad_size)


def first_wedges(mesh: CutMesh) -> np.ndarray:
    """One wedge per connected component of the mesh: its first triangle's first corner."""
    count, label = triangle_components(mesh.faces, mesh.cells.shape[0])
    first = np.array([np.flatnonzero(label == c)[0] for c in range(count)], dtype=np.int64)
    return mesh.corners[first, 0]


def _constraints(mesh: CutMesh, anchor=None) -> list[dict]:
    """Sparse rows {scalar unknown: coefficient} = 0 (unknown 2w + c: coordinate c of wedge w)."""
    rows = []
    edges, faces = mesh.edges, mesh.faces

    def wedge(face, vertex):
        return wedge_of(mesh, face, vertex)

    for e in mesh.cut:
        f, g = int(faces[e, 0]), int(faces[e, 1])
        rot = quarter_turn(mesh.jump[e])
        a, b = int(edges[e, 0]), int(edges[e, 1])
        wf_a, wf_b, wg_a, wg_b = wedge(f, a), wedge(f, b), wedge(g, a), wedge(g, b)
        for c in range(2):  # (X_g(a) − Rot X_f(a)) − (X_g(b) − Rot X_f(b)) = 0, component c
            row: dict[int, float] = {}

            def add(var, coef, row=row):
                row[var] = row.get(var, 0.0) + coef

            add(2 * wg_a + c, 1.0)
            add(2 * wg_b + c, -1.0)
            for d in range(2):
                if rot[c, d]:
                    add(2 * wf_a + d, -rot[c, d])
                    add(2 * wf_b + d, rot[c, d])
            rows.append(row)
    boundary, coordinate = boundary_coordinates(mesh)
    inner, inner_coordinate, _ = interior_curve_coordinates(mesh)
    for e, c in zip(np.concatenate([boundary, inner]),
                    np.concatenate([coordinate, inner_coordinate]), strict=True):
        f = int(faces[e, 0])
        a, b = int(edges[e, 0]), int(edges[e, 1])
        rows.append({2 * wedge(f, a) + c: 1.0, 2 * wedge(f, b) + c: -1.0})
    for w in np.atleast_1d(first_wedges(mesh) if anchor is None else anchor):
        rows.append({2 * int(w): 1.0})
        rows.append({2 * int(w) + 1: 1.0})
    return rows


def _eliminate(rows: list[dict], count: int) -> sp.csr_matrix:
    """T (count × free) with x = T y for every x satisfying the homogeneous ``rows``."""
    expression: dict[int, dict[int, float]] = {}  # eliminated var -> {free var: coef}
    users: dict[int, set] = {}  # free var -> eliminated vars whose expression uses it
    for row in rows:
        reduced: dict[int, float] = {}
        for var, coef in row.items():
            if var in expression:
                for other, c in expression[var].items():
                    reduced[other] = reduced.get(other, 0.0) + coef * c
            else:
                reduced[var] = reduced.get(var, 0.0) + coef
        reduced = {v: c for v, c in reduced.items() if abs(c) > 1e-12}
        if not reduced:
            continue  # redundant
        pivot = max(reduced, key=lambda v: (abs(reduced[v]), -len(users.get(v, ()))))
        scale = -1.0 / reduced.pop(pivot)
        pivot_expr = {v: c * scale for v, c in reduced.items()}
        # substitute the pivot in the expressions that use it
        for user in users.pop(pivot, set()):
            expr = expression[user]
            coef = expr.pop(pivot)
            for v, c in pivot_expr.items():
                new = expr.get(v, 0.0) + coef * c
                if abs(new) > 1e-12:
                    expr[v] = new
                    users.setdefault(v, set()).add(user)
                else:
                    expr.pop(v, None)
                    users.get(v, set()).discard(user)
        expression[pivot] = pivot_expr
        for v in pivot_expr:
            users.setdefault(v, set()).add(pivot)
    free = np.array([v for v in range(count) if v not in expression], dtype=np.int64)
    column = np.full(count, -1, dtype=np.int64)
    column[free] = np.arange(free.size)
    rows_t, cols_t, vals_t = list(free), list(column[free]), [1.0] * free.size
    for var, expr in expression.items():
        for v, c in expr.items():
            rows_t.append(var)
            cols_t.append(column[v])
            vals_t.append(c)
    return sp.csr_matrix((vals_t, (rows_t, cols_t)), shape=(count, free.size))


@dataclass(frozen=True)
class Parametrisation:
    """(U, V) per wedge of ``mesh`` (``uv`` (W, 2)), the scale s, and per triangle the
    Jacobian rows ∇U, ∇V ((m, 2) each) and the targets."""

    mesh: CutMesh
    uv: np.ndarray
    scale: float
    grad_u: np.ndarray
    grad_v: np.ndarray
    target_u: np.ndarray
    target_v: np.ndarray
    area: np.ndarray

    def corner_values(self) -> np.ndarray:
        """(U, V) at the corners of every triangle, (m, 3, 2)."""
        return self.uv[self.mesh.corners]


def elimination(mesh: CutMesh, anchor=None) -> sp.csr_matrix:
    """T (2W × free) with x = T y for every wedge vector x that satisfies the seams, the
    boundary alignment and the anchors (``anchor`` as in :func:`least_squares_system`)."""
    return _eliminate(_constraints(mesh, anchor), 2 * mesh.num_wedges)


def least_squares_system(mesh: CutMesh, scale: float = 1.0, anchor=None):
    """The seamless problem in the free unknowns y.

    Args:
        mesh: the cut mesh with its combed field.
        scale: the global scale s.
        anchor: the wedge, or one wedge per connected component, where (U, V) = 0
            (default :func:`first_wedges`): the map is defined up to a translation of
            every component.

    Returns:
        (A T, b, T): x = T y the wedge values (x[2w + c]: coordinate c of wedge w)
        satisfying the seams, the boundary alignment and the anchors, and A x − b the
        area-weighted misfit rows.
    """
    area, grad = gradients(mesh.x, mesh.cells)
    target_u, target_v = targets(mesh, scale)
    m, count = mesh.cells.shape[0], 2 * mesh.num_wedges
    # Rows: √|f| ∂_k X_c on triangle f, for c (U, V) and k (x, y): 4 per triangle.
    weight = np.sqrt(area)
    rows, cols, vals = [], [], []
    for c in range(2):
        for k in range(2):
            row = (4 * np.arange(m) + 2 * c + k)[:, None].repeat(3, axis=1)
            rows.append(row.ravel())
            cols.append((2 * mesh.corners + c).ravel())
            vals.append((weight[:, None] * grad[:, :, k]).ravel())
    A = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(4 * m, count))
    b = np.empty(4 * m)
    b[0::4], b[1::4] = weight * target_u[:, 0], weight * target_u[:, 1]
    b[2::4], b[3::4] = weight * target_v[:, 0], weight * target_v[:, 1]
    T = elimination(mesh, anchor)
    return (A @ T).tocsc(), b, T


def parametrisation(mesh: CutMesh, uv: np.ndarray, scale: float) -> Parametrisation:
    """The :class:`Parametrisation` of the wedge values ``uv`` (W, 2) at scale ``scale``.

    Args:
        mesh: the cut mesh with its combed field.
        uv: (U, V) per wedge (W, 2).
        scale: the global scale s of the targets.

    Returns:
        The record, with the Jacobian rows and targets per triangle.
    """
    area, grad = gradients(mesh.x, mesh.cells)
    target_u, target_v = targets(mesh, scale)
    corner = uv[mesh.corners]  # (m, 3, 2)
    grad_u = np.einsum("mi,mik->mk", corner[..., 0], grad)
    grad_v = np.einsum("mi,mik->mk", corner[..., 1], grad)
    return Parametrisation(mesh=mesh, uv=uv, scale=scale, grad_u=grad_u, grad_v=grad_v,
                           target_u=target_u, target_v=target_v, area=area)


#: A triangle whose image is this much smaller than the median one's counts as collapsed.
COLLAPSED = 1e-6
#: Rounds of re-weighting folded triangles (:meth:`SeamlessSystem.unfold`), and the factor
#: of each.
REWEIGHTINGS, REWEIGHT_FACTOR = 4, 10.0


def folded(p: Parametrisation) -> np.ndarray:
    """Triangles where the map folds or collapses: det ∇(U, V) ≤ :data:`COLLAPSED` times
    the median (two corners on one point, say two singular vertices rounded together)."""
    det = p.grad_u[:, 0] * p.grad_v[:, 1] - p.grad_u[:, 1] * p.grad_v[:, 0]
    return det <= COLLAPSED * np.median(np.abs(det))


#: |sin| of a corner angle below which :func:`angle_sums` takes a triangle as flat.
FLAT = 1e-9


def angle_sums(cells: np.ndarray, corners: np.ndarray, n: int) -> np.ndarray:
    """Per vertex (n,) the sum of its triangles' corner angles, ``corners`` (m, 3, 2) the
    points of every triangle's corners: the angle between the two edges, in [0, π],
    negative where the triangle is clockwise. A triangle flattened onto a segment (a
    rounded map has such slivers at grid points) counts 0 or π whichever sign round-off
    gives its area: its signed angle would be ±π at random.

    Args:
        cells: vertex indices (m, 3) the angles are summed to.
        corners: the points of every triangle's corners (m, 3, 2), in the order of
            ``cells``.
        n: the number of vertices (the length of the result).

    Returns:
        The signed angle sums (n,), in radians.
    """
    total = np.zeros(n)
    for i in range(3):
        a = corners[:, (i + 1) % 3] - corners[:, i]
        b = corners[:, (i + 2) % 3] - corners[:, i]
        cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
        angle = np.arctan2(np.abs(cross), np.einsum("mk,mk->m", a, b))
        flat = np.abs(cross) <= FLAT * np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1)
        np.add.at(total, cells[:, i], np.where(flat | (cross > 0), angle, -angle))
    return total


def miswound(p: Parametrisation) -> np.ndarray:
    """Vertices around which (U, V) turns by a full turn more or less than the grid: a
    map can be fold-free and still wrap once more (or less) around a cone. Inside, the
    corner angles of (U, V) add up to 2π − j π/2 around a vertex of turn j (a grid
    vertex of valence 4 − j), up to whole turns; on the boundary to the domain's angle
    within half a turn (it is a multiple of π/2 there, the iso-lines' corner)."""
    mesh = p.mesh
    n = mesh.x.shape[0]
    cells = mesh.cells
    expected = angle_sums(cells, mesh.x[cells], n)
    boundary = np.unique(mesh.edges[mesh.faces[:, 1] < 0])
    inside = np.ones(n, dtype=bool)
    inside[boundary] = False
    inside[np.setdiff1d(np.arange(n), cells)] = False
    expected[inside] = 2 * np.pi
    expected[mesh.singular] -= mesh.turns * np.pi / 2
    return np.abs(angle_sums(cells, p.corner_values(), n) - expected) >= np.pi


def invalid(p: Parametrisation) -> np.ndarray:
    """Triangles where the map is not a valid grid map: folded or collapsed
    (:func:`folded`), or around a vertex where it winds wrong (:func:`miswound`)."""
    return folded(p) | miswound(p)[p.mesh.cells].any(axis=1)


def wrong_corners(p: Parametrisation) -> list:
    """(vertex, the map's quarter turns, the domain's) of every boundary vertex around
    which the map's corner angles add up to three eighths of a turn or more away from the
    domain's (:func:`angle_sums`): the map folds there though none of its triangles need
    be inverted (its boundary runs backwards next to the vertex: a 270° corner the map
    turns by 90°). A corner under 45° counted as one quarter turn is less than a quarter
    turn away."""
    mesh = p.mesh
    n = mesh.x.shape[0]
    boundary = np.unique(mesh.edges[mesh.faces[:, 1] < 0])
    domain = angle_sums(mesh.cells, mesh.x[mesh.cells], n)[boundary]
    mapped = angle_sums(mesh.cells, p.corner_values(), n)[boundary]
    off = np.flatnonzero(np.abs(mapped - domain) >= 0.75 * np.pi)
    quarter = np.pi / 2
    return [(int(boundary[i]), int(np.rint(mapped[i] / quarter)),
             int(np.rint(domain[i] / quarter))) for i in off]


def acute_runs(p: Parametrisation, vertices, gap: int = 3) -> set:
    """The ``vertices`` (boundary vertices where the map folds, :func:`wrong_corners`) that
    are reached from a corner under 45° along the boundary through such vertices, at most
    ``gap`` other boundary edges between two of them: the fold of an acute corner's
    absorbed disk (:func:`~ufl_frames.param.pairs.absorb_at_acute_corners`), whose map may
    run backwards along the cusp's curves (Gmsh's fleur), not a concave corner shut."""
    mesh = p.mesh
    n = mesh.x.shape[0]
    boundary = mesh.edges[mesh.faces[:, 1] < 0]
    neighbours: dict[int, list] = {}
    for a, b in boundary.tolist():
        neighbours.setdefault(a, []).append(b)
        neighbours.setdefault(b, []).append(a)
    domain = angle_sums(mesh.cells, mesh.x[mesh.cells], n)
    wrong = set(vertices)
    found: set = set()
    for corner in (v for v in neighbours if domain[v] < np.pi / 4):
        seen, frontier = {corner}, [(corner, gap)]
        while frontier:
            v, left = frontier.pop()
            for w in neighbours[v]:
                if w in seen:
                    continue
                seen.add(w)
                if w in wrong:
                    found.add(w)
                    frontier.append((w, gap))
                elif left > 0:
                    frontier.append((w, left - 1))
    return found


#: Boundary edges on either side of a wrong corner (:func:`wrong_corners`) whose step
#: along the boundary :meth:`SeamlessSystem.open_corners` holds to the field's, and the
#: rounds it tries.
CORNER_EDGES, CORNER_ROUNDS = 3, 3


def boundary_steps(p: Parametrisation, vertices, reach: int = CORNER_EDGES):
    """The boundary edges within ``reach`` edges of ``vertices`` along the boundary, as
    rows (wedge value index at the edge's end, at its start, the field's step): the
    coordinate that runs along the edge (the one :func:`boundary_coordinates` does not
    hold) advances as the target gradient of the edge's triangle integrated along it."""
    mesh = p.mesh
    boundary, constant = boundary_coordinates(mesh)
    touching: dict[int, list] = {}
    for e, c in zip(boundary.tolist(), constant.tolist(), strict=True):
        for v in mesh.edges[e].tolist():
            touching.setdefault(v, []).append((e, c))
    chosen, frontier = {}, set(vertices)
    for _ in range(reach):
        reached = set()
        for v in frontier:
            for e, c in touching.get(v, ()):
                if e not in chosen:
                    chosen[e] = c
                    reached.update(mesh.edges[e].tolist())
        frontier = reached
    rows = []
    for e, c in sorted(chosen.items()):
        f = int(mesh.faces[e, 0])
        a, b = (int(v) for v in mesh.edges[e])
        free = 1 - c
        target = (p.target_u if free == 0 else p.target_v)[f]
        rows.append((2 * wedge_of(mesh, f, b) + free, 2 * wedge_of(mesh, f, a) + free,
                     float(target @ (mesh.x[b] - mesh.x[a]))))
    return rows




def factorise(N) -> spla.SuperLU:
    """SuperLU of the symmetric positive definite normal matrix ``N``: a minimum degree
    ordering of N itself (Nᵀ + N) and diagonal pivots (symmetric mode), which on the plate
    with holes' 465 380 unknowns has 58 % of the factors' entries of SciPy's default
    (COLAMD of NᵀN with partial pivoting) and takes two thirds of its time."""
    return spla.splu(sp.csc_matrix(N), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                     options={"SymmetricMode": True})


def weighted_solve(AT, b, weight: np.ndarray, F_fixed=None, d=None) -> np.ndarray:
    """argmin Σ_f w_f (misfit of triangle f)² over y, subject to F_fixed y = d if given
    (``weight`` per triangle; AT, b of :func:`least_squares_system`), factorised anew.

    Args:
        AT: the misfit rows in y, (4m, free) sparse (:func:`least_squares_system`).
        b: their right-hand side (4m,).
        weight: w_f per triangle (m,).
        F_fixed: the fixed functionals (S, free) sparse, or None (no constraint).
        d: their values (S,).

    Returns:
        The free unknowns y.
    """
    row_weight = np.sqrt(np.repeat(weight, 4))
    WA = sp.diags(row_weight) @ AT
    lu = factorise(WA.T @ WA)
    y0 = lu.solve(WA.T @ (row_weight * b))
    if F_fixed is None or F_fixed.shape[0] == 0:
        return y0
    Z = lu.solve(F_fixed.T.toarray())
    mu = np.linalg.solve(F_fixed @ Z, F_fixed @ y0 - d)
    return y0 - Z @ mu


#: Re-weighted misfit rows up to which a weighted solve updates the one factorisation
#: (:class:`SeamlessSystem`): each costs a back-substitution, and on 10⁵ triangles about
#: a hundred of them cost as much as a factorisation; beyond, the weighted matrix is
#: factorised anew.
WOODBURY_ROWS = 96


#: Right-hand sides per back-substitution block of :meth:`SeamlessSystem.influence`: a
#: dense block has this many columns of the free unknowns (on 4·10⁵ triangles, 4 000
#: columns at once were 12 GB).
INFLUENCE_BLOCK = 64


class SeamlessSystem:
    """The seamless least squares (:func:`least_squares_system`) in the free unknowns y,
    factorised once, with (U, V) = 0 at the ``anchor`` wedges: every map the
    quantisation tries (rounded integers F_S y = d, folded triangles weighted up) is solved
    with that one factorisation of N = (AT)ᵀ(AT).

    The weighted normal matrix N_w = N + A_Rᵀ D A_R differs from N in the few rows R of
    the re-weighted triangles (D = diag(w − 1)), so by the Woodbury identity
    N_w⁻¹ v = N⁻¹ v − B M⁻¹ A_R N⁻¹ v with B = N⁻¹ A_Rᵀ and M = D⁻¹ + A_R B; and the
    constrained minimiser is y = y_w − N_w⁻¹ F_Sᵀ μ, (F_S N_w⁻¹ F_Sᵀ) μ = F_S y_w − d, where
    F_S N⁻¹ F_Sᵀ is the covariance G the greedy rounding computed already. A map costs
    |R| + 2 back-substitutions and dense algebra of the size of S and R, instead of a
    factorisation and |S| back-substitutions (a factorisation where R is large: a map
    folded almost everywhere).
    """

    def __init__(self, mesh: CutMesh, scale: float, anchor=None):
        self.mesh, self.scale = mesh, scale
        self.AT, self.b, self.T = least_squares_system(mesh, scale, anchor)
        self.lu = factorise(self.AT.T @ self.AT)
        self.rhs = self.AT.T @ self.b
        self.y0 = self.lu.solve(self.rhs)

    def solve(self, F=None, G=None, d=None, weight=None) -> np.ndarray:
        """argmin Σ_f w_f (misfit of triangle f)² subject to F y = d.

        Args:
            F: the fixed functionals (S, free) in y, or None.
            G: F N⁻¹ Fᵀ (the unweighted covariance of those functionals).
            d: their integers.
            weight: per triangle (m,), or None for 1 everywhere.

        Returns:
            The free unknowns y.
        """
        rows = np.zeros(0, dtype=np.int64)
        if weight is not None:
            rows = np.flatnonzero(np.repeat(weight, 4) != 1.0)
        if rows.size > WOODBURY_ROWS:  # a factorisation is cheaper
            return weighted_solve(self.AT, self.b, weight, F, d)
        if rows.size:
            A_R = self.AT[rows]
            extra = np.repeat(weight, 4)[rows] - 1.0
            B = self.lu.solve(A_R.T.toarray())
            M = np.diag(1.0 / extra) + A_R @ B
            rhs = self.rhs + A_R.T @ (extra * self.b[rows])

            def inverse(v):  # N_w⁻¹ v
                z = self.lu.solve(v)
                return z - B @ np.linalg.solve(M, A_R @ z)
        else:
            rhs, inverse = self.rhs, self.lu.solve
        y = inverse(rhs) if rows.size else self.y0
        if F is None or F.shape[0] == 0:
            return y
        Gw = G
        if rows.size:
            FB = F @ B
            Gw = G - FB @ np.linalg.solve(M, FB.T)
        mu = np.linalg.solve(Gw, F @ y - d)
        return y - inverse(np.asarray(F.T @ mu).ravel())

    def param(self, y) -> Parametrisation:
        return parametrisation(self.mesh, (self.T @ y).reshape(-1, 2), self.scale)

    def unfold(self, F=None, G=None, d=None) -> Parametrisation:
        """The map with F y = d, its folded triangles and their neighbours weighted up
        (× :data:`REWEIGHT_FACTOR`, at most :data:`REWEIGHTINGS` rounds) until nothing
        folds: a fold is where the least squares traded orientation for misfit, and a
        larger weight there buys it back.

        Args:
            F: the fixed functionals (S, free) in y, or None.
            G: F N⁻¹ Fᵀ (the unweighted covariance of those functionals).
            d: their integers.

        Returns:
            The last map tried (it may still fold after the last round).
        """
        p = self.param(self.solve(F, G, d))
        weight = np.ones(self.mesh.cells.shape[0])
        for _ in range(REWEIGHTINGS):
            bad = folded(p)
            if not bad.any():
                break
            near = np.isin(self.mesh.cells, self.mesh.cells[bad]).any(axis=1)
            weight[near] *= REWEIGHT_FACTOR
            p = self.param(self.solve(F, G, d, weight))
        return p

    def open_corners(self, p: Parametrisation) -> Parametrisation:
        """The map ``p`` (of :meth:`unfold`, with no fixed functionals) where it folds at
        boundary vertices (:func:`wrong_corners`): the boundary's steps next to them held
        to the field's (:func:`boundary_steps`) and unfolded again, the vertices of every
        round kept, while that leaves fewer such vertices (at most
        :data:`CORNER_ROUNDS`). The least squares of a field that is not integrable can
        fold a concave corner shut with no triangle inverted — around a small rotated hole
        of gmsh_full_quad the boundary ran backwards next to its corners — and the traces
        then take the corner as convex; the field's steps along the boundary open it.
        The folds along an acute corner's curves (:func:`acute_runs`) are left as they
        are: the layout meshes them, and holding the steps there squeezed the quads beside
        the cusp of two of Gmsh's fleur's petals (min SJ 0.45 → 0.10)."""
        def concave(corners):
            acute = acute_runs(p, [v for v, _, _ in corners])
            return [c for c in corners if c[0] not in acute]

        wrong = concave(wrong_corners(p))
        held: set = set()
        for _ in range(CORNER_ROUNDS):
            if not wrong:
                break
            held |= {v for v, _, _ in wrong}
            rows = boundary_steps(p, held)
            T = self.T.tocsr()
            F = sp.csr_matrix(sp.vstack([T[i] - T[j] for i, j, _ in rows]))
            d = np.array([step for _, _, step in rows])
            G = F @ self.lu.solve(F.T.toarray())
            candidate = self.unfold(F, G, d)
            left = concave(wrong_corners(candidate))
            if len(left) >= len(wrong):
                break
            p, wrong = candidate, left
        return p

    def influence(self, F, G, triangles: np.ndarray) -> np.ndarray:
        """Per fixed functional (rows of F) how much the wedge values of ``triangles``
        move per unit of its integer: Σ |∂x/∂d| over their corners' coordinates.

        Args:
            F: the fixed functionals (S, free) in y.
            G: F N⁻¹ Fᵀ.
            triangles: the triangles' indices.

        Returns:
            The influence of every functional (S,).
        """
        rows = (2 * self.mesh.corners[triangles].reshape(-1, 1) + np.arange(2)).ravel()
        # ∂y/∂d = N⁻¹ Fᵀ G⁻¹, so T_rows ∂y/∂d = (F N⁻¹ T_rowsᵀ)ᵀ G⁻¹ (N and G symmetric);
        # F N⁻¹ T_rowsᵀ (S, R) by back-substitutions of whichever side is smaller, at most
        # INFLUENCE_BLOCK right-hand sides at a time (never a dense (free, R) matrix)
        T_rows = self.T[rows]
        FZ = np.empty((F.shape[0], rows.size))
        if rows.size <= F.shape[0]:
            for start in range(0, rows.size, INFLUENCE_BLOCK):
                block = slice(start, start + INFLUENCE_BLOCK)
                FZ[:, block] = F @ self.lu.solve(T_rows[block].T.toarray())
        else:
            FT = sp.csc_matrix(F.T)
            for start in range(0, F.shape[0], INFLUENCE_BLOCK):
                block = slice(start, start + INFLUENCE_BLOCK)
                FZ[block] = np.asarray(T_rows @ self.lu.solve(FT[:, block].toarray())).T
        return np.abs(np.linalg.solve(G, FZ).T).sum(axis=0)


def integrate(mesh: CutMesh, scale: float = 1.0, anchor=None,
              unfold_folds: bool = True) -> Parametrisation:
    """The seamless least-squares map of ``mesh``'s combed field at scale ``scale``, zero
    at the ``anchor`` wedges (:func:`least_squares_system`); with ``unfold_folds``,
    folded triangles re-weighted (:meth:`SeamlessSystem.unfold`) and concave corners
    folded shut opened (:meth:`SeamlessSystem.open_corners`).

    Args:
        mesh: the cut mesh with its combed field.
        scale: the global scale s.
        anchor: the wedge, or one wedge per connected component, where (U, V) = 0
            (default :func:`first_wedges`).
        unfold_folds: re-weight folded triangles and solve again.

    Returns:
        The :class:`Parametrisation` (not integer: no rounding here).
    """
    system = SeamlessSystem(mesh, scale, anchor)
    if not unfold_folds:
        return system.param(system.y0)
    return system.open_corners(system.unfold())
