"""Quad-mesh nodes onto the geometry's CAD curves and points.

The quads' boundary (and interface) nodes come from the triangle mesh, whose edges are
chords of the curves: on a curved boundary they lie off it by up to the chords' sagitta
(about 1e-4 of the diameter at the default sizes). :func:`snap_to_cad` rebuilds the
geometry's CAD model in Gmsh without meshing it (a built-in shape with its default
parameters, :data:`~ufl_frames.mesh.builtin.BUILTIN_MODELS`; a ``.geo``, ``.step``/``.stp``
or ``.brep`` file read and its surfaces united as the loader does) and moves

* every node on a model curve to its closest point on that curve
  (``gmsh.model.getClosestPoint``), and
* every node at a model point exactly onto the point (``gmsh.model.getValue``).

Which curve a node lies on comes from the quad mesh's curve edges where it has them;
without them, every boundary node of the quads goes to the closest of the model's
boundary curves, and the boundary node closest to each model point on the boundary goes
onto the point if it lies within :data:`POINT_SNAP` of the boundary's mean edge length of
it (a corner of the geometry, which the quads keep as a vertex; a point where two curves
meet smoothly, a fillet's end, is no quad vertex in general, and its nearest node stays on
its curve). A ``.msh`` has no CAD model: its nodes stay where they are (said in the record's
``note``). A move that would invert a quad or make it degenerate (a scaled Jacobian ≤ 0)
is refused: the node keeps its old position, and the refusals are counted.

Runs on one process (rank 0 of a run), in a child process under a time limit like the
loader's meshing (:func:`ufl_frames.mesh.distribute.create`); Gmsh is left as it was found.
"""

import math
from dataclasses import dataclass
from pathlib import Path

from ufl_frames.bootstrap import init_petsc

init_petsc()

import gmsh  # noqa: E402
import numpy as np  # noqa: E402

from ufl_frames.mesh.builtin import BUILTIN_MODELS  # noqa: E402
from ufl_frames.mesh.domain import GeometryError, one_line  # noqa: E402
from ufl_frames.quads.measures import check_quad_mesh, scaled_jacobians  # noqa: E402
from ufl_frames.quads.msh import mesh_boundary_edges  # noqa: E402

__all__ = ["CadSnap", "MAX_MOVE", "POINT_SNAP", "snap_to_cad"]

#: A move longer than this share of the boundary's mean edge length is refused: a node on
#: its curve moves by a chord's sagitta, far less (a longer one went to another curve).
MAX_MOVE = 0.5
#: Without point nodes, a boundary node goes onto a model point only within this share of
#: the boundary's mean edge length of it: a quad vertex made at the point, up to rounding.
POINT_SNAP = 1e-6


@dataclass(frozen=True)
class CadSnap:
    """Nodes moved onto the CAD model: ``points`` (n, 2) after the moves; ``moved`` nodes
    moved, ``refused`` moves refused (they would invert a quad); ``max_move`` the longest
    move; ``max_offset_before`` / ``max_offset_after`` the largest distance of a node to
    its curve or point before and after; ``note`` why nothing was moved (None when the
    model was there)."""

    points: np.ndarray
    moved: int
    refused: int
    max_move: float
    max_offset_before: float
    max_offset_after: float
    note: str | None = None

    def record(self) -> dict:
        """The numbers, for ``summary.json``."""
        return {"moved": self.moved, "refused": self.refused, "max_move": self.max_move,
                "max_offset_before": self.max_offset_before,
                "max_offset_after": self.max_offset_after, "note": self.note}


def snap_to_cad(source: str, points, quads, curve_edges=None, edge_curve=None,
                point_nodes=None, point_tag=None, time_limit: float = math.inf,
                plane=None) -> CadSnap:
    """The quad mesh's curve and point nodes moved onto the CAD model of ``source``.

    Args:
        source: a built-in shape's name or a geometry file (:func:`ufl_frames.mesh.build`).
        points: the quads' points (n, 2).
        quads: point indices (m, 4), counter-clockwise.
        curve_edges: (k, 2) point pairs of the quad edges on model curves, or None (then
            the boundary nodes go to the closest boundary curve; module text).
        edge_curve: (k,) the curve tag of each.
        point_nodes: (p,) points at model points, or None.
        point_tag: (p,) the model point's tag of each.
        time_limit: seconds for Gmsh to rebuild the model and project (a child process;
            ``math.inf``: in this process, no limit).
        plane: the :class:`~ufl_frames.mesh.domain.Plane` of a model in a tilted plane
            (``points`` are its (u, v) coordinates; projected in the model's own 3D
            coordinates); None: a model in z = const.

    Returns:
        The moved points and the counts.

    Raises:
        GeometryError: the model cannot be rebuilt (a file that no longer reads), a curve
            or point tag is not in it, or Gmsh takes longer than ``time_limit``.
    """
    x = np.array(points, dtype=np.float64)[:, :2]
    q = np.asarray(quads, dtype=np.int64).reshape(-1, 4)
    key = str(source)
    if key not in BUILTIN_MODELS and Path(key).suffix.lower() == ".msh":
        return CadSnap(x, 0, 0, 0.0, math.nan, math.nan,
                       note=f"{key!r} is a mesh without CAD model: the quads' boundary nodes "
                            "stay on the triangles' boundary")
    asked = _asked(x, q, curve_edges, edge_curve, point_nodes, point_tag)

    def work():
        return _session(lambda: _targets(key, x, asked, plane))

    if math.isfinite(time_limit):
        from ufl_frames.mesh.distribute import _in_child

        nodes, targets = _in_child(work, key, time_limit)
    else:
        nodes, targets = work()
    return _apply(x, q, nodes, targets, asked["longest"])


