r"""The integrability energy on the frame manifold: what a solver evaluates (note §3).

A :class:`FrameProblem` holds a P1 frame field ``q``, its compiled UFL forms (H, dH/dq,
the Dirichlet energy) and the manifold 𝓜 of :mod:`ufl_frames.fem.manifold`, and
evaluates at the point ``q = R(x/√m)`` of an iterate x:

* H(q), assembled by DOLFINx from the UFL form;
* the Riemannian gradient in x (the note's steps 1–2 and the sphere's tangent).

With a size target (:class:`SizeTerm`, ``frame_problem(..., size=SizeTarget)``) the objective
is the sized energy J(q) = H(q) + w H_s M(q), M the size misfit of
:func:`~ufl_frames.fem.energy.size_misfit_form` and H_s = (ρ²/A)² the energy scale (constant
on 𝓜), so that the weight w is dimensionless; what is said of H below is then said of J.

What a step needs is passed explicitly: :meth:`FrameProblem.evaluation` returns the
energy and Euclidean gradient at the current ``q`` as an :class:`Evaluation`, cached on
the version of ``q`` while a solver tracks it (:meth:`FrameProblem.tracking`), so that
TAO's callbacks at one iterate (gradient, update, monitor, Hessian) share one retraction
and one assembly instead of relying on whichever was evaluated last.
"""

from contextlib import contextmanager
from dataclasses import dataclass, field

from ufl_frames.bootstrap import init_petsc

init_petsc()

import dolfinx  # noqa: E402
import dolfinx.fem as fem  # noqa: E402
import numpy as np  # noqa: E402
import ufl  # noqa: E402
from mpi4py import MPI  # noqa: E402
from petsc4py import PETSc  # noqa: E402

from ufl_frames.fem import energy  # noqa: E402
from ufl_frames.fem.constraints import FrameConstraints, frame_constraints  # noqa: E402
from ufl_frames.fem.constraints import pin_singularities as _pin_singular_vertices  # noqa: E402
from ufl_frames.fem.manifold import FrameManifold  # noqa: E402
from ufl_frames.frames2d.algebra import ALGEBRA  # noqa: E402
from ufl_frames.frames2d.aspect import DEFAULT_MAX_ASPECT  # noqa: E402

__all__ = ["Evaluation", "FrameProblem", "SizeTerm", "frame_problem", "size_smoothing_option",
           "size_term"]


@dataclass(frozen=True)
class Evaluation:
    """The objective (H, or J = H + w H_s M with a size target) and its Euclidean gradient
    ∂/∂x (local rows, (N, count); ghost rows are partial sums, meaningful only pointwise)
    at one version of ``q``; ``integrability`` is H alone (x·∇J = 4H: the sphere's
    curvature)."""

    energy: float
    gradient_x: np.ndarray = field(repr=False)
    integrability: float | None = None
    #: The size term's smoothing part C S(q) (quadratic: x·∇(C S) = 2 C S), 0 without it.
    smoothing: float = 0.0

    @property
    def radial(self) -> float:
        """(x·∇J)/4: the energy whose Euler identity the sphere's curvature reads
        (H, plus half the quadratic smoothing term)."""
        H = self.energy if self.integrability is None else self.integrability
        return H + 0.5 * self.smoothing


