r"""The ingredients of the second-order solvers (:mod:`ufl_frames.solvers`), checked numerically.

The solver minimises f(x) = H(R(x)) over the scaled unknowns x = √m q, R the retraction
(pointwise projection and normalisation, note §3 steps 4–5). It needs

(a) the Riemannian gradient g (``FrameProblem.riemannian_gradient``): for d tangent to the
    constraint set at x (pointwise tangent to the Odeco variety, boundary and pinned rows
    with their orientation held, and orthogonal to x), g·d = d/dε f(x + εd) at ε = 0.
    Checked by central differences (error O(ε²)) to a relative 1e-6.

(b) the Gauss–Newton product B d (``GaussNewtonModel`` with no damping). What it should and
    should not equal:

    * H = ½∫|r|² with the bracket r(q) = C q ∂q bilinear, so along a straight line
      d²/dt² H(q + tδ) = ∫|Dr[δ]|² + 2∫ r·C δ ∂δ exactly (H(q + tδ) is a quartic in t),
      and for tangent d (δ = d/√m) d·Bd must be the first term. This is checked to 1e-8
      with a five-point stencil (exact on quartics): it tests the assembled JᵀJ, the
      scaling and the projectors, with nothing left to a tolerance.
    * Along the retraction, d²/dε² f(x + εd) is the Riemannian second derivative: JᵀJ plus
      the residual term ∫ r·D²r[δ, δ] and the curvature term ∇H·R''(0), both O(|r|),
      which Gauss–Newton drops. So the two agree to finite-difference accuracy on an
      exactly integrable field (r = 0; a constant frame field on the unit square, whose
      bracket vanishes identically: measured 1e-9 and 2e-7), and along a family of fields
      moved away from it by s (|r| ∝ s) the discrepancy appears, stays below
      |r|_L² = √(2H) and grows x2-3 per doubling of s. On the converged isotropic annulus at
      h = 0.1 (H ≈ 1.9e-3, the discretisation residual) it is below 1e-2 (measured 4e-4).
    * The same for the derivative of the gradient: (g(x+εd) − g(x−εd)) / 2ε, restricted to
      the tangent space at x, equals Bd up to O(|r|) (measured 8e-4 on the annulus).
    * B maps tangent vectors to tangent vectors, and normals n (and x) to μ n (μ x).

(c) superlinear convergence of the default method (Gauss–Newton, ``nls``) on the isotropic
    annulus: once |g|/|g0| < 1e-2 the error ratios e_{k+1}/e_k, e_k = H_k − H_final, fall
    (measured 0.053, 0.008, 0.0002 at h = 0.1) — the damping λ shrinks with |g| and the
    residual of the converged field is small;
(d) a regression bound: the default method converges there in at most 20 iterations
    (measured 13 at h = 0.1, serial and on 2 ranks).

Fields live on ``MPI.COMM_WORLD``: everything here also runs under ``mpirun -n 2``.
"""

import dolfinx
import dolfinx.fem as fem
import dolfinx.fem.petsc  # noqa: F401
import numpy as np
import pytest
import ufl
from mpi4py import MPI

from ufl_frames import solvers
from ufl_frames.bootstrap import petsc_defaults
from ufl_frames.fem import energy
from ufl_frames.frames2d import odeco
from ufl_frames.mesh import build, piano
from ufl_frames.solvers import mbo

COMM = MPI.COMM_WORLD


# --- helpers ----------------------------------------------------------------------


def scaled_x(problem):
    """A new PETSc vector x = √m q of the current field."""
    x = dolfinx.fem.petsc.create_vector(problem.q.function_space)
    problem.write_x(x)
    return x


def tangent(problem, rows, x):
    """The vector of ``rows`` (local (N, 5)) projected on the tangent space at R(x) = q.

    Pointwise tangent projection of the Odeco/boundary constraints at the current q, then
    the component along x removed (tangent of the normalisation sphere |x| = const).
    """
    n = problem.owned
    v = x.duplicate()
    v.getArray()[:] = problem.manifold.projection(problem.rows, rows)[
        :n
    ].ravel()
    v.axpy(-v.dot(x) / x.dot(x), x)
    return v


