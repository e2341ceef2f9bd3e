r"""TAO's Hessian perturbation reaches :class:`solvers.GaussNewtonModel` exactly once.

What PETSc does (3.25; ``src/tao/unconstrained/impls/nls/nls.c``, ``TaoSolve_NLS``, and
the same in ``src/tao/bound/impls/bnk/bnk.c``, ``TaoBNKComputeStep``, for ``bnls``):
after ``TaoComputeHessian`` and before ``KSPSetOperators`` it perturbs the Newton system by
``pert`` (the initial value is ``-tao_nls_sval``, default 0; it is raised after
non-descent, indefinite or failed steps, ``-tao_nls_imin/imax/imfac``, and shrunk after
good ones, ``-tao_nls_psfac/pmsfac``, down to 0 below ``-tao_nls_pmin``)::

    if (pert > 0) {
      MatShift(tao->hessian, pert);
      if (tao->hessian != tao->hessian_pre) MatShift(tao->hessian_pre, pert);
    }

The model gives TAO a Python MatShell (``MatShift`` → ``model.shift``) and a different
assembled AIJ pre-matrix, so both are shifted. ``mult`` used to apply the pre-matrix
(already holding ``pert·I``) and then add ``shift_value·v``: the operator was
B + pert (I + S), S the sphere's tangent projector — 2·pert on tangent directions, which
is what every Newton direction is (measured: the ratio 2.000 on a random tangent vector).
The Newton step TAO computed was then not the perturbed Newton step that its update rules
for ``pert`` assume, and the preconditioner (B's sparse part + pert·I) no longer matched
the operator. Now ``mult`` applies an unshifted copy of the assembled part, and the shell
is B + (total shift)·I whether or not the pre-matrix was shifted too.

Checked here, on the annulus at h = 0.2 (Gauss–Newton on non-isotropic frames, the exact
Hessian on isotropic ones, so that the sphere's curvature term is exercised too):

* after ``MatShift`` on both matrices, exactly as TAO does, the shell applies
  B v + a v, B from the formula of :class:`solvers.GaussNewtonModel` on a copy of the
  unshifted pre-matrix (random v, parallel); the same when only the shell is shifted;
  shifts add up, and the next Hessian evaluation (``update``) starts unshifted;
* serially, the dense matrix of the shifted shell (applied to unit vectors) equals the
  dense reference S (A − σ) S + μ x̂x̂ᵀ + a I;
* TAO ``nls`` and ``bnls`` with the perturbation forced (``-tao_*_sval``; CG to 1e-12 and a
  unit step, one iteration): the shell saw the shift once, and the step d solves
  (B + pert I) d = −g against the reference (serially: equals the dense solve).

Fields live on ``MPI.COMM_WORLD``: all but the dense test also run under ``mpirun -n 2``.
"""

import dolfinx
import dolfinx.fem.petsc  # noqa: F401
import numpy as np
import pytest
from mpi4py import MPI
from petsc4py import PETSc

from ufl_frames import solvers
from ufl_frames.bootstrap import petsc_defaults
from ufl_frames.fem import energy
from ufl_frames.mesh import annulus
from ufl_frames.solvers import mbo
from ufl_frames.solvers.tao import tao_callbacks

COMM = MPI.COMM_WORLD
RTOL = 1e-11  # round-off of a few sparse products against |B| ~ μ


@pytest.fixture(scope="module")
def _field():
    mesh = annulus(COMM, 0.2).mesh
    q = mbo.mbo_frame_field(energy.frame_space(mesh))
    return q, q.x.array.copy()


@pytest.fixture(params=[False, True], ids=["gauss_newton", "exact"])
def setting(request, _field):
    """(problem, exact): non-isotropic frames with Gauss–Newton, isotropic with ∇²H."""
    q, start = _field
    q.x.array[:] = start
    isotropic = exact = request.param
    problem = solvers.frame_problem(q, isotropic=isotropic, max_aspect=None if isotropic else 4.0)
    return problem, exact


class _Tao:
    """What ``GaussNewtonModel.update`` asks of TAO: the gradient at x."""

    def __init__(self, g):
        self.g = g

    def getGradient(self):
        return self.g, None

    def getSolutionStatus(self):  # (its, f, gnorm, cnorm, step, reason): a unit step
        return 0, 0.0, self.g.norm(), 0.0, 1.0, 0


def model_at(problem, exact):
    """A model set up as ``solvers.tao._TaoSolve`` does, then updated at the start as TAO does."""
    x = dolfinx.fem.petsc.create_vector(problem.q.function_space)
    problem.retract()
    problem.write_x(x)
    g = x.duplicate()
    problem.set_from_x(x)
    problem.riemannian_gradient(g)  # TAO evaluates the gradient before the Hessian
    model = solvers.GaussNewtonModel(problem, x, exact=exact)
    model.update(_Tao(g), x, model.shell, model.assembled)
    return model, x, g


