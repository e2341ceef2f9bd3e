"""The Newton systems in reduced tangent coordinates (:class:`ReducedFactorPC`, the
default preconditioner of the Newton TAO types) against the factorised 5N × 5N
pre-matrix they replace.

Serial and under MPI (``mpirun -n 2 python -m pytest -m "not serial"``).
"""

import numpy as np
import pytest
from mpi4py import MPI
from petsc4py import PETSc

from ufl_frames import solvers
from ufl_frames.bootstrap import options_scope
from ufl_frames.mesh import build
from ufl_frames.pipeline import FrameField
from ufl_frames.solvers.hessian import GaussNewtonModel
from ufl_frames.solvers.reduced_pc import ReducedFactorPC

COMM = MPI.COMM_WORLD


@pytest.fixture(scope="module")
def piano():
    return build(COMM, "piano", mesh_size=0.1)


def mbo_problem(domain, isotropic):
    """The frame problem of ``domain``'s MBO field and its iterate x (the caller destroys x)."""
    field = FrameField.initial(domain, isotropic=isotropic)
    problem = solvers.frame_problem(field.q, isotropic=isotropic,
                                    max_aspect=field.max_aspect,
                                    constraints=field.constraints)
    x = problem.q.x.petsc_vec.duplicate()
    problem.write_x(x)
    return problem, x


@pytest.mark.parametrize("isotropic", [False, True])
def test_reduced_pc_inverts_the_pre_matrix(piano, isotropic):
    """y = PC(r) solves A y = r for the model's assembled pre-matrix A = P G P + μ(I − P)
    (+ the variety's curvature for the exact isotropic Hessian), also with a shift."""
    problem, x = mbo_problem(piano, isotropic)
    with GaussNewtonModel(problem, x, exact=isotropic, adapt=not isotropic) as model:
        pc = ReducedFactorPC()
        pc.attach(model, "test_reduced_")
        try:
            rng = np.random.default_rng(7 + COMM.rank)
            r, y, Ay = x.duplicate(), x.duplicate(), x.duplicate()
            for shift in (0.0, 0.3):
                if shift:
                    model.shift(None, shift)
                    model.assembled.shift(shift)
                r.getArray()[:] = rng.standard_normal(r.getLocalSize())
                pc.setUp(None)
                pc.apply(None, r, y)
                model.assembled.mult(y, Ay)
                Ay.axpy(-1.0, r)
                assert Ay.norm() <= 1e-9 * r.norm()
        finally:
            pc.destroy(None)
            for v in (x,):
                v.destroy()


@pytest.mark.parametrize("isotropic", [False, True])
def test_reduced_newton_steps_equal_the_full_ones(piano, isotropic):
    """Ten Newton steps with the reduced preconditioner (default) and with the Cholesky
    factorisation of the 5N pre-matrix (``-tao_nls_pc_type cholesky``): the same iterates
    (H and |g| at every step to 1e-8) and the same Krylov counts to ±1."""
    runs = {}
    for mode in ("reduced", "full"):
        options = {} if mode == "reduced" else {"tao_nls_pc_type": "cholesky"}
        if mode == "full" and PETSc.Sys.hasExternalPackage("mumps"):
            options["tao_nls_pc_factor_mat_solver_type"] = "mumps"
        with options_scope(options.items()):
            field = FrameField.initial(piano, isotropic=isotropic)
            runs[mode] = field.solve(max_it=10)
    a, b = runs["reduced"], runs["full"]
    assert len(a.history) == len(b.history) > 2
    for x, y in zip(a.history, b.history, strict=True):
        assert x["H"] == pytest.approx(y["H"], rel=1e-8)
        assert x["gnorm"] == pytest.approx(y["gnorm"], rel=1e-6, abs=1e-12)
    assert all(abs(p - q) <= 1 for p, q in zip(a.krylov_iterations, b.krylov_iterations,
                                                strict=True))


def test_reduced_pc_is_the_default():
    from ufl_frames.solvers.tao import newton_pc_options

    assert newton_pc_options("nls", COMM)["tao_nls_pc_type"] == "python"
    assert newton_pc_options("nls", COMM, reduced=False)["tao_nls_pc_type"] != "python"


def test_reduced_pc_alone_refuses_to_run():
    with pytest.raises(RuntimeError, match="Newton model"):
        ReducedFactorPC().setUp(None)


