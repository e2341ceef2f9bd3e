r"""Smooth boundary-aligned initial frame field by an MBO scheme (note §3, "Initial condition").

Merriman–Bence–Osher threshold dynamics for frame fields, as in the note's
reference [6]: alternate

1. implicit diffusion for a time τ:  (M + τK) q = M q_prev  (M mass, K stiffness
   matrix of the P1 space, all five components), with q fixed on the boundary to
   unit frames aligned with the boundary normal;
2. pointwise projection onto the unit isotropic Odeco frames (l1 = l2 = 1).

Diffusion over a time τ smooths on the length scale √τ; projecting after it keeps
the field a frame field. The schedule starts at √τ₀ = diameter/4, where the first
solve is close to the harmonic extension of the boundary frames, and divides √τ
by 2 at each level until √τ = h (mean edge length), with ``sweeps`` diffuse–project
iterations per level. The result is the usual smooth cross field whose singularities
sit where the geometry forces them.

The linear solves use a PETSc KSP with options prefix ``mbo_`` (``-mbo_ksp_type``,
``-mbo_pc_type``, ...; default CG with GAMG), and work in parallel.
"""

import math
from contextlib import ExitStack

from ufl_frames.bootstrap import init_petsc, petsc_defaults

init_petsc()

import dolfinx  # noqa: E402
import dolfinx.fem as fem  # noqa: E402
import dolfinx.fem.petsc  # noqa: E402, F401
import numpy as np  # noqa: E402
import ufl  # noqa: E402
from mpi4py import MPI  # noqa: E402
from petsc4py import PETSc  # noqa: E402

from ufl_frames.fem.constraints import FrameConstraints, frame_constraints  # noqa: E402
from ufl_frames.fem.scales import length_scales  # noqa: E402


def diffusion_schedule(mesh, levels: int | None = None) -> list[float]:
    """Diffusion times τ: √τ from diameter/4 halving down to the mean edge length h."""
    diameter, h = length_scales(mesh)
    if levels is None:
        levels = max(1, math.ceil(math.log2(diameter / 4 / h)) + 1)
    return [(diameter / 4 / 2**k) ** 2 for k in range(levels)]


def mbo_frame_field(
    V,
    constraints: FrameConstraints | None = None,
    sweeps: int = 2,
    levels: int | None = None,
    options_prefix: str = "mbo_",
    monitor=None,
) -> fem.Function:
    """Smooth unit isotropic frame field on ``V``, aligned with the boundary (MBO).

    ``monitor(level, tau, change)`` is called after each level when given (change:
    the largest pointwise change of q in the last sweep, max over ranks).

    The diffusion does not couple the coefficients, so it is solved on the scalar P1
    space, one coefficient after the other, with one matrix and preconditioner per level
    (in 2D a fifth of the rows of the blocked system, and faster).

    The constraints' fixed rows (the boundary, and any pinned or prescribed rows) are
    held at the unit frames of their directions; the frame algebra is the constraints'.

    Args:
        V: the P1 space of the frame coefficients.
        constraints: the frames' constraints (None: those of ``V``'s boundary).
        sweeps: diffuse–project iterations per level.
        levels: how many diffusion times (None: down to the mean edge length).
        options_prefix: prefix of the KSP's options.
        monitor: called as ``monitor(level, tau, change)`` after each level.

    Returns:
        The field q.
    """
    mesh = V.mesh
    if constraints is None:
        constraints = frame_constraints(V)
    algebra = constraints.algebra
    q, S, row_of, bcs = _fixed_frames(V, constraints)
    rows = q.x.array.reshape(-1, algebra.count)
    free = constraints.free

    def project(values):
        values[free] = algebra.closest_unit_isotropic(values[free])

    with ScalarDiffusion(S, row_of, bcs, options_prefix) as diffusion:
        run_mbo(diffusion, rows, project, diffusion_schedule(mesh, levels), sweeps, monitor)
    return q


def run_mbo(diffusion: "ScalarDiffusion", rows: np.ndarray, project, schedule, sweeps: int,
            monitor=None) -> None:
    """The MBO iterations on the frame rows ``rows`` (local, owned and ghost; changed in
    place): per diffusion time of ``schedule``, ``sweeps`` times diffuse every coefficient,
    then ``project(rows)`` (in place) onto the frames.

    Args:
        diffusion: the scalar diffusion solver (its fixed rows stay as they are).
        rows: the field's rows (n, count).
        project: called as ``project(rows)`` after each diffusion.
        schedule: the diffusion times τ.
        sweeps: diffuse-project iterations per τ.
        monitor: called as ``monitor(level, tau, change)`` after each level (change: the
            largest pointwise change of the last sweep, max over ranks).
    """
    comm = diffusion.comm
    for level, tau in enumerate(schedule):
        diffusion.set_time(tau)
        change = 0.0
        for _ in range(sweeps):
            before = rows.copy()
            for j in range(rows.shape[1]):
                rows[diffusion.row_of, j] = diffusion.solve(before[diffusion.row_of, j], j)
            project(rows)
            local = float(np.abs(rows - before).max(initial=0.0))
            change = comm.allreduce(local, op=MPI.MAX)
        if monitor is not None:
            monitor(level, tau, change)


