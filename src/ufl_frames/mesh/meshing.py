"""Meshing the current Gmsh model in 2D: the sizing policy and what is overridden.

:func:`mesh_model` makes one conforming domain of the model's surfaces, overrides the
file's requests for quadrilaterals, second order or MeshAdapt (triangles are what the
frame field needs), resolves curved boundaries with at least
:data:`CURVE_POINTS_PER_TURN` points per full turn, and sizes the mesh: the file's own
sizes where it sets any and no size is given, else an absolute size or about
:data:`AUTO_TRIANGLES` triangles; without an absolute size, the sizes are capped where
the shape is thin or tightly curved (:mod:`ufl_frames.mesh.feature_size`); an estimate
above ``max_triangles`` is refused before meshing, and a large uniform mesh is made by
refining a coarser one (:data:`REFINE_ABOVE`). :func:`check_crossings` refuses, before
meshing, boundaries whose curves cross (Gmsh's meshing never ends on them).
"""

import math
from dataclasses import dataclass

from ufl_frames.bootstrap import init_petsc

init_petsc()

import gmsh  # noqa: E402
import numpy as np  # noqa: E402

from ufl_frames.mesh import feature_size  # noqa: E402
from ufl_frames.mesh.arrays import signed_areas, triangles_of_model  # noqa: E402
from ufl_frames.mesh.domain import GeometryError, TooManyTriangles  # noqa: E402

#: Triangles aimed at by the default size of a file that sets no sizes of its own.
AUTO_TRIANGLES = 2000
#: Circles and ellipses get at least this many mesh points per full turn (Gmsh's
#: ``Mesh.MinimumCirclePoints``): a cross turns by 4× the boundary's turn between two
#: boundary vertices, and the discrete index of the field needs that below 180°.
CURVE_POINTS_PER_TURN = 12
#: Other curved curves (splines, B-splines) get at least this many points each.
CURVE_POINTS_PER_CURVE = 8
#: Largest estimated triangle count meshed without asking (``max_triangles``).
MAX_TRIANGLES = 4_000_000
#: Above this estimated triangle count a uniform size h is meshed at 2^k h and refined k
#: times by Gmsh (every triangle split into 4, new boundary points put on the curves),
#: which is much faster than meshing at h directly.
REFINE_ABOVE = 150_000
#: Points per curved boundary curve for the crossing check of :func:`check_crossings`
#: (and, to confirm a crossing found, :data:`CROSSING_CONFIRM` times as many).
CROSSING_SAMPLES = 64
CROSSING_CONFIRM = 16

_EQUILATERAL = math.sqrt(3) / 4  # area of the equilateral triangle of unit edge
_UNSET_SIZE = 1e21  # Gmsh's "no size" is 1e22 (MAX_LC)


@dataclass
class Sizing:
    """How to size the mesh: absolute ``h`` (None: relative to the shape), a factor, and
    how many times at least the mesh is made by splitting a 2^k times coarser one."""

    h: float | None
    factor: float = 1.0
    max_triangles: float = MAX_TRIANGLES
    refinements: int = 0
    #: cap an absolute ``h`` too where the shape is thin or tightly curved
    #: (:mod:`ufl_frames.mesh.feature_size`): a size derived from the quads', not one the
    #: user asked for
    resolve: bool = False


def _unite_surfaces(notes: list[str]) -> None:
    """One conforming domain of several surfaces: fragment (OCC) or merge duplicates."""
    surfaces = gmsh.model.getEntities(2)
    if len(surfaces) < 2:
        return
    occ = gmsh.model.occ.getEntities(2)
    if sorted(occ) == sorted(surfaces):
        before = len(surfaces)
        groups = _groups_and_boxes()
        # curves and points embedded in a surface go in too: so they stay embedded
        embedded = sorted({(d, t) for _, s in surfaces
                           for d, t in gmsh.model.mesh.getEmbedded(2, s) if d < 2})
        tools = surfaces[1:] + embedded
        _, pieces = gmsh.model.occ.fragment(surfaces[:1], tools)
        gmsh.model.occ.synchronize()
        after = len(gmsh.model.getEntities(2))
        notes.append(
            f"{before} surfaces fragmented into one conforming domain of {after} surfaces "
            "(shared curves are interior)"
        )
        _restore_groups(groups, dict(zip(surfaces[:1] + tools, pieces, strict=True)), notes)
    else:
        before = _entity_keys()
        gmsh.model.geo.removeAllDuplicates()
        gmsh.model.geo.synchronize()
        _renumber_field_entities(before)
        notes.append(f"{len(surfaces)} surfaces meshed as one domain (shared curves are interior)")