@pytest.mark.parametrize("isotropic", [False, True])
def test_lean_model_applies_the_same_newton_matrix(piano, isotropic):
    """The lean model (no 5N pre-matrix: nls/ntr with the reduced PC) applies the same
    Newton matrix B as the full one, before and after a shift."""
    problem, x = mbo_problem(piano, isotropic)
    kwargs = {"exact": isotropic, "adapt": not isotropic}
    with GaussNewtonModel(problem, x, **kwargs) as full, \
            GaussNewtonModel(problem, x, lean=True, **kwargs) as lean:
        assert lean.assembled is None and lean.mu == pytest.approx(full.mu, rel=1e-12)
        rng = np.random.default_rng(3 + COMM.rank)
        v, a, b = x.duplicate(), x.duplicate(), x.duplicate()
        try:
            for shift in (0.0, 0.25):
                if shift:
                    full.shift(None, shift)
                    lean.shift(None, shift)
                    lean.reduced_operator()  # the PC's view: R holds the shift now
                v.getArray()[:] = rng.standard_normal(v.getLocalSize())
                full.shell.mult(v, a)
                lean.shell.mult(v, b)
                b.axpy(-1.0, a)
                assert b.norm() <= 1e-10 * a.norm()
        finally:
            for vec in (v, a, b, x):
                vec.destroy()


@pytest.mark.parametrize("isotropic", [False, True])
def test_exact_model_steps_take_two_krylov_iterations(piano, isotropic):
    """The exact Riemannian Hessian (isotropic frames from the start, non-isotropic ones
    after the hybrid model's switch): the preconditioner holds the sphere's curvature −σ I
    as the shell does, so every Newton system is solved in at most 3 Krylov iterations
    (with −σ I in the shell alone: 4–8)."""
    field = FrameField.initial(piano, isotropic=isotropic)
    result = field.solve(max_it=500)
    assert result.converged_reason.startswith("CONVERGED")
    counts = [k for k in result.krylov_iterations if k > 0]
    assert counts and max(counts) <= 3, counts


@pytest.mark.parametrize("tao_type", ["nls", "ntr", "bnls", "bntr"])
def test_every_newton_type_solves_with_the_reduced_pc(tao_type):
    """Each Newton TAO type converges with the default preconditioner, under an options
    prefix. ``bntr`` applies the options again inside its solve, which gives the PC a new
    context; that context finds the model (before: PETSc error 101 at its first step)."""
    field = FrameField.initial(build(COMM, "annulus", mesh_size=0.1), isotropic=True)
    with options_scope([(f"reduced_{tao_type}_tao_type", tao_type)]):
        result = field.solve(max_it=100, options_prefix=f"reduced_{tao_type}_")
    assert result.converged_reason.startswith("CONVERGED"), result.converged_reason
    assert result.iterations > 0
    assert max(result.krylov_iterations) <= 3


