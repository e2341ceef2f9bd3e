"""The hybrid Newton model with a size target (the sized energy J = H + w H_s M): the
earlier switch (``SIZED_SWITCH``) and the safeguard of an exact step whose factorisation
is indefinite: refactorised with a shift (``GaussNewtonModel.inertia_shift``), then taken
with Gauss–Newton (``GaussNewtonModel.gauss_newton_step``).

Serial and under MPI (``mpirun -n 2 python -m pytest -m "not serial"``).
"""

import numpy as np
import pytest
from mpi4py import MPI
from petsc4py import PETSc

from ufl_frames.bootstrap import options_scope
from ufl_frames.mesh import build
from ufl_frames.mesh.sizes import SizeTarget
from ufl_frames.pipeline import FrameField
from ufl_frames.solvers.hessian import GaussNewtonModel
from ufl_frames.solvers.reduced_pc import ReducedFactorPC

COMM = MPI.COMM_WORLD
#: The sized piano at this size (1 887 triangles) takes 38 Newton steps with the unsized
#: problem's switch and no safeguard, three of them gradient steps after
#: DIVERGED_INDEFINITE_PC (measured).
MESH_SIZE = 0.05


#: The safeguard's tests run without the smoothing term (the default's: its constant
#: positive matrix leaves few exact steps indefinite on this piano, none to test on).
UNSMOOTHED = {"frames_size_smoothing": 0}


def sized_solve(options=None, record=None):
    """The sized non-isotropic piano (uniform target) from MBO, without the smoothing
    term, ``options`` on top."""
    field = FrameField.initial(build(COMM, "piano", mesh_size=MESH_SIZE),
                               size=SizeTarget.uniform())
    with options_scope(list({**UNSMOOTHED, **(options or {})}.items())):
        return field.solve(max_it=500, monitor=record)


def test_negative_pivots_count_the_negative_eigenvalues():
    """MUMPS' inertia as :meth:`ReducedFactorPC.negative_pivots` reads it: the number of
    negative eigenvalues of a symmetric tridiagonal matrix (numpy's), on every rank."""
    n = 40
    rng = np.random.default_rng(3)
    diagonal = rng.uniform(-2.0, 3.0, n)
    off = rng.uniform(-0.5, 0.5, n - 1)
    dense = np.diag(diagonal) + np.diag(off, 1) + np.diag(off, -1)
    expected = int(np.count_nonzero(np.linalg.eigvalsh(dense) < 0))
    assert 0 < expected < n
    A = PETSc.Mat().createAIJ((n, n), nnz=3, comm=COMM)
    first, last = A.getOwnershipRange()
    for i in range(first, last):
        for j in range(max(i - 1, 0), min(i + 2, n)):
            A.setValue(i, j, dense[i, j])
    A.assemble()
    context = ReducedFactorPC()
    context.ksp = PETSc.KSP().create(COMM)
    try:
        context.ksp.setType(PETSc.KSP.Type.PREONLY)
        pc = context.ksp.getPC()
        pc.setType(PETSc.PC.Type.CHOLESKY)
        pc.setFactorSolverType("mumps")
        context.ksp.setOperators(A)
        context.ksp.setUp()
        assert context.negative_pivots() == expected
        A.shift(float(-np.linalg.eigvalsh(dense).min()) + 1.0)  # positive definite
        context.ksp.setOperators(A)
        context.ksp.setUp()
        assert context.negative_pivots() == 0
    finally:
        context.ksp.destroy()
        A.destroy()


def test_safeguard_takes_the_indefinite_exact_steps_with_gauss_newton(monkeypatch):
    """With the safeguard every Newton step after the first solves its system (Krylov
    iterations > 0: no gradient step after DIVERGED_INDEFINITE_PC), some exact steps
    fall back to Gauss–Newton, and the solve ends at the minimum the unsafeguarded
    model with the unsized switch reaches, in fewer than 0.8 of its steps."""
    fallbacks = []
    update = GaussNewtonModel.update

    def recording(self, tao, x, H, P):
        update(self, tao, x, H, P)
        fallbacks.append(self.fallbacks)

    monkeypatch.setattr(GaussNewtonModel, "update", recording)
    guarded = sized_solve({"frames_hessian_inertia_shifts": 0})
    monkeypatch.undo()
    plain = sized_solve({"frames_hessian_safeguard": "false",
                         "frames_hessian_switch": 1e-3})
    for result in (guarded, plain):
        assert result.converged_reason.startswith("CONVERGED"), result.converged_reason
    assert fallbacks and fallbacks[-1] > 0  # the safeguard acted
    assert all(e["ksp_its"] > 0 for e in guarded.history[2:]), \
        [e["ksp_its"] for e in guarded.history]
    # without it, some steps were gradient steps after an indefinite factorisation
    assert any(e["ksp_its"] == 0 for e in plain.history[2:])
    assert guarded.H_final == pytest.approx(plain.H_final, rel=1e-6)
    assert guarded.iterations < 0.8 * plain.iterations


