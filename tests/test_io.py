"""ufl_frames.io: summary, ParaView field, figures; serial and under MPI (no subprocesses)."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from ufl_frames.bootstrap import init_petsc

init_petsc([])  # not pytest's command line

import dolfinx  # noqa: E402
import dolfinx.io  # noqa: E402
from mpi4py import MPI  # noqa: E402

from ufl_frames import energy, io, odeco  # noqa: E402

COMM = MPI.COMM_WORLD
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture
def shared_tmp(tmp_path):
    """rank 0's tmp_path on every rank (the files are written by rank 0 or collectively)."""
    return Path(COMM.bcast(str(tmp_path), root=0))


def square_mesh(n=8):
    return dolfinx.mesh.create_rectangle(
        COMM, [[0.0, 0.0], [2.0, 1.0]], [2 * n, n], dolfinx.mesh.CellType.triangle
    )


def twisted_field(mesh):
    """A non-integrable frame field: angle x, lengths 1 + y and 1 + y/2."""
    V = energy.frame_space(mesh)
    return energy.interpolate_frames(V, lambda x: (1 + x[1], 1 + 0.5 * x[1], x[0]))


def test_write_summary_json(shared_tmp):
    data = {"a": np.float64(1.5), "n": np.int32(3), "v": np.arange(3), "p": shared_tmp,
            "history": [{"it": 0, "H": 1.0}]}
    path = shared_tmp / "summary.json"
    io.write_summary(path, data)
    back = json.loads(path.read_text())
    assert back == {"a": 1.5, "n": 3, "v": [0, 1, 2], "p": str(shared_tmp),
                    "history": [{"it": 0, "H": 1.0}]}
    assert path.read_text().count("\n") > 3  # indented


def test_frames_of_rows_match_odeco():
    lengths = np.array([[1.0, 2.0], [0.5, 0.5], [3.0, 1.0]])
    angles = np.array([0.1, -0.7, 0.3])
    rows = np.vstack([odeco.frames_to_q(lengths, angles), np.zeros((1, 5))])
    got_lengths, u, v = io._frames(rows)
    np.testing.assert_allclose(np.linalg.norm(u, axis=1), got_lengths[:, 0], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), got_lengths[:, 1], atol=1e-12)
    np.testing.assert_allclose(np.einsum("ni,ni->n", u, v), 0.0, atol=1e-12)
    # Same frames: the tensor rebuilt from (u, v) is q.
    t = np.arctan2(u[:3, 1], u[:3, 0])
    np.testing.assert_allclose(odeco.frames_to_q(got_lengths[:3], t), rows[:3], atol=1e-12)
    assert np.all(got_lengths[3] == 0) and np.all(u[3] == 0) and np.all(v[3] == 0)


def test_bracket_rms_integrates_to_H():
    q = twisted_field(square_mesh())
    rms = io.bracket_rms(q)
    cell_area = 2.0 * 1.0 / (2 * 16 * 8)  # uniform right triangles
    owned = rms.function_space.dofmap.index_map.size_local
    H_from_rms = COMM.allreduce(0.5 * cell_area * float(np.sum(rms.x.array[:owned] ** 2)))
    H = energy.integrability_energy(q)
    assert H > 1e-3
    assert math.isclose(H_from_rms, H, rel_tol=1e-10)


def test_bracket_rms_vanishes_for_constant_frames():
    mesh = square_mesh(4)
    q = energy.interpolate_frames(energy.frame_space(mesh), lambda x: (1.0, 2.0, 0.3))
    assert np.abs(io.bracket_rms(q).x.array).max() < 1e-12


def test_field_functions():
    q = twisted_field(square_mesh(4))
    functions = io.field_functions(q)
    names = [f.name for f in functions]
    assert names == ["q", "lengths", "u", "v", "bracket_rms"]
    lengths, u, v = (f.x.array.reshape(-1, 2) for f in functions[1:4])
    np.testing.assert_allclose(np.linalg.norm(u, axis=1), lengths[:, 0], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), lengths[:, 1], atol=1e-12)
    # Lengths of the interpolated frames: {1 + y, 1 + y/2} at the vertices.
    y = functions[1].function_space.tabulate_dof_coordinates()[:, 1]
    np.testing.assert_allclose(np.sort(lengths, axis=1),
                               np.stack([1 + y / 2, 1 + y], axis=1), atol=1e-10)


