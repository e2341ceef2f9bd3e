"""The parametrisation of a distributed frame field (pipeline.stages.parametrise), serial and MPI.

Truth: the isotropic annulus field (r e_r, r e_θ) integrates to (ln r, θ) (one cut, no
flipped triangle, misfit O(h)); the gathered problem is the same on any number of ranks, so
the measures agree to rounding between COMM_SELF and COMM_WORLD.
"""

from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from ufl_frames.fem import energy
from ufl_frames.mesh import annulus
from ufl_frames.pipeline import FrameField
from ufl_frames.pipeline.files import write_param
from ufl_frames.pipeline.report import field_summary
from ufl_frames.pipeline.stages import parametrise


def exact_annulus_field(comm, h):
    domain = annulus(comm, h)
    V = energy.frame_space(domain.mesh)
    q = energy.interpolate_frames(
        V, lambda x: (np.hypot(x[0], x[1]), np.hypot(x[0], x[1]), np.arctan2(x[1], x[0])))
    return FrameField(domain=domain, q=q, isotropic=True)


def test_annulus_map_is_log_polar_and_the_same_on_any_ranks(tmp_path):
    found = {}
    for name, comm in (("self", MPI.COMM_SELF), ("world", MPI.COMM_WORLD)):
        field = exact_annulus_field(comm, 0.1)
        param = parametrise(field)
        found[name] = param.quality
        if name == "world":
            out = Path(comm.bcast(str(tmp_path), root=0)) / "out"  # rank 0's folder
            if comm.rank == 0:
                out.mkdir()
            comm.Barrier()
            assert write_param(out, param, "annulus", comm) == ["param.png", "param.vtu"]
            assert (out / "param.png").stat().st_size > 0
            assert "misfit" in (out / "param.vtu").read_text()
            assert field_summary(field, param=param)["param"] == found["world"]
    a, b = found["self"], found["world"]
    assert a["cuts"] == b["cuts"] == 1 and a["flipped_triangles"] == b["flipped_triangles"] == 0
    assert a["misfit"] == pytest.approx(b["misfit"], rel=1e-9)
    assert a["misfit"] < 0.06


def test_misfit_falls_linearly_on_the_exact_annulus():
    misfits = [parametrise(exact_annulus_field(MPI.COMM_WORLD, h)).quality["misfit"]
               for h in (0.1, 0.05)]
    assert misfits[1] < 0.6 * misfits[0], misfits
