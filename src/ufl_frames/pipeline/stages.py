"""What rank 0 makes of a frame field: the seamless map (U, V) and the quad mesh.

::

    root = RootField(field)                     # gathered on rank 0 once (collective)
    param = parametrise(root)                   # Parametrised: measures, map on rank 0
    quads = quadrangulate(root, quad_size=0.05) # QuadMeshed: measures, mesh on rank 0

The field is gathered onto rank 0 (:func:`~ufl_frames.param.gather.gather_field`) once
per :class:`RootField`; there its ± pairs of singularities closer than half a quad are
removed (:func:`~ufl_frames.param.pairs.remove_close_pairs`: the map's input changes, the
field does not), singular vertices closer than :data:`GLUE_WITHIN` quad edges to the
boundary are moved onto it, and it is cut into a disk
(:func:`~ufl_frames.param.cut.cut_mesh`), once per set of pairs removed and quad size:
stages at the same quad size start from the same :class:`~ufl_frames.param.cut.CutMesh`.
Each stage is
collective and returns a frozen record whose measures are the same on every rank.
"""

import functools
import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from ufl_frames.bootstrap import init_petsc

init_petsc()

from ufl_frames.pipeline.field import FrameField  # noqa: E402

__all__ = ["Parametrised", "QuadMeshed", "RootField", "TRIANGLES_PER_QUAD", "parametrise",
           "quadrangulate"]

#: Default quad size of :func:`parametrise`: about one quad per this many triangles.
TRIANGLES_PER_QUAD = 8


@dataclass(frozen=True)
class Parametrised:
    """The seamless map of a field: ``quality`` its measures
    (:func:`ufl_frames.param.measures.quality`, the same dict on every rank),
    ``parametrisation`` the map (:class:`~ufl_frames.param.seamless.Parametrisation`)
    on rank 0, None elsewhere."""

    quality: dict
    parametrisation: object | None = field(default=None, repr=False)


@dataclass(frozen=True)
class QuadMeshed:
    """The quad mesh of a field: ``quality`` its measures (:func:`quadrangulate`, the same
    dict on every rank), ``mesh`` the :class:`~ufl_frames.quads.extract.QuadMesh` on
    rank 0, None elsewhere."""

    quality: dict
    mesh: object | None = field(default=None, repr=False)


#: Singular vertices closer than this many local quad edges to the boundary are moved
#: onto it before the map (:func:`~ufl_frames.param.cut.glue_to_boundary`): their
#: separatrices would run along the boundary a sliver away (Gmsh's fleur: the −1/4 at the
#: petals' tips, 0.06–0.13 local quad edges off at 800 quads; gmsh_t4_holes' −1/4 at
#: 0.33–0.38 are better left where they are).
GLUE_WITHIN = 0.2


