"""What a solve of :func:`ufl_frames.solvers.tao.solve` hands back: its outcome
(:class:`SolveResult`) and, at each accepted iterate, the state it can go on from
(:class:`SolverState`)."""

from dataclasses import dataclass, field

import numpy as np

__all__ = ["SolveResult", "SolverState"]


@dataclass
class SolveResult:
    """Outcome of :func:`~ufl_frames.solvers.tao.solve`.

    ``history`` has one entry per TAO monitor call that found a new iterate: the
    initial state, then one per accepted step (rejected trust-region steps, which
    ``ntr`` reports too, are left out). ``iterations`` counts those steps; it can
    exceed TAO's own count by one (``nls`` and ``bncg`` take a first step that TAO
    numbers 0 again). With a Newton model (``nls``, ``ntr``, ...) each entry also has
    ``ksp_its``: the Krylov iterations spent since the previous entry, and
    ``factorisations``: how many faces of the aspect bound the Newton step that led there
    set up its preconditioner for (more than one: the rounds of
    ``-frames_active_consistent``, see ``ActiveSetRules._consistent_active_set``).
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

    @property
    def krylov_iterations(self) -> list[int] | None:
        """Krylov iterations per accepted step (None without a Newton model)."""
        if not self.history or "ksp_its" not in self.history[0]:
            return None
        return [entry["ksp_its"] for entry in self.history[1:]]


@dataclass
class SolverState:
    """A solve at an accepted iterate: what :func:`~ufl_frames.solvers.tao.solve` needs
    (``resume``) to go on from there as the solve that made it would have. Arrays are
    this rank's local rows.

    ``rows``: the iterate q (owned rows, (n, 5)); ``history`` as in :class:`SolveResult`
    so far; ``tao_iterations``: TAO's own count there; ``tao_gnorm0``: the gradient norm
    TAO's relative test (``-tao_gttol``) divides by; with a Newton model, its damping
    state (``adaptation``, ``model_gnorm0``), the last step length (``step``), the
    aspect bound's active set of the last Newton step (``active``) and the rows it held
    there (``held``; None: none; ``held_only``: they were the whole active set, see
    :attr:`~ufl_frames.fem.problem.FrameProblem.held_only`), the releases it left to the
    next step (``released``, see
    :attr:`~ufl_frames.solvers.hessian.GaussNewtonModel.released`), owned and ghost rows,
    and whether the model was the exact Hessian there (``exact_hessian``: the hybrid model
    may have switched).
    """

    rows: np.ndarray = field(repr=False)
    history: list[dict]
    tao_iterations: int
    tao_gnorm0: float
    wall_time_s: float
    step: float = 0.0
    adaptation: float | None = None
    model_gnorm0: float | None = None
    active: np.ndarray | None = field(default=None, repr=False)
    held: np.ndarray | None = field(default=None, repr=False)
    held_only: bool = False
    released: np.ndarray | None = field(default=None, repr=False)
    exact_hessian: bool | None = None

    @property
    def iterations(self) -> int:
        """Accepted steps so far (as :attr:`SolveResult.iterations`)."""
        return len(self.history) - 1
