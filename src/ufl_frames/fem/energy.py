r"""UFL forms of the integrability and Dirichlet energies on P1 frame fields (note §3).

The frame field is q ∈ [P1]⁵: the Odeco coefficients (see :mod:`ufl_frames.frames2d.odeco`) at
the vertices, interpolated linearly in each triangle; the number of coefficients, the
dimension and the bracket's table are the frame algebra's
(:data:`ufl_frames.frames2d.algebra.ALGEBRA` unless one is given). With the Lie bracket of
eq. (10)

.. math::  [u, v]_i = C_{ijkl}\, q_l\, \partial_k q_j

the energies are

.. math::  H(q) = \tfrac12 \int_\Omega |[u, v]|^2 \,dx \quad\text{(eq. 11)}, \qquad
           E(q) = \tfrac12 \int_\Omega |\nabla q|^2 \,dx .

Their first variations come from :func:`ufl.derivative`; DOLFINx assembles them into
PETSc vectors. The integrand of H is a polynomial of degree 2 on each triangle, so
the quadrature is exact: the only discretisation error is the P1 interpolation of q.
"""

from ufl_frames.bootstrap import init_petsc

init_petsc()

import dolfinx.fem as fem  # noqa: E402
import numpy as np  # noqa: E402
import ufl  # noqa: E402
from mpi4py import MPI  # noqa: E402

from ufl_frames.frames2d.algebra import ALGEBRA  # noqa: E402


def check_frame_mesh(mesh, algebra=ALGEBRA) -> None:
    """Raise ValueError unless ``mesh`` is a mesh of straight (affine) cells of the frame
    ``algebra`` (2D: a planar mesh of triangles)."""
    import dolfinx.mesh

    dim, cell = algebra.dim, algebra.cell
    if mesh.topology.dim != dim or mesh.geometry.dim != dim:
        space = "a planar 2D mesh" if dim == 2 else f"a {dim}D mesh"
        raise ValueError(
            f"frame fields need {space}, got topological dimension "
            f"{mesh.topology.dim} in {mesh.geometry.dim}D"
        )
    if mesh.topology.cell_type != getattr(dolfinx.mesh.CellType, cell):
        raise ValueError(f"frame fields need {cell}s, got {mesh.topology.cell_type.name}")
    if mesh.geometry.cmaps[0].degree != 1:
        raise ValueError(f"frame fields need straight {cell}s (geometry degree 1), got "
                         f"degree {mesh.geometry.cmaps[0].degree}")


def check_frame_function(q, what: str = "q", algebra=ALGEBRA) -> None:
    """Raise ValueError unless ``q`` is a continuous P1 field of the frame ``algebra``'s
    coefficients (5 in 2D) on a mesh that :func:`check_frame_mesh` accepts (what every
    form here assumes).

    Args:
        q: the field to check.
        what: its name in the message.
        algebra: the frame algebra (default: 2D frames).

    Raises:
        ValueError: ``q`` is not a DOLFINx Function, its mesh is not one of straight
            simplices, or its space is not continuous P1 with ``algebra.count`` components.
    """
    if not isinstance(q, fem.Function):
        raise ValueError(f"{what} must be a dolfinx Function, got {type(q).__name__}")
    V = q.function_space
    check_frame_mesh(V.mesh, algebra)
    element = V.ufl_element()
    shape, degree = tuple(V.value_shape), element.embedded_superdegree
    discontinuous = getattr(element, "discontinuous", False)
    if shape != (algebra.count,) or degree != 1 or discontinuous:
        raise ValueError(
            f"{what} must be a continuous P1 function with {algebra.count} "
            f"components (see frame_space), got value shape {shape}, degree {degree}"
            + (", discontinuous" if discontinuous else ""))


def frame_space(mesh, algebra=ALGEBRA) -> fem.FunctionSpace:
    """The P1 space of frame fields: the frame ``algebra``'s coefficients per vertex (5 in
    2D, straight triangles)."""
    check_frame_mesh(mesh, algebra)
    return fem.functionspace(mesh, ("Lagrange", 1, (algebra.count,)))


def interpolate_frames(V, f, name: str = "q") -> fem.Function:
    """The Function of Odeco coefficients of the 2D frames ``f(x) -> (l1, l2, angle)``.

    ``x`` has shape (3, M) (points of the vertices); the frame at each vertex is
    encoded exactly (note eqs. 1–2), so q lies on the Odeco variety at every vertex.

    Args:
        V: the P1 frame space (:func:`frame_space`).
        f: called with the dof coordinates ``x`` (3, M); returns the lengths ``l1``,
            ``l2`` and the ``angle`` of the first branch, each (M,) or broadcastable to it.
        name: the Function's name.

    Returns:
        A new Function on ``V``.
    """
    q = fem.Function(V, name=name)
    x = V.tabulate_dof_coordinates().T
    l1, l2, angle = (np.broadcast_to(np.asarray(a, dtype=np.float64), x.shape[1:]) for a in f(x))
    q.x.array[:] = ALGEBRA.frames_to_q(np.stack([l1, l2], axis=1), angle).ravel()
    return q