def test_inertia_shifts_make_the_exact_steps_definite_and_the_solve_shorter():
    """With the inertia correction (the default) the indefinite exact steps are
    refactorised with R + δ I until MUMPS finds no negative pivot: none falls back to
    Gauss–Newton, each shifted step cost at most ``inertia_shifts`` refactorisations, and
    the solve ends at the minimum of the Gauss–Newton fallback alone (J to 1e-6, the
    same singularities) in fewer Newton steps."""
    shifted = FrameField.initial(build(COMM, "piano", mesh_size=MESH_SIZE),
                                 size=SizeTarget.uniform())
    plain = FrameField.initial(build(COMM, "piano", mesh_size=MESH_SIZE),
                               size=SizeTarget.uniform())
    with options_scope(list(UNSMOOTHED.items())):
        fast = shifted.solve(max_it=500)
    with options_scope([*UNSMOOTHED.items(), ("frames_hessian_inertia_shifts", 0)]):
        slow = plain.solve(max_it=500)
    for result in (fast, slow):
        assert result.converged_reason.startswith("CONVERGED"), result.converged_reason
    last = fast.history[-1]
    assert last["shifted"] > 0 and last["fallbacks"] == 0, last
    assert last["shifted"] <= last["shift_factorisations"] <= 4 * last["shifted"]
    assert slow.history[-1]["shifted"] == 0 and slow.history[-1]["fallbacks"] > 0
    assert fast.H_final == pytest.approx(slow.H_final, rel=1e-6)
    assert fast.iterations < slow.iterations
    assert [(s["index"], round(s["x"], 2), round(s["y"], 2)) for s in shifted.singularities] \
        == [(s["index"], round(s["x"], 2), round(s["y"], 2)) for s in plain.singularities]


def test_the_unsized_problem_never_falls_back(monkeypatch):
    """The safeguard acts with a size target only: the unsized solve's hybrid model
    keeps the exact Hessian from the switch on, whatever the factorisation says."""
    seen = []
    update = GaussNewtonModel.update

    def recording(self, tao, x, H, P):
        update(self, tao, x, H, P)
        seen.append((self.safeguarded, self.fallbacks))

    monkeypatch.setattr(GaussNewtonModel, "update", recording)
    field = FrameField.initial(build(COMM, "piano", mesh_size=0.1))
    field.solve(max_it=500)
    assert seen and not any(guarded or count for guarded, count in seen)


def test_modified_size_hessian_reaches_the_same_minimum_with_fewer_indefinite_steps():
    """``-frames_size_hessian modified`` (the misfit's second derivative made positive
    semidefinite, ``kernels.SIZE_MODIFIED``) ends at the exact model's minimum (both stop
    on J's relative change of 1e-4 a step, ``-frames_h_rtol``, or on the gradient, hence
    1e-3), and a smaller share of its exact factorisations is indefinite (the history's
    safeguard counts: checked ≥ shifted + fallen back), with the Gauss–Newton fallback
    alone (no inertia shifts) as the previous session measured it."""
    exact = sized_solve({"frames_hessian_inertia_shifts": 0})
    modified = sized_solve({"frames_size_hessian": "modified",
                            "frames_hessian_inertia_shifts": 0})
    for result in (exact, modified):
        assert result.converged_reason.startswith("CONVERGED"), result.converged_reason
        last = result.history[-1]
        assert 0 < last["exact_checks"]
        assert 0 <= last["fallbacks"] + last["shifted"] <= last["exact_checks"]
    assert modified.H_final == pytest.approx(exact.H_final, rel=1e-3)

    def share(result):
        return result.history[-1]["fallbacks"] / result.history[-1]["exact_checks"]

    assert share(modified) < share(exact)


def test_a_bad_size_hessian_is_one_clear_line():
    from ufl_frames.petsc_options import petsc_option_problem

    assert petsc_option_problem({"frames_size_hessian": "modified"}) is None
    problem = petsc_option_problem({"frames_size_hessian": "clipped"})
    assert problem == ("-frames_size_hessian must be one of exact, modified, gauss_newton, "
                       "got 'clipped'")
    assert petsc_option_problem({"frames_hessian_inertia_shifts": 0}) is None
    assert "an integer >= 0" in petsc_option_problem({"frames_hessian_inertia_shifts": -1})
