"""Solvers for frame fields: the MBO initial field (:mod:`~ufl_frames.solvers.mbo`), and
the minimisation of the integrability energy on 𝓜 with PETSc TAO
(:mod:`~ufl_frames.solvers.tao`). Its Newton types get the model of
:mod:`~ufl_frames.solvers.hessian`, with the aspect bound's active set of
:mod:`~ufl_frames.solvers.active_set` and the preconditioner of
:mod:`~ufl_frames.solvers.reduced_pc`.

The names most used are here: ``solvers.frame_problem(q)``, ``solvers.solve(problem)``.
"""

from ufl_frames.fem.problem import Evaluation, FrameProblem, frame_problem
from ufl_frames.solvers.hessian import GaussNewtonModel
from ufl_frames.solvers.results import SolveResult, SolverState
from ufl_frames.solvers.tao import (
    DEFAULT_OPTIONS,
    ENERGY_RTOL,
    SECOND_ORDER_TYPES,
    SUPPORTED_TYPES,
    TYPE_OPTIONS,
    converged_reason_name,
    solve,
)

__all__ = [
    "DEFAULT_OPTIONS",
    "ENERGY_RTOL",
    "SECOND_ORDER_TYPES",
    "SUPPORTED_TYPES",
    "TYPE_OPTIONS",
    "Evaluation",
    "FrameProblem",
    "GaussNewtonModel",
    "SolveResult",
    "SolverState",
    "converged_reason_name",
    "frame_problem",
    "solve",
]
