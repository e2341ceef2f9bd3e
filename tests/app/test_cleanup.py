r"""No PETSc object outlives a failed :func:`solvers.solve` or :func:`mbo.mbo_frame_field`.

Both own PETSc objects (the TAO, its vectors and the Gauss–Newton model; the MBO matrix,
right-hand side and KSP) and destroy them however they end, in the same order on every
rank (the destroys are collective). Checked on the annulus at h = 0.2, by two counts:

* :func:`live_petsc_objects`: the petsc4py objects of the process with a live handle,
  after ``gc.collect()`` and ``PETSc.garbage_cleanup()`` (petsc4py puts an object whose
  last Python reference goes on a parallel communicator in a garbage list that this
  destroys collectively). Equal before and after a failed call, once the exception is
  dropped. Before the fix, a monitor raising in an ``nls`` solve left 7 Mat and 3 Vec
  alive for good: the model's shell holds the model as its Python context and the model
  holds the shell, a cycle through PETSc that Python's collector does not see;
* :func:`alive_in_traceback`: while the caller still holds the exception, no PETSc
  object among the variables of the traceback's frames is alive: the call destroyed them
  before the exception reached the caller, not the garbage collector some time later.
  Before the fix: ``x``, ``g``, ``tao`` of ``solvers._solve`` and ``A``, ``rhs``, ``ksp``
  of ``mbo_frame_field``.

Each failure is followed by a normal call in the same process, which must give the same
result as one before the failure. The exceptions raised in callbacks are the caller's
own (type and message), not the ``PETSc.Error`` (code 101) that petsc4py raises when a
callback fails inside ``TaoSolve``.

Options are set under prefixes of this file only (``cleanup_``), with
:func:`bootstrap.petsc_defaults`, which removes them again. All tests run under
``mpirun -n 2`` too: every rank raises at the same point, as a collective error does.
"""

import gc
from collections import Counter

import dolfinx.fem.petsc
import numpy as np
import pytest
from mpi4py import MPI
from petsc4py import PETSc

from ufl_frames import solvers
from ufl_frames.bootstrap import petsc_defaults
from ufl_frames.fem import energy
from ufl_frames.mesh import annulus
from ufl_frames.solvers import mbo

COMM = MPI.COMM_WORLD
MAX_IT = 5


class MonitorError(Exception):
    """What the test monitors raise."""


def live_petsc_objects() -> Counter:
    """petsc4py objects of this process with a non-null handle, by type, after collection.

    Collective (``PETSc.garbage_cleanup``). Twice: destroying a TAO releases its Python
    callbacks, and whatever they held.
    """
    for _ in range(2):
        gc.collect()
        PETSc.garbage_cleanup(COMM)
    return Counter(type(obj).__name__ for obj in gc.get_objects()
                   if isinstance(obj, PETSc.Object) and obj.handle)


def difference(before: Counter, after: Counter) -> dict:
    """Per type, live objects after minus before (nonzero entries only)."""
    return {name: after[name] - before[name] for name in before.keys() | after.keys()
            if after[name] != before[name]}


def assert_no_leak(before: Counter) -> None:
    """No rank has more (or fewer) live PETSc objects than ``before``; same verdict on all."""
    leaks = COMM.allgather(difference(before, live_petsc_objects()))
    assert not any(leaks), f"live PETSc objects changed, per rank: {leaks}"


def alive_in_traceback(tb) -> list[str]:
    """``function:variable`` of the PETSc objects with a live handle among the variables of
    the frames of ``tb`` (the traceback of an exception the caller still holds)."""
    alive = []
    while tb is not None:
        frame = tb.tb_frame
        alive += [f"{frame.f_code.co_name}:{name}" for name, value in frame.f_locals.items()
                  if isinstance(value, PETSc.Object) and value.handle]
        tb = tb.tb_next
    return alive


def assert_none_alive_in(excinfo) -> None:
    """Nothing alive in the frames of the call that raised (the test's own frame, the first
    of the traceback, is left out: it is running, and reading its variables in Python 3.12
    keeps a copy of them, the exception included, for as long as it runs)."""
    alive = COMM.allgather(alive_in_traceback(excinfo.tb.tb_next))
    assert not any(alive), f"alive while the exception is held, per rank: {alive}"


@pytest.fixture(scope="module")
def mbo_field():
    """(V, MBO field values) on the annulus at h = 0.2, on COMM_WORLD."""
    V = energy.frame_space(annulus(COMM, 0.2).mesh)
    q = mbo.mbo_frame_field(V, options_prefix="cleanup_mbo_")
    return V, q.x.array.copy()


def fresh_problem(mbo_field):
    """A new FrameProblem from the MBO field (non-isotropic, Gauss–Newton Hessian)."""
    V, start = mbo_field
    q = dolfinx.fem.Function(V, name="q")
    q.x.array[:] = start
    return solvers.frame_problem(q, max_aspect=4.0)


