"""``ufl-frames mesh``: geometry in, quad mesh out. The files, the boundary nodes on the
circle of a disk to 1e-9 of its diameter (the triangles' chords leave them ~1e-4 off),
``quads.msh`` read back by DOLFINx with the disk's area, ``--quads N``, the usage errors,
and a run under ``mpirun -n 2``.

Subprocess tests are marked ``serial``; the in-process ones also run under
``mpirun -n 2 python -m pytest -m "not serial"``.
"""

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ufl_frames.bootstrap import init_petsc

init_petsc([])  # not pytest's command line

from mpi4py import MPI  # noqa: E402
from msh_readback import read_msh

from ufl_frames.app import cli  # noqa: E402

COMM = MPI.COMM_WORLD
MPIRUN = Path(sys.prefix) / "bin" / "mpirun"
RADIUS = 1.0
DISK_GEO = f'SetFactory("OpenCASCADE");\nDisk(1) = {{0, 0, 0, {RADIUS}}};\n'
FILES = {"quads.msh", "quads.vtu", "quads.png", "summary.json"}


@pytest.fixture(scope="module")
def disk_run(tmp_path_factory):
    """One ``ufl-frames mesh disk.geo`` (in-process, collective): (out folder, summary)."""
    root = Path(COMM.bcast(str(tmp_path_factory.mktemp("disk")), root=0))
    geo = root / "disk.geo"
    if COMM.rank == 0:
        geo.write_text(DISK_GEO)
    COMM.Barrier()
    out = root / "out"
    assert cli.main(["mesh", str(geo), "--out", str(out), "-q"]) == 0
    return out, json.loads((out / "summary.json").read_text())


def test_files_and_summary(disk_run):
    out, summary = disk_run
    assert {p.name for p in out.iterdir()} == FILES
    assert summary["files"] == ["quads.msh", "quads.vtu", "quads.png", "summary.json"]
    assert summary["isotropic"] and summary["quads"]["valid"]
    assert summary["quads"]["min_sj"] > 0.3
    # the run's seconds per step: each positive, together within the whole run's time
    steps = summary["stage_seconds"]
    assert list(steps) == ["mesh", "field", "report", "param and quads"]
    assert all(v > 0 for v in steps.values())
    assert sum(steps.values()) <= summary["total_time_s"]


def test_boundary_nodes_on_the_circle(disk_run):
    out, summary = disk_run
    cad = summary["quads"]["cad"]
    diameter = 2 * RADIUS
    # before: chords of the triangles' boundary; after: on the CAD circle
    assert 1e-6 * diameter < cad["max_offset_before"] < 1e-2 * diameter
    assert cad["refused"] == 0 and cad["moved"] > 0 and cad["note"] is None
    if COMM.rank == 0:
        x, _, boundary = read_msh(out / "quads.msh", dim=2)
        # every boundary node moved onto the circle, except the circle's model point: a
        # quad vertex that the triangle mesh already had exactly on the point
        assert boundary.size - cad["moved"] in (0, 1)
        r = np.linalg.norm(x[boundary], axis=1)
        assert np.abs(r - RADIUS).max() < 1e-9 * diameter


def test_read_back_by_dolfinx_with_the_disk_area(disk_run):
    import dolfinx.fem
    import dolfinx.io.gmsh
    import ufl

    out, summary = disk_run
    data = dolfinx.io.gmsh.read_from_msh(out / "quads.msh", COMM, 0, gdim=2)
    mesh = data.mesh
    assert mesh.topology.cell_name() == "quadrilateral"
    assert mesh.topology.index_map(2).size_global == summary["quads"]["quads"]
    one = dolfinx.fem.Constant(mesh, 1.0)
    area = COMM.allreduce(dolfinx.fem.assemble_scalar(dolfinx.fem.form(one * ufl.dx)),
                          op=MPI.SUM)
    # the file has no groups: one per entity, the circle's curve among the facet tags
    curves = sorted({int(t) for part in COMM.allgather(np.unique(data.facet_tags.values)
                                                       .tolist()) for t in part})
    assert len(curves) == 1
    ds = ufl.Measure("ds", domain=mesh, subdomain_data=data.facet_tags)
    length = COMM.allreduce(dolfinx.fem.assemble_scalar(dolfinx.fem.form(one * ds(curves[0]))),
                            op=MPI.SUM)
    assert area == pytest.approx(math.pi * RADIUS**2, rel=5e-3)
    assert length == pytest.approx(2 * math.pi * RADIUS, rel=5e-3)


