"""The pipeline as one object: a meshed domain, its frame field, the solve and its findings.

::

    domain = mesh.build(comm, "piano")                        # Domain: mesh, curves, corners
    field = FrameField.initial(domain, isotropic=False)       # the smooth MBO cross field
    field.solve(max_it=500)                                   # TAO on the frame manifold
    field.singularities, field.index_theorem()                # indices, Poincaré–Hopf
    field.write("out_piano", label="piano")                   # ParaView files, figures

:class:`FrameField` is what the CLI, the demos and the benchmarks consume (and what a
parametrisation will): the boundary directions of the CAD model reach the MBO field and
the solver's constraints from one place, and the aspect bound's rule (none for
isotropic frames) lives here once.
"""

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

from ufl_frames.bootstrap import init_petsc

init_petsc()

import dolfinx.fem as fem  # noqa: E402
import numpy as np  # noqa: E402

from ufl_frames import output, solvers  # noqa: E402
from ufl_frames.fem import energy  # noqa: E402
from ufl_frames.fem.constraints import FrameConstraints, frame_constraints  # noqa: E402
from ufl_frames.frames2d import singularities  # noqa: E402
from ufl_frames.frames2d.aspect import DEFAULT_MAX_ASPECT, aspect_bound  # noqa: E402
from ufl_frames.mesh import Domain  # noqa: E402
from ufl_frames.solvers import mbo  # noqa: E402

__all__ = ["FrameField"]

#: Default quad size of :meth:`FrameField.parametrise`: about one quad per this many triangles.
TRIANGLES_PER_QUAD = 8