def _shape(dim: int, tag: int) -> np.ndarray:
    """What identifies a model entity across a renumbering: its bounding box and (curves,
    surfaces) its length or area."""
    mass = gmsh.model.occ.getMass(dim, tag) if dim > 0 else 0.0
    return np.array([*gmsh.model.getBoundingBox(dim, tag), mass])


def _groups_and_boxes() -> list:
    """The physical groups of the current model: (dim, tag, name, [(entity, its
    :func:`_shape`)]) each."""
    return [(dim, tag, gmsh.model.getPhysicalName(dim, tag),
             [(int(e), _shape(dim, int(e)))
              for e in gmsh.model.getEntitiesForPhysicalGroup(dim, tag)])
            for dim, tag in gmsh.model.getPhysicalGroups()]


def _restore_groups(groups: list, pieces: dict, notes: list[str]) -> None:
    """The physical groups ``groups`` (:func:`_groups_and_boxes`) again after a fragment
    that changed the model (the OpenCASCADE synchronisation drops them, and renumbers
    curves): an entity the fragment was given by its pieces (``pieces``: (dim, tag) ->
    [(dim, tag), ...]), any other by the entity of the same dimension, bounding box and
    length that is there now; entities not found (a curve split in two) are left out of
    their group, with a note."""
    def present():
        return sorted((d, t, tuple(sorted(int(e) for e in
                                          gmsh.model.getEntitiesForPhysicalGroup(d, t))))
                      for d, t in gmsh.model.getPhysicalGroups())

    if present() == sorted((d, t, tuple(sorted(e for e, _ in members)))
                           for d, t, _, members in groups):
        return
    gmsh.model.removePhysicalGroups()
    now = {d: {t: _shape(d, t) for _, t in gmsh.model.getEntities(d)} for d in range(3)}
    size = max(1.0, _bounding_box_diagonal())
    for dim, tag, name, members in groups:
        kept, lost = [], []
        for entity, shape in members:
            if (dim, entity) in pieces:
                kept += [t for d, t in pieces[(dim, entity)] if d == dim and t in now[dim]]
                continue
            same = [t for t, other in now[dim].items()
                    if np.allclose(other, shape, rtol=1e-9, atol=1e-9 * size)]
            if same:
                kept.append(entity if entity in same else same[0])
            else:
                lost.append(entity)
        if lost:
            notes.append(f"physical group {tag} {name!r} of dimension {dim}: entities "
                         f"{lost} were split by the fragmentation and left out (make the "
                         "geometry conforming with BooleanFragments before the groups)")
        if kept:
            gmsh.model.addPhysicalGroup(dim, sorted(set(kept)), tag, name)


#: Options of Gmsh's size fields that name model entities (of the dimension given).
_FIELD_ENTITY_LISTS = {"PointsList": 0, "CurvesList": 1, "SurfacesList": 2,
                       "ExcludedSurfacesList": 2, "FanPointsList": 0}


def _entity_keys() -> dict[tuple[int, int], np.ndarray]:
    """Where each point, curve and surface of the model is: a point's coordinates; a
    curve's two ends (in a fixed order) and its middle; a surface's bounding box."""
    keys = {}
    for dim, tag in gmsh.model.getEntities(0):
        keys[dim, tag] = np.asarray(gmsh.model.getValue(0, tag, []), dtype=float)
    for dim, tag in gmsh.model.getEntities(1):
        lo, hi = (float(v[0]) for v in gmsh.model.getParametrizationBounds(1, tag))
        ends = np.asarray(gmsh.model.getValue(1, tag, [lo, hi]), dtype=float).reshape(2, 3)
        middle = np.asarray(gmsh.model.getValue(1, tag, [0.5 * (lo + hi)]), dtype=float)
        ends = ends[np.lexsort(ends.T[::-1])]
        keys[dim, tag] = np.concatenate([ends.ravel(), middle])
    for dim, tag in gmsh.model.getEntities(2):
        keys[dim, tag] = np.asarray(gmsh.model.getBoundingBox(dim, tag), dtype=float)
    return keys