def reference(model, A, v):
    """B v = S A S v + μ (x̂·v) x̂ (the class docstring), A the unshifted pre-matrix (which
    holds the sphere's curvature −σ I of the exact model)."""
    xhat = model.xhat
    w = v.copy()
    w.axpy(-xhat.dot(v), xhat)
    y = v.duplicate()
    A.mult(w, y)
    y.axpy(model.mu * xhat.dot(v) - xhat.dot(y), xhat)
    w.destroy()
    return y


def random_vector(template, seed):
    rng = np.random.default_rng([seed, COMM.rank])
    v = template.duplicate()
    v.getArray()[:] = rng.standard_normal(v.getLocalSize())
    return v


def apply(mat, v):
    y = v.duplicate()
    mat.mult(v, y)
    return y


def distance(y, z):
    """|y − z| / |z|."""
    d = y.copy()
    d.axpy(-1.0, z)
    return d.norm() / z.norm()


def a_times(v, a):
    w = v.copy()
    w.scale(a)
    return w


def shifted_reference(model, A, v, a):
    y = reference(model, A, v)
    y.axpy(a, v)
    return y


@pytest.mark.parametrize("shift_pre", [True, False], ids=["both", "shell_only"])
def test_shell_is_shifted_once(setting, shift_pre):
    """MatShift(shell, a) (and MatShift(pre, a), as TAO does): the shell applies B + a I."""
    problem, exact = setting
    model, x, _ = model_at(problem, exact)
    A = model.assembled.copy()  # the unshifted pre-matrix
    assert exact == (model.sphere != 0.0)
    v = random_vector(x, 1)
    tangent = v.copy()
    tangent.axpy(-model.xhat.dot(v), model.xhat)  # tangent to the sphere: S v = v
    before = {"random": apply(model.shell, v), "tangent": apply(model.shell, tangent)}
    assert distance(before["random"], reference(model, A, v)) < RTOL

    a = model.mu  # as large as B's normal part: a double shift is no round-off
    model.shell.shift(a)
    if shift_pre:
        model.assembled.shift(a)
        # The pre-matrix got a·I (PETSc's MatShift on AIJ): the preconditioner of B + a I.
        pre = apply(model.assembled, v)
        pre.axpy(-1.0, apply(A, v))
        assert distance(pre, a_times(v, a)) < RTOL
    for name, w in (("random", v), ("tangent", tangent), ("normal", model.xhat)):
        y = apply(model.shell, w)
        assert distance(y, shifted_reference(model, A, w, a)) < RTOL, name
        # What a shell that also passes the pre-matrix's shift on would give on tangents:
        doubled = shifted_reference(model, A, w, a)
        doubled.axpy(a, w)
        doubled.axpy(-a * model.xhat.dot(w), model.xhat)
        if name != "normal":
            assert distance(y, doubled) > 1e-3, name
    # The quadratic model along the tangent direction: t·(B + a)t, not t·(B + 2a)t.
    t_Bt = tangent.dot(before["tangent"])
    assert tangent.dot(apply(model.shell, tangent)) == pytest.approx(
        t_Bt + a * tangent.dot(tangent), rel=RTOL
    )
    model.free()


def test_shifts_add_up_and_update_resets(setting):
    """Two shifts give B + (a + b) I; the next Hessian evaluation starts from B again."""
    problem, exact = setting
    model, x, g = model_at(problem, exact)
    A = model.assembled.copy()
    v = random_vector(x, 2)
    a, b = 0.3 * model.mu, 2.0 * model.mu
    for s in (a, b):
        model.shell.shift(s)
        model.assembled.shift(s)
    assert distance(apply(model.shell, v), shifted_reference(model, A, v, a + b)) < RTOL
    # TAO's next TaoComputeHessian (same x here): reassembled, shift forgotten, on both.
    model.update(_Tao(g), x, model.shell, model.assembled)
    assert model.shift_value == 0.0
    assert distance(apply(model.shell, v), reference(model, A, v)) < RTOL
    assert distance(apply(model.assembled, v), apply(A, v)) < RTOL
    model.free()


def dense(mat, n):
    """The dense matrix of ``mat`` (serial), column by column from unit vectors."""
    e, y = mat.createVecs()
    columns = []
    for j in range(n):
        e.zeroEntries()
        e.setValue(j, 1.0)
        e.assemble()
        mat.mult(e, y)
        columns.append(y.getArray().copy())
    return np.array(columns).T