def test_write_field_vtx(shared_tmp):
    assert dolfinx.io.has_adios2, "this DOLFINx build should have ADIOS2"
    path = io.write_field(shared_tmp, twisted_field(square_mesh(4)))
    assert path == shared_tmp / "frames.bp"
    assert (path / "md.idx").is_file()
    metadata = b"".join(p.read_bytes() for p in path.glob("md.*"))
    for name in (b"q", b"lengths", b"u", b"v", b"bracket_rms"):
        assert b'Name="' + name + b'"' in metadata


def test_write_field_xdmf_fallback(shared_tmp, monkeypatch):
    monkeypatch.setattr(dolfinx.io, "has_adios2", False)
    path = io.write_field(shared_tmp, twisted_field(square_mesh(4)), stem="fallback")
    assert path == shared_tmp / "fallback.xdmf"
    text = path.read_text()
    for name in ("q", "lengths", "u", "v", "bracket_rms"):
        assert f'Name="{name}"' in text
    assert (shared_tmp / "fallback.h5").is_file()


def test_grid_points_centred():
    points = io.grid_points(np.array([0.0, 0.0]), np.array([2.0, 1.0]), 0.3)
    assert points.shape[1] == 3
    x, y = np.unique(points[:, 0]), np.unique(points[:, 1])
    assert x.size == 7 and y.size == 4
    assert math.isclose(x.mean(), 1.0) and math.isclose(y.mean(), 0.5)
    np.testing.assert_allclose(np.diff(x), 0.3)


def test_glyph_samples_fine_mesh_uses_grid():
    q = twisted_field(square_mesh(16))  # h = 1/16, finer than 2/12
    points, rows, spacing = io.glyph_samples(q, glyphs_across=12)
    assert math.isclose(spacing, 2.0 / 12)
    if COMM.rank == 0:
        assert points.shape == (13 * 7, 2)  # the whole grid lies in the rectangle
        # The field at a sample point is the P1 interpolant there: angle x, lengths 1+y, 1+y/2.
        lengths, _ = odeco.q_to_frames(rows)
        np.testing.assert_allclose(np.sort(lengths, axis=1)[:, 1], 1 + points[:, 1], atol=0.02)
    else:
        assert points is None and rows is None


def test_glyph_samples_coarse_mesh_uses_vertices():
    mesh = square_mesh(2)
    q = twisted_field(mesh)
    points, rows, spacing = io.glyph_samples(q, glyphs_across=36)
    if COMM.rank == 0:
        assert points.shape == (mesh.topology.index_map(0).size_global, 2)
        assert rows.shape == (points.shape[0], 5)
        assert spacing > 2.0 / 36


@pytest.mark.parametrize("isotropic", [False, True])
def test_plot_frames_writes_png(shared_tmp, isotropic):
    mesh = square_mesh(6)
    V = energy.frame_space(mesh)
    q = energy.interpolate_frames(
        V, lambda x: (1 + x[1], (1 + x[1]) if isotropic else 1.0, 0.5 * x[0])
    )
    path = shared_tmp / f"frames_{isotropic}.png"
    sings = [{"index": 0.25, "x": 0.5, "y": 0.5}, {"index": -0.25, "x": 1.5, "y": 0.5},
             {"index": 0.5, "x": 1.0, "y": 0.2}]
    io.plot_frames(path, q, title="test", singularities=sings)
    COMM.Barrier()
    assert path.read_bytes()[:8] == PNG_MAGIC


def test_is_isotropic():
    V = energy.frame_space(square_mesh(3))
    assert io._is_isotropic(energy.interpolate_frames(V, lambda x: (1 + x[0], 1 + x[0], x[1])))
    assert not io._is_isotropic(energy.interpolate_frames(V, lambda x: (1.0, 1.1, x[1])))


@pytest.mark.parametrize("H0", [1.0, 0.0])
def test_plot_convergence_writes_png(shared_tmp, H0):
    history = [{"it": k, "H": H0 * 0.5**k, "E": 2.0 + 0.1 * k, "gnorm": 1.0, "step": 1.0}
               for k in range(8)]
    path = shared_tmp / f"convergence_{H0}.png"
    io.plot_convergence(path, history, title="test")
    COMM.Barrier()
    assert path.read_bytes()[:8] == PNG_MAGIC


def test_describe_singularities():
    assert io.describe_singularities([]) == "none"
    text = io.describe_singularities(
        [{"index": 0.25, "x": 0.349, "y": 0.796}, {"index": -0.25, "x": 1.5, "y": 0.7}]
    )
    assert text == "+1/4 at (0.349, 0.796), -1/4 at (1.5, 0.7)"