def _renumber_field_entities(before: dict) -> None:
    """Point the size fields at the entities that replaced the duplicates they named.

    ``removeAllDuplicates`` deletes a curve or point that repeats another (two surfaces
    drawn with their own copies of a shared side); a field that still names it (a
    ``Distance`` to that curve, a ``Restrict`` to it) made Gmsh throw inside its meshing
    threads, which ends the process with SIGABRT. Each name is replaced by the surviving
    entity at the same place (:func:`_entity_keys`).

    Args:
        before: :func:`_entity_keys` of the model before the duplicates were removed.
    """
    fields = [int(f) for f in gmsh.model.mesh.field.list()]
    if not fields:
        return
    after = _entity_keys()
    scale = max((float(np.abs(k).max()) for k in before.values() if k.size), default=1.0)
    tol = 1e-8 * max(scale, 1e-300)

    def survivor(dim, tag):
        if (dim, tag) in after and np.allclose(after[dim, tag], before[dim, tag], atol=tol):
            return tag
        for (d, t), key in after.items():
            if d == dim and key.shape == before[dim, tag].shape and np.allclose(
                    key, before[dim, tag], atol=tol):
                return t
        return None

    for field in fields:
        for option, dim in _FIELD_ENTITY_LISTS.items():
            try:
                tags = [int(t) for t in gmsh.model.mesh.field.getNumbers(field, option)]
            except Exception:  # the field has no such option
                continue
            known = [t for t in tags if (dim, t) in before]
            renamed = [survivor(dim, t) for t in known]
            renamed = list(dict.fromkeys(t for t in renamed if t is not None))
            if renamed != tags:
                gmsh.model.mesh.field.setNumbers(field, option, renamed)


def _override_meshing_requests(notes: list[str]) -> None:
    """Triangles for the frame field, whatever meshing the file asks for."""
    asked = []
    if gmsh.option.getNumber("Mesh.RecombineAll"):
        gmsh.option.setNumber("Mesh.RecombineAll", 0)
        asked.append("RecombineAll")
    if gmsh.option.getNumber("Mesh.SubdivisionAlgorithm"):
        gmsh.option.setNumber("Mesh.SubdivisionAlgorithm", 0)
        asked.append("subdivision into quadrilaterals")
    if gmsh.option.getNumber("Mesh.Algorithm") == 11:
        gmsh.option.setNumber("Mesh.Algorithm", 6)
        asked.append("the quasi-structured quad algorithm")
    if gmsh.option.getNumber("Mesh.ElementOrder") > 1:
        gmsh.option.setNumber("Mesh.ElementOrder", 1)
        asked.append("second-order elements")
    if asked:
        notes.append(f"the file asks for {', '.join(asked)}: meshed with linear triangles")
    if gmsh.option.getNumber("Mesh.Algorithm") == 3:
        # Measured on deal.II's step-49 input: MeshAdapt gave edges of 0.58 under a cap of
        # 0.1 (Frontal-Delaunay: 0.06), so the sizes asked for would not be the sizes had.
        gmsh.option.setNumber("Mesh.Algorithm", 6)
        notes.append("the file's 2D algorithm MeshAdapt (3) ignores the size limits: "
                     "Frontal-Delaunay (6) used instead")


def _file_sets_sizes() -> bool:
    points = gmsh.model.getEntities(0)
    sizes = np.asarray(gmsh.model.mesh.getSizes(points)) if points else np.zeros(0)
    return bool(
        np.any((sizes > 0) & (sizes < _UNSET_SIZE))
        or len(gmsh.model.mesh.field.list()) > 0
        or gmsh.option.getNumber("Mesh.MeshSizeMax") < _UNSET_SIZE
        or gmsh.option.getNumber("Mesh.MeshSizeFactor") != 1.0
    )


def _largest_file_size(automatic: float) -> float:
    """The size a file that sets its own sizes is compared with for the local feature
    size: the larger of the automatic size and its largest point size, at most its
    ``Mesh.MeshSizeMax``."""
    points = gmsh.model.getEntities(0)
    sizes = np.asarray(gmsh.model.mesh.getSizes(points)) if points else np.zeros(0)
    sizes = sizes[(sizes > 0) & (sizes < _UNSET_SIZE)]
    largest = max(automatic, float(sizes.max()) if sizes.size else 0.0)
    return min(largest, gmsh.option.getNumber("Mesh.MeshSizeMax"))


def _bounding_box_diagonal() -> float:
    x0, y0, _, x1, y1, _ = gmsh.model.getBoundingBox(-1, -1)
    return math.hypot(x1 - x0, y1 - y0)