def dense_reference(model, A):
    """S A S + μ x̂x̂ᵀ with A the assembled (unshifted) pre-matrix (−σ I included), in NumPy."""
    n = A.getSize()[0]
    s = model.xhat.getArray().copy()
    S = np.eye(n) - np.outer(s, s)
    return S @ dense(A, n) @ S + model.mu * np.outer(s, s)


@pytest.mark.serial
def test_dense_shifted_shell(setting):
    """Serially: the shell's matrix after TAO's two MatShift calls is B + a I, B dense."""
    problem, exact = setting
    model, x, _ = model_at(problem, exact)
    n = x.getSize()
    B = dense_reference(model, model.assembled)
    scale = np.abs(B).max()
    assert np.abs(dense(model.shell, n) - B).max() < RTOL * scale
    a = model.mu
    model.shell.shift(a)
    model.assembled.shift(a)
    shell = dense(model.shell, n)
    assert np.abs(shell - (B + a * np.eye(n))).max() < RTOL * scale
    assert np.abs(shell - shell.T).max() < RTOL * scale
    model.free()


SVAL = {"nls": "tao_nls_sval", "bnls": "tao_bnk_sval"}
KSP = {"nls": "tao_nls_", "bnls": "tao_bnk_"}


@pytest.mark.parametrize("tao_type", ["nls", "bnls"])
def test_tao_perturbed_newton_step(tao_type):
    """TAO with the perturbation forced: its step d solves (B + pert I) d = −g.

    One iteration of ``nls`` / ``bnls`` from the MBO field (Gauss–Newton, non-isotropic),
    set up as ``solvers.tao._TaoSolve`` does, with ``-tao_*_sval`` = μ (so pert = μ from the first
    iteration on), CG to 1e-12 with Jacobi on the (shifted) pre-matrix and a unit step
    (``-tao_ls_type unit``): x₁ − x₀ is the Newton direction TAO computed.
    """
    mesh = annulus(COMM, 0.2).mesh
    q = mbo.mbo_frame_field(energy.frame_space(mesh))
    problem = solvers.frame_problem(q, max_aspect=4.0)
    probe, x0, _ = model_at(problem, exact=False)
    pert = probe.mu
    probe.free()

    x = x0.copy()
    g = x.duplicate()

    objective, objective_gradient, update = tao_callbacks(problem)  # as solvers.solve uses

    model = solvers.GaussNewtonModel(problem, x)
    seen = {}

    def hessian(tao, x, H, P):
        model.update(tao, x, H, P)
        seen["A"] = model.assembled.copy()  # before TAO shifts it
        seen["g"] = tao.getGradient()[0].copy()
        seen["x"] = x.copy()

    prefix = f"shift_{tao_type}_"
    ksp = KSP[tao_type]
    options = {"tao_type": tao_type, SVAL[tao_type]: pert, "tao_max_it": 1,
               "tao_ls_type": "unit", f"{ksp}ksp_type": "cg", f"{ksp}pc_type": "jacobi",
               f"{ksp}ksp_rtol": 1e-12, f"{ksp}ksp_atol": 0.0, f"{ksp}ksp_max_it": 5000}
    with petsc_defaults(prefix, options):
        tao = PETSc.TAO().create(COMM)
        tao.setOptionsPrefix(prefix)
        tao.setSolution(x)
        tao.setObjectiveGradient(objective_gradient, g)
        tao.setObjective(objective)
        tao.setHessian(hessian, model.shell, model.assembled)
        tao.setUpdate(update)
        tao.setFromOptions()
        tao.solve()
        ksp_reason = tao.getKSP().getConvergedReason()
        tao.destroy()

    # TAO shifted the shell once, by its initial perturbation; the solve converged.
    assert model.shift_value == pytest.approx(pert, rel=1e-14)
    assert ksp_reason > 0
    d = x.copy()
    d.axpy(-1.0, seen["x"])  # the unit step: d is TAO's Newton direction
    assert d.norm() > 0.0
    residual = shifted_reference(model, seen["A"], d, pert)
    residual.axpy(1.0, seen["g"])
    assert residual.norm() < 1e-9 * seen["g"].norm()
    # The doubled operator B + pert (I + S) would not have given this step.
    wrong = shifted_reference(model, seen["A"], d, 2 * pert)
    wrong.axpy(-pert * model.xhat.dot(d), model.xhat)
    wrong.axpy(1.0, seen["g"])
    assert wrong.norm() > 1e-2 * seen["g"].norm()
    if COMM.size == 1:
        n = x.getSize()
        B = dense_reference(model, seen["A"])
        expected = np.linalg.solve(B + pert * np.eye(n), -seen["g"].getArray())
        assert np.abs(d.getArray() - expected).max() < 1e-8 * np.abs(expected).max()
    model.free()
