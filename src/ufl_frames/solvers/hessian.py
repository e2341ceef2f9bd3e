r"""Newton models of H on the frame manifold for TAO's second-order methods.

:class:`GaussNewtonModel` is the Hessian TAO's ``nls``/``ntr``/``bnls``/``bntr`` get:
the Gauss–Newton (or, with ``exact``, the full) Hessian of the integrability energy,
made Riemannian with the curvature terms of :class:`~ufl_frames.fem.manifold.FrameManifold`
and damped in the H¹ metric; with ``switch`` (the hybrid model, the default for
non-isotropic frames) Gauss–Newton first and the exact Hessian near the minimum.
The aspect bound's active set of its steps is decided by the rules of
:mod:`~ufl_frames.solvers.active_set`, and its systems are preconditioned by
:class:`~ufl_frames.solvers.reduced_pc.ReducedFactorPC`.
"""

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
from ufl_frames.solvers.active_set import (  # noqa: E402
    CONSISTENT_ROUNDS,
    RELEASE_RATIO,
    ActiveSetRules,
)

__all__ = ["DEFAULT_DAMPING", "HYBRID_SWITCH", "INERTIA_SHIFTS", "SIZED_SWITCH",
           "GaussNewtonModel"]

#: Default λ₀ of the Levenberg–Marquardt damping (``-frames_gn_damping``).
DEFAULT_DAMPING = 1.0
#: The damping adapts to the steps (``-frames_gn_adapt``, on by default): after a step
#: the line search accepted whole, the factor a ∈ [:data:`ADAPT_FLOOR`, 1] of λ = λ₀ a …
#: shrinks by :data:`ADAPT_FACTOR`, after a shortened one it grows back (unless the step
#: put frames on the aspect bound:
#: :meth:`~ufl_frames.solvers.active_set.ActiveSetRules._reached_bound`). A fixed λ₀ = 1
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
#: τ of the hybrid model with a size target (the sized energy J = H + w H_s M): Gauss–Newton
#: converges linearly on J long before |g| reaches 1e-3 |g₀| (|g| fell by 10–13 % a step
#: for the last 20 of the 39 steps of the sized piano at 7.5·10³ triangles): the misfit's
#: residual ∇σ is not small at the minimum (M ≈ 0.09 there, w H_s M ≈ 0.6 H), so the
#: terms Gauss–Newton leaves out are not either. Switched earlier, with the safeguard of
#: :meth:`GaussNewtonModel.gauss_newton_step`, the nested piano's levels take 25 / 21 / 18
#: steps instead of 38 / 39 / 36 and end at the same minima (benchmarks/README, "Where the
#: sized problem's Newton steps go").
SIZED_SWITCH = 3e-2
#: Inertia correction of the safeguarded exact steps (:meth:`GaussNewtonModel.inertia_shift`,
#: ``-frames_hessian_inertia_shifts k``): an exact step whose factorisation has negative
#: pivots is factorised again with R + δ I, δ = :data:`INERTIA_FLOOR` μ ×
#: :data:`INERTIA_GROWTH`^j (μ the mean diagonal of Tᵀ G T), at most k times, before the
#: Gauss–Newton fallback. A small δ keeps the exact model's negative curvature as long,
#: cheap directions: the sized piano's nested levels (1 887 / 7 539 / 29 597) take 14 / 22
#: / 17 Newton steps instead of 25 / 21 / 18 to the same minima, and the 24 687-triangle
#: level of the 10⁵ hierarchy 53 instead of 87 (benchmarks/README, "Inertia correction of
#: the exact steps"). A large one is a slow gradient-like model (every shift ≥ 1e-2 μ, a
#: prototype: 203 steps on 7 539 triangles, one level, against 51).
INERTIA_SHIFTS = 4
INERTIA_FLOOR = 1e-4
INERTIA_GROWTH = 8.0


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
    on the values.

    Args:
        blocks: (n, r, c) array, one block per owned vertex.
        index_map: the vertices' DOLFINx index map (owned range, global size).
        comm: the matrix's communicator.
        result: a matrix made by an earlier call with blocks of the same shape: its
            values are replaced in place (PtAP with reuse in parallel needs the same P
            object every time); None: a new matrix.

    Returns:
        The matrix (``result`` where given).
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
    """Pᵀ A P; the models other than the lean one (which assembles R directly).

    PETSc's default parallel algorithm keeps intermediate products for the reuse that are
    larger than the result; its "allatonce" keeps none but its numeric products are
    slower (benchmarks/README, "Memory of the reduced matrix's product in parallel"):
    where memory runs out, on large meshes, it pays. So A of :data:`ALLATONCE_ROWS` rows
    or more gets "allatonce" in parallel, unless the user chose (``-matptap_via``);
    serial PETSc has no such algorithm and keeps less.

    Args:
        A: the square matrix.
        P: the (rectangular) matrix it is projected with.
        result: a product made by an earlier call with the same pattern: the numeric
            product goes into it; None: a new one.

    Returns:
        Pᵀ A P (``result`` where given).
    """
    if result is not None:
        return A.PtAP(P, result=result)
    if A.getComm().getSize() == 1 or A.getSize()[0] < ALLATONCE_ROWS:
        return A.PtAP(P)
    with petsc_defaults("", {"matptap_via": "allatonce"}):
        return A.PtAP(P)