class RootField:
    """A frame field gathered onto rank 0 (collective to make), and the disk it is cut
    into there, made on first use and kept for every later stage.

    ``domain`` is the field's :class:`~ufl_frames.mesh.Domain`; the gathered arrays,
    ``features`` (the model's regions, curves and points on them, with the smooth joints
    a quad edge may span, the 135° and 225° corners and the interior curves' junctions:
    :class:`~ufl_frames.param.features.Features`,
    :func:`~ufl_frames.param.features.with_smooth_joints`,
    :func:`~ufl_frames.param.features.with_tie_corners`,
    :func:`~ufl_frames.param.features.with_junctions`) and the
    :class:`~ufl_frames.param.cut.CutMesh` (one per set of close ± pairs removed:
    :meth:`_cut_mesh`) live on rank 0 only (None elsewhere).
    """

    def __init__(self, frames: FrameField):
        from ufl_frames.param.features import with_junctions, with_smooth_joints, with_tie_corners
        from ufl_frames.param.gather import gather_features, gather_field

        self.domain = frames.domain
        self._arrays = gather_field(frames.q)  # (x, cells, rows) on rank 0
        self.features = gather_features(frames.domain)
        if self.features is not None:  # a polyline's vertices need not be quad vertices
            corners = _cad_corners(frames.domain)
            self.features = with_smooth_joints(
                self.features, self._arrays[0], self._arrays[1],
                getattr(frames.domain, "physical_groups", ()), corners)
            # 135° and 225° corners: their triangles take their other vertices' frames
            self.features = with_tie_corners(self.features, self._arrays[0],
                                             self._arrays[1], corners)
            # the triangles at the curves' junctions take their other vertices' frames
            self.features = with_junctions(self.features, self._arrays[0],
                                           getattr(frames.domain, "junctions", ()))
        self._cuts = {}

    @functools.cached_property
    def corners(self):
        """The corners under 45° with their −1/4 singular vertex moved into them, for the
        map (:func:`~ufl_frames.param.pairs.absorb_at_acute_corners`; rank 0, None
        elsewhere), made on first use."""
        from ufl_frames.param.pairs import absorb_at_acute_corners

        x, cells, rows = self._arrays
        return None if x is None else absorb_at_acute_corners(x, cells, rows, self.features)

    def _cut_mesh(self, quad_size=None, quad_count=None):
        """(the cut mesh, the :class:`~ufl_frames.param.pairs.RemovedPairs`) at this quad
        size or count (neither: :data:`TRIANGLES_PER_QUAD` triangles a quad): the field
        with its ± pairs closer than :data:`~ufl_frames.param.pairs.CLOSER_THAN` local
        quad edges removed (:func:`~ufl_frames.param.pairs.remove_close_pairs`), cut
        into a disk, with the singular vertices closer than :data:`GLUE_WITHIN` local
        quad edges to the boundary moved onto it; one cut per set of pairs removed and
        quad size (or count), kept for every later stage."""
        from ufl_frames.param import cut, pairs

        x, cells, _ = self._arrays
        q, given = self.corners.q, self.corners.frames
        if quad_size is None and quad_count is None:
            quad_count = max(1.0, cells.shape[0] / TRIANGLES_PER_QUAD)
        edge = pairs.local_quad_edge(x, cells, q, quad_size=quad_size, quad_count=quad_count)
        q_map, removed = pairs.remove_close_pairs(x, cells, q, edge, within=pairs.CLOSER_THAN,
                                                  features=self.features, given_frames=given)
        glue = GLUE_WITHIN * edge
        # which singular vertices are glued to the boundary depends on the quad size too
        key = (removed.key, quad_size, quad_count)
        if key not in self._cuts:
            self._cuts[key] = cut.cut_mesh(x, cells, q_map, features=self.features,
                                           given_frames=given, glue_within=glue)
        return self._cuts[key], removed

    def on_root(self, work, failure: str, quad_size=None, quad_count=None):
        """``work(cut_mesh)`` on rank 0, which returns (what rank 0 keeps, the measures
        every rank gets: a dict); that pair, the first None on the other ranks
        (collective). The cut mesh is that of :meth:`_cut_mesh` at ``quad_size`` or
        ``quad_count``; the measures get its ``removed_pairs``
        (:meth:`~ufl_frames.param.pairs.RemovedPairs.as_dict`). A failure of the cut or
        of ``work`` raises ValueError("<failure>: <why>") on every rank."""
        from ufl_frames.quads.extract import ExtractionError

        comm = self.domain.comm
        kept, shared, error = None, None, None
        if comm.rank == 0:
            try:
                mesh, removed = self._cut_mesh(quad_size, quad_count)
                kept, shared = work(mesh)
                shared = dict(shared, removed_pairs=removed.as_dict())
            except (ValueError, np.linalg.LinAlgError, RuntimeError, ExtractionError) as e:
                error = f"{failure}: {e}"
        error = comm.bcast(error, root=0)
        if error is not None:
            raise ValueError(error)
        return kept, comm.bcast(shared, root=0)


