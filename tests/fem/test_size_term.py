r"""The size misfit of the sized non-isotropic problem against independent truth.

M(q) = ½ ∫ |∇(σ − log h)|² dx + ½ (1/A) ∫ |β|² dx, σ = ½ log(l1 l2), |β| = (l1 − l2)/(l1 + l2)
(:func:`ufl_frames.fem.energy.size_misfit_form`). Exact values, by hand, on the annulus
0.5 ≤ r ≤ 1 (area A = 3π/4):

* isotropic frames of length r^p against a uniform target: ∇σ = (p/r) e_r, so
  M = ½ ∫∫ p²/r² r dr dφ = π p² ln 2;
* frames of lengths (2r, r) against h = r: σ − log h = ½ log 2 (no gradient), |β| = 1/3,
  so M = ½ · 1/9 = 1/18;
* the log-polar frames (r e_r, r e_θ), integrable (note-checks §4) and isotropic, against
  h = r: M = 0 and H = 0, so they minimise the sized energy J = H + w H_s M; solved from
  the MBO field, the discrete J, H and M must fall to 0 under refinement (rate ≈ 2, the
  P1 interpolation error squared).

The gradient that the solver uses (``FrameProblem.gradient``, the first variation of J) and
the size term's Hessian forms are checked against finite differences of J and of that
gradient. Serial and under MPI.
"""

import math

import dolfinx.fem as fem
import numpy as np
import pytest
from mpi4py import MPI

from ufl_frames.fem import energy
from ufl_frames.fem.problem import frame_problem, size_term
from ufl_frames.frames2d.algebra import ALGEBRA
from ufl_frames.mesh import build
from ufl_frames.mesh.sizes import SizeTarget
from ufl_frames.pipeline import FrameField

COMM = MPI.COMM_WORLD
AREA = 0.75 * math.pi
SIZES = (0.1, 0.05, 0.025)


def _polar(x):
    return np.hypot(x[0], x[1]), np.arctan2(x[1], x[0])


def misfit_of(mesh, f, target):
    """M of the frames f(x) -> (l1, l2, angle) interpolated on ``mesh``."""
    V = energy.frame_space(mesh)
    q = energy.interpolate_frames(V, f)
    term = size_term(q, target, AREA, 1.0, _constraints(V))
    return COMM.allreduce(fem.assemble_scalar(term.misfit), op=MPI.SUM)


def _constraints(V):
    from ufl_frames.fem.constraints import frame_constraints

    return frame_constraints(V)


def rates(errors, sizes):
    return [math.log(errors[i] / errors[i + 1]) / math.log(sizes[i] / sizes[i + 1])
            for i in range(len(errors) - 1)]


@pytest.fixture(scope="module")
def meshes(annulus_mesh):
    return [annulus_mesh(h) for h in SIZES]


@pytest.mark.parametrize("p", [1.0, 2.0])
def test_misfit_of_power_sizes_against_uniform(meshes, p):
    """Isotropic frames of length r^p, uniform target: M → π p² ln 2 at O(h²)."""
    exact = math.pi * p * p * math.log(2.0)

    def f(x):
        r, phi = _polar(x)
        return r**p, r**p, phi

    errors = [abs(misfit_of(m, f, SizeTarget.uniform()) - exact) for m in meshes]
    assert errors[-1] < 2e-3 * exact, errors
    assert min(rates(errors, SIZES)) > 1.7, (errors, rates(errors, SIZES))


def test_misfit_of_constant_anisotropy(meshes):
    """Lengths (2r, r) against h = r: only the anisotropy, M → 1/18."""

    def f(x):
        r, phi = _polar(x)
        return 2 * r, r, phi

    target = SizeTarget.expression("hypot(x, y)")
    errors = [abs(misfit_of(m, f, target) - 1.0 / 18.0) for m in meshes]
    assert errors[-1] < 1e-3, errors


def test_misfit_is_scale_invariant(meshes):
    """M(α q) = M(q) and M against α h is M against h: sizes up to a global factor."""

    def f(x):
        r, phi = _polar(x)
        return 1 + r**2, 0.7 + r, phi + 0.3 * r

    base = misfit_of(meshes[0], f, SizeTarget.expression("0.1 + x*x"))

    def g(x):
        l1, l2, t = f(x)
        return 3 * l1, 3 * l2, t

    assert misfit_of(meshes[0], g, SizeTarget.expression("0.1 + x*x")) == pytest.approx(
        base, rel=1e-10)
    assert misfit_of(meshes[0], f, SizeTarget.expression("5*(0.1 + x*x)")) == pytest.approx(
        base, rel=1e-10)


