"""A meshed domain's frame field and its solves: :class:`FrameField`.

::

    domain = mesh.build(comm, "piano")                        # Domain: mesh, curves, corners
    field = FrameField.initial(domain, isotropic=False)       # the smooth MBO cross field
    field.solve(max_it=500)                                   # TAO on the frame manifold
    field.singularities, field.index_theorem()                # indices, Poincaré–Hopf

:class:`FrameField` is what the command, the demos and the benchmarks consume: the
boundary directions of the CAD model reach the MBO field and the solver's constraints from
one place, and the aspect bound's rule (none for isotropic frames) lives here once. What
is made from a field lives beside it: the rank-0 stages (:mod:`ufl_frames.pipeline.stages`:
the seamless map, the quad mesh), the files (:mod:`ufl_frames.pipeline.files`) and the
summary record (:mod:`ufl_frames.pipeline.report`).
"""

import math
from dataclasses import dataclass, field

from ufl_frames.bootstrap import init_petsc

init_petsc()

import dolfinx.fem as fem  # noqa: E402
import numpy as np  # noqa: E402

from ufl_frames import solvers  # noqa: E402
from ufl_frames.fem import energy  # noqa: E402
from ufl_frames.fem.constraints import FrameConstraints, frame_constraints  # noqa: E402
from ufl_frames.frames2d import singularities  # noqa: E402
from ufl_frames.frames2d.aspect import DEFAULT_MAX_ASPECT, aspect_bound  # noqa: E402
from ufl_frames.mesh import Domain  # noqa: E402
from ufl_frames.solvers import mbo  # noqa: E402

__all__ = ["FrameField"]