@pytest.mark.parametrize("tao_type", ["nls", "bncg"])
def test_monitor_error_reaches_caller_and_leaks_nothing(mbo_field, tao_type):
    """A monitor raising at iteration 2: the caller gets that exception, nothing stays
    alive, and the next solve in the process equals one made before the failure."""
    prefix = f"cleanup_{tao_type}_"
    defaults = {"tao_type": tao_type}
    with petsc_defaults(prefix, defaults):
        reference_problem = fresh_problem(mbo_field)
        reference = solvers.solve(reference_problem, max_it=MAX_IT, options_prefix=prefix)
        reference_q = reference_problem.q.x.array.copy()
        assert reference.iterations >= 3  # the monitor below does get to iteration 2
        del reference_problem

        problem = fresh_problem(mbo_field)
        before = live_petsc_objects()
        seen = []

        def monitor(entry):
            seen.append(entry["it"])
            if entry["it"] == 2:
                raise MonitorError("stop at iteration 2")

        with pytest.raises(MonitorError) as excinfo:
            solvers.solve(problem, max_it=MAX_IT, options_prefix=prefix, monitor=monitor)
        assert excinfo.type is MonitorError
        assert str(excinfo.value) == "stop at iteration 2"
        assert seen == [0, 1, 2]
        assert_none_alive_in(excinfo)
        del excinfo
        assert_no_leak(before)

        problem = fresh_problem(mbo_field)
        again = solvers.solve(problem, max_it=MAX_IT, options_prefix=prefix)
    assert again.converged_reason == reference.converged_reason
    assert again.iterations == reference.iterations
    assert [e["H"] for e in again.history] == pytest.approx(
        [e["H"] for e in reference.history], rel=1e-12)
    assert np.allclose(problem.q.x.array, reference_q, rtol=0.0, atol=1e-12)
    del problem
    assert_no_leak(before)


def test_bad_hessian_option_leaks_nothing(mbo_field):
    """``-frames_hessian`` rejected (ValueError): nothing created stays alive."""
    prefix = "cleanup_hessian_"
    problem = fresh_problem(mbo_field)
    before = live_petsc_objects()
    with petsc_defaults(prefix, {"frames_hessian": "newton"}):
        with pytest.raises(ValueError, match="-frames_hessian must be") as excinfo:
            solvers.solve(problem, max_it=MAX_IT, options_prefix=prefix)
    assert_none_alive_in(excinfo)
    del excinfo
    assert_no_leak(before)


def test_model_construction_error_leaks_nothing(mbo_field, monkeypatch):
    """The Gauss–Newton model fails part way through its construction (after x, g and its
    first matrix and vector exist): the caller gets that error, nothing stays alive."""
    problem = fresh_problem(mbo_field)

    def failing(*args, **kwargs):
        # the constructor's first assembly, into the model's matrix (made just before)
        raise MonitorError("no Gauss-Newton matrix")

    before = live_petsc_objects()
    monkeypatch.setattr(dolfinx.fem.petsc, "assemble_matrix", failing)
    with pytest.raises(MonitorError, match="no Gauss-Newton matrix") as excinfo:
        solvers.solve(problem, max_it=MAX_IT, options_prefix="cleanup_model_")
    monkeypatch.undo()
    assert_none_alive_in(excinfo)
    del excinfo
    assert_no_leak(before)


@pytest.mark.parametrize("failure", ["ksp", "monitor"])
def test_mbo_error_leaks_nothing(mbo_field, failure):
    """MBO's KSP fails (one CG iteration, no preconditioner: DIVERGED_ITS), or its monitor
    raises: that error reaches the caller, nothing stays alive, the next MBO run is normal."""
    V, reference = mbo_field
    prefix = "cleanup_mbo_fail_"
    before = live_petsc_objects()
    if failure == "ksp":
        options = {"ksp_type": "cg", "pc_type": "none", "ksp_max_it": 1, "ksp_rtol": 1e-14}
        expected, match = RuntimeError, r"MBO diffusion solve failed \(KSP reason -3\)"
        monitor = None
    else:
        options = {}
        expected, match = MonitorError, "level 1"

        def monitor(level, tau, change):
            if level == 1:
                raise MonitorError("level 1")

    with petsc_defaults(prefix, options):
        with pytest.raises(expected, match=match) as excinfo:
            mbo.mbo_frame_field(V, options_prefix=prefix, monitor=monitor)
    assert excinfo.type is expected
    assert_none_alive_in(excinfo)
    del excinfo
    assert_no_leak(before)

    q = mbo.mbo_frame_field(V, options_prefix="cleanup_mbo_")
    # Two complete runs agree bit for bit; after a run stopped by its monitor the next one
    # agrees to ~1e-14 since MBO diffuses on the scalar space (cause not found: GAMG's
    # set-up state, presumably). The test is about a normal next run, not bitwise equality.
    assert np.allclose(q.x.array, reference, rtol=0, atol=1e-12)
    del q
    assert_no_leak(before)


def test_an_exception_in_the_newton_shell_reaches_the_caller(annulus_mesh):
    """A Python exception in the Newton model's product (a KeyboardInterrupt, say) is
    kept and raised after TAO stops, not turned into PETSc error 101 and a crash."""
    mesh = annulus_mesh(0.2)
    mesh = getattr(mesh, "mesh", mesh)
    q = mbo.mbo_frame_field(energy.frame_space(mesh), options_prefix="shellerr_mbo_")
    problem = solvers.frame_problem(q, isotropic=False)
    calls = []
    original = solvers.GaussNewtonModel._mult

    def failing(self, v, y):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt("stop")
        return original(self, v, y)

    solvers.GaussNewtonModel._mult = failing
    try:
        with pytest.raises(KeyboardInterrupt, match="stop"):
            solvers.solve(problem, max_it=5, options_prefix="shellerr_")
    finally:
        solvers.GaussNewtonModel._mult = original
    result = solvers.solve(problem, max_it=2, options_prefix="shellerr_after_")
    assert result.converged_reason == "DIVERGED_MAXITS"  # the next solve runs normally
    assert len(calls) >= 3 and np.isfinite(result.H_final)