def _model_area() -> float:
    """Area of all surfaces: exact for OpenCASCADE, else from a coarse trial mesh."""
    surfaces = gmsh.model.getEntities(2)
    if sorted(gmsh.model.occ.getEntities(2)) == sorted(surfaces):
        return float(sum(gmsh.model.occ.getMass(2, tag) for _, tag in surfaces))
    diagonal = _bounding_box_diagonal()
    names = ("Mesh.MeshSizeMin", "Mesh.MeshSizeMax", "Mesh.MeshSizeFromPoints",
             "Mesh.MeshSizeExtendFromBoundary")
    saved = {k: gmsh.option.getNumber(k) for k in names}
    try:
        gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
        gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
        gmsh.option.setNumber("Mesh.MeshSizeMin", diagonal / 500)
        gmsh.option.setNumber("Mesh.MeshSizeMax", diagonal / 30)
        gmsh.model.mesh.generate(2)
        x, cells = triangles_of_model()[:2]
        area = float(np.abs(signed_areas(x, cells)).sum())
    except Exception:
        area = 0.0
    finally:
        gmsh.model.mesh.clear()
        for k, v in saved.items():
            gmsh.option.setNumber(k, v)
    if not area > 0:  # the trial failed: an upper bound is enough for a size estimate
        x0, y0, _, x1, y1, _ = gmsh.model.getBoundingBox(-1, -1)
        area = (x1 - x0) * (y1 - y0)
    return area


def _curve_points(curve: int, samples: int) -> np.ndarray:
    """(n, 2) points along a curve, equally spaced in its parameter (2 for a line)."""
    n = 2 if gmsh.model.getType(1, curve) == "Line" else samples
    lo, hi = (float(v[0]) for v in gmsh.model.getParametrizationBounds(1, curve))
    xyz = np.asarray(gmsh.model.getValue(1, curve, np.linspace(lo, hi, n)))
    return xyz.reshape(-1, 3)[:, :2]


def _crossing_pairs(polylines: dict, tol: float) -> list[tuple[int, int, np.ndarray]]:
    """(curve, curve, point) of the polylines' segments that cross properly (each end of
    either strictly on its own side of the other, by more than ``tol``); one per pair."""
    curve_of = np.concatenate([np.full(len(p) - 1, c) for c, p in polylines.items()])
    a = np.concatenate([p[:-1] for p in polylines.values()])
    b = np.concatenate([p[1:] for p in polylines.values()])
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    order = np.argsort(lo[:, 0], kind="stable")
    xs = lo[order, 0]
    # Sweep in x: segment i against the later ones whose x-range starts within its own.
    ends = np.searchsorted(xs, hi[order, 0], side="right")
    found = {}
    start = 0
    while start < order.size:
        counts = np.maximum(ends[start:] - np.arange(start, order.size) - 1, 0)
        stop = start + max(1, int(np.searchsorted(np.cumsum(counts), 2_000_000)))
        stop = min(stop, order.size)
        first = np.repeat(np.arange(start, stop), counts[: stop - start])
        offsets = np.arange(first.size) - np.repeat(np.cumsum(counts[: stop - start])
                                                    - counts[: stop - start],
                                                    counts[: stop - start])
        i, j = order[first], order[first + 1 + offsets]
        start = stop
        keep = (lo[i, 1] <= hi[j, 1]) & (lo[j, 1] <= hi[i, 1])
        i, j = i[keep], j[keep]

        def side(p, q, r):
            return ((q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1])
                    - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0]))

        s1, s2 = side(a[i], b[i], a[j]), side(a[i], b[i], b[j])
        s3, s4 = side(a[j], b[j], a[i]), side(a[j], b[j], b[i])
        cross = ((np.minimum(s1, s2) < -tol) & (np.maximum(s1, s2) > tol)
                 & (np.minimum(s3, s4) < -tol) & (np.maximum(s3, s4) > tol))
        for k in np.flatnonzero(cross):
            pair = tuple(sorted((int(curve_of[i[k]]), int(curve_of[j[k]]))))
            t = s3[k] / (s3[k] - s4[k])  # where along segment i
            found.setdefault(pair, a[i[k]] + t * (b[i[k]] - a[i[k]]))
    return [(*pair, point) for pair, point in found.items()]