@pytest.mark.parametrize("via", [None, "scalable"])
@pytest.mark.parametrize("threshold", [0, None])
def test_ptap_equals_the_dense_product_and_leaves_the_options_as_they_were(via, threshold,
                                                                          monkeypatch):
    """``hessian._ptap``: Pᵀ A P of a random sparse A (with entries off the ranks' blocks)
    and a rectangular block-diagonal P equals the dense product, first and reused, with
    the large matrices' algorithm (threshold 0) and without; the parallel default
    ("allatonce") is not left in the options database, and a user's ``-matptap_via`` is
    kept."""
    from ufl_frames.solvers import hessian
    from ufl_frames.solvers.hessian import _ptap

    if threshold is not None:
        monkeypatch.setattr(hessian, "ALLATONCE_ROWS", threshold)

    rng = np.random.default_rng(7)
    rows, cols = 5 * 8, 3 * 8  # 8 "vertices" a rank: 5 rows, 3 columns each
    N, M = rows * COMM.size, cols * COMM.size
    dense_a = np.where(rng.random((N, N)) < 0.2, rng.standard_normal((N, N)), 0.0)
    dense_a = COMM.bcast(dense_a + dense_a.T, root=0)
    dense_p = np.zeros((N, M))
    for v in range(N // 5):
        dense_p[5 * v:5 * v + 5, 3 * v:3 * v + 3] = COMM.bcast(rng.standard_normal((5, 3)))
    A = PETSc.Mat().createAIJ(((rows, N), (rows, N)), comm=COMM)
    P = PETSc.Mat().createAIJ(((rows, N), (cols, M)), comm=COMM)
    for mat, dense in ((A, dense_a), (P, dense_p)):
        mat.setPreallocationNNZ(dense.shape[1])
        lo, hi = mat.getOwnershipRange()
        for i in range(lo, hi):
            nonzero = np.flatnonzero(dense[i]).astype(PETSc.IntType)
            mat.setValues(i, nonzero, dense[i, nonzero])
        mat.assemble()
    options = [("matptap_via", via)] if via else []
    with options_scope(options) as db:
        R = _ptap(A, P)
        assert (db.getString("matptap_via") if db.hasName("matptap_via") else None) == via
        lo, hi = R.getOwnershipRange()
        expected = dense_p.T @ dense_a @ dense_p
        np.testing.assert_allclose(R[lo:hi, :], expected[lo:hi], atol=1e-12)
        A.scale(2.0)
        assert _ptap(A, P, R) is R
        np.testing.assert_allclose(R[lo:hi, :], 2 * expected[lo:hi], atol=1e-12)
    for mat in (A, P, R):
        mat.destroy()


@pytest.mark.skipif(not PETSc.Sys.hasExternalPackage("mumps"), reason="MUMPS's BLR")
def test_block_low_rank_factorisation_takes_the_full_rank_steps():
    """The default factorises the reduced matrix with MUMPS's block low-rank compression
    (threshold :data:`MUMPS_BLR_TOLERANCE`); the non-isotropic piano at h = 0.05 takes the
    same steps as with the full-rank factorisation (``..._icntl_35 0``): H and |g| at every
    step to 1e-8, the same Krylov counts."""
    from ufl_frames.solvers.tao import MUMPS_BLR_TOLERANCE, newton_pc_options

    defaults = newton_pc_options("nls", COMM)
    assert defaults["tao_nls_reduced_mat_mumps_icntl_35"] == "1"
    assert float(defaults["tao_nls_reduced_mat_mumps_cntl_7"]) == MUMPS_BLR_TOLERANCE
    domain = build(COMM, "piano", mesh_size=0.05)
    runs = []
    for options in ({}, {"tao_nls_reduced_mat_mumps_icntl_35": "0"}):
        with options_scope(options.items()):
            runs.append(FrameField.initial(domain).solve(max_it=500))
    blr, full = runs
    assert blr.converged_reason.startswith("CONVERGED"), blr.converged_reason
    assert len(blr.history) == len(full.history) > 5
    for x, y in zip(blr.history, full.history, strict=True):
        assert x["H"] == pytest.approx(y["H"], rel=1e-8)
        assert x["gnorm"] == pytest.approx(y["gnorm"], rel=1e-6, abs=1e-12)
    assert blr.krylov_iterations == full.krylov_iterations


def _dense(A: PETSc.Mat) -> np.ndarray:
    """The whole of A as a numpy array on every rank."""
    first, last = A.getOwnershipRange()
    n = A.getSize()[1]
    rows = A.getValues(range(first, last), range(n))
    return np.vstack(COMM.allgather(rows))


@pytest.mark.skipif(not PETSc.Sys.hasExternalPackage("mumps"), reason="MUMPS' inertia")
def test_negative_pivots_of_the_reduced_matrix_count_its_whole_inertia(piano):
    """The safeguard's inertia (``negative_pivots``) on the reduced matrix R of the piano's
    Gauss–Newton model, shifted to be indefinite: MUMPS runs with ICNTL(13) = 1 on more
    than one rank (a ScaLAPACK root is missing from INFOG(12), and on 2 ranks the sized
    piano's indefinite exact steps went unseen), its default serially, the user's value
    where given; the count is that of the dense matrix's eigenvalues (numpy's)."""
    problem, x = mbo_problem(piano, isotropic=False)
    with GaussNewtonModel(problem, x, adapt=False) as model:
        pc = ReducedFactorPC()
        pc.attach(model, "test_inertia_")
        A = None
        try:
            pc.setUp(None)
            factor = pc.ksp.getPC().getFactorMatrix()
            assert factor.getMumpsIcntl(13) == (1 if COMM.size > 1 else 0)
            A = model.reduced_operator()[1].duplicate(copy=True)
            eigenvalues = np.linalg.eigvalsh(_dense(A))  # ascending
            # the shift: the middle of the widest gap in the middle half of the spectrum
            n = len(eigenvalues)
            k = n // 4 + int(np.argmax(np.diff(eigenvalues[n // 4: 3 * n // 4])))
            A.shift(-0.5 * float(eigenvalues[k] + eigenvalues[k + 1]))
            expected = k + 1
            assert 0 < expected < len(eigenvalues)
            pc.ksp.setOperators(A)
            pc.ksp.setUp()
            assert pc.negative_pivots() == expected
        finally:
            pc.destroy(None)
            if A is not None:
                A.destroy()
        with options_scope([("test_given_reduced_mat_mumps_icntl_13", "0")]):
            given = ReducedFactorPC()
            given.attach(model, "test_given_")
            try:
                given.setUp(None)
                assert given.ksp.getPC().getFactorMatrix().getMumpsIcntl(13) == 0
            finally:
                given.destroy(None)
    x.destroy()
