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
``-tao_gatol``, ``-tao_fmin``, ``-tao_max_it``); the Newton types also stop once the
decrease of H their last steps extrapolate to is below 1e-4 of H (``-frames_h_rtol``,
``CONVERGED_HRTOL``: far below the discretisation error of H), and the finest level of
nested iteration once it is below 1e-3 of what the refinement from the coarser level
bought (``-frames_nested_rtol``). The defaults of
``-tao_gatol`` and ``-tao_fmin`` are
relative to the natural scales of H, not absolute (:attr:`FrameProblem.energy_scale`):
a field that is already integrable, or already stationary, stops at iteration 0
(``CONVERGED_MINF`` / ``CONVERGED_GATOL``) instead of running ``max_it`` Newton steps
on round-off. TAO types:

* ``nls`` (default), ``ntr``, ``bnls``, ``bntr``: Newton line search / trust region on
  the model of :class:`GaussNewtonModel` — the exact Riemannian Hessian for isotropic
  frames; for non-isotropic ones Gauss–Newton, then the exact Hessian once the gradient
  is below τ = 1e-3 of its start (``-frames_hessian hybrid|exact|gauss_newton``,
  ``-frames_hessian_switch τ``; with a size target τ = 3e-2, and an exact step whose
  factorisation is indefinite refactorised with a small shift, up to
  ``-frames_hessian_inertia_shifts k`` times (default 4), and then taken with
  Gauss–Newton, ``-frames_hessian_safeguard``);
  the Newton systems
  are solved by TAO's KSP (``-tao_nls_ksp_type``, ``-tao_nls_pc_type``: by default a
  sparse Cholesky factorisation in reduced tangent coordinates, 3 unknowns per vertex,
  see :func:`newton_pc_options`); the Gauss–Newton
  damping adapts to the line search (``-frames_gn_adapt``) and the aspect bound's active
  set is decided with the Newton step itself (``nls``: ``-frames_active_consistent``, on
  by default, with at most ``-frames_active_rounds r`` refactorisations a step, default
  1), otherwise held until releasing it pays
  (``-frames_active_release η``, 0 to turn off);
  with the aspect bound, ``nls`` backtracks (``-tao_ls_type armijo``, see
  :data:`BOUNDED_OPTIONS`);
* ``lmvm``: L-BFGS, in the lumped-L² metric of the scaled unknowns;
* ``bncg`` with ``-tao_bncg_type gd`` (set by default for ``bncg``) and an Armijo line
  search: the note's projected gradient descent. Every option can be given on the command line,
