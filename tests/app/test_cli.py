"""The ufl-frames command: errors, a complete coarse run, PETSc options, MPI.

Subprocess tests are marked ``serial`` (no mpirun inside mpirun); the in-process
tests also run under ``mpirun -n 2 python -m pytest -m "not serial"``.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from ufl_frames.bootstrap import init_petsc

init_petsc([])  # not pytest's command line

from mpi4py import MPI  # noqa: E402
from petsc4py import PETSc  # noqa: E402

from ufl_frames import __version__, solvers  # noqa: E402
from ufl_frames.app import cli  # noqa: E402
from ufl_frames.app.failures import UsageError  # noqa: E402
from ufl_frames.app.run import RunConfig, default_output_folder, run  # noqa: E402

COMM = MPI.COMM_WORLD
MPIRUN = Path(sys.prefix) / "bin" / "mpirun"
SCRIPT = Path(sys.prefix) / "bin" / "ufl-frames"
COARSE = ["--mesh-size", "0.2"]
SUMMARY_KEYS = {
    "H_initial", "H_final", "E_final", "iterations", "converged_reason", "num_vertices",
    "num_cells", "wall_time_s", "singularities", "history", "geometry", "isotropic",
    "mesh_size", "tao_type", "num_processes",
}
OUTPUT_FILES = {"summary.json", "frames.bp", "frames.png", "convergence.png"}


def run_cli(*args, cwd, timeout=300):
    """``python -m ufl_frames.app ARGS`` in ``cwd``; the CompletedProcess."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.run(
        [sys.executable, "-m", "ufl_frames.app", *map(str, args)],
        cwd=cwd, capture_output=True, text=True, timeout=timeout, env=env, check=False,
    )


def tree(path: Path) -> dict:
    """Every file and folder under ``path`` with its modification time and size."""
    return {str(p.relative_to(path)): (p.stat().st_mtime_ns, p.stat().st_size)
            for p in sorted(path.rglob("*"))}


def assert_one_line_error(proc, status):
    assert proc.returncode == status, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("ufl-frames: error: "), proc.stderr
    assert "Traceback" not in proc.stderr


@pytest.fixture
def shared_tmp(tmp_path):
    """rank 0's tmp_path on every rank: the CLI checks and writes the folder collectively."""
    return Path(COMM.bcast(str(tmp_path), root=0))


@pytest.fixture(scope="module")
def annulus_run(tmp_path_factory):
    """One coarse annulus run through app.run.run (collective), shared by several tests."""
    root = Path(COMM.bcast(str(tmp_path_factory.mktemp("annulus")), root=0))
    out = root / "out"
    options_before = PETSc.Options().getAll()
    summary = run(RunConfig("annulus", mesh_size=0.2, max_it=20, out=out, quiet=True), comm=COMM)
    return summary, out, options_before


# --- files, keys, consistency -------------------------------------------------------


