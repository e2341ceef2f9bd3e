"""Nested iteration: a frame field carried between meshes of one domain, and the solve
that goes from a coarse mesh to a fine one (:meth:`FrameField.nested`, ``--levels``).

Serial and under MPI (``mpirun -n 2 python -m pytest -m "not serial"``).
"""

from pathlib import Path

import dolfinx.fem
import numpy as np
import pytest
from mpi4py import MPI
from petsc4py import PETSc

from ufl_frames import cli, geometry, solvers
from ufl_frames.fem import energy
from ufl_frames.fem.transfer import interpolate_field
from ufl_frames.frames2d import odeco
from ufl_frames.pipeline import FrameField

COMM = MPI.COMM_WORLD


def affine(x):
    """Five affine coefficients: what a P1 field on any mesh reproduces exactly."""
    return np.stack([1.0 + 0.3 * x[0] - 0.2 * x[1], 0.5 * x[0], -0.4 * x[1] + 0.1,
                     0.2 + x[0] + x[1], 0.7 - 0.6 * x[0]])


@pytest.mark.parametrize("shape", ["piano", "annulus"])
def test_interpolate_field_reproduces_affine_fields(shape):
    """Between two independent Gmsh meshes of a curved domain (fine boundary vertices
    lie outside the coarse polygon): an affine field comes through exactly."""
    coarse = geometry.build(COMM, shape, mesh_size=0.2)
    fine = geometry.build(COMM, shape, mesh_size=0.07)
    q = energy.frame_space(coarse.mesh)
    f = dolfinx.fem.Function(q)
    f.interpolate(affine)
    g = interpolate_field(f, fine.mesh)
    x = g.function_space.tabulate_dof_coordinates().T
    expected = affine(x).T.ravel()
    np.testing.assert_allclose(g.x.array, expected, rtol=0, atol=1e-12)


def test_interpolate_field_refuses_another_domain():
    piano = geometry.build(COMM, "piano", mesh_size=0.2)
    annulus = geometry.build(COMM, "annulus", mesh_size=0.2)
    f = FrameField.initial(piano).q
    with pytest.raises(ValueError, match="not the same domain"):
        interpolate_field(f, annulus.mesh)


@pytest.fixture(scope="module")
def piano_nested():
    domains = [geometry.build(COMM, "piano", mesh_size=0.1, size_factor=2.0 ** k)
               for k in (1, 0)]
    levels = []
    field = FrameField.nested(domains, max_it=300, level_monitor=levels.append)
    return domains, field, levels


def test_nested_ends_converged_on_the_fine_mesh(piano_nested):
    """The fine level stops on the whole solve's tolerance: its last gradient is below
    1e-6 of the coarse MBO start's |g₀| (computed again here, independently), and the
    result lies on the frame manifold of the fine mesh (the retraction leaves it)."""
    domains, field, levels = piano_nested
    assert [e["triangles"] for e in levels] == [d.num_cells for d in domains]
    assert field.levels == levels and field.domain is domains[-1]
    assert all(e["reason"].startswith("CONVERGED") for e in levels)
    tolerance = 1e-6 * max(coarse_start_gradient(domains[0]), field.problem.gradient_scale)
    assert field.result.history[-1]["gnorm"] <= tolerance * (1 + 1e-9)
    assert field.result.history[0]["gnorm"] > tolerance  # the fine level had work to do
    rows = field.problem.rows.copy()
    field.problem.retract()
    np.testing.assert_allclose(field.problem.rows, rows, atol=1e-12)


def coarse_start_gradient(domain):
    """|g₀| of the MBO start on the coarsest mesh, computed again."""
    start = FrameField.initial(domain)
    problem = solvers.frame_problem(start.q, constraints=start.constraints)
    g = PETSc.Vec().createMPI((problem.owned * 5, PETSc.DETERMINE), comm=COMM)
    problem.riemannian_gradient(g)
    value = g.norm()
    g.destroy()
    return value


def test_nested_keeps_the_singularities(piano_nested):
    """MBO's +1/4 and −1/4 of the coarse mesh, carried to the fine one and held there."""
    _, field, _ = piano_nested
    assert sorted(s["index"] for s in field.singularities) == [-0.25, 0.25]
    assert field.index_theorem()["agrees"]


def test_nested_fine_level_is_cheaper_than_a_cold_start(piano_nested):
    """The point of nesting: from the coarse solution the fine mesh needs fewer Newton
    steps than from its own MBO field, and reaches an H no higher (to 1 %)."""
    domains, field, levels = piano_nested
    cold = FrameField.initial(domains[-1])
    result = cold.solve(max_it=300)
    assert levels[-1]["iterations"] < result.iterations
    assert levels[-1]["H"] <= 1.01 * result.H_final