@dataclass
class FrameField:
    """A frame field on a :class:`~ufl_frames.mesh.Domain`, and its solve.

    ``q`` is the P1 field (5 coefficients per vertex); ``boundary_angles`` the exact
    cross angles of the CAD model's curves per local row (None without one; the field is
    aligned to the boundary and to the curves inside the domain, see
    :func:`~ufl_frames.fem.constraints.frame_constraints`);
    ``constraints`` the fixed rows, their directions and lumped masses, found once;
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
    #: Whether the lengths are the conformal scale of :meth:`conformal`.
    conformal_scale: bool = False
    #: Per level of :meth:`nested` (coarse to fine): triangles, iterations, H, reason,
    #: seconds; None for a one-mesh solve.
    levels: list[dict] | None = None
    #: Per level of :meth:`nested`: the solve's history (for ``convergence.png``).
    level_histories: list[list[dict]] | None = field(default=None, repr=False)
    #: The size target of the solve (:class:`~ufl_frames.mesh.sizes.SizeTarget`; None:
    #: the objective is H alone). Non-isotropic frames only.
    size: object = None

    @classmethod
    def initial(
        cls,
        domain: Domain,
        isotropic: bool = False,
        max_aspect: float | None = DEFAULT_MAX_ASPECT,
        monitor=None,
        size=None,
    ) -> "FrameField":
        """The smooth boundary-aligned MBO cross field on ``domain`` (collective).

        Args:
            domain: the meshed domain.
            isotropic: isotropic frames (crosses; no aspect bound).
            max_aspect: the bound on l_max/l_min of non-isotropic frames.
            monitor: ``monitor(level, tau, change)`` as for
                :func:`ufl_frames.solvers.mbo.mbo_frame_field`.
            size: the size target of the solves (ignored for isotropic frames).

        Returns:
            The field, with its boundary directions, constraints and singularities.
        """
        V = energy.frame_space(domain.mesh)
        angles = domain.boundary_angles(V)
        constraints = frame_constraints(V, boundary_angles=angles,
                                        interior_facets=domain.interior_curve_facets())
        q = mbo.mbo_frame_field(V, constraints=constraints, monitor=monitor)
        return cls(domain=domain, q=q, isotropic=isotropic,
                   max_aspect=aspect_bound(isotropic, max_aspect), boundary_angles=angles,
                   constraints=constraints, singularities=singularities.locate_singularities(q),
                   size=None if isotropic else size)

    def transferred(self, domain: Domain) -> "FrameField":
        """This field carried to another mesh of the same shape (collective): q interpolated
        at the new vertices (:func:`~ufl_frames.fem.transfer.interpolate_field`), the new
        mesh's boundary directions and constraints; the solver's retraction puts q on the
        frame manifold there. The start of a finer level of :meth:`nested`."""
        from ufl_frames.fem.transfer import interpolate_field

        q = interpolate_field(self.q, domain.mesh)
        angles = domain.boundary_angles(q.function_space)
        constraints = frame_constraints(q.function_space, boundary_angles=angles,
                                        interior_facets=domain.interior_curve_facets())
        return FrameField(domain=domain, q=q, isotropic=self.isotropic,
                          max_aspect=self.max_aspect, boundary_angles=angles,
                          constraints=constraints,
                          singularities=singularities.locate_singularities(q),
                          size=self.size)

    @classmethod
    def nested(cls, domains, isotropic: bool = False,
               max_aspect: float | None = DEFAULT_MAX_ASPECT, pin_singularities: bool = True,
               max_it: int | None = None, monitor=None, mbo_monitor=None,
               level_monitor=None, options_prefix: str = "", checkpoint=None,
               restore=None, pin_radius: float = 0.0, size=None) -> "FrameField":
        """Nested iteration: MBO and a solve on the coarsest of ``domains``, then on each
        finer one a solve from the coarser solution (:meth:`transferred`) (collective).

        Every level stops at the accuracy asked of the whole solve: the gradient tests are
        relative to the coarsest level's |g₀| (``reference_gradient`` of
        :func:`ufl_frames.solvers.solve`), and the finest one also stops once the decrease
        of H still to come is below θ of what it gained on the coarser level's minimum
        (``coarse_energy``, ``-frames_nested_rtol θ``): its algebraic error a small part
        of the discretisation error. With ``pin_singularities`` each level holds the
        singular triangles of its own start, so the singularities are MBO's, carried
        down (a pin of one triangle can be escaped on fine meshes by a ±1/4 pair that
        carries the singularity away; a ``pin_radius`` of the coarsest mesh's size keeps
        MBO's singularities, at a higher H).

        Args:
            domains: meshes of one shape, coarse to fine
                (:func:`ufl_frames.mesh.hierarchy.nested_domains`).
            isotropic: isotropic frames (crosses).
            max_aspect: the bound on l_max/l_min of non-isotropic frames.
            pin_singularities: hold the orientation at each level's singular triangles.
            max_it: TAO iterations at most, per level.
            monitor: gets every level's history entries.
            mbo_monitor: gets the MBO levels, as for
                :func:`ufl_frames.solvers.mbo.mbo_frame_field`.
            level_monitor: ``level_monitor(entry)`` gets a summary per level
                ({"level", "triangles", "iterations", "H", "reason", "singularities",
                "seconds"}).
            options_prefix: the PETSc options prefix of the solves.
            checkpoint: ``checkpoint(state, finest)`` receives every level's states (as for
                :meth:`solve`, ``finest`` telling whether they are of the last mesh; an
                exception from it ends the run).
            restore: ``restore(V)`` returns the :class:`~ufl_frames.solvers.SolverState`
                (or None) to resume the finest level from, V being its space: the coarser
                levels run again (they are deterministic), so the finest one starts from
                the same transferred field, pins and tolerance as the run that saved it.
            pin_radius: also hold every vertex closer than this to a pinned singularity:
                the same disk on every level.
            size: the size target of the solves (non-isotropic frames; None: H alone).

        Returns:
            The field on the finest mesh; its :attr:`levels` lists the per-level summaries
            and :attr:`level_histories` the histories.
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
                                    monitor=mbo_monitor, size=size)
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
        """The integrable isotropic field of this field's directions (collective): lengths
        e^{−φ} from the conformal-scale Poisson problem ∫ ∇φ·∇w = ∫ R∇t·∇w
        (:func:`~ufl_frames.fem.conformal.conformal_field`; one linear solve instead of a
        TAO solve). A new field, with no solve (this one is left as it is)."""
        from ufl_frames.fem.conformal import conformal_field

        q = conformal_field(self.q, options_prefix=options_prefix)
        return FrameField(domain=self.domain, q=q, isotropic=True, max_aspect=None,
                          boundary_angles=self.boundary_angles, constraints=self.constraints,
                          singularities=singularities.locate_singularities(q),
                          conformal_scale=True)

    def solve(self, pin_singularities: bool = True, max_it: int | None = None, monitor=None,
              options_prefix: str = "", checkpoint=None,
              resume: solvers.SolverState | None = None,
              reference_gradient: float | None = None,
              pin_radius: float = 0.0,
              coarse_energy: float | None = None) -> solvers.SolveResult:
        """Minimise H from the current field with TAO (:func:`ufl_frames.solvers.solve`);
        ``q`` holds the result, ``singularities`` are found again (collective).

        A solve resumed on the field :meth:`initial` made (its constraints and pinned
        vertices are those of the original start) ends as the original would have.

        Args:
            pin_singularities: hold the orientation at the singular triangles of the
                current field.
            max_it: TAO iterations at most.
            monitor: gets each history entry.
            options_prefix: the PETSc options prefix of the solve.
            checkpoint: as for :func:`~ufl_frames.solvers.solve`.
            resume: the :class:`~ufl_frames.solvers.SolverState` to go on from.
            reference_gradient: the |g₀| of the gradient tests (nested iteration: see
                :meth:`nested`).
            pin_radius: also hold the vertices closer than this to the pinned singular
                triangles.
            coarse_energy: the coarser level's minimum of H (nested iteration).

        Returns:
            The solve's :class:`~ufl_frames.solvers.SolveResult` (also :attr:`result`).
        """
        self.problem = solvers.frame_problem(
            self.q, isotropic=self.isotropic, pin_singularities=pin_singularities,
            pin_radius=pin_radius,
            max_aspect=self.max_aspect, boundary_angles=self.boundary_angles,
            constraints=self.constraints,  # the MBO field's: fixed rows, directions, masses once
            size=self.size,
        )
        self.result = solvers.solve(self.problem, max_it=max_it, monitor=monitor,
                                   options_prefix=options_prefix, checkpoint=checkpoint,
                                   resume=resume, reference_gradient=reference_gradient,
                                   coarse_energy=coarse_energy)
        self.singularities = singularities.locate_singularities(self.q)
        self.pinned_singularities = pin_singularities
        self.pin_radius = pin_radius if pin_singularities else 0.0
        return self.result

    def index_theorem(self) -> dict:
        """The singularities' index sum against Poincaré–Hopf for the domain
        (:func:`ufl_frames.frames2d.singularities.index_theorem`), with the corner angles (°).

        The boundary's corners alone fix the sum: curves inside the domain (interfaces,
        embedded curves) only say where some singularities sit. ``junction_index`` is the
        index their junctions force (:attr:`~ufl_frames.mesh.domain.Junction.index`: 0 at
        a T or at an interface meeting the boundary at 90°), part of ``index_sum``: the
        triangles touching a junction carry it. ``expected_away_from_junctions`` =
        ``expected`` − ``junction_index`` is what the singularities inside the regions the
        curves cut out sum to (each region's own Poincaré–Hopf sum, a junction's sectors
        its corners of round(angle/90°) quarter turns; see ``Junction``). A boundary
        corner is at least one quarter turn
        (:func:`~ufl_frames.frames2d.singularities.corner_quarter_turns`)."""
        corners = self.domain.corners
        check = singularities.index_theorem(
            self.singularities, self.domain.euler_characteristic, [c.angle for c in corners]
        )
        check["corner_angles_deg"] = [round(math.degrees(c.angle), 6) for c in corners]
        check["junction_index"] = float(sum(j.index for j in self.domain.junctions)) + 0.0
        check["expected_away_from_junctions"] = check["expected"] - check["junction_index"]
        return check
