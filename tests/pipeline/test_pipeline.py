"""FrameField: the pipeline object (domain → MBO field → solve → findings); serial and MPI."""

import math
from pathlib import Path

import pytest

from ufl_frames.bootstrap import init_petsc

init_petsc([])  # not pytest's command line

from mpi4py import MPI  # noqa: E402

from ufl_frames import output  # noqa: E402
from ufl_frames.frames2d.aspect import aspect_bound  # noqa: E402
from ufl_frames.mesh import annulus, load, piano  # noqa: E402
from ufl_frames.pipeline import FrameField  # noqa: E402
from ufl_frames.pipeline.files import write_field  # noqa: E402

COMM = MPI.COMM_WORLD


@pytest.mark.parametrize(
    "isotropic, given, expected",
    [(True, 4.0, None), (False, 4.0, 4.0), (False, math.inf, None), (False, None, None)],
)
def test_aspect_bound(isotropic, given, expected):
    assert aspect_bound(isotropic, given) == expected


def test_frame_field_on_the_piano(tmp_path):
    out = Path(COMM.bcast(str(tmp_path), root=0))
    domain = piano(COMM, 0.15)
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
    names = write_field(out, field, label="piano", tao_type="nls")
    assert names[0] == "frames.bp" and {"frames.png", "convergence.png"} <= set(names)
    data = output.read_vtk(out / "frames.pvd")
    assert data["points"].shape[0] >= domain.num_vertices  # shared points repeat per piece


def test_solver_reuses_the_mbo_constraints():
    """frame_problem(constraints=...) equals the constraints found afresh for the solver."""
    import numpy as np

    from ufl_frames import solvers
    from ufl_frames.fem.constraints import frame_constraints

    field = FrameField.initial(annulus(COMM, 0.2), isotropic=False, max_aspect=3.0)
    q0 = field.q.x.array.copy()
    reused = solvers.frame_problem(field.q, max_aspect=3.0, constraints=field.constraints,
                                  pin_singularities=False).constraints
    field.q.x.array[:] = q0
    fresh = frame_constraints(field.q.function_space, max_aspect=3.0,
                              boundary_angles=field.boundary_angles)
    assert reused.max_aspect == fresh.max_aspect == 3.0 and not reused.isotropic
    for name in ("fixed", "directions", "kind", "weights"):
        assert np.array_equal(getattr(reused, name), getattr(fresh, name)), name


@pytest.mark.parametrize("unit", [1e-6, 1e6])
def test_the_whole_run_does_not_depend_on_the_domain_size(tmp_path, unit):
    """MBO, the Newton systems (H¹ damping in units of the domain) and the stopping tests
    are free of the domain's size: a plate with a hole 65 µm or 65 000 km wide gives the
    field of the 65 m one. (Unscaled, MBO's solve failed at 1e6, Newton stalled.)"""
    results = {}
    for scale in (1.0, unit):
        w, h, r = 65 * scale, 120 * scale, 10 * scale
        path = tmp_path / f"plate_{scale:g}.geo"
        if COMM.rank == 0:
            path.write_text(f'SetFactory("OpenCASCADE");\nRectangle(1) = {{0, 0, 0, {w}, {h}}};\n'
                            f"Disk(2) = {{{w / 2}, {h / 2}, 0, {r}}};\n"
                            "BooleanDifference{ Surface{1}; Delete; }{ Surface{2}; Delete; }\n")
        COMM.Barrier()
        field = FrameField.initial(load(COMM, Path(COMM.bcast(str(path))), 8 * scale),
                                   isotropic=True)
        results[scale] = field.solve(max_it=50)
        assert results[scale].converged_reason.startswith("CONVERGED"), results[scale]
        assert sorted(s["index"] for s in field.singularities) == [-0.25] * 4
    # Gmsh's meshes of the scaled files differ slightly (H_initial by ~2 %): not bit-equal.
    unit_run, scaled = results[1.0], results[unit]
    assert scaled.H_initial == pytest.approx(unit_run.H_initial, rel=5e-2)
    assert scaled.H_final == pytest.approx(unit_run.H_final, rel=5e-2)
    assert abs(scaled.iterations - unit_run.iterations) <= 2