def random_tangent(problem, x, seed):
    rng = np.random.default_rng([seed, COMM.rank])
    d = tangent(problem, rng.standard_normal(problem.rows.shape), x)
    d.scale(1.0 / d.norm())
    return d


def smooth_tangent(problem, x, phase=0.0):
    """A smooth tangent direction (rotation and length changes varying over the domain)."""
    p = problem.q.function_space.tabulate_dof_coordinates()[:, :2].T
    rows = np.stack(
        [
            np.sin(2 * p[0] + 1 + phase) * np.cos(3 * p[1]),
            np.cos(2 * p[1] - phase),
            np.sin(3 * p[0] * p[1]),
            np.cos(p[0] + phase),
            np.sin(4 * p[1]),
        ],
        axis=1,
    )
    d = tangent(problem, rows, x)
    d.scale(1.0 / d.norm())
    return d


def f_along(problem, x, d, eps):
    """f(x + εd) = H(R(x + εd)); leaves q at R(x)."""
    y = x.copy()
    y.axpy(eps, d)
    problem.set_from_x(y)
    value = problem.energy()
    problem.set_from_x(x)
    y.destroy()
    return value


def gradient_at(problem, x):
    g = x.duplicate()
    problem.set_from_x(x)
    problem.riemannian_gradient(g)
    return g


def second_difference(func, eps):
    """f''(0) by the five-point stencil: error O(ε⁴), exact for polynomials of degree 5."""
    return (-func(2 * eps) + 16 * func(eps) - 30 * func(0.0) + 16 * func(-eps) - func(-2 * eps)) / (
        12 * eps**2
    )


def gauss_newton(problem, x):
    """Undamped GaussNewtonModel at R(x) (gradient evaluated first, as TAO does)."""
    gradient_at(problem, x)
    return solvers.GaussNewtonModel(problem, x, damping=0.0, damping_min=0.0)


def apply(model, d):
    y = d.duplicate()
    model.shell.mult(d, y)
    return y


