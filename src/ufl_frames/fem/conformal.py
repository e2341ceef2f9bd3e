r"""The integrable isotropic field of given directions: the conformal scale (beyond the note).

An isotropic frame field has one length l = e^{−φ} and the direction angle t of its
branches u = l (cos t, sin t), v = l (−sin t, cos t). Its map would have ∇U = u/|u|² =
e^{φ} (cos t, sin t) and ∇V = e^{φ} (−sin t, cos t); both are curl-free, [u, v] = 0, iff

    ∇φ = R ∇t,      R (a, b) = (−b, a)         (Cauchy–Riemann for φ + i t)

(the two curl conditions, expanded, are the two components of this equation). So for the
directions of a cross field the integrable isotropic field is *one linear solve*: φ, P1,
minimising ∫ |∇φ − R∇t|² — the Poisson problem

    ∫ ∇φ · ∇w dx = ∫ R∇t · ∇w dx   for all w,     ∫ φ = 0,

with its natural (Neumann) boundary condition ∂φ/∂n = (R∇t)·n = −∂t/∂s: on a boundary the
field follows, −κ, the condition for the boundary to be straight in (U, V). Around a
singularity of index k, t turns by 2πk and φ grows like −k ln r: the frame's length goes
to 0 or ∞ there like r^{±1/4}, the cone of a flat metric — which a P1 field of H, the
note's energy, cannot follow (the TAO isotropic solve stops at a large H), but which the
Poisson solve only needs as a right-hand side. The angle t is read from the Odeco
coefficients: C = q₃ + i q₄ ∝ e^{4it}, so ∇t = (q₃∇q₄ − q₄∇q₃) / (4 |C|²), written in UFL.

The linear solve is a PETSc KSP (prefix ``conformal_``: CG with GAMG by default, the
constants of every connected component removed as its null space); the result is the
isotropic field (l, l, t) at the vertices, scaled on each component to the lumped L² norm
of the input field there.
"""

from contextlib import ExitStack

from ufl_frames.bootstrap import init_petsc, petsc_defaults

init_petsc()

import dolfinx.fem as fem  # noqa: E402
import dolfinx.fem.petsc  # noqa: E402
import numpy as np  # noqa: E402
import ufl  # noqa: E402
from mpi4py import MPI  # noqa: E402
from petsc4py import PETSc  # noqa: E402

from ufl_frames.fem.components import dof_components  # noqa: E402
from ufl_frames.fem.constraints import lumped_mass  # noqa: E402
from ufl_frames.fem.energy import check_frame_function  # noqa: E402
from ufl_frames.frames2d.algebra import ALGEBRA  # noqa: E402

__all__ = ["conformal_field", "conformal_forms", "direction_gradient"]


def direction_gradient(q) -> ufl.core.expr.Expr:
    """∇t of the frame field q (UFL): (q₃∇q₄ − q₄∇q₃) / (4 (q₃² + q₄²))."""
    c, s = q[3], q[4]
    tiny = 1e-300 * (q[0] ** 2 + 1.0)  # |C| vanishes only at a singular point itself
    return (c * ufl.grad(s) - s * ufl.grad(c)) / (4 * (c**2 + s**2) + tiny)


def conformal_forms(q, S):
    """(a, L): the bilinear and linear forms of the conformal-scale Poisson problem on the
    scalar P1 space S, ∫ ∇φ·∇w and ∫ R∇t·∇w."""
    phi, w = ufl.TrialFunction(S), ufl.TestFunction(S)
    grad_t = direction_gradient(q)
    rotated = ufl.as_vector((-grad_t[1], grad_t[0]))
    return (ufl.inner(ufl.grad(phi), ufl.grad(w)) * ufl.dx,
            ufl.inner(rotated, ufl.grad(w)) * ufl.dx)