def _cad_corners(domain):
    """The domain's corners where they come from a CAD model (its curves' tangents: a point
    at none is smooth), None for a ``.msh`` (corners from the mesh, whose boundary is then
    the geometry: :func:`~ufl_frames.param.features.with_smooth_joints` takes its angles)."""
    from pathlib import Path

    from ufl_frames.mesh.files import MESH_EXTENSIONS

    if Path(str(domain.source)).suffix.lower() in MESH_EXTENSIONS:
        return None
    return tuple(getattr(domain, "corners", ()))


def _root(source) -> RootField:
    return source if isinstance(source, RootField) else RootField(source)


def parametrise(source, quad_size: float | None = None) -> Parametrised:
    """The seamless map (U, V) of a field (:mod:`ufl_frames.param`): combed and integrated
    on rank 0 (collective).

    Args:
        source: a :class:`~ufl_frames.pipeline.field.FrameField`, or the
            :class:`RootField` of one (shared with :func:`quadrangulate`).
        quad_size: the mean edge length of the quads the integer iso-lines of U and V
            outline (default: about one quad per :data:`TRIANGLES_PER_QUAD` triangles).

    Returns:
        The map and its measures (with ``removed_pairs``: the ± pairs closer than
        :data:`~ufl_frames.param.pairs.CLOSER_THAN` quad edges removed before the map).

    Raises:
        ValueError: on every rank, where the field cannot be cut or integrated.
    """
    from ufl_frames.param import measures, seamless

    def work(mesh):
        if quad_size is None:
            quads = max(1.0, mesh.cells.shape[0] / TRIANGLES_PER_QUAD)
            scale = seamless.scale_for_quad_count(mesh, quads)
        else:
            scale = seamless.scale_for_quad_size(mesh, quad_size)
        parametrisation = seamless.integrate(mesh, scale)
        return parametrisation, measures.quality(parametrisation)

    kept, quality = _root(source).on_root(work, "cannot parametrise this field",
                                          quad_size=quad_size)
    return Parametrised(quality=quality, parametrisation=kept)


def quad_size_for_count(mesh, quads: float) -> float:
    """The mean quad edge length (as :func:`~ufl_frames.param.seamless.scale_for_quad_size`
    means it) at which the field's grid has about ``quads`` cells
    (:func:`~ufl_frames.param.seamless.scale_for_quad_count`) on the cut mesh ``mesh``."""
    from ufl_frames.param import seamless

    return seamless.scale_for_quad_size(mesh, 1.0) / seamless.scale_for_quad_count(mesh, quads)


#: With a quad count asked for, the quads are made again at a corrected size (at most this
#: many times) while their number is off by more than :data:`COUNT_TOLERANCE`: the grid's
#: count s² ∫ 1/(l1 l2) is what the integer layout rounds, not what it makes.
COUNT_CORRECTIONS = 2
COUNT_TOLERANCE = 0.05


