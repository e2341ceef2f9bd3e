"""From the Gmsh mesh of the current model to checked arrays, corners and CAD directions.

Rank 0 turns the Gmsh mesh into a :class:`MeshArrays`: the nodes the triangles use,
counter-clockwise P1 triangles (second-order ones split into four, quadrilaterals into
two), the boundary edges with the curve each lies on and every edge once, and the model
entities beside them: the surface of every triangle, the interior edges on curves
(interfaces between surfaces, curves embedded in a surface), the nodes at model points
and the physical groups; planarity, degenerate triangles, overlaps and slits are refused
with a :class:`~ufl_frames.mesh.domain.GeometryError`. The boundary's corners, the
junctions of the interior curves and the cross angles of the CAD curves' tangents come
from the same arrays.
"""

import math
from dataclasses import dataclass

from ufl_frames.bootstrap import init_petsc

init_petsc()

import gmsh  # noqa: E402
import numpy as np  # noqa: E402

from ufl_frames.frames2d.singularities import corner_cross  # noqa: E402
from ufl_frames.mesh.domain import (  # noqa: E402
    NO_CURVE,
    Corner,
    GeometryError,
    Junction,
    PhysicalGroup,
    lookup,
)


def surfaces() -> list[int]:
    """Tags of the current Gmsh model's surfaces."""
    return [tag for _, tag in gmsh.model.getEntities(2)]