def lie_bracket(q, algebra=ALGEBRA) -> ufl.core.expr.Expr:
    """[u, v] as a UFL vector expression (note eq. 10), r_i = C_ijkl q_l ∂_k q_j with the
    frame ``algebra``'s table; ``q`` a frame field (checked)."""
    check_frame_function(q, algebra=algebra)
    grad_q = ufl.grad(q)
    entries = algebra.bracket_entries
    components = []
    for i in range(algebra.bracket_components):
        terms = [c * q[l] * grad_q[j, k] for (ii, j, k, l), c in entries if ii == i]
        components.append(sum(terms[1:], terms[0]))
    return ufl.as_vector(components)


def integrability_energy_form(q, algebra=ALGEBRA) -> ufl.Form:
    """H(q) = ½ ∫ |[u, v]|² dx (note eq. 11) as a UFL form."""
    bracket = lie_bracket(q, algebra)
    return 0.5 * ufl.inner(bracket, bracket) * ufl.dx


def dirichlet_energy_form(q) -> ufl.Form:
    """E(q) = ½ ∫ |∇q|² dx as a UFL form."""
    return 0.5 * ufl.inner(ufl.grad(q), ufl.grad(q)) * ufl.dx


def gradient_form(energy: ufl.Form, q) -> ufl.Form:
    """First variation dE(q)[w] of an energy, w the test function (for assembly into a Vec)."""
    return ufl.derivative(energy, q, ufl.TestFunction(q.function_space))


def gauss_newton_form(q, algebra=ALGEBRA) -> ufl.Form:
    r"""Gauss–Newton bilinear form ∫ D[u,v](q)[w] · D[u,v](q)[δq] dx of H (J^T J)."""
    V = q.function_space
    bracket = lie_bracket(q, algebra)
    w, dq = ufl.TestFunction(V), ufl.TrialFunction(V)
    return ufl.inner(ufl.derivative(bracket, q, dq), ufl.derivative(bracket, q, w)) * ufl.dx


#: s = l1 + l2 of a frame from its first coefficient, q0 = 3√2 s/8.
_SUM_PER_Q0 = 8.0 / (3.0 * np.sqrt(2.0))
#: The quadrature degree of the size misfit's forms (not polynomial in q: UFL's estimate of
#: a logarithm's degree is arbitrary).
SIZE_QUADRATURE_DEGREE = 2


def log_size(q) -> ufl.core.expr.Expr:
    r"""σ(q) = ½ log(l1 l2), the log of a frame's size, in q's coefficients: with
    s = l1 + l2 = 8 q0/(3√2) and d² = (l1 − l2)² = 4 (q1² + q2²), l1 l2 = (s² − d²)/4.
    A polynomial of q inside the logarithm: smooth at isotropic frames (d = 0), where the
    lengths l1, l2 themselves (read from |B| = d/2) are not."""
    s = _SUM_PER_Q0 * q[0]
    return 0.5 * ufl.ln((s * s - 4.0 * (q[1] * q[1] + q[2] * q[2])) / 4.0)


def anisotropy(q) -> ufl.core.expr.Expr:
    r"""β(q) = 2 (q1, q2)/s, of length |β| = (l1 − l2)/(l1 + l2) = tanh(½ log(l1/l2)): the
    frame's anisotropy as a vector (its direction is the frame's 2t), smooth where |β| is
    not."""
    s = _SUM_PER_Q0 * q[0]
    return ufl.as_vector([2.0 * q[1] / s, 2.0 * q[2] / s])


def size_misfit_form(q, log_h, inverse_area) -> ufl.Form:
    r"""M(q) = ½ ∫ |∇(σ(q) − log h)|² dx + ½ (1/A) ∫ |β(q)|² dx: how far the frames'
    sizes are from the target h, as a UFL form.

    The first term compares the log of the frame's size √(l1 l2) with log h through their
    gradients: it is zero exactly when l1 l2 = c² h² for one constant c, so it asks for the
    sizes of h up to the global factor that the map's scale (or a number of quads) sets
    afterwards, and it does not fight the normalisation of the frame manifold (it is
    homogeneous of degree 0 in q: dM(q)[q] = 0). The second asks for square quads: |β|² is
    ((l1 − l2)/(l1 + l2))², averaged over the area A. Both are dimensionless (invariant
    under x → s x) and free of the mesh. An integrable isotropic field of size ∝ h (log h
    harmonic, the directions turning as conformality says) has M = 0.

    Args:
        q: the frame field (its frames must have l1 l2 > 0: a finite aspect bound).
        log_h: log h, a scalar Function (P1) or expression.
        inverse_area: 1/A (a Constant or a number).
    """
    metadata = {"quadrature_degree": SIZE_QUADRATURE_DEGREE}
    misfit = ufl.grad(log_size(q) - log_h)
    beta = anisotropy(q)
    return (0.5 * ufl.inner(misfit, misfit) + 0.5 * inverse_area * ufl.inner(beta, beta)) \
        * ufl.dx(metadata=metadata)


