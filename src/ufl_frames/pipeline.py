"""The pipeline as one object: a meshed domain, its frame field, the solve and its findings.

::

    domain = geometry.build(comm, "piano")                    # Domain: mesh, curves, corners
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
from dataclasses import dataclass, field
from pathlib import Path

from ufl_frames.bootstrap import init_petsc

init_petsc()

import dolfinx.fem as fem  # noqa: E402
import numpy as np  # noqa: E402

from ufl_frames import io, solvers  # noqa: E402
from ufl_frames.fem import energy  # noqa: E402
from ufl_frames.fem.constraints import FrameConstraints, frame_constraints  # noqa: E402
from ufl_frames.frames2d import singularities  # noqa: E402
from ufl_frames.frames2d.aspect import DEFAULT_MAX_ASPECT, aspect_bound  # noqa: E402
from ufl_frames.geometry import Domain  # noqa: E402
from ufl_frames.solvers import mbo  # noqa: E402

__all__ = ["FrameField"]

#: Default quad size of :meth:`FrameField.parametrise`: about one quad per this many triangles.
TRIANGLES_PER_QUAD = 8


@dataclass
class FrameField:
    """A frame field on a :class:`~ufl_frames.geometry.Domain`, and what was done to it.

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
    #: The last :meth:`parametrise`'s map (on rank 0; None elsewhere) and its measures.
    parametrisation: object | None = field(default=None, repr=False)
    param_quality: dict | None = None

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

    def solve(self, pin_singularities: bool = True, max_it: int | None = None, monitor=None,
              options_prefix: str = "", checkpoint=None,
              resume: solvers.SolverState | None = None) -> solvers.SolveResult:
        """Minimise H from the current field with TAO (:func:`ufl_frames.solvers.solve`);
        ``q`` holds the result, ``singularities`` are found again (collective).

        ``checkpoint`` and ``resume`` as for :func:`~ufl_frames.solvers.solve`: a solve
        resumed on the field :meth:`initial` made (its constraints and pinned vertices
        are those of the original start) ends as the original would have."""
        self.problem = solvers.frame_problem(
            self.q, isotropic=self.isotropic, pin_singularities=pin_singularities,
            max_aspect=self.max_aspect, boundary_angles=self.boundary_angles,
            constraints=self.constraints,  # the MBO field's: boundary, normals, masses once
        )
        self.result = solvers.solve(self.problem, max_it=max_it, monitor=monitor,
                                   options_prefix=options_prefix, checkpoint=checkpoint,
                                   resume=resume)
        self.singularities = singularities.locate_singularities(self.q)
        self.pinned_singularities = pin_singularities
        return self.result

    def parametrise(self, quad_size: float | None = None) -> dict:
        """The seamless map (U, V) of the current field (:mod:`ufl_frames.param`): cut,
        combed and integrated on rank 0; its measures, the same dict on every rank.

        ``quad_size``: the edge length of the quads the integer iso-lines of U and V
        outline (default: about one quad per :data:`TRIANGLES_PER_QUAD` triangles).
        """
        from ufl_frames.param import cut, measures, seamless
        from ufl_frames.param.gather import gather_field

        comm = self.domain.comm
        x, cells, rows = gather_field(self.q)
        result, error = None, None
        if comm.rank == 0:
            try:
                mesh = cut.cut_mesh(x, cells, rows)
                area, _ = seamless.gradients(mesh.x, mesh.cells)
                size = np.sqrt(mesh.l1 * mesh.l2)  # the frame's length scale per triangle
                if quad_size is None:
                    quads = max(1.0, mesh.cells.shape[0] / TRIANGLES_PER_QUAD)
                    scale = float(np.sqrt(quads / np.dot(area, 1 / size**2)))
                else:
                    scale = float(np.dot(area, size) / area.sum() / quad_size)
                self.parametrisation = seamless.integrate(mesh, scale)
                result = measures.quality(self.parametrisation)
            except (ValueError, np.linalg.LinAlgError, RuntimeError) as e:
                error = f"cannot parametrise this field: {e}"
        error = comm.bcast(error, root=0)
        if error is not None:
            raise ValueError(error)
        self.param_quality = comm.bcast(result, root=0)
        return self.param_quality

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
            "mesh_size": domain.mesh_size,
            "requested_mesh_size": domain.requested_mesh_size,
            "num_vertices": int(domain.num_vertices),
            "num_cells": int(domain.num_cells),
        }
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
        record["singularities"] = self.singularities
        record["poincare_hopf"] = self.index_theorem()
        if self.param_quality is not None:
            record["param"] = self.param_quality
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
        names = [p.name for p in io.write_field(out, self.q)]
        H = f" (H = {self.result.H_final:.3g})" if self.result is not None else ""
        io.plot_frames(out / "frames.png", self.q, title=f"Frame field: {label}, {kind}{H}",
                       singularities=self.singularities)
        names.append("frames.png")
        if self.result is not None:
            method = f", TAO {tao_type}" if tao_type else ""
            io.plot_convergence(
                out / "convergence.png", self.result.history,
                title=f"{label}, {kind}: {self.result.iterations} iterations{method}",
                comm=self.domain.comm,
            )
            names.append("convergence.png")
        return names