def quadrangulate(source, quad_size: float | None = None,
                  quad_count: int | None = None, adapt_size: bool = False) -> QuadMeshed:
    """The quad mesh of a field (:mod:`ufl_frames.quads`), on rank 0 (collective): the
    seamless map's T-mesh with integer arc lengths and its patches' grids
    (:func:`~ufl_frames.quads.patches.quads_of_map`), or where that fails or its worst quad
    is under :data:`MIN_SJ`, the map quantised by greedy rounding
    (:func:`~ufl_frames.param.quantise.quantise`) and its integer iso-lines traced into
    quads (:func:`~ufl_frames.quads.extract.extract_quads`); the worst quads improved
    (:func:`~ufl_frames.quads.improve.improve_worst_quads`).

    Args:
        source: a :class:`~ufl_frames.pipeline.field.FrameField`, or the
            :class:`RootField` of one (shared with :func:`parametrise`).
        quad_size: the quads' target mean edge length (default: the triangles' mean edge
            length, about one quad per two triangles).
        quad_count: about this many quads instead (:func:`quad_size_for_count`).
        adapt_size: where no valid mesh comes out at the size, take the first smaller size
            of :data:`SMALLER_SIZES` that gives one (recorded as ``adapted_size``: the
            size asked for, the size used and why) instead of failing.

    Returns:
        The mesh and its measures (:func:`~ufl_frames.quads.measures.quad_quality`, with
        ``valid``, ``problems``, ``quad_size``, ``quantisation`` (``layout`` or
        ``greedy``) with its counts, ``fallback_reason``, ``removed_pairs`` (the ± pairs
        removed before the map, :func:`~ufl_frames.param.pairs.remove_close_pairs`, at the
        size asked or the count's first size), and the seconds per stage).

    Raises:
        ValueError: on every rank, where no valid integer-grid map exists at that size,
            or its quads are not a valid mesh
            (:func:`~ufl_frames.quads.measures.check_quad_mesh`: too few for the shape).
    """
    from ufl_frames.fem.scales import mean_cell_edge

    root = _root(source)
    size = mean_cell_edge(root.domain.mesh) if quad_size is None else float(quad_size)

    def work(mesh):
        if quad_count is None:
            return _quad_mesh_or_advice(mesh, size, adapt_size)
        chosen = quad_size_for_count(mesh, quad_count)
        kept = _quad_mesh_or_advice(mesh, chosen)
        for _ in range(COUNT_CORRECTIONS):  # the integer layout rounds the grid's count
            found = kept[1]["quads"]
            if abs(found - quad_count) <= COUNT_TOLERANCE * quad_count:
                break
            chosen *= math.sqrt(found / quad_count)
            candidate = _quad_mesh_or_advice(mesh, chosen)
            if abs(candidate[1]["quads"] - quad_count) < abs(found - quad_count):
                kept = candidate
        return kept

    kept, quality = root.on_root(work, "cannot make quads of this field",
                                 quad_size=size if quad_count is None else None,
                                 quad_count=quad_count)
    return QuadMeshed(quality=quality, mesh=kept)


def _has_slits(mesh) -> bool:
    """Whether the triangle mesh was cut open along a slit: two of its boundary vertices
    at one place."""
    from scipy.spatial import cKDTree

    boundary = np.unique(mesh.edges[mesh.faces[:, 1] < 0])
    scale = float(np.ptp(mesh.x, axis=0).max())
    return len(cKDTree(mesh.x[boundary]).query_pairs(1e-12 * scale)) > 0


def _perimeter(mesh) -> float:
    """The length of the triangle mesh's boundary."""
    e = mesh.edges[mesh.faces[:, 1] < 0]
    return float(np.linalg.norm(mesh.x[e[:, 1]] - mesh.x[e[:, 0]], axis=1).sum())


def _euler(mesh) -> int:
    """V − E + F of the (uncut) triangle mesh of the cut mesh ``mesh``."""
    used = np.unique(mesh.cells)
    return int(used.size - mesh.edges.shape[0] + mesh.cells.shape[0])


#: Quad sizes (as shares of the asked one) tried, by the layout alone, where no valid mesh
#: comes out at the asked size, so that the refusal can say which size would work.
SMALLER_SIZES = (0.7, 0.5)


