"""FrameField: the pipeline object (domain → MBO field → solve → findings); serial and MPI."""

import math
from pathlib import Path

import pytest

from ufl_frames.bootstrap import init_petsc

init_petsc([])  # not pytest's command line

from mpi4py import MPI  # noqa: E402

from ufl_frames import geometry, io  # noqa: E402
from ufl_frames.pipeline import FrameField, aspect_bound  # noqa: E402

COMM = MPI.COMM_WORLD


@pytest.mark.parametrize(
    "isotropic, given, expected",
    [(True, 4.0, None), (False, 4.0, 4.0), (False, math.inf, None), (False, None, None)],
)
def test_aspect_bound(isotropic, given, expected):
    assert aspect_bound(isotropic, given) == expected


def test_frame_field_on_the_piano(tmp_path):
    out = Path(COMM.bcast(str(tmp_path), root=0))
    domain = geometry.piano(COMM, 0.15)
    field = FrameField.initial(domain, isotropic=False, max_aspect=4.0)
    # The MBO field already has the piano's pair, and Poincaré–Hopf holds for it.
    assert sorted(s["index"] for s in field.singularities) == [-0.25, 0.25]
    assert field.index_theorem()["agrees"]
    assert field.result is None and field.max_aspect == 4.0
    # The CAD tangents reach the constraints: the arcs' crosses are the exact ones.
    assert field.boundary_angles is not None
    result = field.solve(max_it=15)
    assert result.H_final < result.H_initial and field.problem is not None
    assert field.problem.constraints.max_aspect == 4.0
    assert field.index_theorem()["agrees"]
    names = field.write(out, label="piano", tao_type="nls")
    assert names[0] == "frames.bp" and {"frames.png", "convergence.png"} <= set(names)
    data = io.read_vtk(out / "frames.pvd")
    assert data["points"].shape[0] >= domain.num_vertices  # shared points repeat per piece


def test_solver_reuses_the_mbo_constraints():
    """frame_problem(constraints=...) equals the constraints found afresh for the solver."""
    import numpy as np

    from ufl_frames import projection, solver

    field = FrameField.initial(geometry.annulus(COMM, 0.2), isotropic=False, max_aspect=3.0)
    q0 = field.q.x.array.copy()
    reused = solver.frame_problem(field.q, max_aspect=3.0, constraints=field.constraints,
                                  pin_singularities=False).constraints
    field.q.x.array[:] = q0
    fresh = projection.frame_constraints(field.q.function_space, max_aspect=3.0,
                                         boundary_angles=field.boundary_angles)
    assert reused.max_aspect == fresh.max_aspect == 3.0 and not reused.isotropic
    for name in ("boundary", "normals", "weights"):
        assert np.array_equal(getattr(reused, name), getattr(fresh, name)), name
