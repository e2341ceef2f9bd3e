r"""A smooth boundary-aligned 3D frame field on tetrahedra by MBO (the 2D scheme of
:mod:`ufl_frames.solvers.mbo` with 15 coefficients).

Alternate implicit diffusion of every coefficient for a time τ and the pointwise
projection onto unit isotropic frames, with τ decreasing from (diameter/4)² to h². On the
boundary a frame has one axis along the surface normal and its rotation about the normal
free, so those rows are projected onto the frames aligned with their normal after each
diffusion (not held); on sharp features (curves and corners where surfaces meet at an
angle) the frame is determined by the normals that meet and is held (Dirichlet rows).

The linear solves use a PETSc KSP with options prefix ``mbo_`` (default CG with GAMG).
"""

from ufl_frames.bootstrap import init_petsc

init_petsc()

import dolfinx.fem as fem  # noqa: E402
import numpy as np  # noqa: E402

from ufl_frames.frames3d.algebra import ALGEBRA3D  # noqa: E402
from ufl_frames.solvers.mbo import ScalarDiffusion, diffusion_schedule, run_mbo  # noqa: E402

__all__ = ["frame_space_3d", "mbo_frame_field_3d"]


def frame_space_3d(volume) -> fem.FunctionSpace:
    """The P1 space of 15 frame coefficients on the volume's tetrahedra."""
    import basix.ufl

    element = basix.ufl.element("Lagrange", "tetrahedron", 1, shape=(ALGEBRA3D.count,))
    return fem.functionspace(volume.mesh, element)


def mbo_frame_field_3d(volume, sweeps: int = 2, levels: int | None = None,
                       options_prefix: str = "mbo_", monitor=None) -> fem.Function:
    """Smooth unit isotropic 3D frame field on ``volume``, aligned with its boundary (MBO).

    Args:
        volume: the :class:`~ufl_frames.mesh.volumes.Volume`.
        sweeps: diffuse–project iterations per diffusion time.
        levels: how many diffusion times (None: down to the mean edge length).
        options_prefix: prefix of the KSP's options.
        monitor: called as ``monitor(level, tau, change)`` after each level.

    Returns:
        The field q on :func:`frame_space_3d`.
    """
    algebra = ALGEBRA3D
    V = frame_space_3d(volume)
    (aligned, normals), (features, rotations) = volume.boundary_frames(V)
    q = fem.Function(V, name="q")
    rows = q.x.array.reshape(-1, algebra.count)
    rows[features] = algebra.unit_frames(rotations)
    rows[aligned] = algebra.unit_frames(_any_frame_with_axis(normals))
    S, to_blocked = V.sub(0).collapse()
    row_of = np.asarray(to_blocked, dtype=np.int64) // algebra.count
    is_fixed = np.zeros(rows.shape[0], dtype=bool)
    is_fixed[features] = True
    fixed_dofs = np.flatnonzero(is_fixed[row_of]).astype(np.int32)
    values = [fem.Function(S) for _ in range(algebra.count)]
    for j, g in enumerate(values):
        g.x.array[:] = rows[row_of, j]
    bcs = [fem.dirichletbc(g, fixed_dofs) for g in values] if volume.comm.allreduce(
        fixed_dofs.size) else []
    free = np.flatnonzero(~is_fixed)
    free = np.setdiff1d(free, aligned)

    def project(r):
        r[free] = algebra.closest_unit_isotropic(r[free])
        if aligned.size:
            r[aligned] = algebra.closest_unit_aligned(r[aligned], normals)

    with ScalarDiffusion(S, row_of, bcs, options_prefix) as diffusion:
        run_mbo(diffusion, rows, project, diffusion_schedule(volume.mesh, levels), sweeps,
                monitor)
    q.x.scatter_forward()
    return q


def _any_frame_with_axis(normals: np.ndarray) -> np.ndarray:
    """Rotations (N, 3, 3) whose first column is ``normals`` (unit)."""
    n = normals / np.linalg.norm(normals, axis=1)[:, None]
    helper = np.where(np.abs(n[:, [0]]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    b = np.cross(n, helper)
    b /= np.linalg.norm(b, axis=1)[:, None]
    return np.stack([n, b, np.cross(n, b)], axis=2)