@dataclass
class SizeTerm:
    """The size target's term w H_s M(q) of the sized energy: log h at the vertices, the
    weight's Constant (w H_s), the UFL misfit and its compiled form.

    ``target`` is the :class:`~ufl_frames.mesh.sizes.SizeTarget` it was made from. With a
    smoothing s > 0 (``-frames_size_smoothing``) the term is w H_s (M + s Ŝ), Ŝ = S ∫h²/ρ²
    and S = ½ ∫ |∇q|²/h² (:func:`~ufl_frames.fem.energy.size_smoothing_form`): the
    ``smoothing`` Constant is C = w H_s s ∫h²/ρ², the factor of S; ``inverse_h2`` 1/h² a
    cell (DG0, h = exp of the mean of log h at its vertices)."""

    target: object
    log_h: fem.Function
    inverse_area: fem.Constant
    coefficient: fem.Constant
    misfit_ufl: object = field(repr=False)
    misfit: fem.Form = field(repr=False)
    #: s, dimensionless (0: no smoothing term).
    relative_smoothing: float = 0.0
    smoothing: fem.Constant | None = field(default=None, repr=False)
    inverse_h2: fem.Function | None = field(default=None, repr=False)
    smoothing_ufl: object = field(default=None, repr=False)
    #: S(q) compiled (None without smoothing).
    smoothing_energy: fem.Form | None = field(default=None, repr=False)

    @property
    def smoothing_weight(self) -> float:
        """C = w H_s s ∫h²/ρ², the factor of S in the objective (0 without smoothing)."""
        return 0.0 if self.smoothing is None else float(self.smoothing.value)

    @property
    def objective_ufl(self):
        """The term's UFL form: w H_s M + C S."""
        form = self.coefficient * self.misfit_ufl
        if self.smoothing_ufl is not None:
            form = form + self.smoothing * self.smoothing_ufl
        return form

    @property
    def weight(self) -> float:
        """w H_s, the misfit's factor in the objective."""
        return float(self.coefficient.value)

    def hessian_ufl(self, q, exact: bool):
        """The weighted second derivative (``exact``) or Gauss–Newton form of the term."""
        make = energy.size_hessian_form if exact else energy.size_gauss_newton_form
        form = self.coefficient * make(q, self.log_h, self.inverse_area)
        if self.smoothing_ufl is not None:  # quadratic: the same in both
            form = form + self.smoothing * energy.size_smoothing_hessian_form(
                q, self.inverse_h2)
        return form