def _bend_advice(mesh, size: float, failed=()) -> str | None:
    """Where the boundary bends more tightly than the quads there can follow
    (:func:`~ufl_frames.param.bends.bend_size`, the model's required points as corners):
    the field's quad edge at the bend (the mean of (l1 + l2)/2s over the triangles within
    one bend size of it, s the scale of quad size ``size``) is longer than the bend
    allows. Then: which quad size (the asked one shrunk by as much) would follow it, and
    about how many quads that is; else None (a graded field whose quads are small enough
    there, or no tight bend, or a size of ``failed`` (tried and failed on these
    triangles) at most that size on triangles fine enough for it: at least
    :data:`~ufl_frames.mesh.sizes.TRIANGLES_PER_QUAD_EDGE` mean triangle edges a quad
    edge — then the bend is not what fails)."""
    from ufl_frames.mesh.sizes import TRIANGLES_PER_QUAD_EDGE
    from ufl_frames.param import seamless
    from ufl_frames.param.bends import bend_size

    corners = None if mesh.features is None else mesh.features.required_points
    bend = bend_size(mesh.x, mesh.cells, corners)
    if not np.isfinite(bend.size):
        return None
    x = mesh.x[mesh.cells]
    centroids = x.mean(axis=1)[:, :2]
    near = np.linalg.norm(centroids - bend.at, axis=1) <= bend.size
    if not near.any():
        near = np.linalg.norm(centroids - bend.at, axis=1) == \
            np.linalg.norm(centroids - bend.at, axis=1).min()
    scale = seamless.scale_for_quad_size(mesh, size)
    there = float(np.mean(0.5 * (mesh.l1[near] + mesh.l2[near]))) / scale
    if not there > bend.size:
        return None
    wanted = size * bend.size / there
    digits = 1 - math.floor(math.log10(wanted))  # two significant digits, rounded down
    fits = math.floor(wanted * 10**digits) / 10**digits
    edge = float(np.linalg.norm(mesh.x[mesh.edges[:, 1]] - mesh.x[mesh.edges[:, 0]],
                                axis=1).mean())
    if any(tried <= fits and tried >= TRIANGLES_PER_QUAD_EDGE * edge for tried in failed):
        return None
    area = 0.5 * float(np.abs((x[:, 1, 0] - x[:, 0, 0]) * (x[:, 2, 1] - x[:, 0, 1])
                              - (x[:, 1, 1] - x[:, 0, 1]) * (x[:, 2, 0] - x[:, 0, 0])).sum())
    return (f"the boundary bends with a radius of {bend.radius:.2g} near "
            f"({bend.at[0]:.3g}, {bend.at[1]:.3g}), too tightly for the quads there "
            f"({there:.2g} long at quad size {size:.3g}): quad size {fits:.2g} or less "
            f"follows it (about {float(f'{area / fits**2:.2g}'):.0f} quads), or quads "
            "graded towards it (--size file or an expression)")


def _quad_mesh_or_advice(mesh, size: float, adapt: bool = False):
    """:func:`_quad_mesh`; where it fails, the error says which smaller quad size (of
    :data:`SMALLER_SIZES`) gives a valid mesh, or, where none does and the boundary bends
    too tightly for the quads (:func:`_bend_advice`), which size follows the bend, or that
    none of them does; with ``adapt`` that mesh is returned instead (its measures'
    ``adapted_size`` says so)."""
    try:
        return _quad_mesh(mesh, size)
    except ValueError as e:
        failure = str(e)
    for share in SMALLER_SIZES:
        try:
            found = _quad_mesh(mesh, share * size,
                               methods=("layout", "greedy rounding") if adapt else ("layout",))
        except ValueError:
            continue
        if adapt:
            quad_mesh, quality = found
            quality["adapted_size"] = {"asked": size, "used": share * size, "why": failure}
            return quad_mesh, quality
        raise ValueError(f"{failure} (quad size {share * size:.3g} works)")
    tried = ", ".join(f"{f * size:.3g}" for f in SMALLER_SIZES)
    bend = _bend_advice(mesh, size, failed=[share * size for share in SMALLER_SIZES])
    if bend is not None:
        raise ValueError(f"{failure} (quad sizes {tried} fail too on these triangles; {bend})")
    raise ValueError(f"{failure} (quad sizes {tried} fail too)")


