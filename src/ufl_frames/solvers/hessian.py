r"""Newton models of H on the frame manifold for TAO's second-order methods.

:class:`GaussNewtonModel` is the Hessian TAO's ``nls``/``ntr``/``bnls``/``bntr`` get:
the Gauss–Newton (or, with ``exact``, the full) Hessian of the integrability energy,
made Riemannian with the curvature terms of :class:`~ufl_frames.fem.manifold.FrameManifold`
and damped in the H¹ metric; with ``switch`` (the hybrid model, the default for
non-isotropic frames) Gauss–Newton first and the exact Hessian near the minimum.
"""

from contextlib import contextmanager

from ufl_frames.bootstrap import init_petsc, petsc_defaults

init_petsc()

import dolfinx  # noqa: E402
import dolfinx.fem as fem  # noqa: E402
import dolfinx.fem.petsc  # noqa: E402, F401
import numpy as np  # noqa: E402
import ufl  # noqa: E402
from mpi4py import MPI  # noqa: E402
from petsc4py import PETSc  # noqa: E402

from ufl_frames.fem import kernels  # noqa: E402
from ufl_frames.fem.problem import Evaluation, FrameProblem  # noqa: E402

__all__ = ["DEFAULT_DAMPING", "HYBRID_SWITCH", "GaussNewtonModel", "ReducedFactorPC"]

#: Default λ₀ of the Levenberg–Marquardt damping (``-frames_gn_damping``).
DEFAULT_DAMPING = 1.0
#: The damping adapts to the steps (``-frames_gn_adapt``, on by default): after a step
#: the line search accepted whole, the factor a ∈ [:data:`ADAPT_FLOOR`, 1] of λ = λ₀ a …
#: shrinks by :data:`ADAPT_FACTOR`, after a shortened one it grows back (unless the step
#: put frames on the aspect bound: :meth:`GaussNewtonModel._reached_bound`). A fixed λ₀ = 1
#: damped the non-isotropic piano into a linear crawl (87 / 91 / 194 Newton iterations at
#: h = 0.1 / 0.05 / 0.025, with exact linear solves too); a fixed λ₀ = 1e-3 takes 26 / 47
#: there, but sends the isotropic annulus from MBO to another, 20x higher minimum and
#: the non-isotropic annulus from 21 to 183 iterations: the first steps need the damping,
#: the last ones do not.
ADAPT_FACTOR = 10.0
ADAPT_FLOOR = 1e-3
#: τ of the hybrid model (``-frames_hessian hybrid``, the default for non-isotropic frames;
#: ``-frames_hessian_switch τ``): Gauss–Newton until |g| ≤ τ |g₀|, the exact Riemannian
#: Hessian from there on, see :meth:`GaussNewtonModel._switch`.
HYBRID_SWITCH = 1e-3
#: η of the aspect bound's release rule (``-frames_active_release``; 0: off), see
#: :meth:`GaussNewtonModel._hold_active_set`.
RELEASE_RATIO = 1.0
#: Factorisations of a face more at most per Newton step in
#: :meth:`GaussNewtonModel._consistent_active_set` (``-frames_active_rounds r``). Measured
#: on the non-isotropic piano (benchmarks/README): 2 rounds took as few Newton steps as 4
#: or 6, with fewer factorisations; 1 round as few as 2, with 1.44 factorisations a step
#: instead of 1.79 at 2.5·10⁵ triangles on 2 ranks (197.1 s against 221.9 s end to end,
#: H 1 % lower) and 62.3 s against 63.9 s at 10⁵ serially; 0 rounds more steps (42
#: against 24 on the finest level at 10⁴ triangles, 83.0 s at 10⁵, H 10 % higher).
CONSISTENT_ROUNDS = 1
#: … and none where the step pushes no more than this fraction of the held frames off the
#: bound: those the retraction clamps, and the step's releases wait for the next Newton
#: step (10⁵ triangles: 100.0 s of solve; 118.3 s when a release always ran a round;
#: a round for every pushed frame cost more at every size, benchmarks/README).
CONSISTENT_TOLERANCE = 0.05


def sobolev_form(V: fem.FunctionSpace, area: float) -> ufl.Form:
    """K + M/A, the H¹ metric of the Newton model's damping in units of the domain (A its
    area), so that the damping, like JᵀJ, does not depend on the domain's size (K + M, on
    a domain 6.5e7 wide, was M alone: an L² damping, and Newton stalled at 500 iterations).
    """
    u, w = ufl.TrialFunction(V), ufl.TestFunction(V)
    scale = fem.Constant(V.mesh, PETSc.ScalarType(1.0 / area))
    return (ufl.inner(ufl.grad(u), ufl.grad(w)) + scale * ufl.inner(u, w)) * ufl.dx


def _block_diagonal(blocks: np.ndarray, index_map, comm, result=None) -> PETSc.Mat:
    """PETSc AIJ matrix with the (n, r, c) ``blocks`` on the owned block diagonal: square
    (block size r = c) or rectangular (r rows and c columns per vertex: a tangent basis).

    Every entry of a block is stored, zeros included, so that the pattern does not depend
    on the values. With ``result`` (made by an earlier call) its values are replaced in
    place: PtAP with reuse in parallel needs the same P object every time.
    """
    n, r, c = blocks.shape
    first = index_map.local_range[0]
    rows = (r * n, r * index_map.size_global)
    columns = (c * n, c * index_map.size_global)
    cols = c * (first + np.arange(n))[:, None, None] + np.arange(c)[None, None, :]
    indices = np.broadcast_to(cols, (n, r, c)).astype(PETSc.IntType).ravel()
    indptr = np.arange(0, c * r * n + 1, c, dtype=PETSc.IntType)
    values = np.ascontiguousarray(blocks).ravel()
    if result is None:
        matrix = PETSc.Mat().createAIJ(size=(rows, columns), csr=(indptr, indices, values),
                                       comm=comm, bsize=r if r == c else None)
        return matrix
    result.setValuesCSR(indptr, indices, values)
    result.assemble()
    return result


