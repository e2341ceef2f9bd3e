"""The conformal scale (``ufl_frames.fem.conformal``): the integrable isotropic field of
given directions, serial and MPI.

Truth: on the annulus, frames along e_r and e_θ (t = θ) have ∇t = e_θ / r, so
∇φ = R∇t = −e_r / r, φ = −ln r + c and the length e^{−φ} ∝ r: the isotropic integrable
field (c r e_r, c r e_θ), whatever lengths the input had; the P1 solve converges to it.
On the piano, the conformal field of the MBO directions integrates: the misfit of its
seamless map falls under refinement (that of the MBO field does not), and the same
field comes out on any number of ranks.
"""

from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from ufl_frames.app.run import RunConfig, run
from ufl_frames.fem import energy
from ufl_frames.fem.conformal import conformal_field
from ufl_frames.fem.constraints import lumped_mass
from ufl_frames.frames2d import odeco
from ufl_frames.mesh import annulus, load, piano
from ufl_frames.pipeline import FrameField
from ufl_frames.pipeline.stages import parametrise

COMM = MPI.COMM_WORLD


def radial_field(domain, lengths=lambda r: 1.0 + 0 * r):
    V = energy.frame_space(domain.mesh)
    return energy.interpolate_frames(
        V, lambda x: (lengths(np.hypot(x[0], x[1])), lengths(np.hypot(x[0], x[1])),
                      np.arctan2(x[1], x[0])))


def length_over_r_spread(q) -> float:
    """max/min of l / r over the vertices (1 for l ∝ r), all ranks."""
    lengths, angles = odeco.q_to_frames(q.x.array.reshape(-1, 5))
    x = q.function_space.tabulate_dof_coordinates()
    ratio = lengths[:, 0] / np.hypot(x[:, 0], x[:, 1])
    hi = COMM.allreduce(float(ratio.max()), op=MPI.MAX)
    lo = COMM.allreduce(float(ratio.min()), op=MPI.MIN)
    return hi / lo


def test_annulus_lengths_become_proportional_to_r():
    spreads = []
    for h in (0.1, 0.05):
        q = conformal_field(radial_field(annulus(COMM, h), lambda r: 1 / r))
        lengths, angles = odeco.q_to_frames(q.x.array.reshape(-1, 5))
        assert np.allclose(lengths[:, 0], lengths[:, 1])  # isotropic
        spreads.append(length_over_r_spread(q) - 1)
    # measured 2.3e-3, 7.7e-4 (from 3: the input 1/r spans a factor 4 over 0.5 ≤ r ≤ 1)
    assert spreads[0] < 0.01 and spreads[1] < 0.5 * spreads[0], spreads


def test_directions_are_kept_and_the_norm_too():
    domain = piano(COMM, 0.1)
    field = FrameField.initial(domain, isotropic=True)
    q = conformal_field(field.q)
    _, before = odeco.q_to_frames(field.q.x.array.reshape(-1, 5))
    _, after = odeco.q_to_frames(q.x.array.reshape(-1, 5))
    turn = np.mod(after - before + np.pi / 4, np.pi / 2) - np.pi / 4  # crosses: mod 90°
    assert np.abs(turn).max() < 1e-9
    from ufl_frames.fem.constraints import lumped_mass

    owned = q.function_space.dofmap.index_map.size_local
    w = lumped_mass(q.function_space)[:owned]

    def norm2(f):
        rows = f.x.array.reshape(-1, 5)[:owned]
        return COMM.allreduce(float(np.dot(w, np.sum(rows**2, axis=1))), op=MPI.SUM)

    assert norm2(q) == pytest.approx(norm2(field.q), rel=1e-12)


