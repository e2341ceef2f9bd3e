r"""The MBO initial field (:func:`ufl_frames.solvers.mbo.mbo_frame_field`) on the annulus.

On the annulus 0.5 ≤ r ≤ 1 the smooth boundary-aligned cross field is known exactly: the
cross of e_r and e_θ (angle φ = atan2(y, x) modulo π/2), with no singularity. MBO must
return unit isotropic frames (l1 = l2 = 1), aligned with the boundary normal at the
boundary vertices, and close to that cross inside.
"""

import numpy as np
import pytest
from mpi4py import MPI

from ufl_frames.fem import energy
from ufl_frames.fem.constraints import frame_constraints
from ufl_frames.frames2d import odeco
from ufl_frames.solvers import mbo


def angle_mod_quarter(a):
    """Distance of an angle from 0 modulo π/2, in [0, π/4]."""
    return np.abs((np.asarray(a) + np.pi / 4) % (np.pi / 2) - np.pi / 4)


def mbo_on_annulus(annulus_mesh, h, comm):
    mesh = annulus_mesh(h, comm)
    V = energy.frame_space(mesh)
    constraints = frame_constraints(V)
    return V, constraints, mbo.mbo_frame_field(V, constraints)


def global_max(comm, values):
    return comm.allreduce(float(np.max(values, initial=0.0)), op=MPI.MAX)


def test_mbo_annulus_frames(annulus_mesh):
    comm = MPI.COMM_WORLD
    errors = {}
    for h in (0.1, 0.05):
        V, constraints, q = mbo_on_annulus(annulus_mesh, h, comm)
        rows = q.x.array.reshape(-1, 5)
        lengths, t = odeco.q_to_frames(rows)
        x = V.tabulate_dof_coordinates()
        phi = np.arctan2(x[:, 1], x[:, 0])

        # Unit isotropic frames on the Odeco variety everywhere (boundary included).
        assert global_max(comm, np.abs(lengths - 1.0)) < 1e-8
        assert global_max(comm, np.abs(odeco.variety_residual(rows))) < 1e-8

        # Boundary: aligned with the normal used by the constraints, and with e_r.
        b = constraints.fixed
        psi = np.arctan2(constraints.directions[:, 1], constraints.directions[:, 0])
        assert global_max(comm, angle_mod_quarter(t[b] - psi)) < 1e-8
        boundary_error = global_max(comm, angle_mod_quarter(t[b] - phi[b]))
        assert boundary_error < 0.1 * h  # polygonal boundary: edge normals vs e_r

        # Interior: the cross of e_r, e_θ.
        errors[h] = global_max(comm, angle_mod_quarter(t - phi))
        H, E = energy.integrability_energy(q), energy.dirichlet_energy(q)
        if comm.rank == 0:
            print(
                f"\nMBO annulus h = {h}: max angle error vs e_r {errors[h]:.2e} rad "
                f"(boundary {boundary_error:.2e}), H = {H:.6f}, E = {E:.6f}"
            )
    assert errors[0.05] < 5e-3
    assert errors[0.05] < errors[0.1] / 2


def test_mbo_parallel_matches_serial(annulus_mesh):
    """Same mesh on COMM_SELF and COMM_WORLD: the same H and E (meaningful under mpirun)."""
    energies = {}
    for name, comm in (("self", MPI.COMM_SELF), ("world", MPI.COMM_WORLD)):
        _, _, q = mbo_on_annulus(annulus_mesh, 0.1, comm)
        energies[name] = (energy.integrability_energy(q), energy.dirichlet_energy(q))
    if MPI.COMM_WORLD.rank == 0:
        print(
            f"\nMBO H, E on COMM_SELF {energies['self']}, "
            f"on COMM_WORLD (size {MPI.COMM_WORLD.size}) {energies['world']}"
        )
    assert energies["world"] == pytest.approx(energies["self"], rel=1e-8)
