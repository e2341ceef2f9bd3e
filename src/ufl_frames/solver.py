r"""Minimise the integrability energy over frame fields with PETSc TAO (note §3).

The note's loop — (1) gradient step, (2) projection of the step on the tangent
space, (3) update, (4) Odeco projection (orientation fixed on the boundary),
(5) uniform normalisation — is a Riemannian gradient descent on the set

    𝓜 = { q : q_v on the Odeco variety (isotropic: l1 = l2) at every vertex v,
              aligned with the normal at boundary vertices,  Σ_v m_v |q_v|² = const }

with steps 4–5 as the retraction R. Here TAO runs it:

* the unknowns are x_v = √m_v q_v (m_v the lumped mass of vertex v), so the Euclidean
  inner product TAO uses is the lumped L² product of the field and step sizes and
  tolerances do not depend on the mesh; the pointwise projection commutes with the
  scaling (the variety is a cone) and the normalisation becomes |x| = const;
* the objective at x is H(R(x)), assembled by DOLFINx from the UFL form;
* the gradient is the Riemannian gradient at R(x): the assembled dH/dq, scaled by
  1/√m_v, projected pointwise on the tangent space (step 2) and orthogonally to x
  (the tangent of the normalisation sphere);
* TAO's update hook retracts the iterate, x ← R(x), at the start of every iteration,
  so every iterate lies on 𝓜 and its gradient is exact.

TAO supplies the search direction (``-tao_type``), the line search (``-tao_ls_type``)
and the stopping tests (``-tao_gttol``: relative gradient norm, default 1e-6;
``-tao_gatol``, ``-tao_fmin``, ``-tao_max_it``). The defaults of the last two are
relative to the natural scales of H, not absolute (:attr:`FrameProblem.energy_scale`):
a field that is already integrable, or already stationary, stops at iteration 0
(``CONVERGED_MINF`` / ``CONVERGED_GATOL``) instead of running ``max_it`` Newton steps
on round-off. TAO types:

* ``nls`` (default), ``ntr``, ``bnls``, ``bntr``: Newton line search / trust region on
  the model of :class:`GaussNewtonModel` — the exact Riemannian Hessian for isotropic
  frames, Gauss–Newton for non-isotropic ones (``-frames_hessian``); the Newton systems
  are solved by TAO's KSP (``-tao_nls_ksp_type``, ``-tao_nls_pc_type``, default GAMG);
* ``lmvm``: L-BFGS, in the lumped-L² metric of the scaled unknowns;
* ``bncg`` with ``-tao_bncg_type gd`` (set by default for ``bncg``) and an Armijo line
  search: the note's projected gradient descent. Every option can be given on the command line,
under ``options_prefix`` (default none): defaults below are set only where the user
gave no value, and ``setFromOptions`` comes last.
"""

import time
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field, replace

from ufl_frames.bootstrap import init_petsc, petsc_defaults

init_petsc()

import dolfinx  # noqa: E402
import dolfinx.fem as fem  # noqa: E402
import dolfinx.fem.petsc  # noqa: E402, F401
import numpy as np  # noqa: E402
import ufl  # noqa: E402
from mpi4py import MPI  # noqa: E402
from petsc4py import PETSc  # noqa: E402

from ufl_frames import energy, odeco, projection  # noqa: E402

#: TAO defaults (each overridable from the command line). ``-tao_gatol`` and
#: ``-tao_fmin`` are not here: their defaults depend on the problem (see :func:`solve`).
DEFAULT_OPTIONS = {
    "tao_type": "nls",  # Riemannian Gauss–Newton (GaussNewtonModel); the note's method: bncg
    "tao_grtol": 0.0,
    "tao_gttol": 1e-6,  # |g| / |g_0|: the relative Riemannian gradient norm
    "tao_max_funcs": 1_000_000,
}

#: Default ``-tao_fmin`` relative to :attr:`FrameProblem.energy_scale`: H ≥ 0, so a field
#: with H below it is integrable (|[u, v]| ≲ 1e-8 of its natural size) and a solve has
#: nothing left to do. Far above the H that MBO leaves on straight-sided domains (~1e-21:
#: its KSP tolerance), far below any discretisation error (the annulus at h = 0.1: 1e-3).
ENERGY_RTOL = 1e-16