def constant_field(comm, isotropic, cells=8):
    """Constant frames (l1, l2) = (2, 1) or (1, 1) along the axes on the unit square: r ≡ 0."""
    mesh = dolfinx.mesh.create_unit_square(comm, cells, cells)
    q = fem.Function(energy.frame_space(mesh))
    lengths = [[1.0, 1.0]] if isotropic else [[2.0, 1.0]]
    q.x.array[:] = np.tile(
        odeco.frames_to_q(np.array(lengths), np.zeros(1)), (q.x.array.size // 5, 1)
    ).ravel()
    return solvers.frame_problem(q, isotropic=isotropic, max_aspect=None if isotropic else 4.0)


def moved(problem, x, s, w):
    """R(x + s |x| w) written back into x-units (a new vector); q is left there."""
    y = x.copy()
    y.axpy(s * x.norm(), w)
    problem.set_from_x(y)
    problem.write_x(y)
    return y


# --- a converged isotropic annulus, shared by (b), (c), (d) -------------------------


@pytest.fixture(scope="module")
def _annulus_solve():
    mesh = build(COMM, "annulus", 0.1).mesh
    q = mbo.mbo_frame_field(energy.frame_space(mesh))
    problem = solvers.frame_problem(q, isotropic=True)
    result = solvers.solve(problem, max_it=60, options_prefix="second_order_")
    return problem, result, q.x.array.copy()


@pytest.fixture
def annulus_solution(_annulus_solve):
    """(problem, result) of the default solver from the MBO field on the annulus, h = 0.1,
    isotropic; problem.q is the solution (put back after each test)."""
    problem, result, solution = _annulus_solve
    yield problem, result
    problem.q.x.array[:] = solution


# --- (a) the Riemannian gradient ----------------------------------------------------


@pytest.mark.parametrize(
    "name, isotropic", [("annulus", True), ("annulus", False), ("piano", True), ("piano", False)]
)
def test_riemannian_gradient_matches_central_differences(name, isotropic):
    """g·d = d/dε H(R(x + εd)) on the MBO field (the piano: with pinned singular triangles)."""
    mesh = build(COMM, name, 0.2).mesh
    q = mbo.mbo_frame_field(energy.frame_space(mesh))
    problem = solvers.frame_problem(
        q, isotropic=isotropic, pin_singularities=True, max_aspect=None if isotropic else 4.0
    )
    x = scaled_x(problem)
    g = gradient_at(problem, x)
    for seed in range(3):
        d = random_tangent(problem, x, seed)
        exact = g.dot(d)
        errors = []
        for eps in (1e-3, 1e-5):
            fd = (f_along(problem, x, d, eps) - f_along(problem, x, d, -eps)) / (2 * eps)
            errors.append(abs(fd - exact) / abs(exact))
        if COMM.rank == 0:
            print(
                f"\n{name} isotropic={isotropic}: g.d = {exact:+.10e}, relative error of the "
                f"central difference at eps 1e-3, 1e-5: {errors[0]:.1e}, {errors[1]:.1e}"
            )
        assert errors[1] < 1e-6
        assert errors[1] < 1e-2 * errors[0]  # O(ε²): the error is truncation, not a mismatch


# --- (b) the Gauss–Newton product ---------------------------------------------------


def residual_term(problem, d):
    """2 ∫ r(q) · C δ ∂δ with δ = d / √m: the part of d²H(q + tδ)/dt² that JᵀJ leaves out."""
    q = problem.q
    delta = fem.Function(q.function_space)
    n = problem.owned
    delta.x.array[: 5 * n] = (
        d.getArray(readonly=True).reshape(-1, 5) / problem.sqrt_mass[:n, None]
    ).ravel()
    delta.x.scatter_forward()
    form = fem.form(2 * ufl.inner(energy.lie_bracket(q), energy.lie_bracket(delta)) * ufl.dx)
    return COMM.allreduce(fem.assemble_scalar(form), op=MPI.SUM)


def straight_line_second_derivative(problem, x, d, eps=1e-2):
    """d²/dt² H(q + tδ) at t = 0, no retraction (H is a quartic in t: the stencil is exact)."""
    n = problem.owned
    base = problem.rows.copy()

    def H(t):
        problem.rows[:n] = (x.getArray(readonly=True) + t * d.getArray(readonly=True)).reshape(
            -1, 5
        ) / problem.sqrt_mass[:n, None]
        problem.q.x.scatter_forward()
        return problem.energy()

    value = second_difference(H, eps)
    problem.rows[:] = base
    return value


@pytest.mark.parametrize("field", ["square-iso", "square-noniso", "annulus"])
def test_gauss_newton_is_the_exact_jtj(field, annulus_solution):
    """d·Bd = d²/dt² H(q + tδ) − 2∫ r·Cδ∂δ to 1e-8, for random and smooth tangent d."""
    if field == "annulus":
        problem = annulus_solution[0]
    else:
        problem = constant_field(COMM, isotropic=field == "square-iso")
    x = scaled_x(problem)
    w = smooth_tangent(problem, x)
    x = moved(problem, x, 0.05, w)  # off the minimiser / off the integrable field: r ≠ 0
    model = gauss_newton(problem, x)
    for d in (random_tangent(problem, x, 7), smooth_tangent(problem, x, phase=0.5)):
        dBd = d.dot(apply(model, d))
        line = straight_line_second_derivative(problem, x, d)
        rest = residual_term(problem, d)
        if COMM.rank == 0:
            print(
                f"\n{field}: d.Bd = {dBd:.10e}, H''(line) - residual term = {line - rest:.10e}"
                f" (residual term / d.Bd = {rest / dBd:+.1e})"
            )
        assert line - rest == pytest.approx(dBd, rel=1e-8)
    model.free()


def test_gauss_newton_maps_tangents_to_tangents_and_normals_to_mu(annulus_solution):
    problem = annulus_solution[0]
    x = scaled_x(problem)
    model = gauss_newton(problem, x)
    d = random_tangent(problem, x, 3)
    Bd = apply(model, d)
    Bd_tangent = tangent(problem, _local_rows(problem, Bd), x)
    assert (Bd_tangent - Bd).norm() <= 1e-12 * Bd.norm()
    # a pointwise normal vector (orthogonal to the tangent spaces, hence to x) and x itself
    rng = np.random.default_rng([11, COMM.rank])
    v = x.duplicate()
    raw = rng.standard_normal(problem.rows.shape)
    normal = raw - problem.manifold.projection(problem.rows, raw)
    v.getArray()[:] = normal[: problem.owned].ravel()
    assert abs(v.dot(x)) <= 1e-10 * v.norm() * x.norm()
    for vec in (v, x):
        out = apply(model, vec)
        out.axpy(-model.mu, vec)
        assert out.norm() <= 1e-10 * model.mu * vec.norm()
    model.free()


def _local_rows(problem, vec):
    """Local (owned and ghost) rows of a PETSc vector of owned rows (ghosts from the owners)."""
    f = fem.Function(problem.q.function_space)
    n = problem.owned
    f.x.array[: 5 * n] = vec.getArray(readonly=True)
    f.x.scatter_forward()
    return f.x.array.reshape(-1, 5).copy()


def riemannian_discrepancies(problem, x, d, model, eps=1e-3):
    """(relative |f'' − d·Bd|, relative |P Dg[d] − Bd|) along the retraction at x."""
    Bd = apply(model, d)
    dBd = d.dot(Bd)
    f2 = second_difference(lambda t: f_along(problem, x, d, t), eps)
    step = 1e-4
    y_plus, y_minus = x.copy(), x.copy()
    y_plus.axpy(step, d)
    y_minus.axpy(-step, d)
    dg = gradient_at(problem, y_plus)
    dg.axpy(-1.0, gradient_at(problem, y_minus))
    dg.scale(1.0 / (2 * step))
    problem.set_from_x(x)
    dg_tangent = tangent(problem, _local_rows(problem, dg), x)
    dg_tangent.axpy(-1.0, Bd)
    return abs(f2 - dBd) / dBd, dg_tangent.norm() / Bd.norm()


@pytest.mark.parametrize("isotropic", [True, False])
def test_riemannian_hessian_equals_gauss_newton_on_an_integrable_field(isotropic):
    """r ≡ 0: f'' along the retraction and the gradient's derivative are Bd, to FD accuracy;
    moving the field away by s (|r| ∝ s), the discrepancy appears and grows with |r|."""
    problem = constant_field(COMM, isotropic)
    x0 = scaled_x(problem)
    assert abs(problem.energy()) < 1e-28
    w = smooth_tangent(problem, x0)
    rows = []
    for s in (0.0, 0.01, 0.02, 0.04):
        x = moved(problem, x0, s, w)
        model = gauss_newton(problem, x)
        H = problem.energy()
        worst = np.zeros(2)
        for d in (random_tangent(problem, x, 5), smooth_tangent(problem, x, phase=1.0)):
            worst = np.maximum(worst, riemannian_discrepancies(problem, x, d, model))
        rows.append((s, H, *worst))
        model.free()
    if COMM.rank == 0:
        print(
            f"\nconstant {'isotropic' if isotropic else 'non-isotropic'} frames on the square,"
            " moved by s:"
        )
        for s, H, e2, eg in rows:
            print(
                f"  s = {s:5.3f}  H = {H:.2e}  |f'' - dBd|/dBd = {e2:.1e}  "
                f"|P Dg[d] - Bd|/|Bd| = {eg:.1e}"
            )
    (_, _, e2_0, eg_0), *moved_rows = rows
    assert e2_0 < 1e-6 and eg_0 < 1e-6  # exact where r = 0
    discrepancies = np.array([r[2:] for r in moved_rows])  # s = 0.01, 0.02, 0.04
    residual_norm = np.sqrt(2 * np.array([r[1] for r in moved_rows]))  # |r| in L², ∝ s
    assert np.all(discrepancies > 10 * max(e2_0, eg_0))
    # s doubles: a discrepancy O(|r|) doubles (x 2.0-2.1 measured for the gradient), one with
    # a sizeable O(|r|²) part up to quadruples (x 2.8-3.1 measured for f'', isotropic)
    growth = discrepancies[1:] / discrepancies[:-1]
    assert np.all((growth > 1.5) & (growth < 4.5)), growth
    assert np.all(discrepancies < residual_norm[:, None]), (discrepancies, residual_norm)


def test_riemannian_hessian_near_gauss_newton_at_the_annulus_solution(annulus_solution):
    """At the converged field (r = discretisation residual, H ≈ 1.9e-3): within 1e-2."""
    problem, result = annulus_solution
    x = scaled_x(problem)
    model = gauss_newton(problem, x)
    worst = np.zeros(2)
    for d in (
        random_tangent(problem, x, 1),
        random_tangent(problem, x, 2),
        smooth_tangent(problem, x),
    ):
        worst = np.maximum(worst, riemannian_discrepancies(problem, x, d, model))
    model.free()
    if COMM.rank == 0:
        print(
            f"\nannulus h = 0.1, H = {result.H_final:.3e}: |f'' - dBd|/dBd = {worst[0]:.1e}, "
            f"|P Dg[d] - Bd|/|Bd| = {worst[1]:.1e}"
        )
    assert worst[0] < 1e-2 and worst[1] < 1e-2


# --- (c), (d) convergence of the default method --------------------------------------


def test_default_method_converges_superlinearly(annulus_solution):
    problem, result = annulus_solution
    H = np.array([e["H"] for e in result.history])
    rel_grad = np.array([e["gnorm"] for e in result.history]) / result.history[0]["gnorm"]
    error = H - result.H_final
    close = np.flatnonzero(rel_grad < 1e-2)
    assert close.size, "never got close"
    k0 = close[0]
    # ratios while the error is above rounding (relative 1e-13 of H)
    tail = [k for k in range(k0, len(H) - 1) if error[k + 1] > 1e-13 * result.H_final]
    ratios = np.array([error[k + 1] / error[k] for k in tail])
    if COMM.rank == 0:
        print(
            f"\nnls, isotropic annulus h = 0.1 ({result.iterations} its, "
            f"{result.converged_reason}): e_k = H_k - H_final from k = {k0} "
            f"(|g|/|g0| < 1e-2):"
        )
        for k in range(k0, len(H)):
            line = f"  k = {k:2d}  e = {error[k]:.3e}  |g|/|g0| = {rel_grad[k]:.1e}"
            if k + 1 < len(H) and error[k + 1] > 0:
                # p with e_k+1 = e_k^p (H ~ 1e-3 here, so p < 2 even for quadratic contraction)
                p = np.log(error[k + 1]) / np.log(error[k])
                ratio = error[k + 1] / error[k]
                line += f"  e_k+1/e_k = {ratio:.2e}  p = log e_k+1 / log e_k = {p:.2f}"
            print(line)
    # The energy error reaches rounding within two steps of Newton (exact Hessian, the
    # isotropic default), so judge the contraction on the gradient norm as well.
    grad_ratios = rel_grad[k0 + 1 :] / rel_grad[k0:-1]
    if COMM.rank == 0:
        print(f"  |g_k+1|/|g_k| from k = {k0}: {np.array2string(grad_ratios, precision=2)}")
    assert ratios.size >= 1 and np.all(ratios < 0.1), ratios
    assert grad_ratios.size >= 2
    assert np.all(np.diff(grad_ratios) < 0), grad_ratios  # the contraction improves
    assert np.all(grad_ratios < 0.1), grad_ratios


def test_default_method_iteration_count_regression(annulus_solution):
    """Default TAO type (Gauss–Newton ``nls``), isotropic annulus, h = 0.1: 13 its measured."""
    problem, result = annulus_solution
    assert solvers.DEFAULT_OPTIONS["tao_type"] == "nls"
    assert result.converged_reason.startswith("CONVERGED"), result.converged_reason
    assert result.iterations <= 20, result.iterations


def test_exact_hessian_is_the_riemannian_hessian_at_a_critical_point():
    """``-frames_hessian exact``: ∇²H from UFL in the tangent spaces, plus the chart's
    second-order term g·∂²q (odeco.tangent_curvature) and the sphere's −4H/ρ². At a critical
    point this is the Riemannian Hessian: d·Bd equals the second difference of H(R(x + εd)).

    The pinned isotropic piano is a large-residual minimum (H ≈ 0.14 at h = 0.2) where the
    Gauss–Newton part alone is visibly off — checked too."""
    comm = MPI.COMM_WORLD
    mesh = piano(comm, mesh_size=0.2).mesh
    q = mbo.mbo_frame_field(energy.frame_space(mesh))
    problem = solvers.frame_problem(q, isotropic=True, pin_singularities=True)
    with petsc_defaults("crit_", {"tao_gttol": 1e-11, "tao_nls_ksp_rtol": 1e-12}):
        result = solvers.solve(problem, max_it=60, options_prefix="crit_")
    assert result.converged_reason.startswith("CONVERGED")
    x = scaled_x(problem)
    gradient_at(problem, x)
    exact = solvers.GaussNewtonModel(problem, x, damping=0.0, damping_min=0.0, exact=True)
    gauss_newton_only = solvers.GaussNewtonModel(problem, x, damping=0.0, damping_min=0.0)
    for phase in (0.0, 1.3):
        d = smooth_tangent(problem, x, phase)
        fd = second_difference(lambda e, d=d: f_along(problem, x, d, e), 1e-3)
        dbd = d.dot(apply(exact, d))
        gn = d.dot(apply(gauss_newton_only, d))
        if comm.rank == 0:
            print(f"\nphase {phase}: second difference {fd:.6e}, exact model {dbd:.6e}, "
                  f"Gauss-Newton {gn:.6e}")
        assert dbd == pytest.approx(fd, rel=1e-4)
        assert abs(gn - fd) > 100 * abs(dbd - fd)
    exact.free()
    gauss_newton_only.free()


@pytest.mark.parametrize("smoothing", [0.0, 0.05], ids=["sized", "smoothed"])
def test_exact_hessian_of_the_sized_energy_is_the_riemannian_hessian(smoothing):
    """The same with a size target and its smoothing term C S (``-frames_size_smoothing``):
    the exact model adds w H_s ∇²M and the constant C ∫ ∇δq:∇w/h², and the sphere's
    curvature reads x·∇J = 4H + 2 C S (S is quadratic, M of degree 0). Isotropic frames
    (no aspect bound to cross), a graded target, at a critical point of J."""
    from ufl_frames.mesh.sizes import SizeTarget

    comm = MPI.COMM_WORLD
    mesh = piano(comm, mesh_size=0.2).mesh
    q = mbo.mbo_frame_field(energy.frame_space(mesh))
    problem = solvers.frame_problem(q, isotropic=True, pin_singularities=True,
                                    size=SizeTarget.expression("0.5 + 0.3 * x"),
                                    size_smoothing=smoothing)
    assert (problem.size.smoothing is not None) == (smoothing > 0)
    with petsc_defaults("crits_", {"tao_gttol": 1e-11, "tao_nls_ksp_rtol": 1e-12,
                                   "frames_h_rtol": 0.0}):
        result = solvers.solve(problem, max_it=100, options_prefix="crits_")
    assert result.converged_reason.startswith("CONVERGED")
    x = scaled_x(problem)
    gradient_at(problem, x)
    evaluation = problem.evaluation()
    # the Euler identity that recovers H from the gradient, with the quadratic term
    assert evaluation.integrability == pytest.approx(problem.integrability_energy(), rel=1e-10)
    assert evaluation.smoothing == pytest.approx(
        problem.size.smoothing_weight * problem.size_smoothing(), rel=1e-12)
    exact = solvers.GaussNewtonModel(problem, x, damping=0.0, damping_min=0.0, exact=True)
    for phase in (0.0, 1.3):
        d = smooth_tangent(problem, x, phase)
        fd = second_difference(lambda e, d=d: f_along(problem, x, d, e), 1e-3)
        dbd = d.dot(apply(exact, d))
        if comm.rank == 0:
            print(f"\nphase {phase}: second difference {fd:.8e}, exact model {dbd:.8e}, "
                  f"sphere's share of the smoothing {2 * evaluation.smoothing / problem.norm2:.3e}")
        assert dbd == pytest.approx(fd, rel=1e-5)
        if smoothing:  # without the smoothing's part of the sphere's curvature: off
            without = dbd + 2 * evaluation.smoothing / problem.norm2 * d.dot(d)
            assert abs(without - fd) > 10 * abs(dbd - fd)
    exact.free()