def check_crossings(source: str) -> None:
    """Refuse a surface whose boundary curves cross: a curve loop through itself, or two
    of its loops across each other. Gmsh's 2D meshing never ends on those (it splits the
    crossing edges and tries again, forever). Checked on points along the curves
    (:data:`CROSSING_SAMPLES` per curved one), each crossing confirmed on
    :data:`CROSSING_CONFIRM` times as many (a chord of a curve may cross a curve close
    to it that the curve itself does not); curves that only touch are let through."""
    x0, y0, _, x1, y1, _ = gmsh.model.getBoundingBox(-1, -1)
    tol = 1e-9 * max((x1 - x0) ** 2 + (y1 - y0) ** 2, 1e-300)
    cache: dict[tuple[int, int], np.ndarray] = {}

    def points(curve, samples):
        if (curve, samples) not in cache:
            cache[curve, samples] = _curve_points(curve, samples)
        return cache[curve, samples]

    for _, surface in gmsh.model.getEntities(2):
        boundary = gmsh.model.getBoundary([(2, surface)], combined=False, oriented=False)
        curves = sorted({abs(int(tag)) for dim, tag in boundary if dim == 1})
        if not curves:
            continue
        coarse = {c: points(c, CROSSING_SAMPLES) for c in curves}
        for first, second, _ in _crossing_pairs(coarse, tol):
            fine = {c: points(c, CROSSING_SAMPLES * CROSSING_CONFIRM) for c in {first, second}}
            confirmed = [p for p in _crossing_pairs(fine, tol) if p[:2] == (first, second)]
            if confirmed:
                x, y = confirmed[0][2]
                which = (f"curve {first} crosses itself" if first == second
                         else f"curves {first} and {second} cross")
                raise GeometryError(
                    f"{source!r}: the boundary of surface {surface} crosses itself ({which} "
                    f"near ({x:.4g}, {y:.4g})): Gmsh cannot mesh it; make each curve loop a "
                    "simple closed curve, with holes inside the outline"
                )


def mesh_model(sizing: Sizing, notes: list[str]) -> float | None:
    """Mesh the CAD model of the current Gmsh model in 2D; return the size asked for."""
    _unite_surfaces(notes)
    _override_meshing_requests(notes)
    # Resolve curved boundaries whatever the size (Mesh.MeshSizeFromCurvature would do it
    # too, but hangs Gmsh 4.15 on built-in circles between points of different sizes).
    for name, least in (("Mesh.MinimumCirclePoints", CURVE_POINTS_PER_TURN),
                        ("Mesh.MinimumCurvePoints", CURVE_POINTS_PER_CURVE)):
        gmsh.option.setNumber(name, max(gmsh.option.getNumber(name), least))
    own_sizes = sizing.h is None and _file_sets_sizes()
    area = _model_area()
    if not (area > 0 and math.isfinite(area)):
        raise GeometryError(f"the surfaces have no area to mesh (area {area:.3g})")
    refinements, automatic = sizing.refinements, 0
    automatic_size = math.sqrt(area / (_EQUILATERAL * AUTO_TRIANGLES))
    if own_sizes:
        h = None
        file_factor = gmsh.option.getNumber("Mesh.MeshSizeFactor")
        gmsh.option.setNumber("Mesh.MeshSizeFactor", file_factor * sizing.factor * 2**refinements)
        # Gmsh multiplies the callback's size by the factor too: the caps scale with
        # --size-factor and the refinements, not with the file's own factor.
        field = feature_size.measure(_largest_file_size(automatic_size))[0]
        feature_size.install(field, 1.0 / file_factor, notes)
    else:
        if sizing.h is None:
            h = sizing.factor * automatic_size
        else:
            h = sizing.h * sizing.factor
        estimate = area / (_EQUILATERAL * h * h)
        capped = sizing.h is None or sizing.resolve  # an explicit size is kept as asked
        if capped:  # the default size resolves the shape
            field, caps, step = feature_size.measure(automatic_size)
            estimate += feature_size.extra_triangles(sizing.factor * caps, step, h)
        if estimate > sizing.max_triangles:
            raise TooManyTriangles(
                f"mesh size {h:.3g} on a domain of area {area:.3g} gives about "
                f"{estimate:.2g} triangles, more than the limit {sizing.max_triangles:.3g}: "
                "choose a larger mesh size (or raise the limit)"
            )
        while estimate / 4**(refinements + automatic) > REFINE_ABOVE:
            automatic += 1
        gmsh.option.setNumber("Mesh.MeshSizeMax", h * 2**(refinements + automatic))
        if capped:
            feature_size.install(field, sizing.factor * 2**(refinements + automatic), notes)
    try:
        gmsh.model.mesh.generate(2)
    finally:
        feature_size.uninstall()
    for _ in range(refinements + automatic):
        gmsh.model.mesh.refine()
    if automatic:
        notes.append(f"meshed at size {h * 2**(refinements + automatic):.3g} and refined "
                     f"{refinements + automatic} time(s) (each triangle split into 4): faster "
                     f"than meshing at {h * 2**refinements:.3g}")
    return h
