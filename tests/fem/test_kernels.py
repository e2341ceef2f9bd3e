"""The compiled kernels of the Newton model (:mod:`ufl_frames.fem.kernels`) against the UFL
forms they replace: ∫ J[δq]·J[w] dx (Gauss–Newton, :func:`energy.gauss_newton_form`) or
the second derivative of H (UFL's ``derivative`` of its first variation), plus
λ (∫ ∇δq:∇w dx + ∫ δq·w dx / A) (:func:`hessian.sobolev_form`), assembled by FFCx's kernels.

Truth: the UFL forms, an independent derivation (UFL differentiates the bracket of eq. (10);
the kernels write J and D²r out by hand from the bracket table). Serial and under MPI.
"""

import dolfinx.fem as fem
import dolfinx.fem.petsc
import numpy as np
import pytest
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from ufl_frames.fem import energy, kernels
from ufl_frames.frames2d.algebra import ALGEBRA
from ufl_frames.mesh import build
from ufl_frames.pipeline import FrameField
from ufl_frames.solvers.hessian import sobolev_form

COMM = MPI.COMM_WORLD


def assembled(form):
    A = dolfinx.fem.petsc.create_matrix(form)
    dolfinx.fem.petsc.assemble_matrix(A, form)
    A.assemble()
    return A