def _quad_mesh(mesh, size: float, methods=("layout", "greedy rounding")):
    """(the quad mesh, its measures) of the cut mesh ``mesh`` at quad size ``size``: by
    the T-mesh layout of the seamless map (:func:`~ufl_frames.quads.patches.quads_of_map`,
    valid by construction where the map's traces do not fold), else by greedy rounding and
    iso-line extraction (:func:`~ufl_frames.param.quantise.quantise`,
    :func:`~ufl_frames.quads.extract.extract_quads`); the first whose quads pass the
    checks (:func:`_problems`) with no scaled Jacobian under :data:`MIN_SJ` is kept, else
    the valid one with the better worst quad (of ``methods``, in their order). Both keep
    the cut mesh's features: interior curves are arcs of the T-mesh and integer iso-lines of
    the rounded map, model points its nodes and grid points (checked by :func:`_problems`).
    """
    from ufl_frames.param import measures as param_measures
    from ufl_frames.param import seamless
    from ufl_frames.quads import measures
    from ufl_frames.quads.charts import LayoutError
    from ufl_frames.quads.extract import ExtractionError

    start = time.perf_counter()
    scale = seamless.scale_for_quad_size(mesh, size)
    seamless_map = seamless.integrate(mesh, scale)
    integrated = time.perf_counter()
    failures, kept = [], None
    known = {"layout": _by_layout, "greedy rounding": _by_rounding}
    for name, method in ((name, known[name]) for name in methods):
        begun = time.perf_counter()
        try:
            quad_mesh, record = method(mesh, seamless_map)
        except (ValueError, LayoutError, ExtractionError) as e:  # QuantisationError: a ValueError
            failures.append(f"{name}: {_one_line(e)}")
            continue
        quad_mesh, as_extracted = _improved(quad_mesh)
        problems = _problems(mesh, quad_mesh)
        if problems:
            failures.append(f"{name}: at quad size {size:.3g} the quads are not a valid mesh "
                            f"({problems[0]})")
            continue
        worst = float(measures.scaled_jacobians(quad_mesh.points, quad_mesh.quads).min())
        candidate = (worst, quad_mesh, record, as_extracted, time.perf_counter() - begun)
        if kept is None or worst > kept[0]:
            kept = candidate
        if worst >= MIN_SJ:
            break
        failures.append(f"{name}: its worst quad has a scaled Jacobian of {worst:.2g}, under "
                        f"{MIN_SJ}")
    if kept is None:
        advice = "" if failures[-1].endswith("take a smaller quad size") else \
            "; take a smaller quad size"
        raise ValueError("; ".join(failures) + advice)
    _, quad_mesh, record, as_extracted, quantised = kept
    area = float(seamless_map.area.sum())
    found = measures.quad_quality(quad_mesh.points, quad_mesh.quads)
    found.update(
        valid=True, problems=[], quad_size=size,
        area_error=abs(found["area"] - area) / area,
        misfit_seamless=param_measures.quality(seamless_map)["misfit"],
        **record, fallback_reason=failures[0] if failures else None,
        cancelled_singularities=mesh.cancelled,
        extracted={key: as_extracted[key] for key in ("min_sj", "mean_sj", "sj_at_least_0_8")},
        features=None if mesh.features is None else dict(
            regions=int(np.unique(quad_mesh.quad_region).size),
            curve_edges=int(len(quad_mesh.curve_edges)),
            point_nodes=int(len(quad_mesh.point_nodes))),
        seconds={"integrate": integrated - start, "quantise": quantised})
    return quad_mesh, found


#: The worst scaled Jacobian a quad mesh should have: a method whose quads are worse hands
#: over to the next (the T-mesh's to greedy rounding); the best is kept if none reaches it.
MIN_SJ = 0.3


def _one_line(e: BaseException) -> str:
    return " ".join(str(e).split()) or type(e).__name__


def quantisation_line(quality: dict) -> str:
    """One line saying which path made the quads of :func:`quadrangulate`'s measures
    ``quality``: the T-mesh layout (its patches, arcs and collapsed arcs) or greedy
    rounding, with why the layout was not kept."""
    if quality.get("quantisation") == "layout":
        return (f"made by the T-mesh layout ({quality['patches']} patches, "
                f"{quality['arcs']} arcs, {quality['collapsed_arcs']} collapsed)")
    why = quality.get("fallback_reason")
    return "made by greedy rounding" + ("" if why is None else f" ({why})")