def test_piano_conformal_field_integrates_and_is_the_same_on_any_ranks():
    misfits, mbo_misfits = [], []
    for h in (0.05, 0.025):
        field = FrameField.initial(piano(COMM, h), isotropic=True)
        mbo_misfits.append(parametrise(field).quality["misfit"])
        conformal = field.conformal()
        found = parametrise(conformal).quality
        assert found["flipped_triangles"] == 0 and conformal.conformal_scale
        misfits.append(found["misfit"])
    assert misfits[1] < 0.7 * misfits[0], misfits  # measured 0.038 -> 0.023
    assert mbo_misfits[1] > 0.9 * mbo_misfits[0], mbo_misfits  # 0.085 -> 0.081
    assert misfits[0] < 0.5 * mbo_misfits[0]
    alone = FrameField.initial(piano(MPI.COMM_SELF, 0.05), isotropic=True)
    assert parametrise(alone.conformal()).quality["misfit"] == pytest.approx(parametrise(
        FrameField.initial(piano(COMM, 0.05), isotropic=True).conformal()
    ).quality["misfit"], rel=1e-6)


def test_cli_conformal_runs_no_tao(tmp_path):
    out = Path(COMM.bcast(str(tmp_path), root=0)) / "c"
    summary = run(RunConfig("piano", mesh_size=0.1, out=out, quiet=True, conformal=True,
                            param=True), comm=COMM)
    assert summary["isotropic"] and summary["conformal_scale"]
    assert summary["tao_type"] is None and "iterations" not in summary
    assert "convergence.png" not in summary["files"]
    assert summary["param"]["flipped_triangles"] == 0
    assert summary["H_final"] > 0


TWO_ANNULI = """SetFactory("OpenCASCADE");
Disk(1) = {0, 0, 0, 1};
Disk(2) = {0, 0, 0, 0.5};
BooleanDifference(3) = {Surface{1}; Delete;}{Surface{2}; Delete;};
Disk(4) = {3, 0, 0, 1};
Disk(5) = {3, 0, 0, 0.5};
BooleanDifference(6) = {Surface{4}; Delete;}{Surface{5}; Delete;};
"""


def test_two_components_each_get_their_scale(tmp_path):
    """Two annuli apart, radial frames of lengths 1/r on the first and 3/r' on the second:
    each component is its own Poisson problem (a constant null vector each), so on each
    the length becomes ∝ r' (r' the distance to its own centre), and each keeps the input's
    lumped L² norm on it (the second's is 3x the first's)."""
    path = tmp_path / "two_annuli.geo"
    if COMM.rank == 0:
        path.write_text(TWO_ANNULI)
    COMM.barrier()
    domain = load(COMM, path, mesh_size=0.05)
    V = energy.frame_space(domain.mesh)

    def frames(x):
        right = x[0] > 1.5
        r = np.hypot(x[0] - 3 * right, x[1])
        length = np.where(right, 3.0, 1.0) / r
        return length, length, np.arctan2(x[1], x[0] - 3 * right)

    q_in = energy.interpolate_frames(V, frames)
    q = conformal_field(q_in)
    x = V.tabulate_dof_coordinates()
    right = x[:, 0] > 1.5
    r = np.hypot(x[:, 0] - 3 * right, x[:, 1])
    lengths, _ = odeco.q_to_frames(q.x.array.reshape(-1, 5))
    mass = lumped_mass(V)
    owned = V.dofmap.index_map.size_local
    for side in (False, True):
        ratio = lengths[right == side, 0] / r[right == side]
        hi = COMM.allreduce(float(ratio.max(initial=-np.inf)), op=MPI.MAX)
        lo = COMM.allreduce(float(ratio.min(initial=np.inf)), op=MPI.MIN)
        assert hi / lo - 1 < 0.02, (side, hi / lo)
        mine = (right == side)[:owned]
        norms = [COMM.allreduce(float(np.dot(mass[:owned][mine],
                                             np.sum(v.x.array.reshape(-1, 5)[:owned][mine] ** 2,
                                                    axis=1))), op=MPI.SUM)
                 for v in (q_in, q)]
        assert norms[1] == pytest.approx(norms[0], rel=1e-10)