def _perturbed_problem(annulus_mesh, target, seed=3, smoothing=0.0):
    """A sized problem on a coarse annulus at a smooth non-isotropic field, and a random
    direction (owned rows; the same on every rank count for the owned values)."""
    mesh = annulus_mesh(0.15)
    V = energy.frame_space(mesh)

    def f(x):
        r, phi = _polar(x)
        return 1 + 0.5 * r * np.cos(phi), 1.2 - 0.3 * r, phi + 0.4 * r**2

    q = energy.interpolate_frames(V, f)
    problem = frame_problem(q, pin_singularities=False, size=target, size_smoothing=smoothing)
    rng = np.random.default_rng(seed + COMM.rank)
    direction = fem.Function(V)
    n = problem.owned * ALGEBRA.count
    direction.x.array[:n] = rng.standard_normal(n) * 0.05
    direction.x.scatter_forward()
    return problem, direction


def _owned_dot(problem, a, b):
    n = problem.owned * ALGEBRA.count
    return COMM.allreduce(float(np.dot(a[:n], b[:n])), op=MPI.SUM)


@pytest.mark.parametrize("smoothing", [0.0, 0.5], ids=["misfit", "smoothed"])
def test_gradient_of_the_sized_energy_matches_finite_differences(annulus_mesh, smoothing):
    """dJ(q)[δ] from the assembled gradient form against (J(q + εδ) − J(q − εδ))/2ε (with
    the smoothing term C S too)."""
    problem, direction = _perturbed_problem(annulus_mesh,
                                            SizeTarget.expression("0.2 + hypot(x, y)**2"),
                                            smoothing=smoothing)
    assert (problem.size_smoothing() > 0) == (smoothing > 0)
    q = problem.q
    b = fem.assemble_vector(problem.gradient)
    b.scatter_reverse(__import__("dolfinx").la.InsertMode.add)
    analytic = _owned_dot(problem, b.array, direction.x.array)
    base = q.x.array.copy()
    values = []
    eps = 1e-6
    for sign in (1.0, -1.0):
        q.x.array[:] = base + sign * eps * direction.x.array
        values.append(problem.energy())
    q.x.array[:] = base
    numeric = (values[0] - values[1]) / (2 * eps)
    assert problem.size is not None and problem.size_misfit() > 0
    assert analytic == pytest.approx(numeric, rel=1e-6, abs=1e-12 * abs(problem.energy()))
    # the size term alone, without H: its share of the gradient is not negligible
    misfit_form = fem.form(energy.gradient_form(problem.size.misfit_ufl, q))
    m = fem.assemble_vector(misfit_form)
    m.scatter_reverse(__import__("dolfinx").la.InsertMode.add)
    share = problem.size.weight * abs(_owned_dot(problem, m.array, direction.x.array))
    assert share > 1e-3 * abs(analytic)


@pytest.mark.parametrize("exact", [True, False])
def test_size_hessian_forms(annulus_mesh, exact):
    """The exact Hessian form of M against central differences of M's gradient; the
    Gauss–Newton form is symmetric positive semidefinite and agrees with the exact one
    at a field where the residuals vanish (log-polar frames, h = r)."""
    import dolfinx.fem.petsc
    import ufl

    target = SizeTarget.expression("hypot(x, y)")
    problem, direction = _perturbed_problem(annulus_mesh, target)
    q, size = problem.q, problem.size
    V = q.function_space
    grad_form = fem.form(ufl.derivative(size.misfit_ufl, q, ufl.TestFunction(V)))
    make = energy.size_hessian_form if exact else energy.size_gauss_newton_form
    A = dolfinx.fem.petsc.assemble_matrix(fem.form(make(q, size.log_h, size.inverse_area)))
    A.assemble()
    x = A.createVecRight()
    n = problem.owned * ALGEBRA.count
    x.getArray()[:] = direction.x.array[:n]
    y = A.createVecLeft()
    A.mult(x, y)
    product = y.getArray().copy()
    if exact:
        base, eps, grads = q.x.array.copy(), 1e-6, []
        for sign in (1.0, -1.0):
            q.x.array[:] = base + sign * eps * direction.x.array
            g = fem.assemble_vector(grad_form)
            g.scatter_reverse(__import__("dolfinx").la.InsertMode.add)
            grads.append(g.array[:n].copy())
        q.x.array[:] = base
        numeric = (grads[0] - grads[1]) / (2 * eps)
        error = COMM.allreduce(float(np.sum((product - numeric) ** 2)), op=MPI.SUM)
        scale = COMM.allreduce(float(np.sum(numeric**2)), op=MPI.SUM)
        assert math.sqrt(error) < 1e-6 * math.sqrt(scale)
    else:
        assert A.isSymmetric(1e-10)
        assert COMM.allreduce(float(np.dot(product, x.getArray())), op=MPI.SUM) >= 0
    A.destroy()


