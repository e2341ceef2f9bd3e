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

from ufl_frames import geometry
from ufl_frames.fem import energy, kernels
from ufl_frames.pipeline import FrameField
from ufl_frames.solvers.hessian import sobolev_form

COMM = MPI.COMM_WORLD


def assembled(form):
    A = dolfinx.fem.petsc.create_matrix(form)
    dolfinx.fem.petsc.assemble_matrix(A, form)
    A.assemble()
    return A


@pytest.mark.parametrize("exact", [False, True], ids=["gauss_newton", "hessian"])
@pytest.mark.parametrize("shape, field", [("piano", "mbo"), ("annulus", "mbo"),
                                          ("piano", "arbitrary")])
def test_compiled_model_matrix_equals_the_ufl_form(shape, field, exact):
    """The same matrix to round-off, for a frame field (MBO's) and for arbitrary
    coefficients (the formulas hold for any q: no property of frames is used; there the
    residual r, which only the Hessian's second term sees, is large), with a damping that
    changes between assemblies (the Constants are read each time)."""
    domain = geometry.build(COMM, shape, mesh_size=0.1)
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
        scale = A.norm(PETSc.NormType.FROBENIUS)
        A.axpy(-1.0, B, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
        assert A.norm(PETSc.NormType.FROBENIUS) <= 1e-13 * scale
        A.destroy()
        B.destroy()


def test_kernel_source_comes_from_the_bracket_table():
    """Every nonzero entry of the bracket appears once in each of J's two coefficient
    arrays and once in the Hessian's second term, and nothing else does."""
    from ufl_frames.frames2d.bracket import BRACKET_ENTRIES

    lines = kernels.model_kernel_source().splitlines()

    def count(start, term):
        return sum(line.count(term) for line in lines if line.lstrip().startswith(start))

    assert count("a[", " * gq[") == len(BRACKET_ENTRIES)
    assert count("b[", " * qp[") == len(BRACKET_ENTRIES)
    assert count("{ const double s = weight * r[", "weight * r[") == len(BRACKET_ENTRIES)