@dataclass
class FrameProblem:
    """A frame field ``q``, its compiled energies and the manifold it is kept on."""

    q: fem.Function
    manifold: FrameManifold
    integrability: fem.Form
    gradient: fem.Form
    dirichlet: fem.Form
    #: The domain's area, Σ_v m_v.
    area: float
    #: Local rows held on the aspect bound whatever the gradient says (None: the gradient
    #: decides), set by a solver for the current iterate (the Newton model's anti-zigzag
    #: rule); :meth:`riemannian_gradient` and the Newton model's tangent basis use it.
    held: np.ndarray | None = field(default=None, repr=False)
    #: With it, :attr:`held` is the active set itself (rows on the bound): the gradient
    #: adds none (the Newton model's ``-frames_active_consistent`` rule).
    held_only: bool = field(default=False, repr=False)
    #: The size target's term (None: the objective is H alone).
    size: SizeTerm | None = field(default=None, repr=False)
    #: Counts the changes of q made here (retractions); keys the cached evaluation.
    _version: int = field(default=0, repr=False)
    _evaluated: tuple | None = field(default=None, repr=False)  # (version, Evaluation)
    #: During a solve: the (vector, PETSc state) that q is R of, and the tracking flag.
    _synced: tuple | None = field(default=None, repr=False)
    _tracking: bool = field(default=False, repr=False)
    #: During a solve: the iterate last written with ``keep`` ((vector, state), rows).
    _kept: tuple | None = field(default=None, repr=False)

    @property
    def constraints(self) -> FrameConstraints:
        return self.manifold.constraints

    @property
    def norm2(self) -> float:
        """ρ² = Σ_v m_v |q_v|², kept by the retraction."""
        return self.manifold.radius2

    @property
    def algebra(self):
        """The frame algebra of q (the constraints')."""
        return self.manifold.algebra

    @property
    def sqrt_mass(self) -> np.ndarray:
        return self.manifold.sqrt_mass

    @property
    def rows(self) -> np.ndarray:
        """Local rows (owned and ghost) of q, a (N, count) view."""
        return self.q.x.array.reshape(-1, self.algebra.count)

    @property
    def owned(self) -> int:
        return self.constraints.owned

    @property
    def energy_scale(self) -> float:
        """H_s = (ρ²/A)², ρ² = Σ m_v |q_v|², A the area: H of a field turning by O(1) across
        the domain, up to an O(1) factor (MBO's on the annulus: H = 1.4 H_s).

        Homogeneous of degree 4 in q like H, and, like H, independent of the mesh and of
        the domain's size (x → s x: ρ² and A scale by s², H is invariant).
        """
        return (self.norm2 / self.area) ** 2

    @property
    def gradient_scale(self) -> float:
        """G = H_s / ρ: the scale of the Riemannian gradient norm |g| in the unknowns x.

        |g| ρ bounds the first-order change of H under a relative change 1 of the field
        (x·∇H = 4H), so |g| / G, like H / H_s, is free of the mesh and of the domain's
        size (|g| scales by 1/s under x → s x, as G does). MBO on the annulus: |g| ≈ 25-35 G.
        """
        return self.energy_scale / np.sqrt(self.norm2)

    # --- q and the iterate x --------------------------------------------------------

    @contextmanager
    def tracking(self):
        """Within it, :meth:`set_from_x` skips the retraction when x is the vector, in the
        same PETSc state, that q was last set from or written to (TAO changes x only
        through PETSc, which counts every change), and :meth:`evaluation` reuses its
        assembly while q is unchanged. Only for code that changes q through
        :meth:`set_from_x` and :meth:`retract` alone, such as the TAO callbacks.

        An iterate written with :meth:`write_x` (``keep``) is recognised until the vector
        changes, whatever was evaluated in between: q is then put back as it was, not
        retracted again (R(R(q)) is R(q) only up to round-off)."""
        self._tracking, self._synced, self._evaluated, self.held = True, None, None, None
        self.held_only = False
        self._kept = None
        try:
            yield self
        finally:
            self._tracking, self._synced, self._evaluated, self.held = False, None, None, None
            self.held_only = False
            self._kept = None

    def _mark_synced(self, x: PETSc.Vec) -> None:
        if self._tracking:
            self._synced = (x.getId(), x.stateGet())

    def set_from_x(self, x: PETSc.Vec) -> None:
        """q ← R(x / √m): unscale, fill ghosts, retract (steps 4–5)."""
        if self._tracking and self._synced == (x.getId(), x.stateGet()):
            return  # q is R(x) already
        if self._tracking and self._kept is not None and self._kept[0] == (x.getId(),
                                                                          x.stateGet()):
            self.rows[:] = self._kept[1]  # the iterate x was written from
            self._version += 1
            self._mark_synced(x)
            return
        n = self.owned
        self.rows[:n] = self.manifold.from_x(
            x.getArray(readonly=True).reshape(-1, self.algebra.count))
        self.q.x.scatter_forward()
        self.retract()
        self._mark_synced(x)

    def retract(self) -> None:
        """q ← R(q): steps 4–5 of note §3 in place."""
        self.rows[:] = self.manifold.retraction(self.rows)
        self._version += 1
        self._synced = None

    def write_x(self, x: PETSc.Vec, keep: bool = False) -> None:
        """x ← √m q (owned rows); with ``keep`` (while tracking), x is the solver's iterate:
        :meth:`set_from_x` of it gives this q back, until x changes."""
        x.getArray()[:] = self.manifold.to_x(self.rows).ravel()
        self._mark_synced(x)
        if keep and self._tracking:
            self._kept = ((x.getId(), x.stateGet()), self.rows.copy())

    # --- energies and gradients ------------------------------------------------------

    def energy(self) -> float:
        """The objective: H(q), or J(q) = H + w H_s M with a size target, assembled."""
        local = fem.assemble_scalar(self.integrability)
        if self.size is not None:
            local += self.size.weight * fem.assemble_scalar(self.size.misfit)
            if self.size.smoothing_energy is not None:
                local += self.size.smoothing_weight * fem.assemble_scalar(
                    self.size.smoothing_energy)
        return self.q.function_space.mesh.comm.allreduce(local, op=MPI.SUM)

    def integrability_energy(self) -> float:
        """H(q) alone, assembled."""
        return self.q.function_space.mesh.comm.allreduce(
            fem.assemble_scalar(self.integrability), op=MPI.SUM
        )

    def size_misfit(self) -> float:
        """M(q), the size misfit (without its weight); 0 without a size target."""
        if self.size is None:
            return 0.0
        return self.q.function_space.mesh.comm.allreduce(
            fem.assemble_scalar(self.size.misfit), op=MPI.SUM)

    def size_smoothing(self) -> float:
        """S(q) = ½ ∫ |∇q|²/h² (without its factor C); 0 without a smoothing term."""
        if self.size is None or self.size.smoothing_energy is None:
            return 0.0
        return self.q.function_space.mesh.comm.allreduce(
            fem.assemble_scalar(self.size.smoothing_energy), op=MPI.SUM)

    def dirichlet_energy(self) -> float:
        """E(q) = ½∫|∇q|², assembled."""
        return self.q.function_space.mesh.comm.allreduce(
            fem.assemble_scalar(self.dirichlet), op=MPI.SUM
        )

    def evaluation(self) -> Evaluation:
        """H and ∂H/∂x at the current q: one vector assembly (cached while tracked).

        H comes free with the gradient: the discrete H is a homogeneous quartic in the
        coefficients of q, so dH(q)[q] = 4 H(q) (Euler) — no second assembly. The size
        misfit M is homogeneous of degree 0 (dM(q)[q] = 0), so that stays true of the
        sized gradient; M itself is one more scalar assembly. The smoothing term C S is
        quadratic (dS(q)[q] = 2 S): one more scalar assembly, taken off before dividing.
        """
        if self._tracking and self._evaluated is not None \
                and self._evaluated[0] == self._version:
            return self._evaluated[1]
        b = fem.assemble_vector(self.gradient)
        b.scatter_reverse(dolfinx.la.InsertMode.add)
        owned = self.algebra.count * self.owned
        smoothing = 0.0
        if self.size is not None and self.size.smoothing_energy is not None:
            smoothing = self.size.smoothing_weight * self.size_smoothing()
        H = (self.constraints.comm.allreduce(
            float(np.dot(b.array[:owned], self.q.x.array[:owned])), op=MPI.SUM)
            - 2.0 * smoothing) / 4
        # Ghost rows of b are partial sums: used pointwise (active sets), never summed.
        gradient_x = b.array.reshape(-1, self.algebra.count) / self.sqrt_mass[:, None]
        objective = H
        if self.size is not None:
            objective = H + self.size.weight * self.size_misfit() + smoothing
        result = Evaluation(energy=objective, gradient_x=gradient_x, integrability=H,
                            smoothing=smoothing)
        if self._tracking:
            self._evaluated = (self._version, result)
        return result

    def riemannian_gradient(self, g: PETSc.Vec) -> float:
        """g ← the gradient of H on 𝓜 at q, in the scaled unknowns x (steps 1–2); returns H."""
        evaluation = self.evaluation()
        g.getArray()[:] = self.manifold.riemannian_gradient(
            self.rows, evaluation.gradient_x, held=self.held, only_held=self.held_only).ravel()
        return evaluation.energy