@dataclass
class FrameField:
    """A frame field on a :class:`~ufl_frames.mesh.Domain`, and what was done to it.

    ``q`` is the P1 field (5 coefficients per vertex); ``boundary_angles`` the exact
    boundary cross angles of the CAD model per local row (None without one);
    ``constraints`` the boundary rows, normals and lumped masses, found once;
    ``problem`` and ``result`` are set by :meth:`solve`; ``singularities`` are those of
    the current ``q`` (``{"index", "x", "y"}``, the same list on every rank).
    """

    domain: Domain
    q: fem.Function
    isotropic: bool = False
    max_aspect: float | None = None
    boundary_angles: np.ndarray | None = field(default=None, repr=False)
    constraints: FrameConstraints | None = field(default=None, repr=False)
    problem: solvers.FrameProblem | None = field(default=None, repr=False)
    result: solvers.SolveResult | None = None
    singularities: list[dict] = field(default_factory=list)
    #: Whether the last :meth:`solve` held the singular triangles' orientation.
    pinned_singularities: bool | None = None
    #: The radius of the disk held around each pinned singularity (0: its triangle only).
    pin_radius: float = 0.0
    #: The last :meth:`parametrise`'s map (on rank 0; None elsewhere) and its measures.
    parametrisation: object | None = field(default=None, repr=False)
    param_quality: dict | None = None
    #: Whether the lengths are the conformal scale of :meth:`conformal`.
    conformal_scale: bool = False
    #: The last :meth:`quadrangulate`'s quad mesh (on rank 0; None elsewhere), its measures.
    quad_mesh: object | None = field(default=None, repr=False)
    quad_quality: dict | None = None
    #: Per level of :meth:`nested` (coarse to fine): triangles, iterations, H, reason,
    #: seconds; None for a one-mesh solve.
    levels: list[dict] | None = None
    #: Per level of :meth:`nested`: the solve's history (for ``convergence.png``).
    level_histories: list[list[dict]] | None = field(default=None, repr=False)

    @classmethod
    def initial(
        cls,
        domain: Domain,
        isotropic: bool = False,
        max_aspect: float | None = DEFAULT_MAX_ASPECT,
        monitor=None,
    ) -> "FrameField":
        """The smooth boundary-aligned MBO cross field on ``domain`` (collective).

        ``monitor(level, tau, change)`` as for :func:`ufl_frames.solvers.mbo.mbo_frame_field`.
        """
        V = energy.frame_space(domain.mesh)
        angles = domain.boundary_angles(V)
        constraints = frame_constraints(V, boundary_angles=angles)
        q = mbo.mbo_frame_field(V, constraints=constraints, monitor=monitor)
        return cls(domain=domain, q=q, isotropic=isotropic,
                   max_aspect=aspect_bound(isotropic, max_aspect), boundary_angles=angles,
                   constraints=constraints, singularities=singularities.locate_singularities(q))

    def transferred(self, domain: Domain) -> "FrameField":
        """This field carried to another mesh of the same shape (collective): q interpolated
        at the new vertices (:func:`~ufl_frames.fem.transfer.interpolate_field`), the new
        mesh's boundary directions and constraints; the solver's retraction puts q on the
        frame manifold there. The start of a finer level of :meth:`nested`."""
        from ufl_frames.fem.transfer import interpolate_field

        q = interpolate_field(self.q, domain.mesh)
        angles = domain.boundary_angles(q.function_space)
        constraints = frame_constraints(q.function_space, boundary_angles=angles)
        return FrameField(domain=domain, q=q, isotropic=self.isotropic,
                          max_aspect=self.max_aspect, boundary_angles=angles,
                          constraints=constraints,
                          singularities=singularities.locate_singularities(q))

    @classmethod
    def nested(cls, domains, isotropic: bool = False,
               max_aspect: float | None = DEFAULT_MAX_ASPECT, pin_singularities: bool = True,
               max_it: int | None = None, monitor=None, mbo_monitor=None,
               level_monitor=None, options_prefix: str = "", checkpoint=None,
               restore=None, pin_radius: float = 0.0) -> "FrameField":
        """Nested iteration: MBO and a solve on the coarsest of ``domains`` (meshes of one
        shape, coarse to fine), then on each finer one a solve from the coarser solution
        (:meth:`transferred`); returns the field on the finest (collective).

        Every level stops at the accuracy asked of the whole solve: the gradient tests are
        relative to the coarsest level's |g₀| (``reference_gradient`` of
        :func:`ufl_frames.solvers.solve`), and the finest one also stops once the decrease
        of H still to come is below θ of what it gained on the coarser level's minimum
        (``coarse_energy``, ``-frames_nested_rtol θ``): its algebraic error a small part
        of the discretisation error. With ``pin_singularities`` each level holds the
        singular triangles of its own start, so the singularities are MBO's, carried
        down, and with ``pin_radius`` > 0 also every vertex closer than that to them: the
        same disk on every level. (A pin of one triangle is escaped on fine meshes by a
        ±1/4 pair that carries the singularity away; a disk of the coarsest mesh's size
        keeps MBO's singularities, at a higher H: ``benchmarks/README.md``, "Pinned
        singularities escape by pairs".) ``monitor`` gets every level's history entries,
        ``mbo_monitor`` the MBO levels, ``level_monitor(entry)`` a summary per level
        ({"level", "triangles", "iterations", "H", "reason", "singularities", "seconds"});
        the finest field's :attr:`levels` lists those summaries.

        ``checkpoint(state, finest)`` receives every level's states (as for :meth:`solve`,
        ``finest`` telling whether they are of the last mesh; an exception from it ends
        the run). ``restore(V)``, if given, returns the :class:`~ufl_frames.solvers.SolverState`
        (or None) to resume the finest level from, V being its space: the coarser levels
        run again (they are deterministic and cheap), so the finest one starts from the
        same transferred field, pins and tolerance as the run that saved the state.
        """
        import time

        domains = list(domains)
        if not domains:
            raise ValueError("nested iteration needs at least one domain")
        field, reference, levels, histories = None, None, [], []
        for k, domain in enumerate(domains):
            start = time.perf_counter()
            finest = k == len(domains) - 1
            if field is None:
                field = cls.initial(domain, isotropic=isotropic, max_aspect=max_aspect,
                                    monitor=mbo_monitor)
            else:
                field = field.transferred(domain)
            resume = restore(field.q.function_space) if finest and restore else None

            def keep(state, finest=finest):
                checkpoint(state, finest)

            result = field.solve(pin_singularities=pin_singularities, max_it=max_it,
                                 pin_radius=pin_radius, monitor=monitor,
                                 options_prefix=options_prefix,
                                 checkpoint=None if checkpoint is None else keep,
                                 resume=resume, reference_gradient=reference,
                                 coarse_energy=levels[-1]["H"] if finest and levels else None)
            if reference is None:
                reference = result.history[0]["gnorm"]
            histories.append(result.history)
            levels.append({"level": k, "triangles": domain.num_cells,
                           "iterations": result.iterations, "H": result.H_final,
                           "reason": result.converged_reason,
                           "singularities": sorted(s["index"] for s in field.singularities),
                           "seconds": time.perf_counter() - start})
            if level_monitor is not None:
                level_monitor(levels[-1])
        field.levels, field.level_histories = levels, histories
        return field

    def conformal(self, options_prefix: str = "conformal_") -> "FrameField":
        """Make the field the integrable isotropic field of its own directions: lengths
        e^{−φ} from the conformal-scale Poisson problem ∫ ∇φ·∇w = ∫ R∇t·∇w
        (:func:`~ufl_frames.fem.conformal.conformal_field`; one linear solve instead of a
        TAO solve). Returns ``self`` (collective)."""
        from ufl_frames.fem.conformal import conformal_field

        self.q = conformal_field(self.q, options_prefix=options_prefix)
        self.isotropic, self.max_aspect, self.conformal_scale = True, None, True
        self.singularities = singularities.locate_singularities(self.q)
        return self

    def solve(self, pin_singularities: bool = True, max_it: int | None = None, monitor=None,
              options_prefix: str = "", checkpoint=None,
              resume: solvers.SolverState | None = None,
              reference_gradient: float | None = None,
              pin_radius: float = 0.0,
              coarse_energy: float | None = None) -> solvers.SolveResult:
        """Minimise H from the current field with TAO (:func:`ufl_frames.solvers.solve`);
        ``q`` holds the result, ``singularities`` are found again (collective).

        ``checkpoint`` and ``resume`` as for :func:`~ufl_frames.solvers.solve`: a solve
        resumed on the field :meth:`initial` made (its constraints and pinned vertices
        are those of the original start) ends as the original would have;
        ``reference_gradient`` and ``coarse_energy`` as there (nested iteration: see
        :meth:`nested`). With
        ``pin_singularities`` the orientation is held at the singular triangles of the
        current field and at the vertices closer than ``pin_radius`` to them."""
        self.problem = solvers.frame_problem(
            self.q, isotropic=self.isotropic, pin_singularities=pin_singularities,
            pin_radius=pin_radius,
            max_aspect=self.max_aspect, boundary_angles=self.boundary_angles,
            constraints=self.constraints,  # the MBO field's: boundary, normals, masses once
        )
        self.result = solvers.solve(self.problem, max_it=max_it, monitor=monitor,
                                   options_prefix=options_prefix, checkpoint=checkpoint,
                                   resume=resume, reference_gradient=reference_gradient,
                                   coarse_energy=coarse_energy)
        self.singularities = singularities.locate_singularities(self.q)
        self.pinned_singularities = pin_singularities
        self.pin_radius = pin_radius if pin_singularities else 0.0
        return self.result

    def _on_root(self, work, failure: str):
        """``work(cut_mesh)`` on rank 0, the field cut into a disk there (collective); its
        result on every rank, or ValueError("<failure>: <why>") on every rank."""
        from ufl_frames.param import cut
        from ufl_frames.param.gather import gather_field
        from ufl_frames.quads.extract import ExtractionError

        comm = self.domain.comm
        x, cells, rows = gather_field(self.q)
        result, error = None, None
        if comm.rank == 0:
            try:
                result = work(cut.cut_mesh(x, cells, rows))
            except (ValueError, np.linalg.LinAlgError, RuntimeError, ExtractionError) as e:
                error = f"{failure}: {e}"
        error = comm.bcast(error, root=0)
        if error is not None:
            raise ValueError(error)
        return comm.bcast(result, root=0)

    def parametrise(self, quad_size: float | None = None) -> dict:
        """The seamless map (U, V) of the current field (:mod:`ufl_frames.param`): cut,
        combed and integrated on rank 0; its measures, the same dict on every rank.

        ``quad_size``: the mean edge length of the quads the integer iso-lines of U and V
        outline (default: about one quad per :data:`TRIANGLES_PER_QUAD` triangles).
        """
        from ufl_frames.param import measures, seamless

        def work(mesh):
            if quad_size is None:
                quads = max(1.0, mesh.cells.shape[0] / TRIANGLES_PER_QUAD)
                scale = seamless.scale_for_quad_count(mesh, quads)
            else:
                scale = seamless.scale_for_quad_size(mesh, quad_size)
            self.parametrisation = seamless.integrate(mesh, scale)
            return measures.quality(self.parametrisation)

        self.param_quality = self._on_root(work, "cannot parametrise this field")
        return self.param_quality

    def quadrangulate(self, quad_size: float | None = None) -> dict:
        """The quad mesh of the current field (:mod:`ufl_frames.quads`): the seamless map
        quantised to an integer-grid map (:func:`~ufl_frames.param.quantise.quantise`), its
        integer iso-lines traced into quads (:func:`~ufl_frames.quads.extract.extract_quads`),
        the worst quads improved (:func:`~ufl_frames.quads.improve.improve_worst_quads`),
        on rank 0. Returns the measures (:func:`~ufl_frames.quads.measures.quad_quality`,
        with ``valid``, ``problems``, ``quad_size``, the rounding's and the seconds per
        stage), the same dict on every rank; ``quad_mesh`` holds the mesh on rank 0.

        ``quad_size``: the quads' target mean edge length (default: the triangles' mean
        edge length, about one quad per two triangles). Raises ValueError (every rank)
        where no valid integer-grid map exists at that size, or its quads are not a valid
        mesh (:func:`~ufl_frames.quads.measures.check_quad_mesh`: too few for the shape).
        """
        import time

        from ufl_frames.fem.scales import mean_cell_edge
        from ufl_frames.param import measures as param_measures
        from ufl_frames.param import quantise, seamless
        from ufl_frames.quads import extract, measures
        from ufl_frames.quads.improve import improve_worst_quads

        size = mean_cell_edge(self.domain.mesh) if quad_size is None else float(quad_size)

        def work(mesh):
            start = time.perf_counter()
            scale = seamless.scale_for_quad_size(mesh, size)
            grid_map = quantise.quantise(mesh, scale)
            quantised = time.perf_counter()
            quad_mesh = extract.extract_quads(grid_map)
            extracted = time.perf_counter()
            as_extracted = measures.quad_quality(quad_mesh.points, quad_mesh.quads)
            quad_mesh = replace(quad_mesh, points=improve_worst_quads(quad_mesh.points,
                                                                      quad_mesh.quads))
            improved = time.perf_counter()
            self.quad_mesh = quad_mesh
            area = float(grid_map.param.area.sum())
            problems = measures.check_quad_mesh(quad_mesh.points, quad_mesh.quads)
            if problems:  # the map is valid, but its grid too coarse for the shape
                raise ValueError(f"at quad size {size:.3g} the quads are not a valid mesh "
                                 f"({problems[0]}); take a smaller quad size")
            record = measures.quad_quality(quad_mesh.points, quad_mesh.quads)
            record.update(
                valid=not problems, problems=problems[:5], quad_size=size,
                area_error=abs(record["area"] - area) / area,
                misfit_seamless=param_measures.quality(grid_map.seamless)["misfit"],
                misfit_quantised=param_measures.quality(grid_map.param)["misfit"],
                rounded=grid_map.rounded, max_rounding=grid_map.max_shift,
                repaired=grid_map.repaired, cancelled_singularities=grid_map.mesh.cancelled,
                extracted={key: as_extracted[key] for key in ("min_sj", "mean_sj",
                                                              "sj_at_least_0_8")},
                seconds={"quantise": quantised - start, "extract": extracted - quantised,
                         "improve": improved - extracted})
            return record

        self.quad_quality = self._on_root(work, "cannot make quads of this field")
        return self.quad_quality

    def write_quads(self, out, label: str, stem: str = "quads") -> list[str]:
        """``<stem>.msh`` (Gmsh MSH 4.1), ``<stem>.vtu`` and ``<stem>.png`` of the last
        :meth:`quadrangulate` into ``out``."""
        from ufl_frames.quads.measures import scaled_jacobians
        from ufl_frames.quads.msh import plot_quads, write_quad_msh, write_quad_vtu

        names = [f"{stem}.msh", f"{stem}.vtu", f"{stem}.png"]
        if self.domain.comm.rank == 0:
            mesh, quality = self.quad_mesh, self.quad_quality
            out = Path(out)
            write_quad_msh(out / names[0], mesh.points, mesh.quads)
            write_quad_vtu(out / names[1], mesh.points, mesh.quads,
                           {"scaled_jacobian": scaled_jacobians(mesh.points, mesh.quads)})
            title = (f"{label}: {quality['quads']} quads, {quality['irregular_vertices']} "
                     f"irregular vertices, min SJ {quality['min_sj']:.2f}")
            plot_quads(out / names[2], mesh.points, mesh.quads, title=title)
        self.domain.comm.Barrier()
        return names

    def write_param(self, out, label: str, stem: str = "param") -> list[str]:
        """``<stem>.png`` and ``<stem>.vtu`` of the last :meth:`parametrise` into ``out``."""
        from ufl_frames.param.figures import plot_param, write_param_vtu

        if self.domain.comm.rank == 0:
            quality = self.param_quality
            title = (f"{label}: iso-lines of U, V (misfit {quality['misfit']:.3g}, "
                     f"{quality['flipped_triangles']} flipped, {quality['cuts']} cuts)")
            plot_param(Path(out) / f"{stem}.png", self.parametrisation, title=title)
            write_param_vtu(Path(out) / f"{stem}.vtu", self.parametrisation)
        self.domain.comm.Barrier()
        return [f"{stem}.png", f"{stem}.vtu"]

    def summary(self) -> dict:
        """The field's record for ``summary.json`` (JSON types; collective): the kind of
        frames, the mesh, the solve (after :meth:`solve`), singularities, Poincaré–Hopf."""
        domain, result = self.domain, self.result
        record = {
            "isotropic": bool(self.isotropic),
            "max_aspect": self.max_aspect,
            "pinned_singularities": self.pinned_singularities,
            "pin_radius": self.pin_radius,
            "mesh_size": domain.mesh_size,
            "requested_mesh_size": domain.requested_mesh_size,
            "num_vertices": int(domain.num_vertices),
            "num_cells": int(domain.num_cells),
        }
        if self.conformal_scale:  # no solve: the energy of the field as it is
            record.update(conformal_scale=True, H_final=energy.integrability_energy(self.q))
        if result is not None:
            record.update({
                "converged_reason": result.converged_reason,
                "converged": result.converged_reason.startswith("CONVERGED"),
                "iterations": int(result.iterations),
                "H_initial": result.H_initial,
                "H_final": result.H_final,
                "E_initial": result.history[0]["E"],
                "E_final": result.E_final,
                "wall_time_s": result.wall_time_s,
            })
        if self.levels is not None:
            record["levels"] = self.levels
        record["singularities"] = self.singularities
        record["poincare_hopf"] = self.index_theorem()
        if self.param_quality is not None:
            record["param"] = self.param_quality
        if self.quad_quality is not None:
            record["quads"] = self.quad_quality
        if result is not None:
            record["history"] = result.history
        return record

    def index_theorem(self) -> dict:
        """The singularities' index sum against Poincaré–Hopf for the domain
        (:func:`ufl_frames.frames2d.singularities.index_theorem`), with the corner angles (°)."""
        corners = self.domain.corners
        check = singularities.index_theorem(
            self.singularities, self.domain.euler_characteristic, [c.angle for c in corners]
        )
        check["corner_angles_deg"] = [round(math.degrees(c.angle), 6) for c in corners]
        return check

    def write(self, out, label: str, tao_type: str | None = None) -> list[str]:
        """The field for ParaView, ``frames.png`` and (after a solve) ``convergence.png``
        into the existing folder ``out``; the names written (collective)."""
        out = Path(out)
        kind = "isotropic" if self.isotropic else "non-isotropic"
        names = [p.name for p in output.write_field(out, self.q)]
        H = f" (H = {self.result.H_final:.3g})" if self.result is not None else ""
        output.plot_frames(out / "frames.png", self.q, title=f"Frame field: {label}, {kind}{H}",
                       singularities=self.singularities)
        names.append("frames.png")
        if self.result is not None:
            method = f", TAO {tao_type}" if tao_type else ""
            levels, iterations = None, f"{self.result.iterations} iterations"
            if self.level_histories and len(self.level_histories) > 1:
                levels = [(f"{entry['triangles']} triangles", part) for entry, part
                          in zip(self.levels, self.level_histories, strict=True)]
                iterations = (f"{' + '.join(str(e['iterations']) for e in self.levels)} "
                              f"iterations on {len(self.levels)} meshes")
            output.plot_convergence(
                out / "convergence.png", self.result.history,
                title=f"{label}, {kind}: {iterations}{method}",
                comm=self.domain.comm, levels=levels,
            )
            names.append("convergence.png")
        return names