#: Defaults that apply to one TAO type only.
TYPE_OPTIONS = {
    "bncg": {"tao_bncg_type": "gd", "tao_ls_type": "armijo"},
    "nls": {"tao_nls_pc_type": "gamg"},
    "ntr": {"tao_ntr_pc_type": "gamg"},
    "bnls": {"tao_bnk_pc_type": "gamg"},
    "bntr": {"tao_bnk_pc_type": "gamg"},
}

_REASONS = {
    getattr(PETSc.TAO.ConvergedReason, name): name
    for name in dir(PETSc.TAO.ConvergedReason)
    if not name.startswith("_")
}


def converged_reason_name(reason: int) -> str:
    """TAO's converged reason as text (e.g. ``CONVERGED_GRTOL``)."""
    return _REASONS.get(reason, str(reason))


@dataclass
class FrameProblem:
    """Everything assembled once for a frame field ``q``: compiled forms, constraints, work."""

    q: fem.Function
    constraints: projection.FrameConstraints
    integrability: fem.Form
    gradient: fem.Form
    dirichlet: fem.Form
    norm2: float
    #: The domain's area, Σ_v m_v.
    area: float
    sqrt_mass: np.ndarray = field(repr=False)
    #: The last assembled dH/dq, scaled (local rows): decides the active aspect bounds.
    last_gradient: np.ndarray | None = field(default=None, repr=False)
    #: H at the point of ``last_gradient``.
    last_energy: float | None = None
    #: During a solve (see :meth:`tracking`): the (vector, PETSc state) that q is R of.
    #: TAO's callbacks at one iterate (gradient, update, monitor, Hessian) then retract once.
    _synced: tuple | None = field(default=None, repr=False)
    _tracking: bool = field(default=False, repr=False)

    @property
    def rows(self) -> np.ndarray:
        """Local rows (owned and ghost) of q, a (N, 5) view."""
        return self.q.x.array.reshape(-1, odeco.NUM_COEFFICIENTS)

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

    @contextmanager
    def tracking(self):
        """Within it, :meth:`set_from_x` skips the retraction when x is the vector, in the
        same PETSc state, that q was last set from or written to (TAO changes x only
        through PETSc, which counts every change). Only for code that changes q through
        :meth:`set_from_x` alone, such as the TAO callbacks of :func:`solve`."""
        self._tracking, self._synced = True, None
        try:
            yield self
        finally:
            self._tracking, self._synced = False, None

    def _mark_synced(self, x: PETSc.Vec) -> None:
        if self._tracking:
            self._synced = (x.handle, x.stateGet())

    def set_from_x(self, x: PETSc.Vec) -> None:
        """q ← R(x / √m): unscale, fill ghosts, project pointwise, normalise (steps 4–5)."""
        if self._tracking and self._synced == (x.handle, x.stateGet()):
            return  # q is R(x) already
        n = self.owned
        x_rows = x.getArray(readonly=True).reshape(-1, odeco.NUM_COEFFICIENTS)
        self.rows[:n] = x_rows / self.sqrt_mass[:n, None]
        self.q.x.scatter_forward()
        self.retract()
        self._mark_synced(x)

    def retract(self) -> None:
        """Steps 4–5 of note §3 on q in place."""
        rows = projection.project_rows(self.rows, self.constraints)
        self.rows[:] = projection.normalise_rows(rows, self.constraints, self.norm2)

    def write_x(self, x: PETSc.Vec) -> None:
        """x ← √m q (owned rows)."""
        n = self.owned
        x.getArray()[:] = (self.rows[:n] * self.sqrt_mass[:n, None]).ravel()
        self._mark_synced(x)

    def tangent_basis(self) -> np.ndarray:
        """Tangent basis of the constraints at q (local rows), active set from the last gradient."""
        return projection.tangent_basis_rows(self.rows, self.constraints, self.last_gradient)

    def chart_curvature_blocks(self, basis: np.ndarray) -> np.ndarray:
        """Per owned vertex, B W Bᵀ / m (5×5): the chart's second-order term in x (exact Hessian).

        ``basis``: :meth:`tangent_basis` at the same q.

        W from :func:`odeco.tangent_curvature` with the normal part of the Euclidean
        gradient of H in q (the second fundamental form of the variety); zero where the
        orientation is fixed (boundary, pinned vertices: the chart is linear).
        """
        n, c = self.owned, self.constraints
        gradient_q = self.last_gradient * self.sqrt_mass[:, None]
        # Only the normal part of the gradient pairs with the second fundamental form; the
        # tangent part is the sphere's (radial) at a critical point, counted separately.
        normal = gradient_q - np.einsum("nia,na->ni", basis, np.einsum("nia,ni->na", basis,
                                                                       gradient_q))
        curvature = odeco.tangent_curvature(
            self.rows, normal, c.max_aspect, c.isotropic, active_gradient=self.last_gradient
        )
        curvature[c.boundary] = 0.0
        blocks = np.einsum("nia,nab,njb->nij", basis, curvature, basis)[:n]
        return blocks / self.constraints.weights[:n, None, None]

    def energy(self) -> float:
        return self.q.function_space.mesh.comm.allreduce(
            fem.assemble_scalar(self.integrability), op=MPI.SUM
        )

    def dirichlet_energy(self) -> float:
        return self.q.function_space.mesh.comm.allreduce(
            fem.assemble_scalar(self.dirichlet), op=MPI.SUM
        )

    def riemannian_gradient(self, g: PETSc.Vec) -> float:
        """g ← the gradient of H on 𝓜 at q, in the scaled unknowns x (steps 1–2); returns H.

        H comes free with the gradient: the discrete H is a homogeneous quartic in the
        coefficients of q, so dH(q)[q] = 4 H(q) (Euler) — no second assembly.
        """
        n = self.owned
        b = fem.assemble_vector(self.gradient)
        b.scatter_reverse(dolfinx.la.InsertMode.add)
        comm = self.constraints.comm
        owned = odeco.NUM_COEFFICIENTS * n
        H = comm.allreduce(float(np.dot(b.array[:owned], self.q.x.array[:owned])), op=MPI.SUM)
        # Ghost rows of b are partial sums: projected along (pointwise), then dropped.
        dh = b.array.reshape(-1, odeco.NUM_COEFFICIENTS) / self.sqrt_mass[:, None]
        self.last_gradient, self.last_energy = dh, H / 4
        dh = projection.tangent_project_rows(self.rows, dh, self.constraints)[:n]
        x = self.rows[:n] * self.sqrt_mass[:n, None]
        along = comm.allreduce(float(np.vdot(dh, x)), op=MPI.SUM) / comm.allreduce(
            float(np.vdot(x, x)), op=MPI.SUM
        )
        g.getArray()[:] = (dh - along * x).ravel()
        return H / 4