def test_pin_radius_holds_a_disk_around_each_singular_triangle():
    """``pin_radius``: every vertex closer than the radius to a singular triangle's
    barycentre (distances computed here from the coordinates) is held like a boundary
    vertex, at the field's own cross angle, and nothing farther than the radius or the
    triangle's own vertices; radius 0 holds the two triangles' six vertices only."""
    from ufl_frames.fem.constraints import frame_constraints, pin_singularities

    field = FrameField.initial(geometry.build(COMM, "piano", mesh_size=0.05))
    V = field.q.function_space
    rows = field.q.x.array.reshape(-1, 5)
    base = frame_constraints(V, boundary_angles=field.boundary_angles)
    x = V.tabulate_dof_coordinates()[:, :2]
    centres = np.array([[s["x"], s["y"]] for s in field.singularities])
    assert len(centres) == 2
    distance = np.sqrt(((x[:, None, :] - centres[None]) ** 2).sum(axis=2).min(axis=1))
    counts = []
    for radius in (0.0, 0.06, 0.15):
        held = pin_singularities(V, base, rows, radius=radius)
        pinned = np.setdiff1d(held.boundary, base.boundary)
        near = np.setdiff1d(np.flatnonzero(distance < radius), base.boundary)
        assert np.isin(near, pinned).all()
        assert (distance[pinned] < max(radius, 2 * field.domain.mesh_size)).all()
        _, angles = odeco.q_to_frames(rows[pinned])
        normals = held.normals[len(base.boundary):]
        np.testing.assert_allclose(normals, np.stack([np.cos(angles), np.sin(angles)], 1),
                                   atol=1e-14)
        counts.append(COMM.allreduce(int(np.count_nonzero(pinned < base.owned))))
    assert counts[0] == 6 and counts[0] < counts[1] < counts[2]


def test_nested_pins_a_disk_of_the_coarsest_mesh_size():
    """Two Gmsh levels (1 069 and 4 080 triangles) where a pin of one fine triangle is
    escaped: held at the singular triangles only, the fine level grows a ±1/4 pair next to
    the +1/4 (4 singularities; benchmarks/README.md "Pinned singularities"). Held in a disk
    of the coarse mesh's size (``pin_radius``), both levels end with MBO's two, within a
    coarse edge of where MBO put them."""
    domains = [geometry.build(COMM, "piano", mesh_size=0.03434, size_factor=2.0 ** k)
               for k in (1, 0)]
    radius = domains[0].mesh_size
    field = FrameField.nested(domains, max_it=300, pin_radius=radius)
    coarse, fine = field.levels
    assert coarse["singularities"] == fine["singularities"] == [-0.25, 0.25]
    assert fine["reason"].startswith("CONVERGED")
    assert field.pin_radius == radius and field.summary()["pin_radius"] == radius
    start = FrameField.initial(domains[0]).singularities
    for s, t in zip(start, field.singularities, strict=True):
        assert np.hypot(s["x"] - t["x"], s["y"] - t["y"]) < radius


def test_pin_radius_reaches_the_solve_and_the_summary(tmp_path):
    """``--pin-radius`` on one mesh: recorded in summary.json, MBO's singularities kept, and
    it changes the solve (another H than the default's)."""
    out = Path(COMM.bcast(str(tmp_path), root=0))
    args = ["solve", "piano", "--mesh-size", "0.1", "-q", "--max-it", "300"]
    assert cli.main([*args, "--out", str(out / "a")]) == 0
    assert cli.main([*args, "--pin-radius", "0.2", "--out", str(out / "b")]) == 0
    import json
    default, disk = (json.loads((out / k / "summary.json").read_text()) for k in "ab")
    assert default["pin_radius"] == 0.0 and disk["pin_radius"] == 0.2
    assert sorted(s["index"] for s in disk["singularities"]) == [-0.25, 0.25]
    assert disk["H_final"] != default["H_final"]


@pytest.mark.parametrize("argv, status, words", [
    (["--pin-radius", "-1"], 2, "must be a number >= 0"),  # a usage error
    (["--pin-radius", "nan"], 2, "must be a number >= 0"),
    (["--pin-radius", "0.1", "--free-singularities"], 1, "cannot be combined"),  # input
])
def test_pin_radius_refuses_bad_values(argv, status, words, tmp_path, capsys):
    """One line on rank 0, a non-zero exit status, nothing written."""
    out = Path(COMM.bcast(str(tmp_path), root=0)) / "out"
    assert cli.main(["solve", "piano", "--mesh-size", "0.2", "--out", str(out),
                     *argv]) == status
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == (1 if COMM.rank == 0 else 0)
    if err:
        assert words in err[0]
    assert not out.exists()


def test_checkpoints_without_a_pin_radius_resume_as_radius_zero(tmp_path):
    """Checkpoints written before ``--pin-radius`` existed are of runs with radius 0: they
    resume a run with the default and refuse one with a disk."""
    from ufl_frames import checkpoint as checkpoints

    run = {"geometry_id": "piano", "isotropic": False, "mesh_size": 0.1, "size_factor": 1.0,
           "max_triangles": None, "max_aspect": 4.0, "free_singularities": False,
           "max_it": 300, "petsc_options": []}
    old = {"run": dict(run)}
    checkpoints.check_run(old, {**run, "pin_radius": 0.0}, tmp_path)
    with pytest.raises(checkpoints.CheckpointError, match="--pin-radius differs"):
        checkpoints.check_run(old, {**run, "pin_radius": 0.1}, tmp_path)