def piano_distance(x):
    """Distance of the points (k, 2) to the piano's outline (ufl_frames.mesh.builtin):
    four segments and two quarter circles."""
    from ufl_frames.mesh.builtin import piano_points

    p = np.array(piano_points())
    distance = np.full(len(x), np.inf)
    for a, b in ((0, 1), (1, 2), (3, 4), (5, 0)):
        t = np.clip((x - p[a]) @ (p[b] - p[a]) / np.sum((p[b] - p[a]) ** 2), 0, 1)
        distance = np.minimum(distance, np.linalg.norm(x - p[a] - t[:, None] * (p[b] - p[a]),
                                                       axis=1))
    for centre, radius, quadrant in ((p[6], 0.6, (-1, -1)), (p[7], 0.8, (-1, 1))):
        d = x - centre
        inside = (np.sign(d[:, 0]) == quadrant[0]) & (np.sign(d[:, 1]) == quadrant[1])
        on_arc = np.abs(np.linalg.norm(d, axis=1) - radius)
        distance = np.where(inside, np.minimum(distance, on_arc), distance)
    return distance


def test_quad_count_and_nodes_on_the_piano_arcs(tmp_path_factory):
    root = Path(COMM.bcast(str(tmp_path_factory.mktemp("count")), root=0))
    asked = 150
    assert cli.main(["mesh", "piano", "--quads", str(asked), "--out", str(root / "o"),
                     "-q"]) == 0
    found = json.loads((root / "o" / "summary.json").read_text())["quads"]
    # quads of size sqrt(area / N): about N of them (their edges are not all that size)
    assert found["quad_size"] == pytest.approx(math.sqrt(found["area"] / asked), rel=0.01)
    assert 0.7 * asked < found["quads"] < 1.3 * asked
    # a filleted shape: the nodes on its arcs were chords' ends, now on the arcs
    diameter = math.hypot(2.0, 1.2)
    assert found["cad"]["max_offset_before"] > 1e-5 * diameter
    if COMM.rank == 0:
        x, _, boundary = read_msh(root / "o" / "quads.msh", dim=2)
        assert piano_distance(x[boundary]).max() < 1e-9 * diameter


@pytest.mark.parametrize("args", [
    ["mesh"],
    ["mesh", "piano", "--quads", "0"],
    ["mesh", "piano", "--quads", "2.5"],
    ["mesh", "piano", "--quad-size", "-1"],
    ["mesh", "piano", "--quads", "10", "--quad-size", "0.1"],
    ["mesh", "piano", "--isotropic"],
])
def test_usage_errors(args, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(Path(COMM.bcast(str(tmp_path), root=0)))
    assert cli.main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == (1 if COMM.rank == 0 else 0)
    if err:
        assert err[0].startswith("ufl-frames: error: ")


def test_missing_file_and_existing_folder(tmp_path, capsys):
    root = Path(COMM.bcast(str(tmp_path), root=0))
    assert cli.main(["mesh", str(root / "nosuch.geo"), "--out", str(root / "o")]) == 1
    err = capsys.readouterr().err
    if COMM.rank == 0:
        assert "not found" in err and len(err.strip().splitlines()) == 1
        (root / "busy").mkdir()
        (root / "busy" / "keep").write_text("x")
    COMM.Barrier()
    assert cli.main(["mesh", "piano", "--out", str(root / "busy")]) == 1
    assert "--force" in capsys.readouterr().err or COMM.rank != 0


@pytest.mark.serial
@pytest.mark.skipif(not MPIRUN.exists(), reason=f"no {MPIRUN}")
def test_mesh_under_mpirun(tmp_path):
    (tmp_path / "disk.geo").write_text(DISK_GEO)
    proc = subprocess.run(
        [str(MPIRUN), "-n", "2", sys.executable, "-m", "ufl_frames.app", "mesh", "disk.geo",
         "--out", "par", "--quad-size", "0.15"],
        cwd=tmp_path, capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.count("meshing disk.geo") == 1  # progress from rank 0 only
    assert "onto the CAD curves" in proc.stdout
    summary = json.loads((tmp_path / "par" / "summary.json").read_text())
    assert summary["num_processes"] == 2
    assert {p.name for p in (tmp_path / "par").iterdir()} == FILES
    x, _, boundary = read_msh(tmp_path / "par" / "quads.msh", dim=2)
    assert np.abs(np.linalg.norm(x[boundary], axis=1) - RADIUS).max() < 2e-9


def test_mesh_follows_a_size_expression(tmp_path_factory):
    """``mesh --size EXPR --quads N``: the sized non-isotropic field, quads graded by the
    expression (their local size correlates with it) and about N of them."""
    root = Path(COMM.bcast(str(tmp_path_factory.mktemp("sized")), root=0))
    geo = root / "square.geo"
    if COMM.rank == 0:
        geo.write_text('SetFactory("OpenCASCADE");\nRectangle(1) = {0, 0, 0, 1, 1};\n')
    COMM.Barrier()
    out = root / "out"
    assert cli.main(["mesh", str(geo), "--size", "0.03 + 0.12*x", "--quads", "300",
                     "--out", str(out), "-q"]) == 0
    sizes = json.loads((out / "summary.json").read_text())["sizes"]
    assert sizes["h_ratio"] == pytest.approx(5.0, rel=0.05)
    assert sizes["quads"]["log_correlation"] >= 0.9
    assert abs(sizes["quads"]["quads"] - 300) <= 0.1 * 300