def _block_diagonal(blocks: np.ndarray, index_map, comm, result=None) -> PETSc.Mat:
    """PETSc AIJ matrix (block size k) with the (n, k, k) ``blocks`` on the owned diagonal.

    With ``result`` (made by an earlier call) its values are replaced in place: PtAP
    with reuse in parallel needs the same P object every time.
    """
    n = blocks.shape[0]
    first = index_map.local_range[0]
    k = blocks.shape[1]  # odeco.NUM_COEFFICIENTS
    size = (k * n, k * index_map.size_global)
    cols = k * (first + np.arange(n))[:, None, None] + np.arange(k)[None, None, :]
    indices = np.broadcast_to(cols, (n, k, k)).astype(PETSc.IntType).ravel()
    indptr = np.arange(0, k * k * n + 1, k, dtype=PETSc.IntType)
    if result is None:
        return PETSc.Mat().createAIJ(
            size=(size, size), bsize=k, csr=(indptr, indices, blocks.ravel()), comm=comm
        )
    result.setValuesCSR(indptr, indices, blocks.ravel())
    result.assemble()
    return result


def frame_problem(
    q: fem.Function,
    isotropic: bool = False,
    pin_singularities: bool = True,
    max_aspect: float | None = None,
    boundary_angles: np.ndarray | None = None,
    constraints: projection.FrameConstraints | None = None,
) -> FrameProblem:
    """Compile the energies of ``q``, find its constraints and retract it onto 𝓜.

    The normalisation (step 5) keeps the lumped L² norm of the retracted ``q``. With
    ``pin_singularities`` the cross orientation is held at the vertices of the
    singular triangles of ``q`` (see :func:`projection.pin_singularities`). ``max_aspect``
    bounds l_max/l_min of non-isotropic frames (see :func:`odeco.clamp_aspect`).
    ``boundary_angles``: exact boundary cross angles per local row (see
    :func:`projection.frame_constraints`). ``constraints`` already found for ``q``'s
    space (e.g. the MBO field's) are reused, with ``isotropic`` and ``max_aspect`` set
    from here; ``boundary_angles`` is then not needed.
    """
    V = q.function_space
    if constraints is None:
        constraints = projection.frame_constraints(
            V, isotropic=isotropic, max_aspect=max_aspect, boundary_angles=boundary_angles
        )
    else:
        constraints = replace(constraints, isotropic=isotropic,
                              max_aspect=None if isotropic else max_aspect)
    if pin_singularities:
        rows = q.x.array.reshape(-1, odeco.NUM_COEFFICIENTS)
        constraints = projection.pin_singularities(V, constraints, rows)
    H = energy.integrability_energy_form(q)
    problem = FrameProblem(
        q=q,
        constraints=constraints,
        integrability=fem.form(H),
        gradient=fem.form(energy.gradient_form(H, q)),
        dirichlet=fem.form(energy.dirichlet_energy_form(q)),
        norm2=1.0,
        area=constraints.comm.allreduce(float(constraints.weights[: constraints.owned].sum()),
                                        op=MPI.SUM),
        sqrt_mass=np.sqrt(constraints.weights),
    )
    q.x.array[:] = projection.project_rows(problem.rows, constraints).ravel()
    problem.norm2 = projection.weighted_norm2(problem.rows, constraints)
    return problem