def frame_problem(
    q: fem.Function,
    isotropic: bool = False,
    pin_singularities: bool = True,
    max_aspect: float | None = DEFAULT_MAX_ASPECT,
    boundary_angles: np.ndarray | None = None,
    constraints: FrameConstraints | None = None,
    pin_radius: float = 0.0,
    algebra=ALGEBRA,
    size=None,
    size_smoothing: float | None = None,
) -> FrameProblem:
    """Compile the energies of ``q``, find its constraints and retract it onto 𝓜.

    The sphere of 𝓜 is through the closest point of ``q`` (step 5 keeps its lumped L²
    norm).

    Args:
        q: The frame field (:func:`~ufl_frames.fem.energy.frame_space`); set to its
            retraction.
        isotropic: Whether the frames are isotropic (l1 = l2).
        pin_singularities: Hold the cross orientation at the vertices of the singular
            triangles of ``q`` and at every vertex closer than ``pin_radius`` to one (see
            :func:`~ufl_frames.fem.constraints.pin_singularities`).
        max_aspect: The bound l_max/l_min of non-isotropic frames (``math.inf`` or None:
            no bound, which the non-isotropic energy answers with degenerate frames; see
            :mod:`ufl_frames.frames2d.aspect`).
        boundary_angles: Exact boundary cross angles per local row (see
            :func:`~ufl_frames.fem.constraints.frame_constraints`).
        constraints: Constraints already found for ``q``'s space (e.g. the MBO field's),
            reused with ``isotropic`` and ``max_aspect`` set from here;
            ``boundary_angles`` is then not needed.
        pin_radius: See ``pin_singularities``.
        algebra: The frame algebra of ``q`` (that of ``constraints`` where given).
        size: A :class:`~ufl_frames.mesh.sizes.SizeTarget`: the objective is then the
            sized energy J = H + w H_s M (w its ``weight``); None: H. Needs a finite
            aspect bound (log(l1 l2) of the frames).
        size_smoothing: s of the size term's smoothing (:func:`size_term`); None: the
            option ``-frames_size_smoothing`` (default
            :data:`~ufl_frames.mesh.sizes.DEFAULT_SIZE_SMOOTHING`).

    Returns:
        The problem, ``q`` on 𝓜.
    """
    V = q.function_space
    if constraints is None:
        constraints = frame_constraints(V, isotropic=isotropic, max_aspect=max_aspect,
                                        boundary_angles=boundary_angles, algebra=algebra)
    else:
        constraints = constraints.for_frames(isotropic, max_aspect)
    algebra = constraints.algebra
    rows = q.x.array.reshape(-1, algebra.count)
    if pin_singularities:
        constraints = _pin_singular_vertices(V, constraints, rows, radius=pin_radius)
    cone = FrameManifold(constraints)  # no sphere yet: it passes through the closest point
    projected = cone.closest_point(rows)
    manifold = FrameManifold(constraints, radius2=cone.norm2(projected))
    H = energy.integrability_energy_form(q, algebra)
    area = constraints.comm.allreduce(float(constraints.weights[: constraints.owned].sum()),
                                      op=MPI.SUM)
    term, objective = None, H
    if size is not None:
        term = size_term(q, size, area, (manifold.radius2 / area) ** 2, constraints,
                         smoothing=size_smoothing, radius2=manifold.radius2)
        objective = H + term.objective_ufl
    problem = FrameProblem(
        q=q,
        manifold=manifold,
        integrability=fem.form(H),
        gradient=fem.form(energy.gradient_form(objective, q)),
        dirichlet=fem.form(energy.dirichlet_energy_form(q)),
        area=area,
        size=term,
    )
    q.x.array[:] = projected.ravel()
    return problem