def _by_layout(mesh, seamless_map):
    """layout: the quads of the T-mesh's patches, with integer arc lengths."""
    from ufl_frames.quads import patches

    quad_mesh, lay, n = patches.quads_of_map(seamless_map)
    return quad_mesh, dict(
        quantisation="layout", patches=len(lay.patches), arcs=len(lay.arcs),
        collapsed_arcs=int(np.count_nonzero(np.asarray(n) == 0)),
        untangled_triangles=int(lay.untangled), unlocated_points=int(lay.unlocated),
        misfit_quantised=None, rounded=None, max_rounding=None, repaired=None)


def _by_rounding(mesh, seamless_map):
    """greedy rounding: the integer-grid map's iso-lines."""
    from ufl_frames.param import measures as param_measures
    from ufl_frames.param import quantise
    from ufl_frames.quads import extract

    grid_map = quantise.quantise(mesh, seamless_map.scale)
    return extract.extract_quads(grid_map), dict(
        quantisation="greedy", patches=None, arcs=None, collapsed_arcs=None,
        untangled_triangles=None, unlocated_points=None,
        misfit_quantised=param_measures.quality(grid_map.param)["misfit"],
        rounded=grid_map.rounded, max_rounding=grid_map.max_shift, repaired=grid_map.repaired)


def _improved(quad_mesh):
    """(the quad mesh with its worst quads improved, its measures before)."""
    from ufl_frames.quads import measures
    from ufl_frames.quads.improve import improve_worst_quads

    before = measures.quad_quality(quad_mesh.points, quad_mesh.quads)
    fixed = None
    if quad_mesh.curve_edges is not None:  # nodes on model curves and points stay
        fixed = np.concatenate([np.ravel(quad_mesh.curve_edges), quad_mesh.point_nodes])
    return replace(quad_mesh, points=improve_worst_quads(quad_mesh.points, quad_mesh.quads,
                                                         fixed=fixed)), before


def _problems(mesh, quad_mesh) -> list[str]:
    """What makes ``quad_mesh`` no mesh of the shape of the cut mesh ``mesh``: the
    independent checks (:func:`~ufl_frames.quads.measures.check_quad_mesh`), the Euler
    characteristic, a boundary longer than the triangles' (quads missing there), and where
    the mesh has features, those of the quads
    (:func:`~ufl_frames.quads.features.feature_problems`: model points quad vertices, no
    quad across an interface, every region's area and every curve's length, interior
    curves included, equal to the triangles' within 0.5 %)."""
    from ufl_frames.quads import measures

    problems = measures.check_quad_mesh(quad_mesh.points, quad_mesh.quads,
                                        slits=_has_slits(mesh))
    euler, expected = measures.euler_characteristic(quad_mesh.quads), _euler(mesh)
    if euler != expected:  # a hole the shape does not have, or a hole closed
        problems.append(f"the quads have Euler characteristic {euler}, the shape {expected}")
    # the quads' boundary runs along chords of the triangles' boundary: never longer
    # unless quads are missing (a hole that opens onto the boundary or a slit)
    length, bound = measures.boundary_length(quad_mesh.points, quad_mesh.quads), _perimeter(mesh)
    if length > bound * (1 + 1e-9):
        problems.append(f"the quads' boundary is {length / bound - 1:.2%} longer than the "
                        "shape's (quads are missing)")
    if mesh.features is not None:
        from ufl_frames.quads.features import feature_problems

        if quad_mesh.quad_region is None:
            problems.append("the quads do not carry the features")
        else:
            problems += feature_problems(quad_mesh, mesh.x, mesh.cells, mesh.features)
    return problems