#: In parallel, Pᵀ A P of an A with at least this many rows uses PETSc's "allatonce"
#: algorithm (see :func:`_ptap`): 5 rows a vertex, so meshes of about 6·10⁵ triangles on.
ALLATONCE_ROWS = 1_500_000


def _ptap(A: PETSc.Mat, P: PETSc.Mat, result: PETSc.Mat | None = None) -> PETSc.Mat:
    """Pᵀ A P (into ``result`` where given: the numeric product of the same pattern); the
    models other than the lean one (which assembles R directly).

    PETSc's default parallel algorithm keeps intermediate products for the reuse that are
    larger than the result; its "allatonce" keeps none but its numeric products are
    slower. Measured for Tᵀ G T on 2 ranks (benchmarks/README): at 2.5·10⁵ triangles the
    first product took a rank from 470 to 700 MB (the result: 48 MB a rank), with
    "allatonce" to 541 MB, but a numeric product took 0.78–0.93 s instead of 0.43 s, and at
    10⁵ triangles the solve 78.3 s instead of 67.6 s. At 10⁶ triangles memory is what
    runs out: the peak after two Newton steps is 3 019 instead of 3 660 MB a rank. So A
    of :data:`ALLATONCE_ROWS` rows or more gets "allatonce" in parallel, unless the user
    chose (``-matptap_via``); serial PETSc has no such algorithm and keeps less.
    """
    if result is not None:
        return A.PtAP(P, result=result)
    if A.getComm().getSize() == 1 or A.getSize()[0] < ALLATONCE_ROWS:
        return A.PtAP(P)
    with petsc_defaults("", {"matptap_via": "allatonce"}):
        return A.PtAP(P)