def _asked(x, q, curve_edges, edge_curve, point_nodes, point_tag) -> dict:
    """What to project: (nodes, curve tags) and (nodes, point tags), or the boundary nodes
    and a tolerance for the model points where the mesh names neither."""
    boundary = mesh_boundary_edges(q)
    length = np.linalg.norm(x[boundary[:, 1]] - x[boundary[:, 0]], axis=1)
    edge = float(length.mean()) if length.size else 0.0
    if curve_edges is None and point_nodes is None:
        return {"boundary": np.unique(boundary), "tolerance": POINT_SNAP * edge,
                "longest": MAX_MOVE * edge}
    nodes = np.asarray([] if point_nodes is None else point_nodes, dtype=np.int64).ravel()
    tags = np.asarray([] if point_tag is None else point_tag, dtype=np.int64).ravel()
    edges = np.asarray(np.zeros((0, 2)) if curve_edges is None else curve_edges,
                       dtype=np.int64).reshape(-1, 2)
    curves = np.repeat(np.asarray([] if edge_curve is None else edge_curve,
                                  dtype=np.int64).ravel(), 2)
    if nodes.shape != tags.shape or curves.size != edges.size:
        raise ValueError("point_nodes and point_tag, curve_edges and edge_curve must match")
    # every (node, curve) pair: a node on the edges of two curves (a quad edge spanning a
    # smooth joint) goes to the nearer of them (:func:`_targets`)
    pairs = np.unique(np.stack([edges.ravel(), curves], axis=1).reshape(-1, 2), axis=0)
    keep = ~np.isin(pairs[:, 0], nodes)
    return {"points": (nodes, tags), "curves": (pairs[keep, 0], pairs[keep, 1]),
            "longest": MAX_MOVE * edge}


def _session(work):
    """``work()`` in a fresh Gmsh model; Gmsh left as it was found; errors as
    :class:`GeometryError`."""
    from ufl_frames.mesh.distribute import _release, verbose

    owns, previous, saved = not gmsh.isInitialized(), None, {}
    touched = ("General.Terminal", "General.AbortOnError")
    try:
        if owns:
            gmsh.initialize(argv=[], readConfigFiles=False, interruptible=False)
        else:
            saved = {k: gmsh.option.getNumber(k) for k in touched}
            previous = gmsh.model.getCurrent()
        gmsh.option.setNumber("General.Terminal", 1 if verbose() else 0)
        gmsh.model.add("ufl_frames_cad")
        return work()
    except GeometryError:
        raise
    except Exception as e:
        raise GeometryError(f"Gmsh failed rebuilding the CAD model: {one_line(e)}") from e
    finally:
        _release(owns, previous, saved)


def _rebuild(source: str) -> None:
    """The CAD model of ``source`` in the current Gmsh model, surfaces united as by the
    loader (:func:`ufl_frames.mesh.meshing.mesh_model`), not meshed."""
    from ufl_frames.mesh import files
    from ufl_frames.mesh.meshing import _unite_surfaces

    if source in BUILTIN_MODELS:
        BUILTIN_MODELS[source]()
        return
    path = Path(source)
    if not path.is_file():
        raise GeometryError(f"geometry file not found: {source!r}")
    if path.suffix.lower() in files.GEO_EXTENSIONS:
        files._check_geo_script(path)
    files._merge(path, quiet=path.suffix.lower() in files.CAD_EXTENSIONS)
    _unite_surfaces([])