def size_smoothing_option() -> float:
    """s of ``-frames_size_smoothing`` (:data:`~ufl_frames.mesh.sizes.DEFAULT_SIZE_SMOOTHING`
    where it is not given)."""
    from ufl_frames.mesh.sizes import DEFAULT_SIZE_SMOOTHING

    return PETSc.Options().getReal("frames_size_smoothing", DEFAULT_SIZE_SMOOTHING)


def size_term(q: fem.Function, target, area: float, energy_scale: float,
              constraints: FrameConstraints, smoothing: float | None = None,
              radius2: float | None = None) -> SizeTerm:
    """The :class:`SizeTerm` of a size target on ``q``'s mesh: log h interpolated at the
    vertices, the weight w H_s (w = ``target.weight``, H_s = ``energy_scale``).

    With a smoothing s > 0 (None: :func:`size_smoothing_option`) the term also holds
    w H_s s Ŝ, Ŝ = S ∫h²/ρ², S = ½ ∫ |∇q|²/h² (ρ² = ``radius2``, the sphere's; None:
    Σ_v m_v |q_v|² of ``q``). Ŝ, like
    M and H/H_s, is dimensionless and free of the domain's size, of h's global factor
    and of q's: for q ≈ c h e (sizes following h, e the frames' shape) it is about
    ½ ∫ |∇e|² / mean |e|², the Dirichlet energy of the directions, which grows like
    π log(R/r₀) a singularity (r₀ the mesh size) where H and M stay finite. So s is the
    smoothing's weight relative to the misfit's; its factor C = w H_s s ∫h²/ρ² is
    constant on the frame manifold.

    Raises:
        ValueError: the frames have no finite aspect bound, h is not finite and
            positive at every vertex, or s is not finite and >= 0 (one line).
    """
    bound = constraints.max_aspect
    if not constraints.isotropic and not (bound and np.isfinite(bound)):
        raise ValueError("a size target needs a finite aspect bound (--max-aspect): the "
                         "size of a frame is log(l1 l2), and l2 -> 0 without one")
    mesh = q.function_space.mesh
    S = fem.functionspace(mesh, ("Lagrange", 1))
    log_h = fem.Function(S, name="log_h")
    x = S.tabulate_dof_coordinates()
    log_h.x.array[:] = np.log(target(x[:, :2]))
    inverse_area = fem.Constant(mesh, PETSc.ScalarType(1.0 / area))
    coefficient = fem.Constant(mesh, PETSc.ScalarType(target.weight * energy_scale))
    misfit = energy.size_misfit_form(q, log_h, inverse_area)
    term = SizeTerm(target=target, log_h=log_h, inverse_area=inverse_area,
                    coefficient=coefficient, misfit_ufl=misfit, misfit=fem.form(misfit))
    s = size_smoothing_option() if smoothing is None else float(smoothing)
    if not (np.isfinite(s) and s >= 0):
        raise ValueError(f"the size smoothing must be a finite number >= 0, got {s}")
    if s == 0:
        return term
    if radius2 is None:  # ρ² = Σ_v m_v |q_v|² of q as it is
        rows = q.x.array.reshape(-1, constraints.algebra.count)[: constraints.owned]
        radius2 = constraints.comm.allreduce(
            float(np.einsum("n,ni,ni->", constraints.weights[: constraints.owned], rows, rows)),
            op=MPI.SUM)
    # 1/h² per cell, h = exp(mean log h at the cell's vertices): what the kernel computes
    D0 = fem.functionspace(mesh, ("DG", 0))
    inverse_h2 = fem.Function(D0, name="inverse_h2")
    cells = mesh.topology.index_map(mesh.topology.dim)
    count = cells.size_local + cells.num_ghosts
    mean_log = log_h.x.array[S.dofmap.list[:count]].mean(axis=1)
    inverse_h2.x.array[D0.dofmap.list[:count, 0]] = np.exp(-2.0 * mean_log)
    h2_integral = energy.assemble_energy(fem.form(1.0 / inverse_h2 * ufl.dx))
    factor = target.weight * energy_scale * s * h2_integral / radius2
    smoothing_ufl = energy.size_smoothing_form(q, inverse_h2)
    term.relative_smoothing = s
    term.smoothing = fem.Constant(mesh, PETSc.ScalarType(factor))
    term.inverse_h2 = inverse_h2
    term.smoothing_ufl = smoothing_ufl
    term.smoothing_energy = fem.form(smoothing_ufl)
    return term