def signed_areas(x: np.ndarray, cells: np.ndarray) -> np.ndarray:
    e1 = x[cells[:, 1]] - x[cells[:, 0]]
    e2 = x[cells[:, 2]] - x[cells[:, 0]]
    return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def _split_quads(quads: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Two triangles per quadrilateral (corners in cyclic order), cut along the shorter
    diagonal."""
    d02 = np.linalg.norm(x[quads[:, 2]] - x[quads[:, 0]], axis=1)
    d13 = np.linalg.norm(x[quads[:, 3]] - x[quads[:, 1]], axis=1)
    along02 = (d02 <= d13)[:, None]
    first = np.where(along02, quads[:, [0, 1, 2]], quads[:, [0, 1, 3]])
    second = np.where(along02, quads[:, [0, 2, 3]], quads[:, [1, 2, 3]])
    return np.concatenate([first, second])


# Gmsh's 6-node triangle: corners 0, 1, 2, then the midpoints of 01, 12, 20.
_P2_SPLIT = np.array([[0, 3, 5], [3, 1, 4], [5, 4, 2], [3, 4, 5]])


def triangles_of_model(notes: list[str] | None = None):
    """(xyz of all nodes, triangles as node rows, edges of the 1D elements with their
    curve tags) of the current Gmsh mesh; higher orders and quadrilaterals converted."""
    tags, coords, _ = gmsh.model.mesh.getNodes()
    xyz = coords.reshape(-1, 3)
    row = np.full(int(tags.max(initial=0)) + 1, -1, dtype=np.int64)
    row[tags.astype(np.int64)] = np.arange(tags.size)
    pieces, converted, owners = [], {}, []
    for _, surface in gmsh.model.getEntities(2):
        types, _, nodes = gmsh.model.mesh.getElements(2, surface)
        for kind, element_nodes in zip(types, nodes, strict=True):
            name, _, order, count, _, corners = gmsh.model.mesh.getElementProperties(kind)
            e = row[element_nodes.astype(np.int64)].reshape(-1, count)
            if corners == 3 and count == 6:
                pieces.append(e[:, _P2_SPLIT].reshape(-1, 3))
                what = "second-order triangles split into 4 linear triangles each (all nodes kept)"
            elif corners == 3:
                pieces.append(e[:, :3])
                what = None if order == 1 else f"{name} reduced to their corner nodes"
            elif corners == 4:
                pieces.append(_split_quads(e[:, :4], xyz))
                what = "quadrilaterals split into 2 triangles each"
                if order > 1:
                    what += " (higher-order nodes dropped)"
            else:
                raise GeometryError(f"unsupported 2D element type {name!r}")
            if what:
                converted[what] = converted.get(what, 0) + e.shape[0]
            owners.append(np.full(pieces[-1].shape[0], surface, dtype=np.int64))
    if notes is not None:
        notes.extend(f"{n} {what}" for what, n in converted.items())
    cells = np.concatenate(pieces) if pieces else np.zeros((0, 3), dtype=np.int64)
    cell_surface = np.concatenate(owners) if owners else np.zeros(0, dtype=np.int64)
    edges, edge_curve = [], []
    for _, curve in gmsh.model.getEntities(1):
        types, _, nodes = gmsh.model.mesh.getElements(1, curve)
        for kind, element_nodes in zip(types, nodes, strict=True):
            count = gmsh.model.mesh.getElementProperties(kind)[3]
            e = row[element_nodes.astype(np.int64)].reshape(-1, count)
            # A 3-node line is two edges through its midpoint (node 2), as the P2 split.
            pairs = e if count == 2 else np.concatenate([e[:, [0, 2]], e[:, [2, 1]]])
            edges.append(pairs[:, :2])
            edge_curve.append(np.full(pairs.shape[0], curve, dtype=np.int64))
    edges = np.concatenate(edges) if edges else np.zeros((0, 2), dtype=np.int64)
    curves = np.concatenate(edge_curve) if edge_curve else np.zeros(0, dtype=np.int64)
    return xyz, cells, edges, curves, tags, cell_surface


def slit_curves() -> set[int]:
    """Curves that bound one surface on both of their sides (a slit, a crack: the
    surface's boundary loop runs along the curve and back)."""
    slits = set()
    for _, surface in gmsh.model.getEntities(2):
        try:
            boundary = gmsh.model.getBoundary([(2, surface)], combined=False, oriented=True)
        except Exception:  # a discrete surface without topology: no slits known
            continue
        seen = [abs(int(tag)) for dim, tag in boundary if dim == 1]
        slits |= {c for c in seen if seen.count(c) > 1}
    return slits


def crack(cells: np.ndarray, slit_edges: np.ndarray) -> np.ndarray:
    """The mesh cut open along ``slit_edges`` (k, 2): per node, the triangles around it
    that meet across edges other than slit edges share one copy of it, so both sides
    of a slit become boundary (a slit's tip, which the triangles surround, stays one
    node). Returns, per corner of ``cells`` (m, 3), the new node, numbered from 0, as an
    array shaped like ``cells``; node copy j is of old node ``cells.ravel()`` at the
    first corner labelled j."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    m = cells.shape[0]
    n = int(cells.max()) + 1
    slit = set(_edge_keys(slit_edges, n).tolist())
    # every edge (a, b) of triangle t at its corners i (node a) and i + 1 (node b)
    corner_a = np.arange(3 * m).reshape(m, 3)
    a, b = cells.ravel(), cells[:, [1, 2, 0]].ravel()
    ca, cb = corner_a.ravel(), corner_a[:, [1, 2, 0]].ravel()
    keys = _edge_keys(np.stack([a, b], axis=1), n)
    order = np.argsort(keys, kind="stable")
    k_sorted = keys[order]
    pair = np.flatnonzero(k_sorted[1:] == k_sorted[:-1])  # interior edges: two half-edges
    first, second = order[pair], order[pair + 1]
    joined = ~np.isin(keys[first], list(slit)) if slit else np.ones(first.size, dtype=bool)
    first, second = first[joined], second[joined]
    # the half-edges run opposite ways: a of one is b of the other
    rows = np.concatenate([ca[first], cb[first]])
    cols = np.concatenate([cb[second], ca[second]])
    graph = coo_matrix((np.ones(rows.size), (rows, cols)), shape=(3 * m, 3 * m))
    _, label = connected_components(graph, directed=False)
    _, new = np.unique(label, return_inverse=True)
    return new.reshape(m, 3)


def _edge_keys(pairs: np.ndarray, n: int) -> np.ndarray:
    lo, hi = np.minimum(pairs[:, 0], pairs[:, 1]), np.maximum(pairs[:, 0], pairs[:, 1])
    return lo * n + hi


@dataclass
class MeshArrays:
    """The mesh on rank 0 as arrays (compressed to the nodes the triangles use), with the
    model entities it lies on: the surface of every triangle, the edges on model curves
    (boundary, interfaces between surfaces, curves embedded in a surface) and the nodes at
    model points, and the file's physical groups."""

    x: np.ndarray  # (n, 2)
    cells: np.ndarray  # (m, 3), counter-clockwise
    boundary: np.ndarray  # (k, 2) boundary edges, domain on their left
    boundary_curve: np.ndarray  # (k,) curve tag of each
    gmsh_node: np.ndarray  # (n,) Gmsh node tag of each row
    edges: np.ndarray  # (e, 2) every edge once, (lo, hi)
    cell_surface: np.ndarray = None  # (m,) surface tag of each triangle
    interior_curve_edges: np.ndarray = None  # (c, 2) interior edges on a curve, (lo, hi)
    interior_curve: np.ndarray = None  # (c,) curve tag of each
    point_nodes: np.ndarray = None  # (p,) rows at model points (a slit's end: both copies)
    point_tag: np.ndarray = None  # (p,) the point tag of each
    physical_groups: tuple = ()  # mesh.domain.PhysicalGroup records of the file

    @property
    def curve_edges(self) -> np.ndarray:
        """Every edge on a model curve: the boundary ones (tagged), then the interior ones."""
        tagged = self.boundary_curve != NO_CURVE
        return np.concatenate([self.boundary[tagged], self.interior_curve_edges])

    @property
    def edge_curve(self) -> np.ndarray:
        """The curve tag of each of :attr:`curve_edges`."""
        tagged = self.boundary_curve != NO_CURVE
        return np.concatenate([self.boundary_curve[tagged], self.interior_curve])


def plane_frame(xyz: np.ndarray, source: str):
    """The plane the points lie in: None where it is z = const (within 1e-8 of their
    extent), else (origin, e1, e2): a point and two orthonormal axes of the plane, e1
    along its intersection with z = const (x's direction if it is horizontal-ish),
    e1 × e2 the normal with a positive z (or y) component.

    Raises:
        GeometryError: the points lie in no plane.
    """
    xyz = np.asarray(xyz, dtype=float).reshape(-1, 3)
    scale = max(float(np.abs(xyz).max(initial=0.0)), 1e-300)
    z = xyz[:, 2]
    if xyz.shape[0] == 0 or float(z.max() - z.min()) <= 1e-8 * scale:
        return None
    origin = xyz.mean(axis=0)
    _, sigma, vt = np.linalg.svd(xyz - origin, full_matrices=False)
    normal = vt[-1]
    if float(np.abs((xyz - origin) @ normal).max()) > 1e-8 * scale:
        raise GeometryError(f"{source!r} is not planar (its points lie in no one plane)")
    if normal[2] < 0 or (normal[2] == 0 and normal[1] < 0):
        normal = -normal
    e1 = np.cross([0.0, 0.0, 1.0], normal)
    if np.linalg.norm(e1) < 1e-12:  # horizontal after all
        e1 = np.array([1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    return origin, e1, e2


_PLANE_ATTRIBUTE = "ufl_frames_plane"


def record_plane(frame) -> None:
    """Keep :func:`plane_frame`'s (origin, e1, e2) with the current Gmsh model (read back
    by :func:`recorded_plane`)."""
    gmsh.model.setAttribute(_PLANE_ATTRIBUTE,
                            [repr(float(c)) for v in frame for c in np.ravel(v)])


def recorded_plane():
    """The :class:`~ufl_frames.mesh.domain.Plane` kept by :func:`record_plane` with the
    current Gmsh model, None where none was."""
    from ufl_frames.mesh.domain import Plane

    if _PLANE_ATTRIBUTE not in gmsh.model.getAttributeNames():
        return None
    c = [float(v) for v in gmsh.model.getAttribute(_PLANE_ATTRIBUTE)]
    return Plane(tuple(c[0:3]), tuple(c[3:6]), tuple(c[6:9]))


def plane_coordinates(xyz: np.ndarray, source: str, notes: list[str]) -> np.ndarray:
    """(n, 2) coordinates of mesh nodes in their plane: x, y where it is z = const, else
    the coordinates along :func:`plane_frame`'s axes (said in ``notes``, the frame kept
    by :func:`record_plane`)."""
    frame = plane_frame(xyz, source)
    if frame is None:
        return np.ascontiguousarray(xyz[:, :2])
    origin, e1, e2 = frame
    record_plane(frame)
    notes.append(f"the mesh lies in a tilted plane: meshed in its own coordinates "
                 f"(u, v) = ((p - o)·e1, (p - o)·e2), o = {_vector(origin)}, "
                 f"e1 = {_vector(e1)}, e2 = {_vector(e2)}")
    return np.ascontiguousarray(np.stack([(xyz - origin) @ e1, (xyz - origin) @ e2], axis=1))


def _vector(v) -> str:
    return "(" + ", ".join(f"{float(c):.6g}" for c in v) + ")"


def mesh_arrays(source: str, notes: list[str]) -> MeshArrays:
    """The current Gmsh mesh as checked arrays: used nodes only, planar, valid cells."""
    if len(surfaces()) > 1:  # touching surfaces of a .msh or of a built-in model
        gmsh.model.mesh.removeDuplicateNodes()  # (2 s for 10⁶ triangles: not for one surface)
    xyz, cells, curve_edges, curves, tags, cell_surface = triangles_of_model(notes)
    if cells.size == 0:
        raise GeometryError(f"{source!r} produced no triangle cells")
    used, cells = np.unique(cells, return_inverse=True)
    cells = cells.reshape(-1, 3)
    unused = tags.size - used.size
    if unused:
        notes.append(f"{unused} nodes that no triangle uses were dropped (centre points, ...)")
    xyz = xyz[used]
    if not np.all(np.isfinite(xyz)):
        raise GeometryError(f"{source!r} has nodes with NaN or infinite coordinates")
    x = plane_coordinates(xyz, source, notes)
    if np.any((cells[:, 0] == cells[:, 1]) | (cells[:, 1] == cells[:, 2])
              | (cells[:, 0] == cells[:, 2])):
        raise GeometryError(f"{source!r} has triangles with a repeated node")
    area = signed_areas(x, cells)
    # Degenerate by shape, not by size: graded meshes have tiny good triangles.
    longest = np.max([np.sum((x[cells[:, i]] - x[cells[:, (i + 1) % 3]]) ** 2, axis=1)
                      for i in range(3)], axis=0)
    degenerate = np.abs(area) <= 1e-10 * longest
    if degenerate.any():
        raise GeometryError(f"{source!r} has {int(degenerate.sum())} zero-area triangles")
    cells = np.where((area < 0)[:, None], cells[:, [0, 2, 1]], cells)
    new_row = np.full(int(tags.size), -1, dtype=np.int64)
    new_row[used] = np.arange(used.size)
    node_tags = tags[used]
    point_nodes, point_tag = _model_point_rows(tags, new_row)
    slits = slit_curves()
    if slits and curve_edges.size:
        on_slit = np.isin(curves, list(slits))
        slit_edges = new_row[curve_edges[on_slit]]
        cracked = crack(cells, slit_edges[np.all(slit_edges >= 0, axis=1)])
        copy_of = np.empty(int(cracked.max()) + 1, dtype=np.int64)
        copy_of[cracked.ravel()] = cells.ravel()
        if copy_of.size > x.shape[0]:
            notes.append(f"cut open along {len(slits)} slit curve(s): "
                         f"{copy_of.size - x.shape[0]} nodes doubled")
        x, cells, node_tags = x[copy_of], cracked, node_tags[copy_of]
        # a curve's edges name the old nodes: on the slits, map them to both copies
        curve_edges, curves = _edges_on_copies(curve_edges, curves, new_row, copy_of)
        point_nodes, point_tag = _rows_on_copies(point_nodes, point_tag, copy_of)
        new_row = np.arange(copy_of.size)
        tags = np.arange(copy_of.size)

    n = x.shape[0]
    directed = np.concatenate([cells[:, [0, 1]], cells[:, [1, 2]], cells[:, [2, 0]]])
    keys = _edge_keys(directed, n)
    unique, first, counts = np.unique(keys, return_index=True, return_counts=True)
    mesh_edges = np.stack([unique // n, unique % n], axis=1)
    if np.any(counts > 2):
        raise GeometryError(
            f"{source!r}: {int((counts > 2).sum())} edges are shared by more than two "
            "triangles (overlapping surfaces)"
        )
    boundary = directed[first[counts == 1]]
    own_cell = first[counts == 1] % cells.shape[0]
    # Curve of each boundary edge, from the 1D elements (map their nodes to rows first).
    boundary_curve = np.full(boundary.shape[0], NO_CURVE, dtype=np.int64)
    interior_keys = unique[counts == 2]
    interior_curve = np.zeros(0, dtype=np.int64)
    if curve_edges.size:
        mapped = new_row[curve_edges]
        ok = np.all(mapped >= 0, axis=1)
        curve_keys = _edge_keys(mapped[ok], n)
        order = np.argsort(curve_keys)
        curve_keys, curve_of = curve_keys[order], curves[ok][order]
        found = lookup(curve_keys, curve_of.astype(float), _edge_keys(boundary, n))
        boundary_curve = np.where(np.isnan(found), NO_CURVE, found).astype(np.int64)
        # interfaces and embedded curves: mesh edges of two triangles on a curve
        found = lookup(curve_keys, curve_of.astype(float), interior_keys)
        interior_keys = interior_keys[np.isfinite(found)]
        interior_curve = found[np.isfinite(found)].astype(np.int64)
    else:
        interior_keys = interior_keys[:0]
    _check_conforming(source, x, cells, boundary, cell_surface, own_cell)
    return MeshArrays(x=x, cells=cells, boundary=boundary, boundary_curve=boundary_curve,
                      gmsh_node=node_tags, edges=mesh_edges, cell_surface=cell_surface,
                      interior_curve_edges=np.stack([interior_keys // n, interior_keys % n],
                                                    axis=1),
                      interior_curve=interior_curve, point_nodes=point_nodes,
                      point_tag=point_tag, physical_groups=physical_groups())


def _model_point_rows(tags: np.ndarray, new_row: np.ndarray):
    """(rows, point tags) of the mesh nodes on the model's points (0D entities) that the
    triangles use; ``tags`` are the Gmsh node tags of the uncompressed rows, ``new_row``
    their compressed rows (−1: unused)."""
    row_of_tag = np.full(int(tags.max(initial=0)) + 1, -1, dtype=np.int64)
    row_of_tag[tags.astype(np.int64)] = np.arange(tags.size)
    rows, owner = [], []
    for _, point in gmsh.model.getEntities(0):
        for t in gmsh.model.mesh.getNodes(0, point)[0].astype(np.int64):
            r = row_of_tag[t] if t < row_of_tag.size else -1
            if r >= 0 and new_row[r] >= 0:
                rows.append(int(new_row[r]))
                owner.append(int(point))
    return np.array(rows, dtype=np.int64), np.array(owner, dtype=np.int64)


def _rows_on_copies(rows: np.ndarray, values: np.ndarray, copy_of: np.ndarray):
    """``rows`` (with their ``values``) in the cracked numbering: every copy of each."""
    order = np.argsort(copy_of, kind="stable")
    start = np.searchsorted(copy_of[order], rows, side="left")
    stop = np.searchsorted(copy_of[order], rows, side="right")
    new = [order[a:b] for a, b in zip(start, stop, strict=True)]
    counts = np.array([part.size for part in new], dtype=np.int64)
    out = np.concatenate(new) if new else np.zeros(0, dtype=np.int64)
    return out.astype(np.int64), np.repeat(values, counts)


def physical_groups() -> tuple[PhysicalGroup, ...]:
    """The current model's physical groups, by dimension and number."""
    groups = []
    for dim, tag in sorted(gmsh.model.getPhysicalGroups()):
        entities = gmsh.model.getEntitiesForPhysicalGroup(dim, tag)
        groups.append(PhysicalGroup(dim=int(dim), tag=int(tag),
                                    name=gmsh.model.getPhysicalName(dim, tag),
                                    entities=tuple(sorted(int(e) for e in entities))))
    return tuple(groups)


def _edges_on_copies(curve_edges, curves, new_row, copy_of):
    """The curves' edges (old node tags' rows) in the cracked numbering: an edge whose
    nodes were doubled is listed once per pair of copies (the lookup keeps the ones that
    are mesh edges)."""
    copies = [[] for _ in range(int(new_row.max()) + 1)]
    for new, old in enumerate(copy_of):
        copies[old].append(new)
    pairs, owner = [], []
    for (ta, tb), curve in zip(new_row[curve_edges], curves, strict=True):
        if ta < 0 or tb < 0:
            continue
        for a in copies[ta]:
            for b in copies[tb]:
                pairs.append((a, b))
                owner.append(curve)
    return (np.array(pairs, dtype=np.int64).reshape(-1, 2),
            np.array(owner, dtype=np.int64))


def _check_conforming(source: str, x, cells, boundary, cell_surface, own_cell) -> None:
    """Refuse boundary edges that lie inside another surface: surfaces that touch or
    overlap without sharing their nodes (the frame field would see a slit there). A
    boundary edge facing its own surface (a slit, a notch narrower than the probe) is
    the shape itself."""
    from scipy.spatial import cKDTree

    a, b = x[boundary[:, 0]], x[boundary[:, 1]]
    edge = b - a
    outward = np.stack([edge[:, 1], -edge[:, 0]], axis=1)  # the domain is on the left
    probe = 0.5 * (a + b) + 1e-3 * outward
    centres = x[cells].mean(axis=1)
    k = min(12, cells.shape[0])
    _, near = cKDTree(centres).query(probe, k=k)
    near = near.reshape(probe.shape[0], -1)
    inside = np.zeros(probe.shape[0], dtype=bool)
    for j in range(near.shape[1]):
        tri = x[cells[near[:, j]]]  # (k, 3, 2)
        d = [
            (tri[:, (i + 1) % 3, 0] - tri[:, i, 0]) * (probe[:, 1] - tri[:, i, 1])
            - (tri[:, (i + 1) % 3, 1] - tri[:, i, 1]) * (probe[:, 0] - tri[:, i, 0])
            for i in range(3)
        ]
        other = cell_surface[near[:, j]] != cell_surface[own_cell]
        inside |= (d[0] > 0) & (d[1] > 0) & (d[2] > 0) & other
    if inside.any():
        raise GeometryError(
            f"{source!r}: {int(inside.sum())} boundary edges lie inside the domain: surfaces "
            "touch or overlap without sharing nodes (use BooleanFragments or Coherence)"
        )


def interior_angles(x, cells, n) -> np.ndarray:
    """Sum of the triangle angles at every node (2π inside, the interior angle on ∂Ω).

    Args:
        x: node coordinates (n, 2).
        cells: triangles (m, 3), node indices.
        n: the number of nodes (the length of the result).

    Returns:
        The angle sums (n,), in radians (0 at a node of no triangle).
    """
    total = np.zeros(n)
    for i in range(3):
        p, q, r = cells[:, i], cells[:, (i + 1) % 3], cells[:, (i + 2) % 3]
        u, v = x[q] - x[p], x[r] - x[p]
        angle = np.arctan2(np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]),
                           np.einsum("ij,ij->i", u, v))
        np.add.at(total, p, angle)
    return total


def cad_directions(arrays: MeshArrays, mesh_angle: np.ndarray):
    """Cross angles ψ at the nodes on model curves from the curves' tangents, the
    boundary's corners and the junctions of the curves inside the domain.

    At a node inside a curve ψ is the tangent's angle there; at a geometric point the
    crosses of the curves meeting there are averaged in the 4-fold representation
    e^{4iψ} (on the boundary those of the boundary curves only: the boundary's cross
    wins over an interface's) and the interior angle is the angle between the boundary
    curves' outgoing tangents (on the side the mesh says, for reflex corners). A point
    where interior curves (interfaces, embedded curves) end, turn or meet is a
    :class:`~ufl_frames.mesh.domain.Junction`; a boundary point that only interior curves
    meet is no corner.

    Returns:
        (ψ (n,) with NaN where the model gives none, corners, junctions).
    """
    n = arrays.x.shape[0]
    on_boundary = np.zeros(n, dtype=bool)
    on_boundary[arrays.boundary.ravel()] = True
    interior_edges = _or_empty(arrays.interior_curve_edges)
    interior_tags = _or_empty(arrays.interior_curve, (0,))
    curve_nodes = np.unique(np.concatenate([arrays.boundary.ravel(), interior_edges.ravel()]))
    rows_of_tag: dict[int, list[int]] = {}  # a node cut open along a slit has two rows
    for row in curve_nodes:
        rows_of_tag.setdefault(int(arrays.gmsh_node[row]), []).append(int(row))
    psi = np.full(n, np.nan)
    boundary_curves = {int(c) for c in arrays.boundary_curve if c != NO_CURVE}
    interior_curves = {int(c) for c in interior_tags} - boundary_curves
    for curve in sorted(boundary_curves | interior_curves):
        tags, _, param = gmsh.model.mesh.getNodes(1, curve, includeBoundary=False,
                                                  returnParametricCoord=True)
        if not tags.size or param.size != tags.size:
            continue
        d = np.asarray(gmsh.model.getDerivative(1, curve, param)).reshape(-1, 3)
        for t, (dx, dy, _) in zip(tags, d, strict=True):
            if math.hypot(dx, dy) > 0:
                psi[rows_of_tag.get(int(t), [])] = math.atan2(dy, dx)
    corners, junctions = [], []
    for _, point in gmsh.model.getEntities(0):
        tags = gmsh.model.mesh.getNodes(0, point)[0]
        if tags.size != 1 or int(tags[0]) not in rows_of_tag:
            continue
        rows = rows_of_tag[int(tags[0])]
        if len(rows) > 1:  # a slit's end on the boundary: each copy its own corner
            corners += [Corner(float(arrays.x[r, 0]), float(arrays.x[r, 1]),
                               float(mesh_angle[r])) for r in rows
                        if round(mesh_angle[r] / (math.pi / 2)) != 2]
            continue
        node = rows[0]
        outer = _outgoing(point, boundary_curves)
        inner = _outgoing(point, interior_curves)
        here = (float(arrays.x[node, 0]), float(arrays.x[node, 1]))
        if not on_boundary[node]:
            z = sum(np.exp(4j * math.atan2(ty, tx)) for tx, ty in inner)
            if inner and abs(z) > 1e-9 * len(inner):
                psi[node] = np.angle(z) / 4
            sectors = _sectors(inner, None)
            if sectors and not (len(sectors) == 2 and abs(sectors[0] - math.pi) < 1e-6):
                junctions.append(Junction(*here, sectors=sectors, on_boundary=False))
            continue
        if not outer:
            continue
        z = sum(np.exp(4j * math.atan2(ty, tx)) for tx, ty in outer)
        if abs(z) > 1e-9 * len(outer):
            psi[node] = np.angle(z) / 4
        if len(outer) == 1:  # a slit's tip: the boundary turns back, a full turn
            corners.append(Corner(*here, float(mesh_angle[node])))
        if len(outer) == 2:
            (ax, ay), (bx, by) = outer
            theta = math.atan2(abs(ax * by - ay * bx), ax * bx + ay * by)
            angle = min((theta, 2 * math.pi - theta), key=lambda a: abs(a - mesh_angle[node]))
            if abs(angle - math.pi) > 1e-6:
                corners.append(Corner(*here, angle))
            if angle < math.pi / 4:  # the average above turns the 0-quarter-turn way
                psi[node] = _acute_cross(outer)
            if inner:
                sectors = _sectors(outer + inner, _first_boundary_ray(arrays, node, outer))
                if sectors:
                    junctions.append(Junction(*here, sectors=sectors, on_boundary=True))
    return psi, corners, junctions


def _acute_cross(rays) -> float:
    """The cross ψ at a corner under 45° between the two ``rays`` (x, y) leaving it, the
    domain between them: one quarter turn (:func:`~ufl_frames.frames2d.singularities.corner_cross`
    of their bisector), not the 4-fold average's none."""
    (ax, ay), (bx, by) = rays
    ux, uy = ax / math.hypot(ax, ay) + bx / math.hypot(bx, by), \
        ay / math.hypot(ax, ay) + by / math.hypot(bx, by)
    theta = math.atan2(abs(ax * by - ay * bx), ax * bx + ay * by)
    return corner_cross(math.atan2(uy, ux), theta)


def acute_corner_directions(arrays: MeshArrays, mesh_angle: np.ndarray):
    """The cross angles at the corners under 45° of a bare mesh (no CAD curves), from its
    boundary edges: (nodes, ψ), or None where there are none. Elsewhere the boundary
    cross is the 4-fold average of the edges' (:mod:`ufl_frames.fem.constraints`), which
    at such a corner turns the 0-quarter-turn way (:func:`_acute_cross`)."""
    nodes, psi = [], []
    for v in np.unique(arrays.boundary):
        if mesh_angle[v] >= math.pi / 4:
            continue
        after = arrays.boundary[arrays.boundary[:, 0] == v, 1]  # the domain on their left
        before = arrays.boundary[arrays.boundary[:, 1] == v, 0]
        if after.size == 1 and before.size == 1:
            nodes.append(int(v))
            psi.append(_acute_cross([tuple(arrays.x[after[0]] - arrays.x[v]),
                                     tuple(arrays.x[before[0]] - arrays.x[v])]))
    if not nodes:
        return None
    return np.asarray(nodes, dtype=np.int64), np.asarray(psi, dtype=np.float64)


def _or_empty(values, shape=(0, 2)) -> np.ndarray:
    return np.zeros(shape, dtype=np.int64) if values is None else values


def _outgoing(point: int, curves: set[int]) -> list[tuple[float, float]]:
    """The tangents (x, y) of ``curves`` leaving the model point ``point`` (one per end of
    a curve there: a closed curve through it gives two)."""
    xyz = gmsh.model.getValue(0, point, [])
    out = []
    for curve in gmsh.model.getAdjacencies(0, point)[0]:
        if int(curve) not in curves:
            continue
        lo, hi = (float(v[0]) for v in gmsh.model.getParametrizationBounds(1, int(curve)))
        for end, sign in ((lo, 1.0), (hi, -1.0)):
            at = gmsh.model.getValue(1, int(curve), [end])
            if math.dist(at[:2], xyz[:2]) > 1e-9 * max(1.0, math.hypot(*xyz[:2])):
                continue
            t = gmsh.model.getDerivative(1, int(curve), [end])
            if math.hypot(t[0], t[1]) > 0:
                out.append((sign * t[0], sign * t[1]))
    return out


def _first_boundary_ray(arrays: MeshArrays, node: int, outer) -> int:
    """Which of the two boundary tangents ``outer`` at a boundary ``node`` runs along the
    boundary edge that leaves it (the domain on its left)."""
    edge = arrays.boundary[arrays.boundary[:, 0] == node]
    if not edge.size:
        return 0
    d = arrays.x[edge[0, 1]] - arrays.x[node]
    return int(np.argmax([tx * d[0] + ty * d[1] for tx, ty in outer]))


def _sectors(rays, first: int | None) -> tuple[float, ...]:
    """The angles between consecutive ``rays`` counter-clockwise: all around (``first``
    None: a point inside the domain), or from ray ``first`` (a boundary tangent) to the
    other boundary ray, ``rays[0]`` or ``rays[1]`` (a point on the boundary)."""
    if not rays:
        return ()
    angles = np.array([math.atan2(ty, tx) for tx, ty in rays])
    start = angles[0 if first is None else first]
    turn = np.mod(angles - start, 2 * math.pi)
    if first is None:
        turn = np.sort(turn)
        return tuple(float(a) for a in np.diff(np.append(turn, 2 * math.pi)))
    end = turn[1 - first]
    inside = np.sort(turn[(turn > 0) & (turn < end)])
    return tuple(float(a) for a in np.diff(np.concatenate([[0.0], inside, [end]])))


def mesh_corners(arrays: MeshArrays, mesh_angle: np.ndarray) -> list[Corner]:
    """Corners of a bare mesh: boundary nodes whose interior angle is not ~180° (the
    ones a boundary-aligned cross must turn a quarter at)."""
    nodes = np.unique(arrays.boundary)
    turns = np.rint(mesh_angle[nodes] / (math.pi / 2))
    return [
        Corner(float(arrays.x[v, 0]), float(arrays.x[v, 1]), float(mesh_angle[v]))
        for v in nodes[turns != 2]
    ]


def euler_characteristic(arrays: MeshArrays) -> int:
    """χ = V − E + F of the triangulation (1 for a disc, 1 − holes in general)."""
    return int(arrays.x.shape[0] - arrays.edges.shape[0] + arrays.cells.shape[0])


def mean_edge_length(arrays: MeshArrays) -> float:
    e = arrays.edges
    return float(np.linalg.norm(arrays.x[e[:, 1]] - arrays.x[e[:, 0]], axis=1).mean())