class ScalarDiffusion:
    """Implicit diffusion steps (M + τK) u = M u_prev on a scalar P1 space, one coefficient
    of a frame field at a time, each with its own Dirichlet condition (the fixed rows), a
    PETSc KSP with the options prefix given (default CG + GAMG, ``setFromOptions`` last).

    A context manager: the matrix, vector and KSP are destroyed on leaving it, however it
    is left (the destroys are collective, in reverse order of creation).
    """

    def __init__(self, S, row_of, bcs, options_prefix: str = "mbo_"):
        mesh = S.mesh
        self.comm = mesh.comm
        self.row_of = row_of
        self._bcs = bcs
        self._prefix = options_prefix
        self._tau = fem.Constant(mesh, PETSc.ScalarType(1.0))
        u, w = ufl.TrialFunction(S), ufl.TestFunction(S)
        # Both sides divided by h²: entries O(1) whatever the domain's size, like the unit
        # diagonal DOLFINx puts on the boundary rows (unscaled, a domain 6.5e7 wide had
        # entries ~1e12 against those 1s, and CG + GAMG failed: KSP reason -8).
        unit = fem.Constant(mesh, PETSc.ScalarType(1.0 / length_scales(mesh)[1] ** 2))
        self._a = fem.form(unit * (u * w + self._tau * ufl.inner(ufl.grad(u), ufl.grad(w)))
                           * ufl.dx)
        self._previous = fem.Function(S)
        self._L = fem.form(unit * self._previous * w * ufl.dx)
        self._component = fem.Function(S)
        self._owned = ExitStack()

    def __enter__(self):
        owned = self._owned
        try:
            self._A = dolfinx.fem.petsc.create_matrix(self._a)
            owned.callback(self._A.destroy)
            self._rhs = dolfinx.fem.petsc.create_vector(self._component.function_space)
            owned.callback(self._rhs.destroy)
            self._ksp = PETSc.KSP().create(self.comm)
            owned.callback(self._ksp.destroy)
            self._ksp.setOptionsPrefix(self._prefix)
            self._ksp.setOperators(self._A)
            defaults = {"ksp_type": "cg", "pc_type": "gamg", "ksp_rtol": 1e-12}
            with petsc_defaults(self._prefix, defaults):
                self._ksp.setFromOptions()
        except BaseException:
            owned.close()
            raise
        return self

    def __exit__(self, *exc):
        self._owned.close()
        return False

    def set_time(self, tau: float) -> None:
        """Assemble the operator for the diffusion time τ (the same fixed rows for every
        coefficient: the first condition's)."""
        self._tau.value = tau
        self._A.zeroEntries()
        dolfinx.fem.petsc.assemble_matrix(self._A, self._a, bcs=self._bcs[:1])
        self._A.assemble()

    def solve(self, previous: np.ndarray, j: int) -> np.ndarray:
        """Coefficient ``j`` after one step from ``previous`` (the scalar space's local
        values)."""
        self._previous.x.array[:] = previous
        _diffusion_solve(self._ksp, self._rhs, self._a, self._L,
                         self._bcs[j] if self._bcs else None, self._component, self._prefix)
        return self._component.x.array.copy()


def _fixed_frames(V, constraints: FrameConstraints):
    """The field q with the constraints' fixed rows at the unit frames of their directions
    (zero elsewhere), and the scalar P1 space the diffusion is solved on.

    Args:
        V: the P1 space of the frame coefficients.
        constraints: the frames' constraints.

    Returns:
        (q, S, row_of, bcs): q; the collapsed scalar space S of ``V.sub(0)``; the vertex
        row of ``V`` of each dof of S; one Dirichlet condition on S per coefficient,
        holding the fixed rows at q's values.
    """
    algebra = constraints.algebra
    k = algebra.count
    S, to_blocked = V.sub(0).collapse()
    row_of = np.asarray(to_blocked, dtype=np.int64) // k  # S dof -> vertex row of V
    is_fixed = np.zeros(V.dofmap.index_map.size_local + V.dofmap.index_map.num_ghosts, bool)
    is_fixed[constraints.fixed] = True
    fixed_dofs = np.flatnonzero(is_fixed[row_of]).astype(np.int32)

    q = fem.Function(V, name="q")
    rows = q.x.array.reshape(-1, k)
    rows[constraints.fixed] = algebra.unit_frames(constraints.directions)
    fixed_values = [fem.Function(S) for _ in range(k)]
    for j, g in enumerate(fixed_values):
        g.x.array[:] = rows[row_of, j]
    bcs = [fem.dirichletbc(g, fixed_dofs) for g in fixed_values]
    return q, S, row_of, bcs


def _diffusion_solve(ksp: PETSc.KSP, rhs: PETSc.Vec, a: fem.Form, L: fem.Form, bc,
                     component: fem.Function, options_prefix: str) -> None:
    """One coefficient's implicit diffusion step: ``component`` = A⁻¹ b, b the assembled
    ``L`` with the fixed rows of ``bc`` lifted and set.

    Args:
        ksp: the level's KSP (operator A, the matrix of ``a``).
        rhs: the right-hand side vector, overwritten.
        a: the bilinear form of A (for the lifting).
        L: the linear form of b.
        bc: the coefficient's Dirichlet condition (None: none).
        component: where the solution goes (ghosts updated).
        options_prefix: the KSP's prefix, for the error message.
    """
    with rhs.localForm() as local:
        local.set(0.0)
    dolfinx.fem.petsc.assemble_vector(rhs, L)
    bcs = [] if bc is None else [bc]
    dolfinx.fem.petsc.apply_lifting(rhs, [a], bcs=[bcs])
    rhs.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    dolfinx.fem.petsc.set_bc(rhs, bcs)
    ksp.solve(rhs, component.x.petsc_vec)
    if ksp.getConvergedReason() < 0:
        raise RuntimeError(
            f"MBO diffusion solve failed (KSP reason "
            f"{ksp.getConvergedReason()}); try other "
            f"-{options_prefix}ksp_type / -{options_prefix}pc_type"
        )
    component.x.scatter_forward()