class GaussNewtonModel(ActiveSetRules):
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
      become singular and the Krylov iterations explode (85 Newton steps against 35
      with r = 1e-3 on the annulus at h = 0.05, benchmarks/README).

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

    With a size target (``problem.size``) G also holds the size term's matrix
    w H_s (Gauss–Newton, or with ``exact`` the second derivative of M, or with
    ``size_mode`` its positive semidefinite modification), and the constant matrix of its
    smoothing term C S where there is one (``-frames_size_smoothing``; the sphere's
    curvature then reads x·∇J = 4H + 2 C S, :attr:`Evaluation.radial`). The lean model's
    kernels add it to H's element matrix (:func:`kernels.reduced_model_form` with a
    :class:`~ufl_frames.fem.kernels.SizeKernel`): one matrix, no matrix of its own and no
    product Tᵀ G_M T a step. The 5N path assembles it from its UFL form
    (:meth:`~ufl_frames.fem.problem.SizeTerm.hessian_ufl`) into a matrix of its own,
    added to G.

    B is a MatShell for TAO; the assembled sparse part (without the rank-one terms)
    is the preconditioning matrix. By default :class:`~.reduced_pc.ReducedFactorPC` inverts it in
    reduced tangent coordinates (:meth:`reduced_operator`); ``-tao_nls_pc_type`` /
    ``-tao_ntr_pc_type`` (cholesky, gamg, hypre, lu, ...) act on the 5N matrix itself.
    With ``lean`` (``nls`` and ``ntr`` with the reduced PC) no 5N matrix is made at all:
    R is assembled directly by the kernel of :func:`kernels.reduced_model_form` (not as
    Tᵀ G T by PtAP, which takes longer and more memory: benchmarks/README, "The reduced
    matrix assembled directly"), the one product with G the active set needs by a vector
    kernel, and the shell applies B from R (T R Tᵀ + μ (I − T Tᵀ)) and is TAO's
    pre-matrix too.

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
              "reduced_curvature", "absent", "lean_t", "lean_u", "lean_w", "product_vector",
              "size_matrix", "reduced_size", "size_product")

    def __init__(self, problem: FrameProblem, template: PETSc.Vec,
                 damping: float = DEFAULT_DAMPING,
                 damping_min: float = 1e-3, exact: bool = False, adapt: bool = False,
                 release: float = RELEASE_RATIO, lean: bool = False, bound_steps: bool = True,
                 switch: float | None = None, consistent: bool = False,
                 rounds: int = CONSISTENT_ROUNDS, safeguard: bool = True,
                 size_mode: int = kernels.SIZE_EXACT, inertia_shifts: int = INERTIA_SHIFTS):
        """The model at ``problem``'s current q (collective; :meth:`free` destroys it).

        Args:
            problem: the frame problem whose H is modelled.
            template: a vector of TAO's unknowns x (sizes and layout of the shell's).
            damping: λ₀ of the damping (``-frames_gn_damping``).
            damping_min: its floor r (``-frames_gn_damping_min``).
            exact: the exact Riemannian Hessian instead of Gauss–Newton.
            adapt: adapt the damping to the steps (see :data:`ADAPT_FACTOR`).
            release: η of the hold-and-release rule
                (:meth:`~ufl_frames.solvers.active_set.ActiveSetRules._hold_active_set`).
            lean: no 5N × 5N matrix: the reduced matrix assembled directly.
            bound_steps: a shortened step that reached the bound counts as a whole one.
            switch: τ of the hybrid model (None: no switch).
            consistent: decide the active set with the Newton step
                (:meth:`~ufl_frames.solvers.active_set.ActiveSetRules._consistent_active_set`).
            rounds: refactorisations at most per step there.
            safeguard: with a size target, an exact step of the hybrid model whose
                factorisation is indefinite is taken with Gauss–Newton
                (:meth:`gauss_newton_step`, ``-frames_hessian_safeguard``), after at most
                ``inertia_shifts`` factorisations shifted to correct its inertia
                (:meth:`inertia_shift`, ``-frames_hessian_inertia_shifts``; 0: none).
            size_mode: the size misfit's matrix where the model is exact (lean model,
                ``-frames_size_hessian``): :data:`kernels.SIZE_EXACT`, its second
                derivative, or :data:`kernels.SIZE_MODIFIED`, its positive semidefinite
                modification (slower: 72 Newton steps instead of 25 on the sized piano
                at 1 887 triangles, benchmarks/README); Gauss–Newton's where the model is.
        """
        self.size_mode = size_mode
        self.problem, self.damping, self.damping_min = problem, damping, damping_min
        self.consistent = consistent  # see _consistent_active_set
        self.rounds = rounds  # refactorisations at most per step there
        self.bound_rounds = []  # (released, pushed) per round of the last step
        self.released = None  # the releases the last step left to the next one
        self.switch = None if exact else switch  # see _switch
        self.safeguard = safeguard  # see safeguarded
        self.switched = False  # the hybrid model has switched to the exact Hessian
        self.fallbacks = 0  # exact steps taken as Gauss–Newton (gauss_newton_step)
        self.exact_checks = 0  # exact factorisations the safeguard read the inertia of
        self.inertia_shifts = inertia_shifts  # shifted refactorisations at most a step
        self.shifted = 0  # exact steps taken with an inertia shift (inertia_shift)
        self.shift_factorisations = 0  # the refactorisations those shifts cost
        self._gnorm = None  # |g| of the last update (the damping of a fallback)
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
        second 5N × 5N matrix to add each step).
        Both are the hand-written kernels of :mod:`ufl_frames.fem.kernels`: the same
        matrices as the UFL forms (``energy.gauss_newton_form``, the second derivative of
        H, plus :func:`sobolev_form`) to round-off, assembled in about half the time.

        The lean model assembles the reduced matrix Tᵀ G T itself
        (:func:`kernels.reduced_model_form`, T scaled by W⁻¹), with no 5N × 5N matrix G
        and no PtAP product (see :meth:`_build_reduced`)."""
        if self.size_kernel is not None:
            self.size_kernel.mode.value = self.size_mode if exact else kernels.SIZE_GAUSS_NEWTON
        if self.lean:
            return kernels.reduced_model_form(self.problem.q, self.scaled_basis,
                                              self.reduced_space,
                                              self.damping_weight, self.inverse_area, exact,
                                              algebra=self.problem.algebra,
                                              size=self.size_kernel)
        make = kernels.damped_hessian_form if exact else kernels.damped_gauss_newton_form
        return make(self.problem.q, self.damping_weight, self.inverse_area,
                    algebra=self.problem.algebra)

    def _size_form(self, exact: bool) -> fem.Form | None:
        """The compiled form of the size term's matrix (None without a size target, or
        where the lean model's kernel adds it, :attr:`size_kernel`)."""
        size = self.problem.size
        if size is None or self.size_kernel is not None:
            return None
        return fem.form(size.hessian_ufl(self.problem.q, exact))

    def _assemble_size(self) -> None:
        """The size term's matrix at the current q, in x (W⁻¹ G_M W⁻¹)."""
        if self.size_matrix is None:
            return
        self.size_matrix.zeroEntries()
        dolfinx.fem.petsc.assemble_matrix(self.size_matrix, self.size_form)
        self.size_matrix.assemble()
        self.size_matrix.diagonalScale(self.unscale, self.unscale)

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
        # the lean model's kernels add the size term's matrix (2D frames): one matrix
        size = problem.size
        self.size_kernel = None
        if self.lean and size is not None and problem.algebra.dim == 2:
            self.size_kernel = kernels.SizeKernel(
                size.log_h, size.coefficient, size.inverse_area,
                fem.Constant(mesh, PETSc.ScalarType(kernels.SIZE_GAUSS_NEWTON)),
                size.smoothing)
        self.form = self._model_form(self.exact)
        self.size_form = self._size_form(self.exact)
        if self.size_form is not None:
            self.size_matrix = dolfinx.fem.petsc.create_matrix(self.size_form)
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
        """The pre-matrix at the current q.

        Args:
            result: the pre-matrix of an earlier assembly, refilled; None: a new one.
            gnorm: |g|, which sets the damping (None: its largest value).
            evaluation: H and ∂H/∂x at q, which decide the active aspect bounds and give
                the curvature terms.

        Returns:
            The 5N × 5N pre-matrix (None for the lean model).
        """
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
        self._assemble_size()
        if not self.lean:  # the lean model assembles Tᵀ G T in _build_reduced instead
            G.zeroEntries()
            dolfinx.fem.petsc.assemble_matrix(G, self.form)
            G.assemble()
            G.diagonalScale(self.unscale, self.unscale)
            if self.size_matrix is not None:
                G.axpy(1.0, self.size_matrix,
                       structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
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
            # Curvature of the sphere |x| = ρ: −(x·∇J)/ρ² on its tangent space, x·∇H = 4H
            # (x·∇M = 0: the size misfit is homogeneous of degree 0; the smoothing term
            # C S is quadratic, x·∇(C S) = 2 C S: Evaluation.radial).
            self.sphere = manifold.sphere_curvature(evaluation.radial)
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
        T R⁻¹ Tᵀ + (I − T Tᵀ)/(μ − σ + s): :class:`~.reduced_pc.ReducedFactorPC` applies it with one
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
            if self.size_matrix is not None:  # Tᵀ G_M T: the kernel knows H alone
                self.reduced_size = _ptap(self.size_matrix, self.basis_matrix,
                                          self.reduced_size)
                R.axpy(1.0, self.reduced_size,
                       structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
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
        switched to the exact Hessian.

        Args:
            adaptation: the damping factor a.
            gnorm0: the reference gradient |g₀| of the damping.
            active: the active set of the last assembly (None: none yet).
            step: the last step length.
            exact: whether the model was the exact Hessian there.
            released: the releases left to the next step.
        """
        self.adaptation, self.gnorm0 = adaptation, gnorm0
        self.active = None if active is None else np.asarray(active, dtype=bool).copy()
        self.released = None if released is None else np.asarray(released, dtype=bool).copy()
        self._resumed_step = step
        if exact and self.switch is not None and not self.exact:
            self.switched = True
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
            self.switched = True
            self._use_exact()

    def _use_exact(self) -> None:
        self.exact, self.form = True, self._model_form(True)
        self.size_form = self._size_form(True)

    def _use_gauss_newton(self) -> None:
        self.exact, self.form = False, self._model_form(False)
        self.size_form = self._size_form(False)

    @property
    def safeguarded(self) -> bool:
        """Whether an exact step of this hybrid model that the factorisation finds
        indefinite is taken with Gauss–Newton instead (:meth:`gauss_newton_step`): with a
        size target, where the model switched to the exact Hessian."""
        return self.safeguard and self.problem.size is not None and self.switched

    def inertia_shift(self, tries: int) -> float:
        """The shift δ_j the ``tries``-th refactorisation (j = ``tries`` ≥ 0) of an
        indefinite exact step adds to the model (TAO's shift ``shift_value``: the operator
        and R alike), on top of the δ_0 … δ_{j−1} added before: δ_0 + … + δ_j =
        :data:`INERTIA_FLOOR` μ :data:`INERTIA_GROWTH`^j, μ the mean diagonal of Tᵀ G T
        (the inertia correction of interior-point methods, e.g. IPOPT's, with no memory
        between steps, so that a resumed solve takes the same shifts).

        The exact Hessian of the sized energy J = H + w H_s M is indefinite on many steps
        after the switch (the misfit's residual ∇σ is not small at the minimum): each such
        step was redone with Gauss–Newton (:meth:`gauss_newton_step`), which crawled
        along directions of negative curvature with whole steps that each lowered J by
        ~1e-3 of it (the sized piano at 1 887 triangles: 12 such steps in a row). Where
        one of the shifts 1e-4 μ … 5e-2 μ makes the factorisation positive definite, the
        step keeps those directions as long ones (there: 14 steps instead of 25, no
        fallback; benchmarks/README, "Inertia correction of the exact steps"). Where none
        does, the shift is taken off and the step falls back to Gauss–Newton.
        """
        total = INERTIA_FLOOR * self.mu * INERTIA_GROWTH**tries
        return total if tries == 0 else total - total / INERTIA_GROWTH

    def gauss_newton_step(self) -> bool:
        """Reassemble the model of the current step as Gauss–Newton (the hybrid model's
        safeguard, called by :class:`~.reduced_pc.ReducedFactorPC` when the factorisation
        of the exact model has negative pivots); the next Newton step is exact again.
        TAO's shift, the active set and the damping are kept.

        With a size target the exact Hessian of J = H + w H_s M is indefinite along much
        of the solve after the switch (M's residual ∇σ is not small at the minimum, and
        its curvature terms have either sign): each such step ended in
        ``DIVERGED_INDEFINITE_PC`` and a gradient step of length 1e-4–1e-3 that left J
        where it was (benchmarks/README, "Where the sized problem's Newton steps go").

        Returns:
            Whether the model changed (False: it was Gauss–Newton already).
        """
        if not self.exact:
            return False
        shift = self.shift_value
        self._use_gauss_newton()
        self._assemble(self.assembled, gnorm=self._gnorm, evaluation=self.problem.evaluation())
        self.shift_value = shift  # reduced_operator() adds it to R again
        self.fallbacks += 1
        return True

    def update(self, tao, x, H, P):
        """TAO Hessian callback at x (TAO has just evaluated the gradient there): adapts the
        damping, decides the active set, switches model where due and assembles.

        Args:
            tao: the TAO.
            x: the iterate.
            H: the Hessian TAO was given (the shell).
            P: its pre-matrix.
        """
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
        if self.switched and not self.exact:  # the last step fell back (gauss_newton_step)
            self._use_exact()
        self._gnorm = gnorm
        self.assemble(gnorm=gnorm)
        if self.consistent:
            self._consistent_active_set(tao.getKSP(), H, P, g)

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
                                             algebra=problem.algebra, size=self.size_kernel)
            self.product_form = (self.exact, form)
        self.direction.x.petsc_vec.pointwiseMult(v, self.unscale)  # d = W⁻¹ v
        self.direction.x.scatter_forward()
        b = self.product_vector
        with b.localForm() as local:
            local.set(0.0)
        dolfinx.fem.petsc.assemble_vector(b, self.product_form[1])
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        y.pointwiseMult(b, self.unscale)  # y = W⁻¹ G_q W⁻¹ v
        if self.size_matrix is not None:  # + W⁻¹ G_M W⁻¹ v, the size term's
            if self.size_product is None:
                self.size_product = y.duplicate()
            self.size_matrix.mult(v, self.size_product)
            y.axpy(1.0, self.size_product)

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
        """MatShell product: y = B v + shift·v (exceptions go to :attr:`on_error` first).

        Args:
            mat: the shell.
            v: the vector multiplied.
            y: the result.
        """
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


