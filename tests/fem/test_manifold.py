"""The frame manifold 𝓜 as one object (:class:`ufl_frames.fem.manifold.FrameManifold`) and
the explicit evaluation the Newton model is built from (:meth:`FrameProblem.evaluation`).

Truth, independent of the code under test:

* R is a retraction: its points satisfy the variety equations (odeco.variety_residual),
  the boundary alignment and the norm; R(R(x)) = R(x); R(x + εd) = x + εd + O(ε²) for
  tangent d (first-order agreement, measured at two ε);
* the tangent basis is orthonormal where it has columns, and spans directions along
  which the variety residual grows only at second order;
* the Riemannian gradient is the derivative of H∘R: g·d = d/dε H(R(x + εd)) for tangent
  d (central differences), and g ⟂ x;
* the Newton model depends on the current q alone: assembled after evaluations at another
  point, it equals the model of a fresh problem at q.
"""

import dolfinx.fem.petsc  # noqa: F401
import numpy as np
import pytest
from mpi4py import MPI

from ufl_frames import solvers
from ufl_frames.fem import energy
from ufl_frames.frames2d import odeco
from ufl_frames.mesh import piano
from ufl_frames.solvers import mbo

COMM = MPI.COMM_WORLD


def perturbed_piano(max_aspect, prefix):
    """The non-isotropic piano at h = 0.2: the MBO field with lengths 1 + 2 sin²(3x) and 1
    (up to 3:1) and a smooth extra rotation, retracted with the bound ``max_aspect``."""
    domain = piano(COMM, mesh_size=0.2)
    q = mbo.mbo_frame_field(energy.frame_space(domain.mesh), options_prefix=prefix)
    p = q.function_space.tabulate_dof_coordinates()[:, :2]
    lengths = np.stack([1 + 2 * np.sin(3 * p[:, 0]) ** 2, np.ones(len(p))], axis=1)
    _, angles = odeco.q_to_frames(q.x.array.reshape(-1, 5))
    q.x.array[:] = odeco.frames_to_q(lengths, angles + 0.3 * np.sin(2 * p[:, 1])).ravel()
    problem = solvers.frame_problem(q, isotropic=False, max_aspect=max_aspect,
                                    pin_singularities=True)
    problem.retract()
    return problem


@pytest.fixture(scope="module")
def piano_problem():
    """No frame on the aspect bound (A = 4 > 3): 𝓜 is smooth there."""
    return perturbed_piano(4.0, "man_mbo_")


@pytest.fixture(scope="module")
def bounded_problem():
    """A = 2 < 3: about half the frames on the bound, an active set that the gradient
    decides."""
    return perturbed_piano(2.0, "man_bounded_mbo_")


def owned(problem, rows):
    return rows[: problem.owned]


def test_retraction_lands_on_the_manifold(piano_problem):
    problem = piano_problem
    manifold, rows = problem.manifold, problem.rows
    c = problem.constraints
    residual = np.abs(odeco.variety_residual(owned(problem, rows))).max()
    assert residual <= 1e-12 * np.abs(rows).max() ** 2
    _, t = odeco.q_to_frames(rows[c.fixed])
    normal_angle = np.arctan2(c.directions[:, 1], c.directions[:, 0])
    # aligned: the frame angle equals the normal's modulo 90°
    mismatch = np.abs(np.angle(np.exp(4j * (t - normal_angle))))
    assert mismatch.max(initial=0.0) <= 1e-9
    assert manifold.norm2(rows) == pytest.approx(manifold.radius2, rel=1e-13)
    lengths, _ = odeco.q_to_frames(owned(problem, rows))
    ratio = lengths.max(axis=1) / lengths.min(axis=1)
    assert ratio.max() <= 4.0 * (1 + 1e-9)
    assert np.allclose(manifold.retraction(rows), rows, rtol=0, atol=1e-12 * np.abs(rows).max())


def test_retraction_applies_the_aspect_bound(bounded_problem):
    lengths, _ = odeco.q_to_frames(owned(bounded_problem, bounded_problem.rows))
    ratio = lengths.max(axis=1) / lengths.min(axis=1)
    assert ratio.max() <= 2.0 * (1 + 1e-9)
    assert COMM.allreduce(int(np.sum(ratio > 2.0 * (1 - 1e-9))), op=MPI.SUM) > 10


def test_tangent_basis_is_orthonormal_and_tangent(piano_problem):
    problem = piano_problem
    manifold, rows = problem.manifold, problem.rows
    basis = manifold.tangent_basis(rows)
    gram = np.einsum("nia,nib->nab", basis, basis)
    present = np.linalg.norm(basis, axis=1) > 0  # (N, 3)
    expected = np.einsum("na,ab->nab", present.astype(float), np.eye(3))
    assert np.abs(gram - expected).max() <= 1e-12
    assert not present[problem.constraints.fixed, 2].any()  # orientation held
    # first order along every column: the residual of R-free steps is O(ε²)
    residual = []
    for eps in (1e-3, 5e-4):
        step = rows + eps * basis.sum(axis=2) * np.abs(rows).max()
        residual.append(np.abs(odeco.variety_residual(step)).max())
    assert residual[1] / residual[0] == pytest.approx(0.25, abs=0.03)