class GaussNewtonModel:
    r"""Riemannian (Gauss–)Newton Hessian of H on 𝓜, with Sobolev (H¹) damping.

    In the scaled unknowns x = W q (W = diag √m) at the current iterate:

        B = S [ P W⁻¹ (JᵀJ + λ (K + M/A)) W⁻¹ P + μ (I − P) ] S + μ x̂ x̂ᵀ

    * JᵀJ: the linearised bracket, the matrix of :func:`energy.gauss_newton_form`
      (assembled with the compiled kernel of :mod:`ufl_frames.fem.kernels`);
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
      default :data:`DEFAULT_DAMPING`; ``-frames_gn_damping_min r``, default 1e-3). G is
      :attr:`FrameProblem.gradient_scale`: from an already nearly stationary start (a
      restart, |g₀| ≪ G) the damping starts near its floor instead of at its largest
      (|g|/|g₀| = 1), and |g₀| = 0 is no 0/0. Without a floor the Newton systems
      become singular and the Krylov iterations explode (measured: 85 Newton steps and
      ~70 s against 35 steps and ~3 s with r = 1e-3 on the annulus at h = 0.05).

    With ``exact`` (``-frames_hessian exact``, the default for isotropic frames) JᵀJ is
    replaced by the full Hessian ∇²H (the second derivative of H's UFL form, by the
    compiled kernel), and the curvature of the constraint set is added: per vertex the
    second fundamental form of the variety paired with the normal part of the gradient
    (the algebra's ``tangent_curvature``, zero where the orientation is fixed), and −4H/ρ² on
    the sphere's tangent space (x·∇H = 4H).
    At a critical point this is the Riemannian Hessian (tested against second
    differences of H∘R to 1e-7): Newton then converges quadratically even where the
    residual is large — the pinned isotropic piano (H ≈ 0.18) takes 10 iterations at
    h = 0.05 against 58 with Gauss–Newton. For non-isotropic frames ∇²H is indefinite
    along their many free directions far from a minimum, and it was no faster from the
    start (annulus 14/21 iterations at h = 0.1/0.05 against 17/29; nested piano at 3e4
    triangles 61/131/310 per level against 25/38/52). Their default is the hybrid
    (``switch`` = τ, ``-frames_hessian hybrid``): Gauss–Newton, then the exact Hessian
    once |g| ≤ τ |g₀| (:meth:`_switch`), which ends Gauss–Newton's linear tail.

    B is a MatShell for TAO; the assembled sparse part (without the rank-one terms)
    is the preconditioning matrix. By default :class:`ReducedFactorPC` inverts it in
    reduced tangent coordinates (:meth:`reduced_operator`); ``-tao_nls_pc_type`` /
    ``-tao_ntr_pc_type`` (cholesky, gamg, hypre, lu, ...) act on the 5N matrix itself.
    With ``lean`` (``nls`` and ``ntr`` with the reduced PC) no 5N matrix is made at all:
    R is assembled directly by the kernel of :func:`kernels.reduced_model_form` (not as
    Tᵀ G T by PtAP: at 10⁶ triangles 4.9 s instead of 14.1 s serially, 751 instead of
    3 972 MB), the one product with G the active set needs by a vector kernel, and the
    shell applies B from R (T R Tᵀ + μ (I − T Tᵀ)) and is TAO's pre-matrix too.

    TAO's Hessian perturbation (``nls``, ``bnls``: ``MatShift`` by ``pert`` after each
    Hessian evaluation) shifts both: the shell (:meth:`shift`, so the shell is B + pert·I)
    and, because it is a different matrix, the pre-matrix too (B's sparse part + pert·I,
    its preconditioner). :meth:`mult` therefore applies an unshifted copy of the assembled
    part (:attr:`unshifted`, refreshed with every assembly), not the pre-matrix: applying
    the shifted pre-matrix and then adding the shell's own shift gave B + pert (I + S),
    the perturbation twice on every tangent direction.
    """

    #: The PETSc objects the model owns (destroyed by :meth:`free`).
    _OWNED = ("shell", "assembled", "unshifted", "gauss_newton", "unscale", "xhat",
              "work", "tangent", "normal", "curvature", "basis_matrix", "reduced_matrix",
              "reduced_curvature", "absent", "lean_t", "lean_u", "lean_w", "product_vector")

    def __init__(self, problem: FrameProblem, template: PETSc.Vec,
                 damping: float = DEFAULT_DAMPING,
                 damping_min: float = 1e-3, exact: bool = False, adapt: bool = False,
                 release: float = RELEASE_RATIO, lean: bool = False, bound_steps: bool = True,
                 switch: float | None = None, consistent: bool = False,
                 rounds: int = CONSISTENT_ROUNDS):
        self.problem, self.damping, self.damping_min = problem, damping, damping_min
        self.consistent = consistent  # see _consistent_active_set
        self.rounds = rounds  # refactorisations at most per step there
        self.bound_rounds = []  # (released, pushed) per round of the last step
        self.released = None  # the releases the last step left to the next one
        self.switch = None if exact else switch  # see _switch
        self.bound_steps = bound_steps  # see _reached_bound
        self.lean = lean
        self.release, self.active = release, None
        self.adapt, self.adaptation = adapt, 1.0  # the factor a of λ (see ADAPT_FACTOR)
        self._resumed_step = None  # the step length the first update adapts to (resume)
        self.exact, self.sphere = exact, 0.0
        for name in self._OWNED:
            setattr(self, name, None)
        try:
            self._create(template)
        except BaseException:
            self.free()  # what was created before the error (collective, as the creation was)
            raise

    def _model_form(self, exact: bool) -> fem.Form:
        """The compiled form of the model's matrix: ∇²H (``exact``) or JᵀJ, plus the damping
        λ (K + M/A). λ is part of the form (a Constant): one assembly per Newton step, no
        second 5N × 5N matrix to add (at 1e5 triangles its MatAXPY took 5 % of a step).
        Both are the hand-written kernels of :mod:`ufl_frames.fem.kernels`: the same
        matrices as the UFL forms (``energy.gauss_newton_form``, the second derivative of
        H, plus :func:`sobolev_form`) to round-off, assembled in about half the time.

        The lean model assembles the reduced matrix Tᵀ G T itself
        (:func:`kernels.reduced_model_form`, T scaled by W⁻¹), with no 5N × 5N matrix G
        and no PtAP product (see :meth:`_build_reduced`)."""
        if self.lean:
            return kernels.reduced_model_form(self.problem.q, self.scaled_basis,
                                              self.reduced_space,
                                              self.damping_weight, self.inverse_area, exact,
                                              algebra=self.problem.algebra)
        make = kernels.damped_hessian_form if exact else kernels.damped_gauss_newton_form
        return make(self.problem.q, self.damping_weight, self.inverse_area,
                    algebra=self.problem.algebra)

    def _create(self, template: PETSc.Vec) -> None:
        problem = self.problem
        mesh = problem.q.function_space.mesh
        self.damping_weight = fem.Constant(mesh, PETSc.ScalarType(0.0))
        self.inverse_area = fem.Constant(mesh, PETSc.ScalarType(1.0 / problem.area))
        if self.lean:  # the reduced matrix's space and the basis T W⁻¹ (5 × c a vertex)
            columns = len(self._columns())
            self.scaled_basis = fem.Function(fem.functionspace(
                mesh, ("Lagrange", 1, (problem.algebra.count * columns,))))
            self.reduced_space = fem.functionspace(mesh, ("Lagrange", 1, (columns,)))
        self.product_form, self.direction = None, None  # see _model_product
        self.form = self._model_form(self.exact)
        if self.lean:
            self.reduced_matrix = dolfinx.fem.petsc.create_matrix(self.form)
        else:
            self.gauss_newton = dolfinx.fem.petsc.create_matrix(self.form)
        self.unscale = template.duplicate()
        inverse = 1.0 / problem.sqrt_mass[: problem.owned]
        self.unscale.getArray()[:] = np.repeat(inverse, problem.algebra.count)
        self.xhat, self.work = template.duplicate(), template.duplicate()
        self.mu, self.shift_value, self.lam, self.gnorm0 = 1.0, 0.0, 0.0, None
        # tangent, normal, curvature: block-diagonal, reused; unshifted: copy of the
        # pre-matrix that TAO's MatShift does not reach (all made by the first _assemble)
        # the model at the current q (TAO calls update again before its first product)
        self.assembled = self._assemble(None, gnorm=None, evaluation=problem.evaluation())
        sizes = (template.getSizes(), template.getSizes())
        self.shell = PETSc.Mat().createPython(sizes, comm=template.comm)
        self.shell.setPythonContext(self)
        self.shell.setUp()

    def _assemble(self, result, gnorm, evaluation: Evaluation):
        """The pre-matrix at the current q; ``evaluation`` (H, ∂H/∂x there) decides the
        active aspect bounds and gives the curvature terms."""
        problem, G = self.problem, self.gauss_newton
        if self.gnorm0 is None and gnorm is not None:
            # The first Hessian is at the initial iterate. Its gradient is no reference
            # when the start is already (nearly) stationary: the natural scale then is.
            self.gnorm0 = max(gnorm, problem.gradient_scale)
        n = problem.owned
        scale = problem.constraints.comm.allreduce(
            float(np.einsum("ni,ni->", problem.rows[:n], problem.rows[:n])), op=MPI.SUM
        ) / problem.q.function_space.dofmap.index_map.size_global
        ratio = 1.0 if gnorm is None else min(1.0, gnorm / self.gnorm0)
        self.lam = self.damping * self.adaptation * max(self.damping_min, ratio) * scale
        self.damping_weight.value = self.lam
        if not self.lean:  # the lean model assembles Tᵀ G T in _build_reduced instead
            G.zeroEntries()
            dolfinx.fem.petsc.assemble_matrix(G, self.form)
            G.assemble()
            G.diagonalScale(self.unscale, self.unscale)
        return self._assemble_tangent(result, evaluation)

    def _assemble_tangent(self, result, evaluation: Evaluation):
        """The parts of the model that depend on the tangent basis (the aspect bound's
        active set, with ``problem.held``), from the assembled G: the reduced matrix (lean)
        or the 5N pre-matrix, the curvature terms, x̂."""
        problem = self.problem
        manifold, n = problem.manifold, problem.owned
        basis = manifold.tangent_basis(problem.rows, evaluation.gradient_x, held=problem.held,
                                      only_held=problem.held_only)
        if not problem.constraints.isotropic:  # frames held on the aspect bound (no e_d)
            self.active = manifold.on_bound(basis)
        self._basis = basis[:n]  # for reduced_operator (the tangent basis of this model)
        if self.exact:
            self._curvature_blocks = manifold.curvature_blocks(problem.rows, basis,
                                                               evaluation.gradient_x)
            # Curvature of the sphere |x| = ρ: −(x·∇H)/ρ² on its tangent space, x·∇H = 4H.
            self.sphere = manifold.sphere_curvature(evaluation.energy)
        if self.lean:  # only the reduced matrix: no 5N × 5N pre-matrix, no copy of it
            self.mu = None  # from trace(Tᵀ G T), as the 5N path's trace(P G P) / trace(P)
            self._build_reduced()
            result = None
        else:
            result = self._assemble_full(result, basis[:n])
        problem.write_x(self.xhat)
        self.xhat.normalize()
        self.shift_value = 0.0
        if self.lean:
            self.reduced_shift = 0.0  # R is built, unshifted
            if self.shell is not None:  # the PC's operator changed: PCSetUp runs again
                self.shell.stateIncrease()
        else:
            self.reduced_shift = None  # reduced_operator() is out of date
        return result

    def _assemble_full(self, result, basis) -> PETSc.Mat:
        """The 5N × 5N pre-matrix P G P + μ (I − P) (+ curvature − σ I) into ``result``
        (None: a new one), and its unshifted copy for the shell's product."""
        G, problem = self.gauss_newton, self.problem
        index_map, comm = problem.q.function_space.dofmap.index_map, problem.constraints.comm
        blocks = np.einsum("nik,njk->nij", basis, basis)
        self.tangent = _block_diagonal(blocks, index_map, comm, self.tangent)
        identity = np.eye(problem.algebra.count)
        self.normal = _block_diagonal(identity - blocks, index_map, comm, self.normal)
        result = _ptap(G, self.tangent, result)
        diagonal, dofs = result.getDiagonal(), self.tangent.getDiagonal()
        try:
            self.mu = diagonal.sum() / max(dofs.sum(), 1.0)
        finally:
            diagonal.destroy()
            dofs.destroy()
        result.axpy(self.mu, self.normal, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        if self.exact:
            self.curvature = _block_diagonal(self._curvature_blocks, index_map, comm,
                                             self.curvature)
            result.axpy(1.0, self.curvature,
                        structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
            result.shift(-self.sphere)  # the sphere's curvature, in the preconditioner too
        # TAO shifts the pre-matrix (``result``) in place; the shell's product must not see
        # that shift, it adds its own (``shift_value``) exactly once.
        if self.unshifted is None:
            self.unshifted = result.duplicate(copy=True)
        else:
            result.copy(self.unshifted, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        return result

    def reduced_operator(self) -> tuple[PETSc.Mat, PETSc.Mat]:
        """The model's assembled part in reduced tangent coordinates: (T, R) with T the
        rectangular block-diagonal tangent basis (5 rows and c = 3 columns per vertex, 2
        for isotropic frames) and R = Tᵀ G T + μ E + (s − σ) I, G the damped Gauss–Newton
        matrix, E the identity on the columns that are absent at a vertex (fixed
        orientation, aspect bound; so that R is regular whatever the active set), s TAO's
        shift, σ the sphere's curvature of the exact model (0 for Gauss–Newton).

        The pre-matrix P G P + μ (I − P) − σ I of the model (P = T Tᵀ) then has the inverse
        T R⁻¹ Tᵀ + (I − T Tᵀ)/(μ − σ + s): :class:`ReducedFactorPC` applies it with one
        factorisation of R, c/5 of the unknowns of the pre-matrix (for c = 3 about a
        fifth of the factorisation's flops). Rebuilt after each assembly, on demand;
        the matrices are the model's (reused, same pattern: one symbolic factorisation).
        """
        if self.reduced_shift == self.shift_value:
            return self.basis_matrix, self.reduced_matrix
        if self.reduced_shift is not None:  # only TAO's shift changed since
            self.reduced_matrix.shift(self.shift_value - self.reduced_shift)
            self.reduced_shift = self.shift_value
            return self.basis_matrix, self.reduced_matrix
        self._build_reduced()
        if self.shift_value:
            self.reduced_matrix.shift(self.shift_value)
        self.reduced_shift = self.shift_value
        return self.basis_matrix, self.reduced_matrix

    def _columns(self) -> list[int]:
        """The tangent basis' columns that are unknowns of R: all of them (2D: e_s, e_d and
        the rotation), less the anisotropy columns for isotropic frames (no e_d)."""
        algebra = self.problem.algebra
        columns = range(algebra.tangent_columns)
        if not self.problem.constraints.isotropic:
            return list(columns)
        return [k for k in columns if k not in algebra.anisotropy_columns]

    def _build_reduced(self) -> None:
        """T and R = Tᵀ G T (+ the reduced curvature) + μ E at the current q and basis, no
        shift; μ from the trace of Tᵀ G T where it is not known yet (lean model).

        The lean model assembles Tᵀ G T (G in x = W q: Tᵀ W⁻¹ G_q W⁻¹ T) with the kernel of
        :func:`kernels.reduced_model_form`, the others as the product Pᵀ G P of their
        assembled 5N × 5N G. Per element 9 × 9 values instead of 15 × 15, and no PtAP:
        measured in benchmarks/README ("The reduced matrix assembled directly")."""
        problem = self.problem
        basis = self._basis[:, :, self._columns()]
        index_map = problem.q.function_space.dofmap.index_map
        comm = problem.constraints.comm
        n = problem.owned
        self.basis_matrix = _block_diagonal(basis, index_map, comm, self.basis_matrix)
        if self.lean:
            R = self.reduced_matrix
            scaled = self.scaled_basis.x.array.reshape(-1, *basis.shape[1:])
            scaled[:n] = basis / problem.sqrt_mass[:n, None, None]
            self.scaled_basis.x.scatter_forward()  # ghosts: the owner's active set
            R.zeroEntries()
            dolfinx.fem.petsc.assemble_matrix(R, self.form)
            R.assemble()
        else:
            self.reduced_matrix = _ptap(self.gauss_newton, self.basis_matrix,
                                        self.reduced_matrix)
        missing = np.linalg.norm(basis, axis=1) == 0  # (n, c)
        if self.mu is None:
            trace = self.reduced_matrix.getDiagonal()
            try:
                total = trace.sum()
            finally:
                trace.destroy()
            count = comm.allreduce(int(np.count_nonzero(~missing)), op=MPI.SUM)
            self.mu = total / max(count, 1)
        if self.exact:  # the variety's curvature, in the same coordinates (c × c blocks)
            reduced = np.einsum("nai,nab,nbj->nij", basis, self._curvature_blocks, basis)
            self.reduced_curvature = _block_diagonal(reduced, index_map, comm,
                                                     self.reduced_curvature)
            self.reduced_matrix.axpy(1.0, self.reduced_curvature,
                                     structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        if self.absent is None:
            self.absent = self.reduced_matrix.createVecRight()
        # −σ, the sphere's curvature (exact model): in R, the preconditioner is the model's
        # tangent block itself, and a Krylov solve takes 2 iterations instead of 5-8
        self.absent.getArray()[:] = (np.where(missing, self.mu, 0.0) - self.sphere).ravel()
        self.reduced_matrix.setDiagonal(self.absent, addv=PETSc.InsertMode.ADD_VALUES)

    def resume(self, adaptation: float, gnorm0: float | None, active, step: float,
               exact: bool | None = None, released=None) -> None:
        """Go on from an earlier solve's state (:class:`ufl_frames.solvers.SolverState`):
        its damping factor and reference gradient, the active set of its last assembly and
        the releases it left to the next step (:attr:`released`), the length of its last
        step (which a new TAO does not report) and, for the hybrid model, whether it had
        switched to the exact Hessian."""
        self.adaptation, self.gnorm0 = adaptation, gnorm0
        self.active = None if active is None else np.asarray(active, dtype=bool).copy()
        self.released = None if released is None else np.asarray(released, dtype=bool).copy()
        self._resumed_step = step
        if exact and self.switch is not None and not self.exact:
            self._use_exact()

    def _switch(self, gnorm: float) -> None:
        """The hybrid model (``switch`` = τ): from the first Newton step with |g| ≤ τ |g₀|
        on, the exact Riemannian Hessian instead of Gauss–Newton, for the rest of the solve.

        Far from a minimum ∇²H of non-isotropic frames is indefinite along their many free
        directions, and Gauss–Newton is the better model. Near one, H is not 0 (a residual
        of the discretisation, H ≈ 1.4e-4 on the piano at 3e4 triangles), the terms JᵀJ
        leaves out are not small against its near-kernel, and Gauss–Newton converges
        linearly: with the active set fixed, |g| fell by 8 % per step. The exact Hessian
        there converges quadratically (the last step overshoots the tolerance by orders).
        """
        if self.switch is None or self.exact or self.gnorm0 is None:
            return
        if gnorm <= self.switch * self.gnorm0:
            self._use_exact()

    def _use_exact(self) -> None:
        self.exact, self.form = True, self._model_form(True)

    def update(self, tao, x, H, P):
        """TAO Hessian callback at x (TAO has just evaluated the gradient there)."""
        self.problem.set_from_x(x)
        free = self._free_basis()
        if self.adapt and self.gnorm0 is not None:  # after the first Newton step
            step = tao.getSolutionStatus()[4]  # the last line search's step length
            if self._resumed_step is not None:
                step, self._resumed_step = self._resumed_step, None
            if step >= 1.0 - 1e-12 or (self.bound_steps and self._reached_bound(free)):
                self.adaptation = max(ADAPT_FLOOR, self.adaptation / ADAPT_FACTOR)
            else:
                self.adaptation = min(1.0, self.adaptation * ADAPT_FACTOR)
        g = tao.getGradient()[0]
        if self.consistent:  # may put g on the held face
            self._start_active_set(g, free)
        else:
            self._hold_active_set(g, free)
        gnorm = g.norm()
        self._switch(gnorm)
        self.assemble(gnorm=gnorm)
        if self.consistent:
            self._consistent_active_set(tao.getKSP(), H, P, g)

    def _pushed_off_bound(self, pc: PETSc.PC, g: PETSc.Vec,
                          step: PETSc.Vec | None = None) -> np.ndarray:
        """Owned frames on the aspect bound that the step −(PC⁻¹ g) pushes outwards
        (``step``: where PC⁻¹ g is put, a work vector of the caller; None: a new one)."""
        work = g.duplicate() if step is None else step
        try:
            pc.apply(g, work)  # ≈ B⁻¹ g: the Newton direction is −work
            return self.problem.manifold.pushed_off_bound(
                self.problem.rows,
                -work.getArray(readonly=True).reshape(-1, self.problem.algebra.count))
        finally:
            if step is None:
                work.destroy()

    def _bounded(self) -> bool:
        """Whether the frames have an aspect bound that an active set applies to."""
        c = self.problem.constraints
        return not c.isotropic and c.max_aspect is not None

    def _start_active_set(self, g: PETSc.Vec, free: np.ndarray | None) -> None:
        """The face a Newton step of :meth:`_consistent_active_set` starts from: the frames
        the gradient holds on the bound and those the last step ended with (while still
        on it), less those the last step released without a round (:attr:`released`),
        held exactly (:attr:`FrameProblem.held_only`); ``g`` is put on that face.
        ``free``: :meth:`_free_basis` (None: computed here)."""
        problem = self.problem
        problem.held, problem.held_only = None, False
        if self.active is None or not self._bounded():
            return
        if free is None:
            free = problem.manifold.tangent_basis(problem.rows,
                                                  problem.evaluation().gradient_x)
        held = problem.manifold.on_bound(free) | self.active
        if self.released is not None:
            held &= ~self.released
            self.released = None
        problem.held, problem.held_only = held, True
        problem.riemannian_gradient(g)

    def _consistent_active_set(self, ksp: PETSc.KSP, H: PETSc.Mat, P: PETSc.Mat,
                               g: PETSc.Vec) -> None:
        """The aspect bound's active set decided by the Newton step itself
        (``-frames_active_consistent``, the default of ``nls``; collective): primal–dual
        active-set rounds on the model's quadratic problem, with the preconditioner the
        Krylov solve then reuses (exact with the default :class:`ReducedFactorPC` or a
        factorisation of the pre-matrix).

        The gradient decides the active set frame by frame, the step couples them: a
        frame on the bound whose gradient points inwards can still be carried outwards
        by its neighbours' step, and the retraction then clamps it back, bending the path
        away from the Newton step (after a release on the non-isotropic piano at 3·10⁴
        triangles H rose by 22 times the predicted decrease at the full step, and fell by
        0.3 of it along the same step without the clamp). And a held frame is released
        here by the model's multiplier, not by the gradient: once the step is taken, is
        the model's gradient g_free + G δ (g_free: the gradient with no bound, G the
        model's matrix, δ the step) still pointing outwards? The gradient alone released
        a third of the set per step and a sixth came back, so a region of the bound
        unwound from its edge over tens of steps.

        From the face of :meth:`_start_active_set`, the step δ on the current face is
        factorised and solved; the first round releases the held frames whose multiplier
        is negative and holds the frames δ pushes off the bound, later rounds (at most
        ``rounds`` factorisations more, ``-frames_active_rounds``, default
        :data:`CONSISTENT_ROUNDS`; none for a few pushed frames:
        :data:`CONSISTENT_TOLERANCE`) only hold pushed ones, so the set settles. Where no
        round follows the first (few frames pushed, or ``rounds`` = 0), its releases are
        left to the next Newton step
        (:attr:`released`, see :meth:`_start_active_set`): a refactorisation for a few
        released frames cost more than the step they wait (at 10⁵ triangles 100.0 s
        against 118.3 s of solve, the same steps and H). ``g`` follows the face.
        :attr:`bound_rounds` records (released, pushed) per round of the last step. On the
        non-isotropic piano the finest level's Newton steps no longer grow with the mesh:
        36 / 27 / 29 at 10⁴ / 3·10⁴ / 10⁵ triangles, against 58 / 36 / 60 with the
        hold-and-release rule (benchmarks/README).
        """
        problem = self.problem
        pc = ksp.getPC()
        self.bound_rounds = []
        if self.active is None or not self._bounded():
            return
        manifold, comm, n = problem.manifold, problem.constraints.comm, problem.owned
        evaluation = problem.evaluation()
        rows = problem.rows
        unbounded = manifold.riemannian_gradient(  # only_held with nothing held: no bound
            rows, evaluation.gradient_x, held=np.zeros(rows.shape[0], bool), only_held=True)
        held = (self.active if problem.held is None else problem.held).copy()
        ksp.setOperators(H, P)
        step, product = g.duplicate(), g.duplicate()
        try:
            for round_ in range(self.rounds + 1):
                pc.setUp()
                pushed = self._pushed_off_bound(pc, g, step) & ~held[:n]
                released = np.zeros(n, dtype=bool)
                if round_ == 0:
                    self._model_product(step, product)  # G (−δ)
                    model_gradient = unbounded - product.getArray(readonly=True).reshape(
                        -1, problem.algebra.count)
                    # the multiplier ≥ 0 where the model gradient still pushes outwards
                    released = self.active[:n] & ~manifold.pushed_off_bound(rows,
                                                                            -model_gradient)
                counts = (comm.allreduce(int(np.count_nonzero(released)), op=MPI.SUM),
                          comm.allreduce(int(np.count_nonzero(pushed)), op=MPI.SUM))
                self.bound_rounds.append(counts)
                if counts == (0, 0):
                    break
                held_count = comm.allreduce(int(np.count_nonzero(self.active[:n])), op=MPI.SUM)
                if round_ == self.rounds or counts[1] <= CONSISTENT_TOLERANCE * held_count:
                    # a few frames clamped by the retraction cost less than a round (or no
                    # round is left), and the released frames can wait for the next
                    # step's face (only the first round releases)
                    if counts[0]:
                        self.released = np.zeros(rows.shape[0], dtype=bool)
                        self.released[:n] = released
                    break
                held = held.copy()
                held[:n] = (held[:n] & ~released) | pushed
                problem.held, problem.held_only = held, True
                problem.riemannian_gradient(g)
                self._assemble_tangent(self.assembled, evaluation)
        finally:
            step.destroy()
            product.destroy()
        pc.setUp()

    def _model_product(self, v: PETSc.Vec, y: PETSc.Vec) -> None:
        """y = G v, G the damped model's matrix (in x, without the tangent projections) at
        the last assembly: the 5N × 5N matrix's product, or where the lean model has no
        such matrix, the vector of :func:`kernels.model_action_form` (G_x = W⁻¹ G_q W⁻¹)."""
        if not self.lean:
            self.gauss_newton.mult(v, y)
            return
        problem = self.problem
        if self.direction is None:
            self.direction = fem.Function(problem.q.function_space)
            self.product_vector = dolfinx.fem.petsc.create_vector(problem.q.function_space)
        if self.product_form is None or self.product_form[0] != self.exact:
            form = kernels.model_action_form(problem.q, self.direction, self.damping_weight,
                                             self.inverse_area, self.exact,
                                             algebra=problem.algebra)
            self.product_form = (self.exact, form)
        self.direction.x.petsc_vec.pointwiseMult(v, self.unscale)  # d = W⁻¹ v
        self.direction.x.scatter_forward()
        b = self.product_vector
        with b.localForm() as local:
            local.set(0.0)
        dolfinx.fem.petsc.assemble_vector(b, self.product_form[1])
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        y.pointwiseMult(b, self.unscale)  # y = W⁻¹ G_q W⁻¹ v

    def _free_basis(self) -> np.ndarray | None:
        """The tangent basis at the current q with the aspect bound's active set decided by
        the gradient alone (nothing held), which the bound rules compare with the last
        Newton step's; None where neither rule is on, without a bound or before the first
        Newton step."""
        problem = self.problem
        if (not (self.release or self.bound_steps) or self.active is None
                or problem.constraints.isotropic
                or problem.constraints.max_aspect is None):
            return None
        return problem.manifold.tangent_basis(problem.rows, problem.evaluation().gradient_x)

    def _reached_bound(self, free: np.ndarray | None) -> bool:
        """Whether the last step put frames on the aspect bound that the last Newton step
        left free (collective): frames on it now, pushed outwards, not active then.

        The retraction clamps such frames onto the bound, so the step taken bends away
        from the Newton step and the line search shortens it; that is the bound's kink,
        not a poor model, and growing the damping for it was the wrong answer: on the
        non-isotropic piano at h = 0.05 / 0.025 / 0.0125 the damping then alternated
        between a = 1 and 0.1 for most of the solve. Counting such a step as a whole
        one (with the Armijo line search, :data:`~ufl_frames.solvers.tao.BOUNDED_OPTIONS`)
        took the Newton steps from 45 / 72 / 122 to 24 / 42 / 67, to the same H.
        ``-frames_gn_adapt_bound false`` grows the damping after every shortened step.
        """
        if free is None:
            return False
        problem = self.problem
        active = problem.manifold.on_bound(free)
        n = problem.owned
        new = bool(np.any(active[:n] & ~self.active[:n]))
        return problem.constraints.comm.allreduce(new, op=MPI.LOR)

    def _hold_active_set(self, g: PETSc.Vec, free: np.ndarray | None) -> None:
        """The anti-zigzag rule of the aspect bound (``-frames_active_release η``), where
        the active set is not decided with the step (:meth:`_consistent_active_set`: the
        other Newton types and PCs, or ``-frames_active_consistent false``).

        Frames on the bound that were active at the last Newton step stay held there,
        even where the gradient now points inwards, unless releasing them would add more
        gradient than is left on the current face (|g_free − g_face| > η |g_face|): leave
        a face only once it is nearly optimal on it (Moré–Toraldo). Without it, frames at
        the bound flipped in and out at every step (141 vertices, 1212 changes in 99 steps
        on the piano at h = 0.05) and the line search cut the steps. With a held set, TAO's
        gradient ``g`` is recomputed on that face, so that the Newton system, the line
        search and the stopping test see the same one. ``free``: :meth:`_free_basis`.
        """
        problem = self.problem
        problem.held, problem.held_only = None, False
        if not self.release or free is None:
            return
        manifold, rows = problem.manifold, problem.rows
        gradient = problem.evaluation().gradient_x
        free = manifold.projection(rows, gradient, basis=free)
        face = manifold.projection(rows, gradient, held=self.active)
        on_face = np.sqrt(manifold.inner(face, face))
        released = np.sqrt(manifold.inner(free - face, free - face))
        if released == 0.0 or released > self.release * on_face:
            return
        problem.held = self.active
        problem.riemannian_gradient(g)

    def assemble(self, gnorm: float | None = None) -> None:
        """The model at the problem's current q, from its :meth:`~FrameProblem.evaluation`
        there (one vector assembly, or none when cached); ``gnorm`` = |g| sets the damping
        (None: its largest value)."""
        self._assemble(self.assembled, gnorm=gnorm, evaluation=self.problem.evaluation())

    # MatShell interface
    #: Called with an exception raised in :meth:`mult` before it reaches PETSc (which turns
    #: it into an error code): the solver keeps it to raise once TAO has stopped.
    on_error = None

    def mult(self, mat, v, y):
        """y = B v + shift·v (exceptions go to :attr:`on_error` first)."""
        try:
            self._mult(v, y)
        except BaseException as exc:
            if self.on_error is not None:
                self.on_error(exc)
            raise

    def _mult(self, v, y):
        """y = B v + shift·v; the unshifted assembled part, whatever TAO did to the pre-matrix."""
        along = self.xhat.dot(v)
        self.work.waxpy(-along, self.xhat, v)
        if self.lean:
            self._reduced_mult(self.work, y)
        else:
            self.unshifted.mult(self.work, y)
        y.axpy(self.mu * along - self.xhat.dot(y), self.xhat)
        if self.shift_value:
            y.axpy(self.shift_value, v)

    def _reduced_mult(self, w, y):
        """y = T (R − s I) Tᵀ w + (μ − σ) (w − T Tᵀ w), s the shift R holds: the assembled
        part (P G P + μ (I − P) − σ I, + curvature) from the reduced matrix (lean model)."""
        T, R = self.basis_matrix, self.reduced_matrix
        if self.lean_t is None:
            self.lean_t, self.lean_u, self.lean_w = (R.createVecRight(), R.createVecRight(),
                                                     T.createVecLeft())
        t, u, tangent = self.lean_t, self.lean_u, self.lean_w
        T.multTranspose(w, t)
        R.mult(t, u)
        if self.reduced_shift:
            u.axpy(-self.reduced_shift, t)
        T.mult(t, tangent)
        T.mult(u, y)
        y.axpy(self.mu - self.sphere, w)
        y.axpy(self.sphere - self.mu, tangent)

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


class ReducedFactorPC:
    r"""Preconditioner of the Newton systems in reduced tangent coordinates (PC python
    context; the default of the Newton TAO types, see
    :func:`ufl_frames.solvers.tao.newton_pc_options`).

    Applies the exact inverse of the model's pre-matrix P G P + μ (I − P) (− σ I for the
    exact model's sphere, + TAO's shift s) without factorising that 5N × 5N matrix: with
    the tangent basis T of :meth:`GaussNewtonModel.reduced_operator`,

        y = T R⁻¹ Tᵀ r + (r − T Tᵀ r) / (μ − σ + s),   R = Tᵀ G T (+ μ on absent columns, + s − σ),

    R being 3N × 3N (2N isotropic). So the Krylov iterations are those of the factorised
    pre-matrix (2 per step), for about a fifth of the factorisation's flops and a third
    of its memory. R is solved by an inner KSP under the prefix ``<newton prefix>reduced_``
    (default ``preonly`` + sparse Cholesky, MUMPS where PETSc has it), so
    ``-tao_nls_reduced_pc_type gamg`` and the like act on R. ``-tao_nls_pc_type
    cholesky`` (or any other PC) goes back to factorising the pre-matrix itself.
    """

    #: The Newton model of the solve that runs under each KSP options prefix
    #: (:meth:`solving`): :meth:`setUp` of a context without one takes it from here, so
    #: that it does not matter when PETSc makes the context. TAO's ``bntr`` applies the
    #: options again inside its solve, which makes a new one (with the model given to the
    #: first context only, that solve failed with PETSc error 101).
    _solving: dict = {}

    @classmethod
    @contextmanager
    def solving(cls, model: GaussNewtonModel, prefix: str):
        """Within it, a context of this class made for a PC under ``prefix`` uses ``model``."""
        cls._solving[prefix] = model
        try:
            yield
        finally:
            cls._solving.pop(prefix, None)

    def __init__(self):
        self.model, self.ksp, self.work = None, None, None

    def attach(self, model: GaussNewtonModel, prefix: str) -> None:
        """Use ``model``'s reduced operator; the inner KSP gets ``prefix + 'reduced_'``."""
        self.model = model
        comm = model.problem.constraints.comm
        self.ksp = PETSc.KSP().create(comm)
        self.ksp.setOptionsPrefix(prefix + "reduced_")
        self.ksp.setType(PETSc.KSP.Type.PREONLY)
        pc = self.ksp.getPC()
        if PETSc.Sys.hasExternalPackage("mumps"):
            pc.setType(PETSc.PC.Type.CHOLESKY)
            pc.setFactorSolverType("mumps")
        elif comm.size == 1:
            pc.setType(PETSc.PC.Type.CHOLESKY)
        else:
            self.ksp.setType(PETSc.KSP.Type.CG)
            pc.setType(PETSc.PC.Type.GAMG)
        self.ksp.setFromOptions()

    def setUp(self, pc):
        prefix = None if pc is None else pc.getOptionsPrefix() or ""
        if self.model is None and prefix in self._solving:
            self.attach(self._solving[prefix], prefix)
        if self.model is None:
            raise RuntimeError("ReducedFactorPC needs the Newton model: use it through "
                               "ufl_frames.solvers.solve")
        T, R = self.model.reduced_operator()
        self.ksp.setOperators(R)
        self.ksp.setUp()
        if self.work is None:
            self.work = (R.createVecRight(), R.createVecRight(), T.createVecLeft())

    def apply(self, pc, r, y):
        T, R = self.model.reduced_operator()
        t, s, w = self.work
        T.multTranspose(r, t)           # t = Tᵀ r
        self.ksp.solve(t, s)            # s = R⁻¹ t
        T.mult(t, w)                    # w = T Tᵀ r (the tangent part of r)
        T.mult(s, y)                    # y = T R⁻¹ Tᵀ r
        normal = self.model.mu - self.model.sphere + self.model.shift_value
        y.axpy(1.0 / normal, r)
        y.axpy(-1.0 / normal, w)

    def destroy(self, pc):
        if self.ksp is not None:
            self.ksp.destroy()
        for v in self.work or ():
            v.destroy()
        self.ksp, self.work, self.model = None, None, None