def size_gauss_newton_form(q, log_h, inverse_area) -> ufl.Form:
    r"""The Gauss–Newton form of M (:func:`size_misfit_form`): ∫ ∇Dσ[δq]·∇Dσ[w] dx +
    (1/A) ∫ Dβ[δq]·Dβ[w] dx, w the test and δq the trial function."""
    V = q.function_space
    w, dq = ufl.TestFunction(V), ufl.TrialFunction(V)
    metadata = {"quadrature_degree": SIZE_QUADRATURE_DEGREE}
    grad_sigma = ufl.grad(log_size(q))
    beta = anisotropy(q)
    return (ufl.inner(ufl.derivative(grad_sigma, q, dq), ufl.derivative(grad_sigma, q, w))
            + inverse_area * ufl.inner(ufl.derivative(beta, q, dq), ufl.derivative(beta, q, w))
            ) * ufl.dx(metadata=metadata)


def size_smoothing_form(q, inverse_h2) -> ufl.Form:
    r"""S(q) = ½ ∫ |∇q|² / h² dx: the Dirichlet energy of q in the metric of the size target,
    as a UFL form (``inverse_h2`` = 1/h², a cell-wise constant: DG0).

    The sized energy's smoothing term (:func:`ufl_frames.fem.problem.size_term`): a
    singularity of q costs it ∝ log(R/r₀), r₀ the core (the mesh size), as in
    Ginzburg–Landau, where H and the misfit M (:func:`size_misfit_form`) are finite for
    a field with a ± pair. Dividing by h² makes it scale-free once multiplied by ∫ h²/ρ²
    (see ``size_term``). Quadratic in q: its second derivative is constant."""
    return 0.5 * inverse_h2 * ufl.inner(ufl.grad(q), ufl.grad(q)) * ufl.dx


def size_smoothing_hessian_form(q, inverse_h2) -> ufl.Form:
    """The (constant) second derivative of :func:`size_smoothing_form`:
    ∫ ∇δq:∇w / h² dx, w the test and δq the trial function."""
    V = q.function_space
    w, dq = ufl.TestFunction(V), ufl.TrialFunction(V)
    return inverse_h2 * ufl.inner(ufl.grad(dq), ufl.grad(w)) * ufl.dx


def size_hessian_form(q, log_h, inverse_area) -> ufl.Form:
    """The second derivative of M (:func:`size_misfit_form`) as a bilinear form."""
    V = q.function_space
    M = size_misfit_form(q, log_h, inverse_area)
    return ufl.derivative(ufl.derivative(M, q, ufl.TestFunction(V)), q, ufl.TrialFunction(V))


def assemble_energy(form) -> float:
    """Assemble a scalar form (UFL or compiled) over all ranks (collective)."""
    compiled = form if isinstance(form, fem.Form) else fem.form(form)
    mesh = compiled.mesh
    return mesh.comm.allreduce(fem.assemble_scalar(compiled), op=MPI.SUM)


def integrability_energy(q, algebra=ALGEBRA) -> float:
    """H(q) (note eq. 11) of a frame Function q, collective over MPI."""
    return assemble_energy(integrability_energy_form(q, algebra))


def dirichlet_energy(q) -> float:
    """E(q) = ½ ∫ |∇q|² dx of a frame Function q, collective over MPI."""
    return assemble_energy(dirichlet_energy_form(q))


def bracket_rms(q: fem.Function) -> fem.Function:
    r"""Cell-wise RMS of the Lie bracket, :math:`\sqrt{|K|^{-1}\int_K |[u,v]|^2\,dx}`, in DG0.

    The L² projection of :math:`|[u,v]|^2` onto piecewise constants, then the square
    root: :math:`\tfrac12\sum_K |K|\,b_K^2 = H(q)` exactly, so the picture shows where
    the integrability energy sits. (On each cell [u,v] is linear in x; a value at
    one point, e.g. ``fem.Expression`` at the centroid, would miss part of it.)
    """
    check_frame_function(q)
    mesh = q.function_space.mesh
    D0 = fem.functionspace(mesh, ("DG", 0))
    w = ufl.TestFunction(D0)
    bracket = lie_bracket(q)
    density = fem.assemble_vector(fem.form(ufl.inner(bracket, bracket) * w * ufl.dx))
    volume = fem.assemble_vector(fem.form(w * ufl.dx))
    owned = D0.dofmap.index_map.size_local
    out = fem.Function(D0, name="bracket_rms")
    out.x.array[:owned] = np.sqrt(
        np.maximum(density.array[:owned], 0.0) / volume.array[:owned]
    )
    out.x.scatter_forward()
    return out