def test_retraction_agrees_to_first_order(piano_problem):
    problem = piano_problem
    manifold, rows = problem.manifold, problem.rows.copy()
    rng = np.random.default_rng([3, COMM.rank])
    d = manifold.projection(rows, rng.standard_normal(rows.shape))
    d -= (manifold.inner(manifold.to_x(d), manifold.to_x(rows))
          / manifold.norm2(rows)) * rows  # the sphere's tangent too
    scale = np.abs(rows).max()
    errors = [np.abs(manifold.retraction(rows, e * scale * d) - (rows + e * scale * d)).max()
              for e in (1e-3, 5e-4)]
    assert errors[1] / errors[0] == pytest.approx(0.25, abs=0.05)


def test_riemannian_gradient_is_the_derivative_of_H_on_the_manifold(piano_problem):
    problem = piano_problem
    x = dolfinx.fem.petsc.create_vector(problem.q.function_space)
    g = x.duplicate()
    try:
        problem.write_x(x)
        problem.riemannian_gradient(g)
        assert abs(g.dot(x)) <= 1e-12 * g.norm() * x.norm()
        d = g.copy()  # tangent by construction; also a random tangent one
        rng = np.random.default_rng([5, COMM.rank])
        rows = problem.manifold.projection(problem.rows,
                                                rng.standard_normal(problem.rows.shape))
        e = x.duplicate()
        e.getArray()[:] = owned(problem, rows).ravel()
        e.axpy(-e.dot(x) / x.dot(x), x)
        for direction in (d, e):
            direction.scale(1.0 / direction.norm())
            eps = 1e-5 * x.norm()
            values = []
            for sign in (1, -1):
                y = x.copy()
                y.axpy(sign * eps, direction)
                problem.set_from_x(y)
                values.append(problem.energy())
                y.destroy()
            fd = (values[0] - values[1]) / (2 * eps)
            assert g.dot(direction) == pytest.approx(fd, rel=1e-5)
        e.destroy()
        d.destroy()
    finally:
        problem.set_from_x(x)
        x.destroy()
        g.destroy()


def test_evaluation_is_cached_on_the_version_of_q(piano_problem):
    problem = piano_problem
    x = dolfinx.fem.petsc.create_vector(problem.q.function_space)
    try:
        problem.write_x(x)
        fresh = problem.evaluation()
        assert problem.evaluation() is not fresh  # not tracked: assembled every time
        with problem.tracking():
            problem.set_from_x(x)
            first = problem.evaluation()
            assert problem.evaluation() is first
            problem.set_from_x(x)  # same vector, same state: q untouched
            assert problem.evaluation() is first
            x.scale(1.01)  # another state: R(x) again, a new version of q
            problem.set_from_x(x)
            assert problem.evaluation() is not first
        assert first.energy == pytest.approx(fresh.energy, rel=1e-14)
    finally:
        x.destroy()


def test_newton_model_depends_on_the_current_q_only(bounded_problem):
    """Before: the active set and the sphere term came from whatever gradient was assembled
    last. Now a model assembled after evaluations elsewhere equals a fresh one at q."""
    problem = bounded_problem
    x = dolfinx.fem.petsc.create_vector(problem.q.function_space)
    other = x.duplicate()
    problem.write_x(x)
    q0 = problem.q.x.array.copy()
    with solvers.GaussNewtonModel(problem, x, exact=True) as reference:
        reference.assemble(gnorm=1.0)
        reference_matrix = reference.assembled.copy()
    try:
        # evaluate the gradient at another point, then return q to R(x) without evaluating
        other.getArray()[:] = x.getArray() * (1 + 0.2 * np.cos(np.arange(x.getLocalSize())))
        g = x.duplicate()
        problem.set_from_x(other)
        problem.riemannian_gradient(g)
        elsewhere = problem.evaluation().gradient_x
        problem.set_from_x(x)
        here = problem.evaluation().gradient_x
        # the test can fail: the gradient elsewhere gives q another active set
        manifold = problem.manifold
        changed = np.abs(manifold.tangent_basis(problem.rows, elsewhere)
                         - manifold.tangent_basis(problem.rows, here)).max()
        assert COMM.allreduce(changed, op=MPI.MAX) > 0.1
        assert np.allclose(problem.q.x.array, q0, rtol=0, atol=1e-14 * np.abs(q0).max())
        with solvers.GaussNewtonModel(problem, x, exact=True) as model:
            model.assemble(gnorm=1.0)
            difference = model.assembled.copy()
            difference.axpy(-1.0, reference_matrix)
            assert difference.norm() <= 1e-12 * reference_matrix.norm()
            difference.destroy()
        g.destroy()
    finally:
        reference_matrix.destroy()
        other.destroy()
        x.destroy()