def _targets(source: str, x: np.ndarray, asked: dict, plane=None):
    """(nodes, their targets (k, 2)) on the rebuilt model of ``source`` (in ``plane``'s
    coordinates where it is given)."""
    _rebuild(source)
    if "boundary" in asked:
        return _nearest_targets(x, asked["boundary"], asked["tolerance"], plane)
    nodes, targets = [], []
    point_nodes, point_tags = asked["points"]
    known = {tag for _, tag in gmsh.model.getEntities(0)}
    for node, tag in zip(point_nodes.tolist(), point_tags.tolist(), strict=True):
        if tag not in known:
            raise GeometryError(f"model point {tag} is not in {source!r}")
        nodes.append(node)
        targets.append(_point(tag, plane))
    curve_nodes, curve_tags = asked["curves"]
    known = {tag for _, tag in gmsh.model.getEntities(1)}
    for tag in np.unique(curve_tags).tolist():
        if tag not in known:
            raise GeometryError(f"model curve {tag} is not in {source!r}")
        mine = curve_nodes[curve_tags == tag]
        nodes += mine.tolist()
        targets += list(_closest(tag, x[mine], plane))
    nodes = np.asarray(nodes, dtype=np.int64)
    targets = np.asarray(targets, dtype=float).reshape(-1, 2)
    # a node asked onto several curves: the nearest target (model points come first)
    gap = np.linalg.norm(targets - x[nodes], axis=1) if nodes.size else np.zeros(0)
    gap[: len(point_nodes)] = -1.0
    order = np.lexsort((gap, nodes))
    first = np.unique(nodes[order], return_index=True)[1]
    return nodes[order][first], targets[order][first]


def _point(tag: int, plane=None) -> np.ndarray:
    """The model point ``tag``'s (2,) coordinates (in ``plane``'s where it is given)."""
    xyz = np.asarray(gmsh.model.getValue(0, tag, []), dtype=float)
    return xyz[:2] if plane is None else plane.to_plane(xyz)[0]


def _closest(curve: int, x: np.ndarray, plane=None) -> np.ndarray:
    """The closest points (k, 2) of ``x`` on the model curve ``curve`` (``x`` and the
    points in ``plane``'s coordinates where it is given)."""
    if not x.shape[0]:
        return np.zeros((0, 2))
    xyz = np.c_[x, np.zeros(x.shape[0])] if plane is None else plane.to_3d(x)
    closest, _ = gmsh.model.getClosestPoint(1, curve, xyz.ravel())
    closest = np.asarray(closest, dtype=float).reshape(-1, 3)
    return closest[:, :2] if plane is None else plane.to_plane(closest)


def _nearest_targets(x: np.ndarray, boundary: np.ndarray, tolerance: float, plane=None):
    """Without curve edges: each boundary node to the closest boundary curve; the node
    closest to each model point on the boundary onto it, within ``tolerance``."""
    surfaces = gmsh.model.getEntities(2)
    # every curve a surface's boundary runs along, a slit's (twice, opposite) included
    curves = sorted({abs(tag) for _, tag in gmsh.model.getBoundary(surfaces, combined=False,
                                                                    oriented=False)})
    if not curves or not boundary.size:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 2))
    candidates = np.stack([_closest(c, x[boundary], plane) for c in curves])  # (curves, k, 2)
    distance = np.linalg.norm(candidates - x[boundary][None], axis=2)
    targets = candidates[np.argmin(distance, axis=0), np.arange(boundary.size)]
    ends = gmsh.model.getBoundary([(1, c) for c in curves], combined=False, oriented=False)
    for tag in sorted({abs(t) for _, t in ends}):
        point = _point(tag, plane)
        gap = np.linalg.norm(x[boundary] - point, axis=1)
        nearest = int(np.argmin(gap))
        if gap[nearest] <= tolerance:
            targets[nearest] = point
    return boundary, targets


def _apply(x: np.ndarray, q: np.ndarray, nodes: np.ndarray, targets: np.ndarray,
           longest: float) -> CadSnap:
    """The moves of ``nodes`` to ``targets``, but those longer than ``longest`` and those
    that would invert a quad."""
    offset = np.linalg.norm(targets - x[nodes], axis=1) if nodes.size else np.zeros(0)
    before = float(offset.max(initial=0.0))
    moving = offset > 0
    nodes, targets, offset = nodes[moving], targets[moving], offset[moving]
    accepted = offset <= longest
    y = x.copy()
    y[nodes[accepted]] = targets[accepted]
    slot = np.full(x.shape[0], -1, dtype=np.int64)
    slot[nodes] = np.arange(nodes.size)
    while nodes.size:  # in every bad quad, the longest move still kept is undone
        corner = slot[q[scaled_jacobians(y, q) <= 0]]  # (bad, 4) move of each corner, or -1
        valid = corner >= 0
        valid[valid] = accepted[corner[valid]]
        length = np.where(valid, offset[np.maximum(corner, 0)], -1.0)
        worst = corner[np.arange(corner.shape[0]), np.argmax(length, axis=1)]
        undo = np.unique(worst[length.max(axis=1, initial=-1.0) >= 0])
        if not undo.size:
            break
        accepted[undo] = False
        y[nodes[undo]] = x[nodes[undo]]
    if check_quad_mesh(y, q, slits=True) and not check_quad_mesh(x, q, slits=True):
        accepted[:] = False  # a check fails only after the moves: keep the mesh as it was
        y = x.copy()
    after = float(offset[~accepted].max(initial=0.0))
    return CadSnap(y, int(accepted.sum()), int((~accepted).sum()),
                   float(offset[accepted].max(initial=0.0)), before, after)