def test_run_writes_all_files(annulus_run):
    _, out, _ = annulus_run
    assert OUTPUT_FILES <= {p.name for p in out.iterdir()}
    for png in ("frames.png", "convergence.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (out / "frames.bp" / "md.idx").is_file()


def test_summary_keys_and_consistency(annulus_run):
    summary, out, _ = annulus_run
    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk == json.loads(json.dumps(summary))
    assert SUMMARY_KEYS <= set(on_disk)
    assert on_disk["geometry"] == "annulus" and on_disk["isotropic"] is False
    assert on_disk["requested_mesh_size"] == 0.2 and on_disk["num_processes"] == COMM.size
    # The mesh size reported is the mean edge length actually meshed, a bit under the cap.
    assert 0.1 < on_disk["mesh_size"] <= 0.2
    # The annulus: no singularity, and Poincaré–Hopf (χ = 0, no corners) agrees.
    assert on_disk["poincare_hopf"]["agrees"] and on_disk["poincare_hopf"]["expected"] == 0
    assert on_disk["tao_type"] == solvers.DEFAULT_OPTIONS["tao_type"] == "nls"
    assert on_disk["num_vertices"] > 50 and on_disk["num_cells"] > on_disk["num_vertices"]
    assert on_disk["H_final"] <= on_disk["H_initial"]
    history = on_disk["history"]
    assert len(history) == on_disk["iterations"] + 1
    assert [h["it"] for h in history] == list(range(len(history)))
    assert all({"it", "H", "E", "gnorm"} <= set(h) for h in history)
    assert history[0]["H"] == on_disk["H_initial"] and history[-1]["H"] == on_disk["H_final"]
    assert history[-1]["E"] == on_disk["E_final"]
    assert on_disk["wall_time_s"] > 0
    assert isinstance(on_disk["converged_reason"], str) and on_disk["converged_reason"]


def test_annulus_has_no_singularities(annulus_run):
    summary, _, _ = annulus_run
    assert summary["singularities"] == []


def test_run_leaves_petsc_options_as_found(annulus_run):
    _, _, before = annulus_run
    assert PETSc.Options().getAll() == before


def test_piano_lists_singularities(shared_tmp):
    summary = run(RunConfig("piano", mesh_size=0.2, max_it=5, out=shared_tmp / "piano",
                            quiet=True), comm=COMM)
    assert isinstance(summary["singularities"], list)
    for s in summary["singularities"]:
        assert set(s) == {"index", "x", "y"}


def test_param_adds_the_map(shared_tmp):
    """--param: param.png, param.vtu and the map's measures in the summary (the annulus
    field is cut once, from the inner to the outer circle, and nothing flips)."""
    summary = run(RunConfig("annulus", mesh_size=0.2, max_it=20, out=shared_tmp / "p", quiet=True,
                            param=True, quad_size=0.2), comm=COMM)
    assert {"param.png", "param.vtu"} <= set(summary["files"])
    assert {p.name for p in (shared_tmp / "p").iterdir()} >= {"param.png", "param.vtu"}
    found = summary["param"]
    assert found["cuts"] == 1 and found["flipped_triangles"] == 0
    assert 0 < found["misfit"] < 0.2


COARSE_SQUARE = """// a unit square whose own point sizes (0.5) are coarser than the quads asked for
Point(1) = {0, 0, 0, 0.5}; Point(2) = {1, 0, 0, 0.5};
Point(3) = {1, 1, 0, 0.5}; Point(4) = {0, 1, 0, 0.5};
Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 1};
Curve Loop(1) = {1, 2, 3, 4}; Plane Surface(1) = {1};
"""


def test_quads_size_the_triangles(shared_tmp, capsys):
    """--quads --quad-size S without --mesh-size: the triangles are no larger than S (the
    file's own size, 0.5, is five times the quads'), the log says so, and the quads are
    the square's 10 × 10 grid; an explicit --mesh-size is kept."""
    geo = shared_tmp / "coarse_square.geo"
    if COMM.rank == 0:
        geo.write_text(COARSE_SQUARE)
    COMM.Barrier()
    summary = run(RunConfig(str(geo), conformal=True, quads=True, quad_size=0.1,
                            out=shared_tmp / "sq"), comm=COMM)
    lines = capsys.readouterr().out
    if COMM.rank == 0:
        assert "mesh size 0.1: the quad size" in lines
    assert summary["requested_mesh_size"] == 0.1 and summary["mesh_size"] <= 0.1
    found = summary["quads"]
    assert found["valid"] and found["quads"] == 100 and found["irregular_vertices"] == 0
    kept = run(RunConfig(str(geo), conformal=True, quads=True, quad_size=0.1, mesh_size=0.08,
                         out=shared_tmp / "sq2", quiet=True), comm=COMM)
    assert kept["requested_mesh_size"] == 0.08


def test_a_size_from_the_quads_resolves_the_shape():
    """The triangles' size taken from the quads' (``solve --quads --quad-size`` without
    ``--mesh-size``, and ``ufl-frames mesh``) is still capped by the local feature size
    (``resolve_features``); a ``--mesh-size`` the user gives is not."""
    from ufl_frames.app.run import sized_for_quads

    config, sized = sized_for_quads(RunConfig("shape.geo", conformal=True, quads=True,
                                              quad_size=0.1))
    assert sized and config.mesh_size == 0.1 and config.resolve_features
    config, sized = sized_for_quads(RunConfig("shape.geo", conformal=True, quads=True,
                                              quad_size=0.1, mesh_size=0.08))
    assert not sized and not config.resolve_features
    assert RunConfig.for_mesh("shape.geo", quad_size=0.1).resolve_features


def test_progress_lines(shared_tmp, capsys):
    run(RunConfig("annulus", mesh_size=0.2, max_it=3, out=shared_tmp / "o"), comm=COMM)
    lines = capsys.readouterr().out.splitlines()
    if COMM.rank == 0:
        text = "\n".join(lines)
        for stage in ("meshing annulus", "MBO initial field", "  level 0:", "solving",
                      "singularities: none", "wrote"):
            assert stage in text
        its = [line for line in lines if line.startswith("  it ")]
        assert len(its) >= 2 and "H " in its[0] and "|grad| " in its[0]
    else:
        assert lines == []


def test_quiet_run_prints_nothing(shared_tmp, capsys):
    run(RunConfig("annulus", mesh_size=0.2, max_it=2, out=shared_tmp / "o", quiet=True), comm=COMM)
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err == ""


# --- in-process main -------------------------------------------------------------------


def test_main_passes_petsc_options(shared_tmp):
    before = PETSc.Options().getAll()
    out = shared_tmp / "o"
    status = cli.main(["solve", "annulus", *COARSE, "--max-it", "50", "--out", out, "-q",
                       "-tao_type", "lmvm", "-tao_max_it", "2"])
    assert status == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["tao_type"] == "lmvm"
    assert summary["max_it"] == 2
    assert summary["iterations"] <= 2
    assert summary["petsc_options"] == {"tao_type": "lmvm", "tao_max_it": "2"}
    assert PETSc.Options().getAll() == before  # taken out again


@pytest.mark.parametrize(
    "args",
    [
        ["solve", "annulus", "--mesh-size", "0"],
        ["solve", "annulus", "--mesh-size", "-0.1"],
        ["solve", "annulus", "--mesh-size", "abc"],
        ["solve", "annulus", "--mesh-size", "nan"],
        ["solve", "annulus", "--max-it", "0"],
        ["solve", "annulus", "--max-it", "-3"],
        ["solve", "annulus", "--max-it", "2.5"],
        ["solve", "annulus", "stray"],
        ["solve", "annulus", "--bogus"],
        ["solve"],
        ["frobnicate"],
        [],
    ],
)
def test_main_usage_errors(args, shared_tmp, capsys, monkeypatch):
    monkeypatch.chdir(shared_tmp)
    assert cli.main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == (1 if COMM.rank == 0 else 0)
    if err:
        assert err[0].startswith("ufl-frames: error: ")
    assert list(shared_tmp.iterdir()) == []


def test_main_existing_output_folder_is_refused(shared_tmp, capsys):
    out = shared_tmp / "busy"
    if COMM.rank == 0:
        out.mkdir()
        (out / "keep.txt").write_text("precious")
    COMM.Barrier()
    before = tree(shared_tmp)
    assert cli.main(["solve", "annulus", *COARSE, "--out", out]) == 1
    err = capsys.readouterr().err
    if COMM.rank == 0:
        assert "--force" in err and len(err.strip().splitlines()) == 1
    assert tree(shared_tmp) == before
    assert (out / "keep.txt").read_text() == "precious"


def test_main_output_path_is_a_file(shared_tmp, capsys):
    out = shared_tmp / "file"
    if COMM.rank == 0:
        out.write_text("x")
    COMM.Barrier()
    assert cli.main(["solve", "annulus", *COARSE, "--out", out, "--force"]) == 1
    assert out.read_text() == "x"
    capsys.readouterr()


def test_main_force_and_empty_folder(shared_tmp):
    out = shared_tmp / "o"
    if COMM.rank == 0:
        out.mkdir()  # empty: accepted without --force
    COMM.Barrier()
    assert cli.main(["solve", "annulus", *COARSE, "--max-it", "2", "--out", out, "-q"]) == 0
    assert cli.main(["solve", "annulus", *COARSE, "--max-it", "2", "--out", out, "-q"]) == 1
    assert cli.main(["solve", "annulus", *COARSE, "--max-it", "2", "--out", out, "-q",
                     "--force"]) == 0


def test_main_unknown_geometry(shared_tmp, capsys, monkeypatch):
    monkeypatch.chdir(shared_tmp)
    assert cli.main(["solve", "trapezoid", *COARSE]) == 1
    err = capsys.readouterr().err
    if COMM.rank == 0:
        assert "trapezoid" in err and len(err.strip().splitlines()) == 1
    assert list(shared_tmp.iterdir()) == []


def test_split_petsc_options():
    assert cli.split_petsc_options(["-tao_type", "lmvm", "-tao_monitor", "-tao_gatol", "-1e-3"]) \
        == [("tao_type", "lmvm"), ("tao_monitor", None), ("tao_gatol", "-1e-3")]
    for bad in (["--nope"], ["stray"], ["-a", "b", "c"]):
        with pytest.raises(UsageError):
            cli.split_petsc_options(bad)


def test_default_output_folder():
    assert default_output_folder("piano") == Path("out_piano")
    assert default_output_folder("meshes/part.step") == Path("out_part")


# --- subprocesses (serial) -----------------------------------------------------------------


@pytest.mark.serial
def test_python_m_ufl_frames_is_the_command(tmp_path):
    """``python -m ufl_frames`` runs the ``ufl-frames`` command, as ``python -m ufl_frames.app``."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.run([sys.executable, "-m", "ufl_frames", "--help"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=120, env=env, check=False)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == run_cli("--help", cwd=tmp_path).stdout
    assert "solve" in proc.stdout


@pytest.mark.serial
@pytest.mark.parametrize(
    "args",
    [
        [],
        ["solve"],
        ["solve", "annulus", "--mesh-size", "0"],
        ["solve", "annulus", "--mesh-size", "-1"],
        ["solve", "annulus", "--max-it", "0"],
        ["solve", "annulus", "--bogus"],
    ],
)
def test_cli_usage_errors(args, tmp_path):
    proc = run_cli(*args, cwd=tmp_path)
    assert_one_line_error(proc, 2)
    assert proc.stdout == ""
    assert list(tmp_path.iterdir()) == []


def _write_bad_inputs(folder: Path) -> dict:
    (folder / "corrupt.msh").write_text("$MeshFormat\nthis is not a mesh\n")
    (folder / "box.geo").write_text('SetFactory("OpenCASCADE");\nBox(1) = {0, 0, 0, 1, 1, 1};\n')
    (folder / "notes.txt").write_text("hello")
    return {
        "unknown name": ["trapezoid"],
        "missing file": ["missing.msh"],
        "corrupt file": ["corrupt.msh"],
        "3D geometry on the 2D path": ["box.geo", "--dim", "2"],
        "unsupported file": ["notes.txt"],
    }


@pytest.mark.serial
def test_cli_geometry_errors(tmp_path):
    cases = _write_bad_inputs(tmp_path)
    before = tree(tmp_path)
    for what, args in cases.items():
        proc = run_cli("solve", *args, *COARSE, cwd=tmp_path)
        assert_one_line_error(proc, 1)
        assert tree(tmp_path) == before, what


@pytest.mark.serial
def test_cli_existing_output_folder(tmp_path):
    out = tmp_path / "out_annulus"
    out.mkdir()
    (out / "summary.json").write_text("{}")
    before = tree(tmp_path)
    proc = run_cli("solve", "annulus", *COARSE, cwd=tmp_path)  # default --out
    assert_one_line_error(proc, 1)
    assert "out_annulus" in proc.stderr and "--force" in proc.stderr
    assert tree(tmp_path) == before


@pytest.mark.serial
def test_cli_version_and_info(tmp_path):
    proc = run_cli("--version", cwd=tmp_path)
    assert proc.returncode == 0 and proc.stdout.strip() == f"ufl-frames {__version__}"
    proc = run_cli("info", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    for name in ("dolfinx", "petsc", "gmsh", "mpi"):
        assert name in proc.stdout


@pytest.mark.serial
def test_cli_solve_with_petsc_options(tmp_path):
    proc = run_cli("solve", "annulus", *COARSE, "--max-it", "20", "-q",
                   "-tao_type", "lmvm", "-tao_max_it", "3", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == ""
    summary = json.loads((tmp_path / "out_annulus" / "summary.json").read_text())
    assert summary["tao_type"] == "lmvm"
    assert summary["iterations"] <= 3
    assert len(summary["history"]) == summary["iterations"] + 1
    assert OUTPUT_FILES <= {p.name for p in (tmp_path / "out_annulus").iterdir()}


needs_mpirun = pytest.mark.skipif(not MPIRUN.exists(), reason=f"no {MPIRUN}")


@pytest.mark.serial
@needs_mpirun
def test_cli_under_mpirun(tmp_path):
    command = [str(SCRIPT)] if SCRIPT.exists() else [sys.executable, "-m", "ufl_frames.app"]
    proc = subprocess.run(
        [str(MPIRUN), "-n", "2", *command, "solve", "annulus", *COARSE, "--max-it", "10",
         "--out", "par"],
        cwd=tmp_path, capture_output=True, text=True, timeout=300, check=False,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.count("meshing annulus") == 1  # progress from rank 0 only
    summary = json.loads((tmp_path / "par" / "summary.json").read_text())
    assert summary["num_processes"] == 2
    assert summary["singularities"] == []
    assert summary["H_final"] <= summary["H_initial"]
    assert OUTPUT_FILES <= {p.name for p in (tmp_path / "par").iterdir()}


@pytest.mark.serial
@needs_mpirun
def test_cli_error_under_mpirun_is_reported_once(tmp_path):
    command = [str(SCRIPT)] if SCRIPT.exists() else [sys.executable, "-m", "ufl_frames.app"]
    proc = subprocess.run(
        [str(MPIRUN), "-n", "2", *command, "solve", "nosuch.msh", *COARSE],
        cwd=tmp_path, capture_output=True, text=True, timeout=120, check=False,
    )
    assert_one_line_error(proc, 1)
    assert list(tmp_path.iterdir()) == []


# The disc (circles through a centre point) with two holes, and a second surface
# sharing a curve that asks for quadrilaterals: what real .geo files look like.
REAL_GEO = """Point(1) = {0, 0, 0}; Point(2) = {1, 0, 0}; Point(3) = {0, 1, 0};
Point(4) = {-1, 0, 0}; Point(5) = {0, -1, 0};
Circle(1) = {2, 1, 3}; Circle(2) = {3, 1, 4}; Circle(3) = {4, 1, 5}; Circle(4) = {5, 1, 2};
Point(6) = {0.4, 0, 0}; Point(7) = {0.6, 0, 0}; Point(8) = {0.4, 0.2, 0};
Point(9) = {0.2, 0, 0}; Point(10) = {0.4, -0.2, 0};
Circle(5) = {7, 6, 8}; Circle(6) = {8, 6, 9}; Circle(7) = {9, 6, 10}; Circle(8) = {10, 6, 7};
Point(20) = {-0.4, 0.3, 0}; Point(21) = {-0.3, 0.3, 0}; Point(22) = {-0.4, 0.4, 0};
Point(23) = {-0.5, 0.3, 0}; Point(24) = {-0.4, 0.2, 0};
Circle(20) = {21, 20, 22}; Circle(21) = {22, 20, 23}; Circle(22) = {23, 20, 24};
Circle(23) = {24, 20, 21};
Curve Loop(1) = {1, 2, 3, 4}; Curve Loop(2) = {5, 6, 7, 8}; Curve Loop(3) = {20, 21, 22, 23};
Plane Surface(1) = {1, 2, 3};
Point(12) = {1, -1, 0}; Point(13) = {2, -1, 0}; Point(14) = {2, 0, 0};
Line(9) = {5, 12}; Line(10) = {12, 13}; Line(11) = {13, 14}; Line(12) = {14, 2};
Curve Loop(4) = {9, 10, 11, 12, -4}; Plane Surface(2) = {4};
Recombine Surface{2};
"""


def test_run_solve_on_a_real_geo_file(shared_tmp):
    path = shared_tmp / "real.geo"
    if COMM.rank == 0:
        path.write_text(REAL_GEO)
    COMM.Barrier()
    summary = run(RunConfig(str(path), mesh_size=0.15, max_it=10, out=shared_tmp / "out",
                            quiet=True), comm=COMM)
    notes = " ".join(summary["loader_notes"])
    assert "no triangle uses" in notes and "quadrilaterals split" in notes
    check = summary["poincare_hopf"]
    # χ = 1 − 2 holes. Corners: (2, −1) and (2, 0) convex right angles (+1/4 each), (1, 0)
    # reflex, where the top side meets the disc (−1/4); (0, −1) is tangential, (1, −1)
    # straight. So −1 − (1/4 + 1/4 − 1/4).
    assert check["euler_characteristic"] == -1 and check["corners"] == 3
    assert check["expected"] == -1.25
    assert check["agrees"], summary["singularities"]
    assert summary["requested_mesh_size"] == 0.15
    assert summary["mesh_size"] <= 0.15