def assert_same_matrix(A, B, rtol=1e-13):
    """‖A − B‖_F ≤ rtol ‖A‖_F (A is overwritten by A − B)."""
    scale = A.norm(PETSc.NormType.FROBENIUS)
    A.axpy(-1.0, B, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
    assert A.norm(PETSc.NormType.FROBENIUS) <= rtol * scale


@pytest.mark.parametrize("exact", [False, True], ids=["gauss_newton", "hessian"])
@pytest.mark.parametrize("shape, field", [("piano", "mbo"), ("annulus", "mbo"),
                                          ("piano", "arbitrary")])
def test_compiled_model_matrix_equals_the_ufl_form(shape, field, exact):
    """The same matrix to round-off, for a frame field (MBO's) and for arbitrary
    coefficients (the formulas hold for any q: no property of frames is used; there the
    residual r, which only the Hessian's second term sees, is large), with a damping that
    changes between assemblies (the Constants are read each time)."""
    domain = build(COMM, shape, mesh_size=0.1)
    q = FrameField.initial(domain).q
    if field == "arbitrary":
        x = q.function_space.tabulate_dof_coordinates()
        rng = np.random.default_rng(7)
        q.x.array[:] = (np.sin(3.0 * x[:, :1] + rng.standard_normal((1, 5)))
                        * np.cos(2.0 * x[:, 1:2])).ravel()[: q.x.array.size]
    V = q.function_space
    area = 1.7
    damping = fem.Constant(V.mesh, PETSc.ScalarType(0.0))
    inverse_area = fem.Constant(V.mesh, PETSc.ScalarType(1.0 / area))
    if exact:
        H = energy.integrability_energy_form(q)
        model = ufl.derivative(energy.gradient_form(H, q), q, ufl.TrialFunction(V))
        compiled = kernels.damped_hessian_form(q, damping, inverse_area)
    else:
        model = energy.gauss_newton_form(q)
        compiled = kernels.damped_gauss_newton_form(q, damping, inverse_area)
    reference = fem.form(model + damping * sobolev_form(V, area))
    for value in (0.0, 0.37):
        damping.value = value
        A, B = assembled(reference), assembled(compiled)
        assert_same_matrix(A, B)
        A.destroy()
        B.destroy()


def test_kernel_source_comes_from_the_bracket_table():
    """Every nonzero entry of the bracket appears once in each of J's two coefficient
    arrays of each of the two functions that form J (the 15 × 15 model and the reduced
    Gauss–Newton kernel) and once in the Hessian's second term, and nothing else does."""
    from ufl_frames.frames2d.bracket import BRACKET_ENTRIES

    lines = kernels.model_kernel_source().splitlines()

    def count(start, term):
        return sum(line.count(term) for line in lines if line.lstrip().startswith(start))

    assert count("a[", " * gq[") == 2 * len(BRACKET_ENTRIES)
    assert count("b[", " * qp[") == 2 * len(BRACKET_ENTRIES)
    assert count("{ const double s = weight * r[", "weight * r[") == len(BRACKET_ENTRIES)


def _block_columns(blocks, V):
    """The owned (n, 5, c) blocks as a PETSc matrix with 5 rows and c columns a vertex."""
    from ufl_frames.solvers.hessian import _block_diagonal

    return _block_diagonal(blocks, V.dofmap.index_map, V.mesh.comm)


@pytest.mark.parametrize("exact", [False, True], ids=["gauss_newton", "hessian"])
@pytest.mark.parametrize("columns", [3, 2])
def test_reduced_model_matrix_equals_the_product_with_the_basis(columns, exact):
    """Tᵀ A T assembled with the reduced kernel equals PETSc's product Pᵀ A P of the 5N
    matrix (itself tested against UFL above) with a block-diagonal T: arbitrary 5 × c
    blocks a vertex, a zero column at some vertices (an absent direction), in parallel
    with the ghost vertices' blocks from their owners."""
    domain = build(COMM, "piano", mesh_size=0.1)
    q = FrameField.initial(domain).q
    V, mesh = q.function_space, q.function_space.mesh
    n = V.dofmap.index_map.size_local
    damping = fem.Constant(mesh, PETSc.ScalarType(0.37))
    inverse_area = fem.Constant(mesh, PETSc.ScalarType(0.6))
    global_vertex = V.dofmap.index_map.local_to_global(np.arange(n, dtype=np.int32))
    blocks = np.sin(np.arange(5 * columns)[None, :] + 0.7 * global_vertex[:, None]).reshape(
        n, 5, columns)
    blocks[global_vertex % 7 == 0, :, -1] = 0.0
    basis = fem.Function(fem.functionspace(mesh, ("Lagrange", 1, (5 * columns,))))
    basis.x.array.reshape(-1, 5, columns)[:n] = blocks
    basis.x.scatter_forward()
    space = fem.functionspace(mesh, ("Lagrange", 1, (columns,)))
    reduced = assembled(kernels.reduced_model_form(q, basis, space, damping, inverse_area,
                                                   exact))
    make = kernels.damped_hessian_form if exact else kernels.damped_gauss_newton_form
    full = assembled(make(q, damping, inverse_area))
    T = _block_columns(blocks, V)
    product = full.PtAP(T)
    assert_same_matrix(product, reduced)
    for matrix in (reduced, full, T, product):
        matrix.destroy()


@pytest.mark.parametrize("exact", [False, True], ids=["gauss_newton", "hessian"])
def test_model_action_equals_the_matrix_product(exact):
    """The vector of :func:`kernels.model_action_form` equals the 5N matrix times the
    field, on an arbitrary direction, serial and in parallel (ghost sums added)."""
    domain = build(COMM, "annulus", mesh_size=0.1)
    q = FrameField.initial(domain).q
    V, mesh = q.function_space, q.function_space.mesh
    damping = fem.Constant(mesh, PETSc.ScalarType(0.2))
    inverse_area = fem.Constant(mesh, PETSc.ScalarType(1.3))
    direction = fem.Function(V)
    x = V.tabulate_dof_coordinates()
    direction.x.array[:] = np.cos(np.arange(5)[None, :] + 4.0 * x[:, :1] * x[:, 1:2]).ravel()
    form = kernels.model_action_form(q, direction, damping, inverse_area, exact)
    b = dolfinx.fem.petsc.assemble_vector(form)
    b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    make = kernels.damped_hessian_form if exact else kernels.damped_gauss_newton_form
    A = assembled(make(q, damping, inverse_area))
    reference = A.createVecLeft()
    A.mult(direction.x.petsc_vec, reference)
    scale = reference.norm()
    reference.axpy(-1.0, b)
    assert reference.norm() <= 1e-13 * scale
    for obj in (b, A, reference):
        obj.destroy()


def test_reduced_form_rejects_a_basis_of_the_wrong_shape():
    domain = build(COMM, "annulus", mesh_size=0.2)
    q = FrameField.initial(domain).q
    mesh = q.function_space.mesh
    constant = fem.Constant(mesh, PETSc.ScalarType(1.0))
    basis = fem.Function(fem.functionspace(mesh, ("Lagrange", 1, (12,))))
    space = fem.functionspace(mesh, ("Lagrange", 1, (3,)))
    with pytest.raises(ValueError, match="tangent basis"):
        kernels.reduced_model_form(q, basis, space, constant, constant)


@pytest.mark.parametrize("exact", [False, True], ids=["gauss_newton", "hessian"])
def test_kernels_of_another_algebra_equal_its_ufl_forms(exact):
    """The C template takes its sizes from the algebra: with 7 coefficients a vertex and a
    residual of 4 components (an arbitrary table) the kernels still give the matrices of
    the UFL forms of that algebra, serial and in parallel."""
    import dataclasses
    import itertools

    import dolfinx.mesh

    from ufl_frames.frames2d.algebra import ALGEBRA

    rng = np.random.default_rng(5)
    entries = tuple((index, float(rng.uniform(-1, 1))) for index in
                    itertools.product(range(4), range(7), range(2), range(7))
                    if rng.random() < 0.2)
    algebra = dataclasses.replace(ALGEBRA, count=7, bracket_components=4,
                                  bracket_entries=entries)
    mesh = dolfinx.mesh.create_unit_square(COMM, 6, 5)
    V = energy.frame_space(mesh, algebra)
    q = fem.Function(V)
    x = V.tabulate_dof_coordinates()
    q.x.array[:] = np.cos(np.arange(7)[None, :] + 3 * x[:, :1] - 2 * x[:, 1:2] ** 2).ravel()
    damping = fem.Constant(mesh, PETSc.ScalarType(0.37))
    inverse_area = fem.Constant(mesh, PETSc.ScalarType(1.0))
    if exact:
        H = energy.integrability_energy_form(q, algebra)
        ufl_form = ufl.derivative(energy.gradient_form(H, q), q, ufl.TrialFunction(V))
        compiled = kernels.damped_hessian_form(q, damping, inverse_area, algebra=algebra)
    else:
        ufl_form = energy.gauss_newton_form(q, algebra)
        compiled = kernels.damped_gauss_newton_form(q, damping, inverse_area, algebra=algebra)
    A = assembled(fem.form(ufl_form + damping * sobolev_form(V, 1.0)))
    B = assembled(compiled)
    assert_same_matrix(A, B)
    A.destroy()
    B.destroy()


# --- the size misfit's matrix (kernels.size_model_form and the sized kernels) -----------


def _sized_problem(mesh_size=0.15, smoothing=0.0):
    """A sized problem on a coarse annulus: a non-isotropic field whose lengths, ratio and
    angle vary (q1, q2 ≠ 0: β and every term of σ's derivatives count) and a graded
    target (the residual ∇(σ − log h) is not small), with the kernels' size term (and its
    smoothing term of relative weight ``smoothing``)."""
    from ufl_frames.fem.problem import frame_problem
    from ufl_frames.mesh.sizes import SizeTarget

    domain = build(COMM, "annulus", mesh_size=mesh_size)
    V = energy.frame_space(domain.mesh)

    def f(x):
        r = np.hypot(x[0], x[1])
        phi = np.arctan2(x[1], x[0])
        return 1 + 0.5 * r * np.cos(phi), 1.2 - 0.3 * r, phi + 0.4 * r**2

    q = energy.interpolate_frames(V, f)
    problem = frame_problem(q, pin_singularities=False,
                            size=SizeTarget.expression("0.6 + x*x + 0.5*y"),
                            size_smoothing=smoothing)
    size = problem.size
    mode = fem.Constant(V.mesh, PETSc.ScalarType(kernels.SIZE_GAUSS_NEWTON))
    return q, size, kernels.SizeKernel(size.log_h, size.coefficient, size.inverse_area, mode,
                                       size.smoothing)


@pytest.mark.parametrize("smoothing", [0.0, 0.7], ids=["misfit", "smoothed"])
@pytest.mark.parametrize("exact", [False, True], ids=["gauss_newton", "hessian"])
def test_compiled_size_matrix_equals_the_ufl_form(exact, smoothing):
    """w H_s times the size misfit's Gauss–Newton form and its second derivative (UFL:
    ``energy.size_gauss_newton_form``, the derivative of ``energy.size_misfit_form``
    twice) to round-off, serial and in parallel; the mode is a Constant, read at every
    assembly. With a smoothing term, its matrix C ∫ ∇δq:∇w/h² (the kernel's h from
    log h at the vertices, UFL's a DG0 function) is added in both."""
    q, size, kernel = _sized_problem(smoothing=smoothing)
    assert (size.smoothing is not None) == (smoothing > 0)
    reference = assembled(fem.form(size.hessian_ufl(q, exact)))
    compiled = kernels.size_model_form(q, kernel)
    kernel.mode.value = kernels.SIZE_EXACT if exact else kernels.SIZE_GAUSS_NEWTON
    B = assembled(compiled)
    assert_same_matrix(reference, B)
    reference.destroy()
    B.destroy()


@pytest.mark.serial
def test_modified_size_matrix_is_positive_semidefinite_and_above_the_exact_one():
    """The modification (:data:`kernels.SIZE_MODIFIED`) is positive semidefinite where
    the exact second derivative is not (dense eigenvalues), lies above it (their
    difference is positive semidefinite) and changes nothing that is not the residual's
    curvature: it agrees with the exact matrix on a field and target with no residual
    (the misfit's minimiser: isotropic frames of size ∝ h, h uniform, e = 0 and β = 0)."""
    q, size, kernel = _sized_problem()
    form = kernels.size_model_form(q, kernel)

    def dense(mode):
        kernel.mode.value = mode
        A = assembled(form)
        try:
            return A.convert("dense").getDenseArray().copy()
        finally:
            A.destroy()

    exact, modified = dense(kernels.SIZE_EXACT), dense(kernels.SIZE_MODIFIED)
    scale = np.abs(exact).max()
    assert np.linalg.eigvalsh(exact).min() < -1e-3 * scale  # the case the change is for
    assert np.linalg.eigvalsh(modified).min() >= -1e-12 * scale
    assert np.linalg.eigvalsh(modified - exact).min() >= -1e-12 * scale
    assert np.abs(modified - modified.T).max() <= 1e-14 * scale
    # no residual: a uniform isotropic field and a uniform target (log h constant)
    q.x.array.reshape(-1, 5)[:] = ALGEBRA.frames_to_q(
        np.ones((q.x.array.size // 5, 2)), np.zeros(q.x.array.size // 5))
    size.log_h.x.array[:] = 0.3
    exact, modified = dense(kernels.SIZE_EXACT), dense(kernels.SIZE_MODIFIED)
    assert np.abs(modified - exact).max() <= 1e-13 * np.abs(exact).max()


@pytest.mark.parametrize("mode", [0, 1, 2], ids=["gauss_newton", "exact", "modified"])
def test_sized_reduced_kernel_equals_the_product_of_the_sum(mode):
    """The reduced kernel with the size term (one matrix for J = H + w H_s M) equals
    Pᵀ (A_H + A_M) P, A_H the 5N model matrix and A_M the size term's compiled matrix
    (the latter tested against UFL above), in parallel too; and the sized action kernel
    equals (A_H + A_M) d."""
    q, size, kernel = _sized_problem()
    kernel.mode.value = mode
    exact = mode != kernels.SIZE_GAUSS_NEWTON
    V, mesh = q.function_space, q.function_space.mesh
    n, columns = V.dofmap.index_map.size_local, 3
    damping = fem.Constant(mesh, PETSc.ScalarType(0.37))
    inverse_area = fem.Constant(mesh, PETSc.ScalarType(0.6))
    global_vertex = V.dofmap.index_map.local_to_global(np.arange(n, dtype=np.int32))
    blocks = np.sin(np.arange(5 * columns)[None, :] + 0.7 * global_vertex[:, None]).reshape(
        n, 5, columns)
    basis = fem.Function(fem.functionspace(mesh, ("Lagrange", 1, (5 * columns,))))
    basis.x.array.reshape(-1, 5, columns)[:n] = blocks
    basis.x.scatter_forward()
    space = fem.functionspace(mesh, ("Lagrange", 1, (columns,)))
    reduced = assembled(kernels.reduced_model_form(q, basis, space, damping, inverse_area,
                                                   exact, size=kernel))
    make = kernels.damped_hessian_form if exact else kernels.damped_gauss_newton_form
    full = assembled(make(q, damping, inverse_area))
    misfit = assembled(kernels.size_model_form(q, kernel))
    full.axpy(1.0, misfit, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
    T = _block_columns(blocks, V)
    product = full.PtAP(T)
    assert_same_matrix(product, reduced)
    direction = fem.Function(V)
    x = V.tabulate_dof_coordinates()
    direction.x.array[:] = np.cos(np.arange(5)[None, :] + 4.0 * x[:, :1] * x[:, 1:2]).ravel()
    b = dolfinx.fem.petsc.assemble_vector(
        kernels.model_action_form(q, direction, damping, inverse_area, exact, size=kernel))
    b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    reference = full.createVecLeft()
    full.mult(direction.x.petsc_vec, reference)
    scale = reference.norm()
    reference.axpy(-1.0, b)
    assert reference.norm() <= 1e-13 * scale
    for obj in (reduced, full, misfit, T, product, b, reference):
        obj.destroy()