@pytest.fixture(scope="module")
def log_polar_solves():
    """The sized solve against h = r from the MBO field at three mesh sizes, without the
    smoothing term (``-frames_size_smoothing 0``: J = H + w H_s M, whose minimum the
    log-polar field is): (size, J/H_s, H/H_s, M, median |log(l/(c h))|) each."""
    from ufl_frames.bootstrap import options_scope

    rows = []
    for h in SIZES:
        field = FrameField.initial(build(COMM, "annulus", mesh_size=h),
                                   size=SizeTarget.expression("hypot(x, y)"))
        with options_scope([("frames_size_smoothing", "0")]):
            result = field.solve(max_it=200)
        assert result.converged_reason.startswith("CONVERGED"), result.converged_reason
        problem = field.problem
        scale = problem.energy_scale
        lengths, _ = ALGEBRA.q_to_frames(problem.rows[: problem.owned])
        x = field.q.function_space.tabulate_dof_coordinates()[: problem.owned]
        logs = np.log(lengths) - np.log(np.hypot(x[:, 0], x[:, 1]))[:, None]
        gathered = np.concatenate(COMM.allgather(logs.ravel()))
        spread = float(np.median(np.abs(gathered - np.median(gathered))))
        rows.append((h, problem.energy() / scale, problem.integrability_energy() / scale,
                     problem.size_misfit(), spread))
    if COMM.rank == 0:
        for row in rows:
            print("log-polar sized solve h=%g: J/Hs=%.3e H/Hs=%.3e M=%.3e |log(l/ch)|=%.2e"
                  % row)
    return rows


def test_log_polar_target_is_recovered_under_refinement(log_polar_solves):
    """J, H and M fall to 0 at rate ≈ 2 (three sizes); the frames' lengths are c·r."""
    misfits = [row[3] for row in log_polar_solves]
    energies = [row[1] for row in log_polar_solves]
    assert min(rates(misfits, SIZES)) > 1.7, (misfits, rates(misfits, SIZES))
    assert min(rates(energies, SIZES)) > 1.7, (energies, rates(energies, SIZES))
    assert misfits[-1] < 1e-3
    assert log_polar_solves[-1][4] < 0.01  # lengths within 1 % of c r (median)


def test_log_polar_sizes_are_kept_with_the_smoothing_term():
    """With the smoothing term (s = 0.1) J's minimum is no longer the log-polar
    field (its directions turn: Ŝ > 0, M stays about 0.01, measured), but the frames'
    lengths still follow h = r: within 1 % of c r (median; 0.2 % measured at h = 0.025,
    0.7 % at h = 0.1, the size used here) and H falls as without it."""
    field = FrameField.initial(build(COMM, "annulus", mesh_size=SIZES[0]),
                               size=SizeTarget.expression("hypot(x, y)"))
    from ufl_frames.bootstrap import options_scope
    from ufl_frames.mesh.sizes import SIZE_SMOOTHING

    with options_scope([("frames_size_smoothing", str(SIZE_SMOOTHING))]):
        result = field.solve(max_it=200)
    assert result.converged_reason.startswith("CONVERGED"), result.converged_reason
    problem = field.problem
    assert problem.size.smoothing_weight > 0
    lengths, _ = ALGEBRA.q_to_frames(problem.rows[: problem.owned])
    x = field.q.function_space.tabulate_dof_coordinates()[: problem.owned]
    logs = np.log(lengths) - np.log(np.hypot(x[:, 0], x[:, 1]))[:, None]
    gathered = np.concatenate(COMM.allgather(logs.ravel()))
    assert float(np.median(np.abs(gathered - np.median(gathered)))) < 0.01
    assert problem.integrability_energy() / problem.energy_scale < 5e-3


def near_bound_share(problem, bound=4.0):
    """The share of the vertices whose aspect l_max/l_min is within 10 % of ``bound``."""
    lengths, _ = ALGEBRA.q_to_frames(problem.rows[: problem.owned])
    near = np.count_nonzero(lengths.max(axis=1) / lengths.min(axis=1) > 0.9 * bound)
    return COMM.allreduce(int(near), op=MPI.SUM) / COMM.allreduce(problem.owned, op=MPI.SUM)


def test_uniform_target_keeps_the_piano_off_the_aspect_bound():
    """Without a size target the non-isotropic piano's minimiser presses on the aspect
    bound (the degenerate problem: 22 % of the vertices within 10 % of it at h = 0.1,
    measured); with the uniform target none is, and the misfit M of the sized solve is far
    below that of the unsized minimiser (5.98, measured)."""
    domain = build(COMM, "piano", mesh_size=0.1)
    plain = FrameField.initial(domain)
    plain.solve(max_it=300)
    sized = FrameField.initial(domain, size=SizeTarget.uniform())
    result = sized.solve(max_it=300)
    assert result.converged_reason.startswith("CONVERGED"), result.converged_reason
    assert near_bound_share(plain.problem) > 0.1
    assert near_bound_share(sized.problem) <= 0.05
    unsized_misfit = COMM.allreduce(fem.assemble_scalar(size_term(
        plain.q, SizeTarget.uniform(), plain.problem.area, 1.0, plain.constraints).misfit),
        op=MPI.SUM)
    assert sized.problem.size_misfit() < 0.1 * unsized_misfit