def conformal_field(q: fem.Function, options_prefix: str = "conformal_") -> fem.Function:
    """The isotropic frame field with q's directions and the conformal scale l = e^{−φ}
    (module docstring); scaled to q's lumped L² norm (collective)."""
    algebra = ALGEBRA  # 2D frames: the conformal scale is a planar construction
    check_frame_function(q, algebra=algebra)
    V = q.function_space
    mesh = V.mesh
    k = algebra.count
    S, to_blocked = V.sub(0).collapse()
    row_of = np.asarray(to_blocked, dtype=np.int64) // k
    a_ufl, L_ufl = conformal_forms(q, S)
    a, L = fem.form(a_ufl), fem.form(L_ufl)
    phi = fem.Function(S)
    with ExitStack() as owned:
        A = dolfinx.fem.petsc.assemble_matrix(a)
        owned.callback(A.destroy)
        A.assemble()
        b = dolfinx.fem.petsc.assemble_vector(L)
        owned.callback(b.destroy)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        count, component = dof_components(S)
        constants = []
        for c in range(count):  # one constant a component: disjoint, so orthogonal
            constant = A.createVecRight()
            owned.callback(constant.destroy)
            constant.array[:] = component[: constant.getLocalSize()] == c
            constant.normalize()
            constants.append(constant)
        nullspace = PETSc.NullSpace().create(vectors=constants, comm=mesh.comm)
        owned.callback(nullspace.destroy)
        A.setNullSpace(nullspace)
        nullspace.remove(b)
        ksp = PETSc.KSP().create(mesh.comm)
        owned.callback(ksp.destroy)
        ksp.setOptionsPrefix(options_prefix)
        ksp.setOperators(A)
        with petsc_defaults(options_prefix, {"ksp_type": "cg", "pc_type": "gamg",
                                             "ksp_rtol": 1e-10}):
            ksp.setFromOptions()
        ksp.solve(b, phi.x.petsc_vec)
        if ksp.getConvergedReason() < 0:
            raise RuntimeError(f"the conformal-scale solve failed (KSP reason "
                               f"{ksp.getConvergedReason()}); try other "
                               f"-{options_prefix}ksp_type / -{options_prefix}pc_type")
    phi.x.scatter_forward()
    rows = q.x.array.reshape(-1, k)
    _, angles = algebra.q_to_frames(rows)
    values = np.empty(rows.shape[0])
    values[row_of] = phi.x.array
    owned_rows = V.dofmap.index_map.size_local
    label = np.empty(rows.shape[0], dtype=np.int64)
    label[row_of] = component
    # φ is fixed up to a constant on each component, the length up to a factor: each
    # component is scaled to q's lumped L² norm on it (one component: the whole mesh)
    shift = _per_component(mesh.comm, values[:owned_rows], label[:owned_rows], count, MPI.MAX)
    length = np.exp(-(values - shift[label]))  # ≤ 1 before the normalisation: no overflow
    result = fem.Function(V, name="q")
    result.x.array[:] = algebra.frames_to_q(np.stack([length, length], axis=1),
                                            angles).ravel()
    result.x.scatter_forward()
    mass = lumped_mass(V)[:owned_rows]
    out_rows = result.x.array.reshape(-1, k)
    norm_in, norm_out = (
        _per_component(mesh.comm, mass * np.sum(r[:owned_rows] ** 2, axis=1),
                       label[:owned_rows], count, MPI.SUM)
        for r in (rows, out_rows))
    result.x.array[:] *= np.repeat(np.sqrt(norm_in / norm_out)[label], k)
    return result


def _per_component(comm, values: np.ndarray, label: np.ndarray, count: int, op) -> np.ndarray:
    """The maximum (``op`` MPI.MAX) or sum (MPI.SUM) of ``values`` on every component
    (``label``, ``count`` of them) over all ranks."""
    local = np.full(count, -np.inf if op == MPI.MAX else 0.0)
    (np.maximum if op == MPI.MAX else np.add).at(local, label, values)
    total = np.empty_like(local)
    comm.Allreduce(local, total, op=op)
    return total