@dataclass
class SolveResult:
    """Outcome of :func:`solve`.

    ``history`` has one entry per TAO monitor call that found a new iterate: the
    initial state, then one per accepted step (rejected trust-region steps, which
    ``ntr`` reports too, are left out). ``iterations`` counts those steps; it can
    exceed TAO's own count by one (``nls`` and ``bncg`` take a first step that TAO
    numbers 0 again).
    """

    history: list[dict]
    converged_reason: str
    iterations: int
    wall_time_s: float

    @property
    def H_initial(self) -> float:
        return self.history[0]["H"]

    @property
    def H_final(self) -> float:
        return self.history[-1]["H"]

    @property
    def E_final(self) -> float:
        return self.history[-1]["E"]


#: TAO types that get the Gauss–Newton Hessian of :class:`GaussNewtonModel`.
SECOND_ORDER_TYPES = {"nls", "ntr", "ntl", "bnls", "bntr", "bntl", "tron"}


class GaussNewtonModel:
    r"""Riemannian (Gauss–)Newton Hessian of H on 𝓜, with Sobolev (H¹) damping.

    In the scaled unknowns x = W q (W = diag √m) at the current iterate:

        B = S [ P W⁻¹ (JᵀJ + λ (K + M/A)) W⁻¹ P + μ (I − P) ] S + μ x̂ x̂ᵀ

    * JᵀJ: the linearised bracket, assembled from :func:`energy.gauss_newton_form`;
    * P: block-diagonal tangent projector of the Odeco constraints (per vertex);
      the normal directions get μ, the mean tangent curvature, so that a Newton
      step from a tangent gradient is tangent;
    * S = I − x̂x̂ᵀ: tangent projector of the normalisation sphere |x| = const
      (without it the model predicts decreases by shrinking the frames, which the
      retraction undoes);
    * λ (K + M/A): Levenberg–Marquardt damping in the H¹ metric (A the area: in units of
      the domain, so the damping does not depend on its size). H has a large family
      of minimisers (integrable fields are far from unique), so JᵀJ is singular;
      an L² (identity) damping lets the steps excite rough null directions, an H¹
      damping keeps them smooth. λ = λ₀ max(r, min(1, |g|/max(|g₀|, G))) · mean|q|²
      decreases with the gradient down to the floor r (``-frames_gn_damping λ₀``,
      default 1; ``-frames_gn_damping_min r``, default 1e-3). G is
      :attr:`FrameProblem.gradient_scale`: from an already nearly stationary start (a
      restart, |g₀| ≪ G) the damping starts near its floor instead of at its largest
      (|g|/|g₀| = 1), and |g₀| = 0 is no 0/0. Without a floor the Newton systems
      become singular and the Krylov iterations explode (measured: 85 Newton steps and
      ~70 s against 35 steps and ~3 s with r = 1e-3 on the annulus at h = 0.05).

    With ``exact`` (``-frames_hessian exact``, the default for isotropic frames) JᵀJ is
    replaced by the full Hessian ∇²H (UFL, second derivative of H), and the curvature of
    the constraint set is added: per vertex the second fundamental form of the variety
    paired with the normal part of the gradient (:func:`odeco.tangent_curvature`, zero
    where the orientation is fixed), and −4H/ρ² on the sphere's tangent space (x·∇H = 4H).
    At a critical point this is the Riemannian Hessian (tested against second
    differences of H∘R to 1e-7): Newton then converges quadratically even where the
    residual is large — the pinned isotropic piano (H ≈ 0.18) takes 10 iterations at
    h = 0.05 against 58 with Gauss–Newton. For non-isotropic frames Gauss–Newton stays
    the default: ∇²H is indefinite along their many free directions, and it was no
    faster there (annulus 14/21 iterations at h = 0.1/0.05 against 17/29).

    B is a MatShell for TAO; the assembled sparse part (without the rank-one terms)
    is the preconditioning matrix, so ``-tao_nls_pc_type`` / ``-tao_ntr_pc_type``
    (gamg, hypre, lu, ...) act on it.

    TAO's Hessian perturbation (``nls``, ``bnls``: ``MatShift`` by ``pert`` after each
    Hessian evaluation) shifts both: the shell (:meth:`shift`, so the shell is B + pert·I)
    and, because it is a different matrix, the pre-matrix too (B's sparse part + pert·I,
    its preconditioner). :meth:`mult` therefore applies an unshifted copy of the assembled
    part (:attr:`unshifted`, refreshed with every assembly), not the pre-matrix: applying
    the shifted pre-matrix and then adding the shell's own shift gave B + pert (I + S),
    the perturbation twice on every tangent direction.
    """

    #: The PETSc objects the model owns (destroyed by :meth:`free`).
    _OWNED = ("shell", "assembled", "unshifted", "gauss_newton", "sobolev", "unscale", "xhat",
              "work", "tangent", "normal", "curvature")

    def __init__(self, problem: FrameProblem, template: PETSc.Vec, damping: float = 1.0,
                 damping_min: float = 1e-3, exact: bool = False):
        self.problem, self.damping, self.damping_min = problem, damping, damping_min
        self.exact, self.sphere = exact, 0.0
        for name in self._OWNED:
            setattr(self, name, None)
        try:
            self._create(template)
        except BaseException:
            self.free()  # what was created before the error (collective, as the creation was)
            raise

    def _create(self, template: PETSc.Vec) -> None:
        problem, exact = self.problem, self.exact
        if exact:
            H = energy.integrability_energy_form(problem.q)
            V = problem.q.function_space
            hessian = ufl.derivative(energy.gradient_form(H, problem.q), problem.q,
                                     ufl.TrialFunction(V))
            self.form = fem.form(hessian)
        else:
            self.form = fem.form(energy.gauss_newton_form(problem.q))
        self.gauss_newton = dolfinx.fem.petsc.create_matrix(self.form)
        self.unscale = template.duplicate()
        inverse = 1.0 / problem.sqrt_mass[: problem.owned]
        self.unscale.getArray()[:] = np.repeat(inverse, odeco.NUM_COEFFICIENTS)
        V = problem.q.function_space
        u, w = ufl.TrialFunction(V), ufl.TestFunction(V)
        # K + M/A (A the area): the H¹ metric in units of the domain, so that the damping,
        # like JᵀJ, does not depend on the domain's size (K + M, on a domain 6.5e7 wide,
        # was M alone: an L² damping, and Newton stalled at 500 iterations).
        area = fem.Constant(V.mesh, PETSc.ScalarType(problem.area))
        sobolev = fem.form((ufl.inner(ufl.grad(u), ufl.grad(w)) + ufl.inner(u, w) / area)
                           * ufl.dx)
        self.sobolev = dolfinx.fem.petsc.assemble_matrix(sobolev)
        self.sobolev.assemble()
        self.sobolev.diagonalScale(self.unscale, self.unscale)
        self.xhat, self.work = template.duplicate(), template.duplicate()
        self.mu, self.shift_value, self.lam, self.gnorm0 = 1.0, 0.0, 0.0, None
        # tangent, normal, curvature: block-diagonal, reused; unshifted: copy of the
        # pre-matrix that TAO's MatShift does not reach (all made by the first _assemble)
        self.assembled = self._assemble(None, gnorm=None)  # pattern only: TAO calls update
        self.shell = PETSc.Mat().createPython(self.assembled.getSizes(), comm=template.comm)
        self.shell.setPythonContext(self)
        self.shell.setUp()

    def _assemble(self, result, gnorm):
        problem, G = self.problem, self.gauss_newton
        G.zeroEntries()
        dolfinx.fem.petsc.assemble_matrix(G, self.form)
        G.assemble()
        G.diagonalScale(self.unscale, self.unscale)
        if self.gnorm0 is None and gnorm is not None:
            # The first Hessian is at the initial iterate. Its gradient is no reference
            # when the start is already (nearly) stationary: the natural scale then is.
            self.gnorm0 = max(gnorm, problem.gradient_scale)
        n = problem.owned
        scale = problem.constraints.comm.allreduce(
            float(np.einsum("ni,ni->", problem.rows[:n], problem.rows[:n])), op=MPI.SUM
        ) / problem.q.function_space.dofmap.index_map.size_global
        ratio = 1.0 if gnorm is None else min(1.0, gnorm / self.gnorm0)
        self.lam = self.damping * max(self.damping_min, ratio) * scale
        G.axpy(self.lam, self.sobolev, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        basis = problem.tangent_basis()
        blocks = np.einsum("nik,njk->nij", basis[:n], basis[:n])
        index_map, comm = problem.q.function_space.dofmap.index_map, problem.constraints.comm
        self.tangent = _block_diagonal(blocks, index_map, comm, self.tangent)
        identity = np.eye(odeco.NUM_COEFFICIENTS)
        self.normal = _block_diagonal(identity - blocks, index_map, comm, self.normal)
        if result is None:
            result = G.PtAP(self.tangent)
        else:
            G.PtAP(self.tangent, result=result)
        diagonal, dofs = result.getDiagonal(), self.tangent.getDiagonal()
        try:
            self.mu = diagonal.sum() / max(dofs.sum(), 1.0)
        finally:
            diagonal.destroy()
            dofs.destroy()
        result.axpy(self.mu, self.normal, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        if self.exact and problem.last_gradient is not None:
            self.curvature = _block_diagonal(
                problem.chart_curvature_blocks(basis), index_map, comm, self.curvature
            )
            result.axpy(1.0, self.curvature,
                        structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        problem.write_x(self.xhat)
        if self.exact:
            # Curvature of the sphere |x| = ρ: −(x·∇H)/ρ² on its tangent space, x·∇H = 4H.
            H = problem.energy() if problem.last_energy is None else problem.last_energy
            self.sphere = 4 * H / self.xhat.dot(self.xhat)
        self.xhat.normalize()
        # TAO shifts the pre-matrix (``result``) in place; the shell's product must not see
        # that shift, it adds its own (``shift_value``) exactly once.
        if self.unshifted is None:
            self.unshifted = result.duplicate(copy=True)
        else:
            result.copy(self.unshifted, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        self.shift_value = 0.0
        return result

    def update(self, tao, x, H, P):
        """TAO Hessian callback at x (TAO has just evaluated the gradient there)."""
        self.problem.set_from_x(x)
        self._assemble(self.assembled, gnorm=tao.getGradient()[0].norm())

    # MatShell interface
    def mult(self, mat, v, y):
        """y = B v + shift·v; the unshifted assembled part, whatever TAO did to the pre-matrix."""
        along = self.xhat.dot(v)
        self.work.waxpy(-along, self.xhat, v)
        self.unshifted.mult(self.work, y)
        if self.sphere:
            y.axpy(-self.sphere, self.work)
        y.axpy(self.mu * along - self.xhat.dot(y), self.xhat)
        if self.shift_value:
            y.axpy(self.shift_value, v)

    def shift(self, mat, a):
        """MatShift on the shell: B + a·I from now on (until the next assembly)."""
        self.shift_value += a

    def free(self):
        """Destroy the PETSc objects (not named ``destroy``: MatPython calls that one).

        Collective. Needed: the shell holds the model as its Python context and the model
        holds the shell, a cycle through PETSc that Python's garbage collector cannot see.
        Safe to call twice, and on a model whose construction failed part way.
        """
        for name in self._OWNED:
            obj = getattr(self, name, None)
            if obj is not None:
                obj.destroy()

    def __enter__(self):
        return self

    def __exit__(self, *exc_info):
        self.free()


def solve(
    problem: FrameProblem,
    max_it: int | None = None,
    options_prefix: str = "",
    defaults: dict | None = None,
    monitor=None,
) -> SolveResult:
    """Minimise H over 𝓜 from ``problem.q`` with TAO; ``problem.q`` holds the result.

    ``max_it`` is a default for ``-tao_max_it`` (the command line wins). ``monitor``
    receives each history entry ``{"it", "H", "E", "gnorm", "step"}`` (on every rank).

    Two defaults are relative to the scales of ``problem`` (given values are absolute):

    * ``-tao_fmin`` = :data:`ENERGY_RTOL` · H_s: an integrable field (H = 0 up to the
      accuracy of the initial field) ends with ``CONVERGED_MINF``;
    * ``-tao_gatol`` = gttol · G: the gradient test is |g| ≤ gttol · max(|g₀|, G), so a
      start that is already stationary ends with ``CONVERGED_GATOL``. TAO's own gttol
      test compares with |g₀| only, which, at a stationary start, is round-off: its
      target (1e-6 of that) is out of reach and the solve ran to ``max_it``. G, not an
      absolute number, because the gradient norm depends on the domain's size.

    Both are tested by TAO before the first step, for every TAO type (0 iterations).
    """
    options = {**DEFAULT_OPTIONS, **(defaults or {})}
    opts = PETSc.Options(options_prefix)
    tao_type = opts.getString("tao_type", options["tao_type"])
    options.update(TYPE_OPTIONS.get(tao_type, {}))
    if max_it is not None:
        options["tao_max_it"] = max_it
    gttol = opts.getReal("tao_gttol", float(options["tao_gttol"]))
    options.setdefault("tao_gatol", gttol * problem.gradient_scale)
    options.setdefault("tao_fmin", ENERGY_RTOL * problem.energy_scale)
    with petsc_defaults(options_prefix, options):
        return _solve(problem, tao_type, options_prefix, monitor)


def _released(exc: BaseException) -> BaseException:
    """``exc`` with the locals of this module's frames in its traceback cleared.

    Those are the callbacks TAO called (and what they called here): their arguments are
    petsc4py's own references to the TAO and its vectors, which would keep them alive as
    long as the caller keeps the exception, past their ``destroy()``. The frames stay in
    the traceback (file, line, function); only their variables go. The caller's frames,
    ``monitor``'s included, keep theirs.
    """
    tb = exc.__traceback__
    while tb is not None:
        if tb.tb_frame.f_code.co_filename == __file__:
            try:
                tb.tb_frame.clear()
            except RuntimeError:  # a frame still running (none here: TAO has returned)
                pass
        tb = tb.tb_next
    return exc


def _solve(problem, tao_type, options_prefix, monitor) -> SolveResult:
    """TAO from ``problem.q``, with the options already in the database (see :func:`solve`).

    Every PETSc object made here (x, g, the model, the TAO) is destroyed on the way out,
    whether the solve returns or raises, in the same order on every rank (collective).
    An exception raised by a callback (``monitor`` included) reaches PETSc as an error that
    aborts ``TaoSolve``; petsc4py then raises a ``PETSc.Error`` (code 101) in its place, so
    the callbacks keep the first one and it is that exception the caller sees.
    """
    comm = problem.constraints.comm
    hessian = None
    if tao_type in SECOND_ORDER_TYPES:
        opts = PETSc.Options(options_prefix)
        hessian = opts.getString("frames_hessian",
                                 "exact" if problem.constraints.isotropic else "gauss_newton")
        if hessian not in ("exact", "gauss_newton"):
            raise ValueError(f"-frames_hessian must be 'exact' or 'gauss_newton', got {hessian!r}")

    errors = []  # the first exception raised inside a callback, re-raised after TAO stops

    def guarded(callback):
        def call(*args):
            try:
                return callback(*args)
            except BaseException as exc:
                if not errors:
                    errors.append(exc)
                raise

        return call

    def objective(tao, x):
        problem.set_from_x(x)
        return problem.energy()

    def objective_gradient(tao, x, g):
        problem.set_from_x(x)
        return problem.riemannian_gradient(g)

    def update(tao, it):
        problem.set_from_x(tao.getSolution())
        problem.write_x(tao.getSolution())

    history = []

    def record(tao):
        _, f, gnorm, _, step, _ = tao.getSolutionStatus()
        if history and (f, gnorm) == (history[-1]["H"], history[-1]["gnorm"]):
            return  # a rejected trust-region step (ntr monitors those too): x did not move
        problem.set_from_x(tao.getSolution())
        entry = {"it": len(history), "H": float(f), "E": problem.dirichlet_energy(),
                 "gnorm": float(gnorm), "step": float(step)}
        history.append(entry)
        if monitor is not None:
            monitor(entry)

    with ExitStack() as owned:  # destroys in reverse order of creation, on every exit
        owned.enter_context(problem.tracking())
        x = dolfinx.fem.petsc.create_vector(problem.q.function_space)
        owned.callback(x.destroy)
        problem.retract()
        problem.write_x(x)
        g = x.duplicate()
        owned.callback(g.destroy)
        model = None
        if hessian is not None:
            opts = PETSc.Options(options_prefix)
            model = owned.enter_context(GaussNewtonModel(
                problem, x, damping=opts.getReal("frames_gn_damping", 1.0),
                damping_min=opts.getReal("frames_gn_damping_min", 1e-3),
                exact=hessian == "exact"))
        tao = PETSc.TAO().create(comm)
        owned.callback(tao.destroy)
        tao.setOptionsPrefix(options_prefix)
        tao.setSolution(x)
        tao.setObjectiveGradient(guarded(objective_gradient), g)
        tao.setObjective(guarded(objective))  # line-search trials need no gradient
        if model is not None:
            tao.setHessian(guarded(model.update), model.shell, model.assembled)
        tao.setUpdate(guarded(update))
        tao.setMonitor(guarded(record))
        tao.setFromOptions()

        start = time.perf_counter()
        try:
            tao.solve()
        except PETSc.Error:
            if not errors:
                raise
        if errors:  # outside the except clause: no PETSc.Error chained to it
            raise _released(errors.pop())
        wall = comm.allreduce(time.perf_counter() - start, op=MPI.MAX)
        problem.set_from_x(tao.getSolution())
        reason = converged_reason_name(tao.getConvergedReason())
    iterations = len(history) - 1  # TAO's own count restarts in some types (bncg)
    return SolveResult(history=history, converged_reason=reason, iterations=iterations,
                       wall_time_s=wall)