def test_size_target_needs_an_aspect_bound(annulus_mesh):
    V = energy.frame_space(annulus_mesh(0.2))
    q = energy.interpolate_frames(V, lambda x: (1.0, 1.0, 0.0))
    with pytest.raises(ValueError, match="aspect bound"):
        frame_problem(q, max_aspect=None, size=SizeTarget.uniform())


@pytest.mark.parametrize("options", [{"tao_type": "bntr"}, {"tao_type": "ntr"},
                                     {"frames_hessian": "exact"}])
def test_newton_models_with_the_size_term_agree(options):
    """The size term in every Newton model: the lean reduced matrix of the default ``nls``
    (Tᵀ G_M T by PtAP), the 5N pre-matrix of the bounded ``bntr``, ``ntr`` and the exact
    Hessian reach the same minimum of J on the sized piano."""
    from ufl_frames.bootstrap import options_scope

    domain = build(COMM, "piano", mesh_size=0.1)
    energies = []
    for extra in ({}, options):
        field = FrameField.initial(domain, size=SizeTarget.uniform())
        with options_scope(list({"frames_h_rtol": 0.0, **extra}.items())):
            result = field.solve(max_it=300)
        assert result.converged_reason.startswith("CONVERGED"), (extra, result.converged_reason)
        energies.append(field.problem.energy())
    assert energies[1] == pytest.approx(energies[0], rel=2e-3), energies


def test_smoothing_keeps_the_unpinned_sized_piano_from_forming_pairs():
    """The sized energy alone (no smoothing) is lowered by ±1/4 pairs: the unpinned sized
    piano at 3 925 triangles, solved from MBO's 2 singularities, ends with 8 (measured).
    The smoothing term (``-frames_size_smoothing``, ``SIZE_SMOOTHING``) charges each
    singularity ∝ log(1/h), and the same solve keeps MBO's 2."""
    from ufl_frames.bootstrap import options_scope
    from ufl_frames.mesh.sizes import SIZE_SMOOTHING

    domain = build(COMM, "piano", mesh_size=0.035)
    counts = {}
    for options in ([("frames_size_smoothing", "0")],
                    [("frames_size_smoothing", str(SIZE_SMOOTHING))]):
        field = FrameField.initial(domain, size=SizeTarget.uniform())
        assert len(field.singularities) == 2
        with options_scope(options):
            result = field.solve(pin_singularities=False, max_it=200)
        assert result.converged_reason.startswith("CONVERGED"), result.converged_reason
        smoothing = field.problem.size.relative_smoothing
        counts[smoothing] = sorted(s["index"] for s in field.singularities)
    assert set(counts) == {0.0, SIZE_SMOOTHING}
    assert len(counts[0.0]) > 2, counts
    assert counts[SIZE_SMOOTHING] == [-0.25, 0.25], counts


def test_smoothing_term_is_scale_free_and_refused_when_negative(annulus_mesh):
    """Ŝ = S ∫h²/ρ² (C S = w H_s s Ŝ) does not change when h or q is multiplied by a
    constant; s < 0 is one ValueError."""
    V = energy.frame_space(annulus_mesh(0.15))

    def f(x):
        r, phi = _polar(x)
        return 1 + 0.5 * r, 1.2 - 0.3 * r, phi + 0.4 * r**2

    values = []
    for scale, text in ((1.0, "0.2 + x*x"), (3.0, "0.2 + x*x"), (1.0, "7*(0.2 + x*x)")):
        q = energy.interpolate_frames(V, lambda x, scale=scale: tuple(
            v * scale if k < 2 else v for k, v in enumerate(f(x))))
        problem = frame_problem(q, pin_singularities=False, size_smoothing=0.5,
                                size=SizeTarget.expression(text))
        term = problem.size
        values.append(problem.size_smoothing() * term.smoothing_weight / term.weight)
    assert values[0] > 0
    assert values[1] == pytest.approx(values[0], rel=1e-10)
    assert values[2] == pytest.approx(values[0], rel=1e-10)
    q = energy.interpolate_frames(V, f)
    with pytest.raises(ValueError, match="smoothing"):
        frame_problem(q, pin_singularities=False, size_smoothing=-1.0,
                      size=SizeTarget.uniform())