under ``options_prefix`` (default none): defaults below are set only where the user
gave no value, and ``setFromOptions`` comes last.
"""

import time
from contextlib import ExitStack

from ufl_frames.bootstrap import init_petsc, options_scope, petsc_defaults

init_petsc()

import dolfinx.fem.petsc  # noqa: E402, F401
from mpi4py import MPI  # noqa: E402
from petsc4py import PETSc  # noqa: E402

from ufl_frames.fem.problem import FrameProblem  # noqa: E402
from ufl_frames.petsc_options import HESSIANS, SIZE_HESSIANS, TAO_TYPES  # noqa: E402
from ufl_frames.solvers.active_set import CONSISTENT_ROUNDS, RELEASE_RATIO  # noqa: E402
from ufl_frames.solvers.hessian import (  # noqa: E402
    DEFAULT_DAMPING,
    HYBRID_SWITCH,
    INERTIA_SHIFTS,
    SIZED_SWITCH,
    GaussNewtonModel,
)
from ufl_frames.solvers.reduced_pc import ReducedFactorPC  # noqa: E402
from ufl_frames.solvers.results import SolveResult, SolverState  # noqa: E402

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

#: The stopping test on H of the Newton types (``-frames_h_rtol ε``; 0 turns it off): stop
#: once the decrease of H still to come, extrapolated from the last Newton steps
#: (:func:`remaining_decrease`), is below ε H. The discrete minimum's H is itself
#: discretisation error (on the non-isotropic piano H falls like h^1.7, by 2.5x per 2x
#: refinement), so an algebraic error of 1e-4 of it is far below what the mesh resolves;
#: the gradient test alone went on for another 16 of the finest level's 37 Newton steps at
#: 10⁵ triangles for the last 3e-4 of H, the gradient at 0.01–0.1 of the coarse start's
#: while the Gauss–Newton tail crept along the energy's nearly flat directions
#: (benchmarks/README, "Stopping at the discretisation's accuracy").
H_RTOL = 1e-4
#: The finest level of nested iteration also stops once the decrease still to come is
#: below θ (H_c − H), H_c the coarser level's minimum (``-frames_nested_rtol θ``; 0 turns
#: it off): H_c − H* (H* the finest level's minimum) is the decrease one refinement buys,
#: a measure of the discretisation error of H, and the algebraic error is left at θ of
#: it (H_c − H ≤ H_c − H*: the test is on the safe side). The finest level is where the
#: time is, and its tail moves along the energy's flat directions: on the non-isotropic
#: piano at 10⁵ triangles its H was 0.3 % above its end after 14 of 31 Newton steps (the
#: coarser level's H 185 % above), while the Dirichlet energy E still changed by 2.4 %.
#: Coarser levels are solved to :data:`H_RTOL`: where a level
#: ends decides the next one's start, and a cruder start cost more than it saved
#: (benchmarks/README, "The finest level stops at the discretisation's accuracy").
NESTED_RTOL = 1e-3
#: Newton steps per window of :func:`remaining_decrease`.
H_WINDOW = 3
#: The converged reason of that test (TAO's own is ``CONVERGED_USER``).
H_RTOL_REASON = "CONVERGED_HRTOL"


def remaining_decrease(energies, window: int = H_WINDOW) -> float:
    """A bound on the decrease of H still to come after the last of ``energies`` (H after
    each step, oldest first), from the last ``2 window`` steps: with d₁, d₂ the decreases
    over the two windows and r = d₂ / d₁ < 1 their contraction, the sequence extrapolated
    as a linearly converging one (Aitken) has d₂ r / (1 − r) left, and at least d₂ is
    taken (the last window's own decrease: a sudden drop of the rate, which Aitken reads
    as convergence, is not enough alone). ``inf`` where there is no such estimate: too few
    values, H rising, or r ≥ 1 (not contracting: a stall, the active set still moving);
    0 where neither window changed H.
    """
    if window < 1 or len(energies) < 2 * window + 1:
        return float("inf")
    first, middle, last = energies[-2 * window - 1], energies[-window - 1], energies[-1]
    older, newer = first - middle, middle - last
    if newer < 0 or older <= 0:
        return 0.0 if newer == 0 == older else float("inf")
    ratio = newer / older
    return float("inf") if ratio >= 1 else newer * max(1.0, ratio / (1 - ratio))


def _h_converged(history: list[dict], rtol: float, window: int = H_WINDOW,
                 coarse_energy: float | None = None, nested_rtol: float = 0.0) -> bool:
    """Whether the last ``2 window`` steps of ``history`` were all Newton steps (Krylov
    iterations > 0: not the gradient steps ``nls`` falls back to where the model is
    indefinite, whose tiny decreases say nothing of what is left) and the decrease they
    bound (:func:`remaining_decrease`) is at most ``rtol`` H, or at most ``nested_rtol``
    (H_c − H) where the coarser level's H_c = ``coarse_energy`` is given (see
    :data:`NESTED_RTOL`).

    Args:
        history: the solve's history (:attr:`SolveResult.history`).
        rtol: ε of the test relative to H (``-frames_h_rtol``).
        window: Newton steps per window.
        coarse_energy: the coarser level's H (None: no nested test).
        nested_rtol: θ of the nested test (``-frames_nested_rtol``).

    Returns:
        Whether the solve may stop.
    """
    steps = history[-2 * window:]
    energy = history[-1]["H"] if history else 0.0
    tolerance = rtol * energy
    if coarse_energy is not None:
        tolerance = max(tolerance, nested_rtol * (coarse_energy - energy))
    if tolerance <= 0 or len(history) < 2 * window + 1 \
            or any(e.get("ksp_its", 0) <= 0 for e in steps):
        return False
    energies = [e["H"] for e in history[-2 * window - 1:]]
    return remaining_decrease(energies, window) <= tolerance


#: Defaults that apply to one TAO type only (the Newton types' preconditioner: see
#: :func:`newton_pc_options`).
TYPE_OPTIONS = {
    "bncg": {"tao_bncg_type": "gd", "tao_ls_type": "armijo"},
}

#: Line search of ``nls`` where frames have an aspect bound: backtracking (Armijo) instead
#: of TAO's default Moré–Thuente search. The retraction bends the search path where it
#: clamps frames onto the bound; there Moré–Thuente's interpolation settled on steps of
#: 0.1-0.4 that a sufficient-decrease test takes whole (non-isotropic piano, h = 0.025:
#: 55 Newton steps instead of 72, same H). Elsewhere (isotropic frames, no bound) the
#: path is smooth and Moré–Thuente stays: its curvature test still makes progress at
#: gradients near round-off, where differences of H no longer can.
BOUNDED_OPTIONS = {
    "nls": {"tao_ls_type": "armijo"},
}

#: Options a resumed solve of a TAO type sets over the user's (only while its TAO is set
#: up). ``nls`` starts with an "interpolation" of its trust radius (``-tao_nls_init_type``):
#: up to five trial steps along -g, and the best of them taken as a first iterate where
#: it lowers J. At a solve's start that is its gradient step numbered 1 (Krylov count 0);
#: at a resumed iterate it is a step the interrupted solve never took, after which the
#: iterates part (the sized piano with the smoothing term, resumed at Newton step 4 of
#: 9: one step more, issue 39). ``nls`` solves its Newton systems with the KSP's radius
#: at its maximum whatever the trust radius, so "constant" changes nothing else. A state
#: of the start itself (iterate 0) resumes as the start did, with the interpolation.
RESUMED_OPTIONS = {
    "nls": {"tao_nls_init_type": "constant"},
}

#: Options prefix of the Newton KSP inside each Newton TAO type.
NEWTON_KSP_PREFIX = {"nls": "tao_nls_", "ntr": "tao_ntr_", "bnls": "tao_bnk_",
                     "bntr": "tao_bnk_"}


#: Dropping threshold of MUMPS's block low-rank factorisation of the reduced Newton matrix
#: (``-<newton prefix>reduced_mat_mumps_cntl_7``; ``..._icntl_35 0`` turns BLR off).
MUMPS_BLR_TOLERANCE = 1e-8


def newton_pc_options(tao_type: str, comm, reduced: bool = True) -> dict:
    """The default preconditioner of the Newton systems of ``tao_type``: the sparse
    Cholesky factorisation of the model's assembled part in reduced tangent coordinates
    (:class:`~ufl_frames.solvers.reduced_pc.ReducedFactorPC`: 3 unknowns per vertex instead
    of 5); with ``reduced=False``, of the 5N × 5N pre-matrix itself (MUMPS where PETSc has
    it, which runs in parallel; PETSc's own in serial; GAMG as the last resort).

    Why direct: the Gauss–Newton matrix JᵀJ has a large near-kernel (integrable fields are
    far from unique), which no smoother-based multigrid sees; with GAMG the Krylov
    iterations per Newton step grew 107 → 159 → 340 from h = 0.1 to 0.025 on the
    non-isotropic piano, with the factorisation they are 2 at every size
    (``benchmarks/scaling.py``).

    Args:
        tao_type: the TAO type (no options for types without a Newton KSP).
        comm: the communicator of the solve.
        reduced: the reduced PC (else a PC of the pre-matrix itself).

    Returns:
        The options, under the Newton KSP's prefix.
    """
    prefix = NEWTON_KSP_PREFIX.get(tao_type)
    if prefix is None:
        return {}
    if reduced:
        options = {f"{prefix}pc_type": "python",
                   f"{prefix}pc_python_type": "ufl_frames.solvers.reduced_pc.ReducedFactorPC"}
        if PETSc.Sys.hasExternalPackage("mumps"):
            # MUMPS's block low-rank factorisation at a 1e-8 threshold: the same steps
            # and Krylov counts, faster factorisations on large meshes (benchmarks/README)
            options[f"{prefix}reduced_mat_mumps_icntl_35"] = "1"
            options[f"{prefix}reduced_mat_mumps_cntl_7"] = str(MUMPS_BLR_TOLERANCE)
        return options
    if PETSc.Sys.hasExternalPackage("mumps"):
        return {f"{prefix}pc_type": "cholesky", f"{prefix}pc_factor_mat_solver_type": "mumps"}
    if comm.size == 1:
        return {f"{prefix}pc_type": "cholesky"}
    return {f"{prefix}pc_type": "gamg"}

_REASONS = {
    getattr(PETSc.TAO.ConvergedReason, name): name
    for name in dir(PETSc.TAO.ConvergedReason)
    if not name.startswith("_")
}


def converged_reason_name(reason: int) -> str:
    """TAO's converged reason as text (e.g. ``CONVERGED_GRTOL``)."""
    return _REASONS.get(reason, str(reason))


#: TAO types that run on this problem (checked by the CLI before anything is meshed).
SUPPORTED_TYPES = TAO_TYPES

#: TAO types that get the Gauss–Newton Hessian of :class:`GaussNewtonModel`.
SECOND_ORDER_TYPES = {"nls", "ntr", "ntl", "bnls", "bntr", "bntl", "tron"}


def solve(
    problem: FrameProblem,
    max_it: int | None = None,
    options_prefix: str = "",
    defaults: dict | None = None,
    monitor=None,
    checkpoint=None,
    resume: SolverState | None = None,
    reference_gradient: float | None = None,
    coarse_energy: float | None = None,
) -> SolveResult:
    """Minimise H over 𝓜 from ``problem.q`` with TAO; ``problem.q`` holds the result.

    ``max_it`` is a default for ``-tao_max_it`` (the command line wins). ``monitor``
    receives each history entry ``{"it", "H", "E", "gnorm", "step"}`` (on every rank).
    ``checkpoint`` receives, before ``monitor``, the :class:`SolverState` at each
    accepted iterate (collective: on every rank). ``resume`` goes on from such a state,
    made for the same ``problem`` (the same mesh, initial field and options): the
    history continues it, ``max_it`` counts from the original start, the relative
    gradient test keeps the original |g₀|, and the Newton model its damping and active
    set, so that the result is that of the solve that made the state (for ``nls`` and
    ``bncg`` bit for bit as measured, mostly): ``nls`` resumes without the trial gradient
    steps of its start (:data:`RESUMED_OPTIONS`). What TAO keeps inside starts afresh:
    the trust radius of ``ntr``, ``lmvm``'s L-BFGS memory.

    Two defaults are relative to the scales of ``problem`` (given values are absolute):

    * ``-tao_fmin`` = :data:`ENERGY_RTOL` · H_s: an integrable field (H = 0 up to the
      accuracy of the initial field) ends with ``CONVERGED_MINF``;
    * ``-tao_gatol`` = gttol · G: the gradient test is |g| ≤ gttol · max(|g₀|, G), so a
      start that is already stationary ends with ``CONVERGED_GATOL``. TAO's own gttol
      test compares with |g₀| only, which, at a stationary start, is round-off: its
      target (1e-6 of that) is out of reach and the solve ran to ``max_it``. G, not an
      absolute number, because the gradient norm depends on the domain's size.
      ``reference_gradient`` (a coarser level's |g₀| in nested iteration) raises G to it:
      a fine level that starts from a coarse solution stops at the accuracy the whole
      solve was asked for, not 1e-6 of its own, already small, |g₀| (the scaled unknowns
      make gradient norms comparable across meshes of one domain).

    Both are tested by TAO before the first step, for every TAO type (0 iterations).

    ``coarse_energy`` (the coarser level's H when this is the finest level of nested
    iteration) adds the test on H against the discretisation error: the Newton types
    also stop once the decrease of H still to come is below θ (``coarse_energy`` − H),
    θ = ``-frames_nested_rtol`` (default :data:`NESTED_RTOL`).

    Args:
        problem: the frame problem; ``problem.q`` is the start and holds the result.
        max_it: default of ``-tao_max_it``.
        options_prefix: prefix of the TAO's options.
        defaults: option defaults over this module's (the command line wins).
        monitor: called with each history entry.
        checkpoint: called with the :class:`SolverState` at each accepted iterate.
        resume: a state to go on from.
        reference_gradient: a coarser level's |g₀|, a floor of G.
        coarse_energy: the coarser level's H (finest level of nested iteration).

    Returns:
        The :class:`SolveResult`.
    """
    opts = PETSc.Options(options_prefix)
    tao_type = opts.getString("tao_type", (defaults or {}).get("tao_type",
                                                                 DEFAULT_OPTIONS["tao_type"]))
    bounded = BOUNDED_OPTIONS.get(tao_type, {}) if problem.constraints.max_aspect else {}
    options = {**DEFAULT_OPTIONS, **TYPE_OPTIONS.get(tao_type, {}), **bounded,
               **newton_pc_options(tao_type, problem.constraints.comm), **(defaults or {})}
    if max_it is not None:
        options["tao_max_it"] = max_it
    gttol = opts.getReal("tao_gttol", float(options["tao_gttol"]))
    scale = max(problem.gradient_scale, reference_gradient or 0.0)
    options.setdefault("tao_gatol", gttol * scale)
    options.setdefault("tao_fmin", ENERGY_RTOL * problem.energy_scale)
    with petsc_defaults(options_prefix, options):
        return _TaoSolve(problem, tao_type, options_prefix, monitor, checkpoint, resume,
                         coarse_energy).run()


def tao_callbacks(problem: FrameProblem):
    """TAO's objective, objective-and-gradient and update callbacks on 𝓜 for ``problem``.

    Each sets q = R(x) first (one retraction per iterate under
    :meth:`FrameProblem.tracking`); the objective is H(R(x)), the gradient the Riemannian
    one (steps 1–2), and the update hook, at the start of every iteration, writes the
    retracted iterate back into x, so every iterate lies on 𝓜.
    """

    def objective(tao, x):
        problem.set_from_x(x)
        return problem.energy()

    def objective_gradient(tao, x, g):
        problem.set_from_x(x)
        return problem.riemannian_gradient(g)

    def update(tao, it):
        problem.set_from_x(tao.getSolution())
        problem.write_x(tao.getSolution(), keep=True)

    return objective, objective_gradient, update


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


class _TaoSolve:
    """One TAO solve of :func:`solve` from ``problem.q``, with the options already in the
    database: TAO's callbacks and the state they share (the history, the Krylov count,
    the first exception), the Newton model, and the solve itself (:meth:`run`).

    Every PETSc object :meth:`run` makes (x, g, the model, the TAO) is destroyed on the
    way out, whether the solve returns or raises, in the same order on every rank
    (collective). An exception raised by a callback (``monitor`` included) reaches PETSc
    as an error that aborts ``TaoSolve``; petsc4py then raises a ``PETSc.Error`` (code 101)
    in its place, so the callbacks keep the first one and it is that exception the caller
    sees.

    Args:
        problem: the frame problem; ``problem.q`` is the start and holds the result.
        tao_type: the TAO type the options give.
        options_prefix: the prefix of the TAO's options.
        monitor: called with each history entry (None: none).
        checkpoint: called with the :class:`SolverState` at each accepted iterate.
        resume: the state to go on from (None: a new solve).
        coarse_energy: the coarser level's H (finest level of nested iteration).
    """

    def __init__(self, problem: FrameProblem, tao_type: str, options_prefix: str, monitor,
                 checkpoint=None, resume: SolverState | None = None,
                 coarse_energy: float | None = None):
        self.problem, self.tao_type, self.options_prefix = problem, tao_type, options_prefix
        self.monitor, self.checkpoint, self.resume = monitor, checkpoint, resume
        self.coarse_energy = coarse_energy
        self.comm = problem.constraints.comm
        self.hessian = None
        if tao_type in SECOND_ORDER_TYPES:
            opts = PETSc.Options(options_prefix)
            self.hessian = opts.getString("frames_hessian",
                                          "exact" if problem.constraints.isotropic
                                          else "hybrid")
            if self.hessian not in HESSIANS:
                raise ValueError(f"-frames_hessian must be one of {', '.join(HESSIANS)}, "
                                 f"got {self.hessian!r}")

        self.errors = []  # the first exception raised inside a callback, re-raised after TAO
        self.callbacks = tao_callbacks(problem)  # objective, objective_gradient, update

        self.history = [] if resume is None else [dict(entry) for entry in resume.history]
        # Krylov iterations so far, and at the last history entry
        self.linear_iterations = [0, 0]
        self.skip_first = resume is not None  # TAO's first report is the resumed iterate again
        self.earlier = 0.0 if resume is None else resume.wall_time_s

        self.tao_base = 0 if resume is None else resume.tao_iterations
        self.stopped_on_h = False  # whether the test on H (H_RTOL) ended the solve
        self.h_rtol = PETSc.Options(options_prefix).getReal("frames_h_rtol", H_RTOL)
        self.nested_rtol = PETSc.Options(options_prefix).getReal("frames_nested_rtol",
                                                                 NESTED_RTOL)
        self.gnorm0 = None  # what TAO's relative gradient test divides by
        self.model = None  # the Newton model (second-order types), made by run()
        self.start = None  # when TAO's solve started

    def keep(self, exc: BaseException) -> None:
        """Keep ``exc`` where it is the first exception of a callback."""
        if not self.errors:
            self.errors.append(exc)

    def guarded(self, callback):
        """``callback`` keeping the exceptions it raises (:meth:`keep`) before PETSc sees
        them."""
        def call(*args):
            try:
                return callback(*args)
            except BaseException as exc:
                self.keep(exc)
                raise

        return call

    def count_linear(self, ksp, it, rnorm):
        """KSP monitor: counts the Krylov iterations.

        Args:
            ksp: the Newton KSP.
            it: its iteration number (0: the start of a solve, not counted).
            rnorm: the residual norm.
        """
        if it > 0:
            self.linear_iterations[0] += 1

    def record(self, tao):
        """TAO monitor: a history entry for each new iterate, then ``checkpoint`` and
        ``monitor``, and the stopping test on H."""
        resume, model, history = self.resume, self.model, self.history
        _, f, gnorm, _, step, _ = tao.getSolutionStatus()
        if resume is None and tao.getIterationNumber() == 0:
            self.gnorm0 = float(gnorm)  # TAO's |g₀|: its last report numbered 0 (see SolveResult)
        if self.skip_first:
            self.skip_first = False
            return
        if history and (f, gnorm) == (history[-1]["H"], history[-1]["gnorm"]):
            return  # a rejected trust-region step (ntr monitors those too): x did not move
        if resume is not None and len(history) == len(resume.history) \
                and tao.getIterationNumber() == 0:
            # This TAO numbers its first step 0 again (bncg does, see SolveResult): it
            # would allow one step more than the iterations left.
            tao.setMaximumIterations(max(tao.getMaximumIterations() - 1, 0))
        problem = self.problem
        problem.set_from_x(tao.getSolution())
        entry = {"it": len(history), "H": float(f), "E": problem.dirichlet_energy(),
                 "gnorm": float(gnorm), "step": float(step)}
        if model is not None:  # Krylov iterations of the Newton step(s) that led here
            entry["ksp_its"] = self.linear_iterations[0] - self.linear_iterations[1]
            self.linear_iterations[1] = self.linear_iterations[0]
            # faces factorised for it: one, or one per round of the consistent rule
            entry["factorisations"] = max(len(model.bound_rounds), 1)
            # the safeguard's count so far: exact factorisations checked, and those found
            # indefinite and redone as Gauss–Newton
            entry["exact_checks"], entry["fallbacks"] = model.exact_checks, model.fallbacks
            # ... and those made definite by a shift (GaussNewtonModel.inertia_shift), with
            # the refactorisations that cost
            entry["shifted"] = model.shifted
            entry["shift_factorisations"] = model.shift_factorisations
        history.append(entry)
        if self.checkpoint is not None:
            self.checkpoint(self.snapshot(tao, float(step)))
        if self.monitor is not None:
            self.monitor(entry)
        if model is not None and gnorm > tao.getTolerances()[0] and _h_converged(
                history, self.h_rtol, coarse_energy=self.coarse_energy,
                nested_rtol=self.nested_rtol):
            # TAO tests its own criteria after the monitor and keeps a reason set here
            self.stopped_on_h = True
            tao.setConvergedReason(PETSc.TAO.ConvergedReason.CONVERGED_USER)

    def snapshot(self, tao, step) -> SolverState:
        """The :class:`SolverState` at TAO's current iterate (collective)."""
        problem, model = self.problem, self.model
        wall = self.comm.allreduce(time.perf_counter() - self.start, op=MPI.MAX)
        state = SolverState(
            rows=problem.rows[: problem.owned].copy(),
            history=[dict(e) for e in self.history],
            tao_iterations=self.tao_base + tao.getIterationNumber(),
            tao_gnorm0=self.tao_gnorm0(), wall_time_s=self.earlier + wall, step=step)
        if model is not None:
            state.adaptation, state.model_gnorm0 = model.adaptation, model.gnorm0
            state.exact_hessian = model.exact
            state.active = None if model.active is None else model.active.copy()
            state.held = None if problem.held is None else problem.held.copy()
            state.held_only = problem.held_only
            state.released = None if model.released is None else model.released.copy()
        return state

    def tao_gnorm0(self) -> float:
        """The |g₀| TAO's relative gradient test divides by (the original solve's)."""
        return self.resume.tao_gnorm0 if self.resume is not None else self.gnorm0

    def initial_iterate(self, owned: ExitStack) -> PETSc.Vec:
        """x at the start: R(q), or the resumed iterate as it is (owned by ``owned``)."""
        problem, resume = self.problem, self.resume
        x = dolfinx.fem.petsc.create_vector(problem.q.function_space)
        owned.callback(x.destroy)
        if resume is None:
            problem.retract()
        else:  # the iterate is on 𝓜 already: no retraction, which would move it by round-off
            problem.rows[: problem.owned] = resume.rows
            problem.q.x.scatter_forward()
            problem.held = None if resume.held is None else resume.held.copy()
            problem.held_only = resume.held_only and problem.held is not None
        problem.write_x(x, keep=True)
        return x

    def newton_model(self, owned: ExitStack, x: PETSc.Vec) -> GaussNewtonModel | None:
        """The Newton model of the second-order types from the options, resumed where
        the solve is (owned by ``owned``); None for the other types."""
        hessian, tao_type, resume = self.hessian, self.tao_type, self.resume
        if hessian is None:
            return None
        opts = PETSc.Options(self.options_prefix)
        prefix = NEWTON_KSP_PREFIX.get(tao_type)
        # nls and ntr with the reduced PC need no 5N pre-matrix (the bounded types
        # take sub-matrices of it: they keep it).
        lean = (tao_type in ("nls", "ntr")
                and opts.getString(f"{prefix}pc_type", "") == "python"
                and opts.getString(f"{prefix}pc_python_type", "").endswith(
                    "ReducedFactorPC"))
        # -frames_active_consistent (nls, the default): the active set is decided with
        # the Newton step (ActiveSetRules._consistent_active_set) instead of held and
        # released by the gradient; Newton steps that no longer grow with the mesh,
        # for more factorisations per step (benchmarks/README).
        consistent = tao_type == "nls" and opts.getBool("frames_active_consistent", True)
        model = owned.enter_context(GaussNewtonModel(
            self.problem, x, damping=opts.getReal("frames_gn_damping", DEFAULT_DAMPING),
            damping_min=opts.getReal("frames_gn_damping_min", 1e-3),
            adapt=opts.getBool("frames_gn_adapt", hessian != "exact"),
            release=opts.getReal("frames_active_release",
                                 0.0 if consistent else RELEASE_RATIO),
            consistent=consistent,
            rounds=opts.getInt("frames_active_rounds", CONSISTENT_ROUNDS),
            bound_steps=opts.getBool("frames_gn_adapt_bound", True),
            exact=hessian == "exact", lean=lean,
            switch=(opts.getReal("frames_hessian_switch", HYBRID_SWITCH
                                 if self.problem.size is None else SIZED_SWITCH)
                    if hessian == "hybrid" else None),
            safeguard=opts.getBool("frames_hessian_safeguard", True),
            inertia_shifts=opts.getInt("frames_hessian_inertia_shifts", INERTIA_SHIFTS),
            size_mode=SIZE_HESSIANS.get(opts.getString("frames_size_hessian", "exact"),
                                        SIZE_HESSIANS["exact"])))
        if resume is not None and resume.adaptation is not None:
            model.resume(resume.adaptation, resume.model_gnorm0, resume.active,
                         resume.step, exact=resume.exact_hessian,
                         released=resume.released)
        return model

    def create_tao(self, owned: ExitStack, x: PETSc.Vec, g: PETSc.Vec) -> PETSc.TAO:
        """The TAO with the guarded callbacks, its options set.

        Args:
            owned: the stack that destroys the TAO (and ends the PC's model scope).
            x: the iterate's vector.
            g: the gradient's vector.

        Returns:
            The TAO.
        """
        guarded, model = self.guarded, self.model
        objective, objective_gradient, update = self.callbacks
        tao = PETSc.TAO().create(self.comm)
        owned.callback(tao.destroy)
        tao.setOptionsPrefix(self.options_prefix)
        tao.setSolution(x)
        tao.setObjectiveGradient(guarded(objective_gradient), g)
        tao.setObjective(guarded(objective))  # line-search trials need no gradient
        if model is not None:
            pre = model.shell if model.lean else model.assembled
            tao.setHessian(guarded(model.update), model.shell, pre)
        tao.setUpdate(guarded(update))
        tao.setMonitor(guarded(self.record))
        resumed = {}
        if self.resume is not None and len(self.resume.history) > 1:  # past the start
            resumed = RESUMED_OPTIONS.get(self.tao_type, {})
        with options_scope([(self.options_prefix + k, v) for k, v in resumed.items()]):
            tao.setFromOptions()
        if model is not None:
            # The Newton KSP's ReducedFactorPC (the default PC), whenever PETSc makes it,
            # takes this model; any other PC acts on the model's pre-matrix as it is.
            owned.enter_context(ReducedFactorPC.solving(model,
                                                        tao.getKSP().getOptionsPrefix() or ""))
            tao.getKSP().setMonitor(guarded(self.count_linear))
            model.on_error = self.keep  # the shell's products, guarded too
        return tao

    def run(self) -> SolveResult:
        """Make x, g, the model and the TAO, solve, destroy them; the result."""
        problem, comm = self.problem, self.comm
        with ExitStack() as owned:  # destroys in reverse order of creation, on every exit
            owned.enter_context(problem.tracking())
            x = self.initial_iterate(owned)
            g = x.duplicate()
            owned.callback(g.destroy)
            # The model refers back to this runner (model.on_error): a cycle that only the
            # garbage collector would free, at a different time on every rank, and a PETSc
            # object freed then is a collective on one rank only (a hang). Dropped on the
            # way out, so it all goes when the solve ends, on every rank.
            owned.callback(setattr, self, "model", None)
            self.model = self.newton_model(owned, x)
            tao = self.create_tao(owned, x, g)
            original_tests = (_continue_tests(tao, self.resume) if self.resume is not None
                              else None)

            self.start = time.perf_counter()
            try:
                tao.solve()
            except PETSc.Error:
                if not self.errors:
                    raise
            if self.errors:  # outside the except clause: no PETSc.Error chained to it
                raise _released(self.errors.pop())
            wall = self.earlier + comm.allreduce(time.perf_counter() - self.start, op=MPI.MAX)
            problem.set_from_x(tao.getSolution())
            reason = converged_reason_name(tao.getConvergedReason())
            if self.stopped_on_h and reason == "CONVERGED_USER":
                reason = H_RTOL_REASON
            if original_tests is not None:
                reason = _original_reason(original_tests, reason, self.history[-1]["gnorm"])
        iterations = len(self.history) - 1  # TAO's own count restarts in some types (bncg)
        return SolveResult(history=self.history, converged_reason=reason,
                           iterations=iterations, wall_time_s=wall)


def _continue_tests(tao, resume: SolverState) -> tuple[float, float]:
    """TAO's stopping tests of the solve ``resume`` comes from, on a TAO that restarts
    there: the iterations left, and the relative gradient test |g| ≤ gttol |g₀| with the
    original |g₀| as the absolute test it is now (TAO would divide by the new start's).
    Returns the original (gatol, gttol)."""
    gatol, grtol, gttol = tao.getTolerances()
    original = (gatol, gttol)
    if gttol > 0 and resume.tao_gnorm0 > 0:
        gatol = max(gatol, gttol * resume.tao_gnorm0)
    tao.setTolerances(gatol=gatol, grtol=grtol, gttol=0.0)
    tao.setMaximumIterations(max(tao.getMaximumIterations() - resume.tao_iterations, 0))
    return original


def _original_reason(tests: tuple[float, float], reason: str, gnorm: float) -> str:
    """The reason the original tests give where :func:`_continue_tests` rewrote them: a
    gradient below the absolute tolerance only by the rewritten gttol test is GTTOL.

    Args:
        tests: the original (gatol, gttol) :func:`_continue_tests` returned.
        reason: TAO's reason, as text.
        gnorm: the last iterate's gradient norm.

    Returns:
        The reason, as text.
    """
    gatol, gttol = tests
    if reason == "CONVERGED_GATOL" and gnorm > gatol and gttol > 0:
        return "CONVERGED_GTTOL"
    return reason
