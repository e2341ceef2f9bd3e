"""Bad input and failures of the ``ufl-frames`` command: one line, a status, nothing partial.

Every case checks the exit status, exactly one ``ufl-frames: error:`` line on stderr, no
traceback, and that nothing outside the output folder was touched (no hidden staging
folder left behind). Subprocess tests (some under ``mpirun -n 2``) are marked ``serial``;
the in-process ones also run under ``mpirun -n 2 python -m pytest -m "not serial"``.
"""

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from ufl_frames.bootstrap import init_petsc

init_petsc([])  # not pytest's command line

from mpi4py import MPI  # noqa: E402

from ufl_frames import checkpoint, interrupts, output, petsc_options  # noqa: E402
from ufl_frames.app import cli  # noqa: E402
from ufl_frames.app.failures import InputError  # noqa: E402
from ufl_frames.app.run import RunConfig, run  # noqa: E402
from ufl_frames.fem import energy  # noqa: E402
from ufl_frames.output import figures  # noqa: E402

COMM = MPI.COMM_WORLD
MPIRUN = Path(sys.prefix) / "bin" / "mpirun"
COARSE = ["--mesh-size", "0.2", "--max-it", "3"]
ERROR = "ufl-frames: error: "
TRIANGLE = ("Point(1) = {0, 0, 0}; Point(2) = {1, 0, 0}; Point(3) = {0, 1, 0};\n"
            "Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 1};\n"
            "Curve Loop(1) = {1, 2, 3}; Plane Surface(1) = {1};\n")
# A curve loop through itself: Gmsh's 2D meshing of it never ends.
BOWTIE = ("Point(1) = {0, 0, 0}; Point(2) = {1, 1, 0}; Point(3) = {1, 0, 0};\n"
          "Point(4) = {0, 1, 0}; Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4};\n"
          "Line(4) = {4, 1}; Curve Loop(1) = {1, 2, 3, 4}; Plane Surface(1) = {1};\n")
# Options that make a solve fail inside PETSc, after validation.
MBO_FAILS = ["-mbo_ksp_type", "cg", "-mbo_pc_type", "none", "-mbo_ksp_max_it", "1",
             "-mbo_ksp_rtol", "1e-30"]
TAO_FAILS = ["-tao_nls_ksp_type", "richardson", "-tao_nls_pc_type", "none",
             "-tao_nls_ksp_max_it", "1", "-tao_nls_ksp_error_if_not_converged"]

needs_mpirun = pytest.mark.skipif(not MPIRUN.exists(), reason=f"no {MPIRUN}")


def _env(**extra):
    return {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1", **extra}


def _command(mpi: bool = False) -> list[str]:
    command = [sys.executable, "-m", "ufl_frames.app"]
    return [str(MPIRUN), "-n", "2", *command] if mpi else command


def run_cli(*args, cwd, mpi=False, timeout=120, env=None):
    """``python -m ufl_frames.app ARGS`` in ``cwd`` (under ``mpirun -n 2`` if ``mpi``)."""
    return subprocess.run([*_command(mpi), *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=timeout, env=env or _env(), check=False)


def tree(path: Path) -> dict:
    """Every entry under ``path`` (links not followed), with its mtime and size."""
    return {str(p.relative_to(path)): (p.lstat().st_mtime_ns, p.lstat().st_size)
            for p in sorted(path.rglob("*"))}


def assert_one_line_error(proc, status, *words):
    assert proc.returncode == status, (proc.returncode, proc.stderr)
    errors = [line for line in proc.stderr.splitlines() if line.startswith(ERROR)]
    assert len(errors) == 1, proc.stderr
    assert "Traceback" not in proc.stderr and "PETSC ERROR" not in proc.stderr, proc.stderr
    for word in words:
        assert word in errors[0], proc.stderr
    return errors[0]


def assert_nothing_partial(folder: Path):
    leftovers = [p.name for p in folder.iterdir() if p.name.startswith(".")]
    assert leftovers == [], leftovers


@pytest.fixture
def shared_tmp(tmp_path):
    """rank 0's tmp_path on every rank."""
    return Path(COMM.bcast(str(tmp_path), root=0))


# --- PETSc options and arguments, refused before meshing (in-process) ------------------------


@pytest.mark.parametrize(
    "options, words",
    [
        (["-tao_type", "gpcg"], ["gpcg", "nls", "lmvm", "bncg"]),
        (["-tao_type", "owlqn"], ["owlqn"]),
        (["-tao_type", "ipm"], ["ipm"]),
        (["-tao_type", "pdipm"], ["pdipm"]),
        (["-tao_type", "almm"], ["almm"]),
        (["-tao_type", "shell"], ["shell"]),
        (["-tao_type", "python"], ["python"]),
        (["-tao_type", "admm"], ["admm"]),
        (["-tao_type", "lcl"], ["lcl"]),
        (["-tao_type", "nosuch"], ["nosuch"]),
        (["-tao_type"], ["-tao_type needs a value"]),
        (["-tao_max_it", "0"], ["-tao_max_it"]),
        (["-tao_max_it", "-5"], ["-tao_max_it"]),
        (["-tao_max_it", "2.5"], ["-tao_max_it"]),
        (["-tao_max_it", "99999999999999999999"], ["-tao_max_it"]),
        (["-tao_nls_ksp_type", "nosuch"], ["KSP", "nosuch"]),
        (["-tao_nls_pc_type", "nosuch"], ["PC", "nosuch"]),
        (["-tao_ntr_ksp_type", "nosuch"], ["KSP"]),
        (["-tao_bnk_pc_type", "nosuch"], ["PC"]),
        (["-mbo_ksp_type", "gmress"], ["-mbo_ksp_type", "gmress"]),
        (["-mbo_pc_type", "gamgg"], ["-mbo_pc_type"]),
        (["-tao_ls_type", "nosuch"], ["line search"]),
        (["-frames_hessian", "newton"], ["exact", "gauss_newton"]),
        (["-frames_gn_damping", "-1"], ["-frames_gn_damping"]),
        (["-frames_gn_damping", "abc"], ["-frames_gn_damping"]),
        (["-frames_gn_damping_min", "nan"], ["-frames_gn_damping_min"]),
        (["-frames_gn_damping_min", "inf"], ["-frames_gn_damping_min"]),
        (["-tao_gttol", "-1"], ["-tao_gttol"]),
        (["-frames_h_rtol", "-1e-4"], ["-frames_h_rtol"]),
        (["-frames_nested_rtol", "-1e-3"], ["-frames_nested_rtol"]),
        (["-frames_nested_rtol", "nan"], ["-frames_nested_rtol"]),
        (["-frames_active_rounds", "-1"], ["-frames_active_rounds"]),
        (["-frames_active_rounds", "1.5"], ["-frames_active_rounds"]),
        (["-frames_hessian_inertia_shifts", "-1"], ["-frames_hessian_inertia_shifts"]),
        (["-frames_size_smoothing", "-0.1"], ["-frames_size_smoothing", ">= 0"]),
        (["-frames_size_smoothing", "inf"], ["-frames_size_smoothing"]),
        (["-frames_active_consistent", "maybe"], ["-frames_active_consistent", "true or false"]),
    ],
)
def test_bad_petsc_options_are_usage_errors(options, words, shared_tmp, capsys, monkeypatch):
    monkeypatch.chdir(shared_tmp)
    assert cli.main(["solve", "annulus", *COARSE, *options]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == (1 if COMM.rank == 0 else 0)
    if err:
        assert err[0].startswith(ERROR)
        for word in words:
            assert word in err[0], err[0]
    assert "meshing" not in captured.out
    assert list(shared_tmp.iterdir()) == []


@pytest.mark.parametrize("value", ["99999999999999999999", str(2**31)])
def test_max_it_out_of_range(value, shared_tmp, capsys, monkeypatch):
    monkeypatch.chdir(shared_tmp)
    assert cli.main(["solve", "annulus", "--max-it", value]) == 2
    if COMM.rank == 0:
        assert "--max-it" in capsys.readouterr().err
    assert list(shared_tmp.iterdir()) == []


def test_supported_tao_types_pass_validation():
    for tao_type in petsc_options.TAO_TYPES:
        assert petsc_options.petsc_option_problem({"tao_type": tao_type}) is None
    for name, value in [("tao_nls_ksp_type", "gmres"), ("mbo_pc_type", "gamg"),
                        ("tao_ls_type", "armijo"), ("frames_hessian", "exact"),
                        ("frames_gn_damping", "0"), ("tao_max_it", "7"), ("frames_h_rtol", "0"),
                        ("frames_nested_rtol", "0"), ("frames_active_rounds", "0"),
                        ("frames_size_smoothing", "0.01"),
                        ("tao_bncg_type", "gd"), ("tao_monitor", None)]:
        assert petsc_options.petsc_option_problem([(name, value)]) is None, name
    # The last value of an option counts, as in PETSc.
    assert petsc_options.petsc_option_problem([("tao_type", "gpcg"), ("tao_type", "lmvm")]) is None


def test_run_solve_checks_the_options_database(shared_tmp):
    from ufl_frames.bootstrap import options_scope

    with options_scope([("tao_type", "pounders")]):
        with pytest.raises(InputError, match="pounders"):
            run(RunConfig("annulus", mesh_size=0.2, out=shared_tmp / "o", quiet=True), comm=COMM)
    assert list(shared_tmp.iterdir()) == []


# --- failures after validation, in-process (collective) ---------------------------------------


def test_write_failure_is_one_line_and_leaves_nothing(shared_tmp, capsys, monkeypatch):
    def full_disk(path, *args):
        raise OSError(28, "No space left on device", str(path))

    monkeypatch.setattr(figures, "_draw_convergence", full_disk)
    monkeypatch.setattr(checkpoint, "CHECKPOINT_EVERY", 1)  # checkpoints, removed too
    if COMM.rank == 0:
        (shared_tmp / "keep").mkdir()
    COMM.Barrier()
    before = tree(shared_tmp)
    out = shared_tmp / "o"
    assert cli.main(["solve", "annulus", *COARSE, "-q", "--out", out]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    errors = [line for line in err if line.startswith(ERROR)]
    assert len(errors) == (1 if COMM.rank == 0 else 0), err
    if errors:
        assert "No space left on device" in errors[0] and "writing the results" in errors[0]
    assert tree(shared_tmp) == before  # no output folder, no staging folder


def test_stale_staging_folder_does_not_block_a_rerun(shared_tmp):
    stale = shared_tmp / ".o.ufl-frames-dead.partial"
    if COMM.rank == 0:
        stale.mkdir()
        (stale / "frames.png").write_text("half")
    COMM.Barrier()
    assert cli.main(["solve", "annulus", *COARSE, "-q", "--out", shared_tmp / "o"]) == 0
    assert (shared_tmp / "o" / "summary.json").is_file()
    assert (stale / "frames.png").read_text() == "half"  # another run's: not ours to remove


# --- geometry files refused or stopped (in-process, collective) --------------------------------


def _main_error(args, capsys) -> tuple[int, str | None]:
    """(status, the one error line on rank 0 or None elsewhere) of ``cli.main(args)``."""
    status = cli.main(args)
    err = capsys.readouterr().err.strip().splitlines()
    errors = [line for line in err if line.startswith(ERROR)]
    assert len(errors) == (1 if COMM.rank == 0 else 0), err
    assert "Traceback" not in "\n".join(err)
    return status, errors[0] if errors else None


@pytest.mark.parametrize(
    "script, words",
    [
        ('SystemCall "touch made";', ["line 4", "SystemCall", "runs a program"]),
        ('NonBlockingSystemCall "touch made";', ["NonBlockingSystemCall"]),
        ('System "touch made";', ["System", "runs a program"]),
        ('OnelabRun("x", "touch made");', ["OnelabRun"]),
        ('Save "made.msh";', ["Save", "writes a file"]),
        ('Print "made.png";', ["Print", "writes a file"]),
        ('CreateDir "made";', ["CreateDir", "creates a folder"]),
        ('Printf("a %g", 1 > 0) > "made";', ["Printf", "writes a file"]),
        ('Printf("a") >> "made";', ["Printf", "writes a file"]),
        ('Include StrCat("in", "ner.geo");', ["Include", "computed"]),
        ('Merge "inner.geo";', ["inner.geo", "line 4", "Save"]),
    ],
    ids=lambda v: v if isinstance(v, str) and " " not in v else None,
)
def test_geo_commands_that_act_outside_are_refused(script, words, shared_tmp, capsys,
                                                   monkeypatch):
    monkeypatch.chdir(shared_tmp)
    if COMM.rank == 0:
        (shared_tmp / "inner.geo").write_text(TRIANGLE + 'Save "made.msh";\n')
        (shared_tmp / "shape.geo").write_text(
            TRIANGLE + f"{script}\n// SystemCall in a comment, Printf(\"x\"); are fine\n")
    COMM.Barrier()
    before = tree(shared_tmp)
    status, line = _main_error(["solve", "shape.geo", *COARSE, "-q"], capsys)
    assert status == 1
    if line is not None:
        for word in words:
            assert word in line, line
    assert tree(shared_tmp) == before  # nothing ran, nothing made


@pytest.mark.parametrize(
    "text, words",
    [(BOWTIE, ["surface 1 crosses itself", "curves 1 and 3", "(0.5, 0.5)"]),
     (TRIANGLE + "Point(5) = {0.4, 0.1, 0}; Point(6) = {0.8, 0.1, 0}; Point(7) = {0.6, 0.1, 0};\n"
      "Circle(5) = {5, 7, 6}; Circle(6) = {6, 7, 5}; Curve Loop(2) = {5, 6};\n"
      "Plane Surface(2) = {1, 2};\n", ["surface 2", "cross"])],
    ids=["bowtie", "hole-across-the-outline"],
)
def test_crossing_boundary_is_refused_before_meshing(text, words, shared_tmp, capsys,
                                                     monkeypatch):
    monkeypatch.chdir(shared_tmp)
    if COMM.rank == 0:
        (shared_tmp / "cross.geo").write_text(text)
    COMM.Barrier()
    started = time.monotonic()
    status, line = _main_error(["solve", "cross.geo", *COARSE, "-q"], capsys)
    assert status == 1
    assert time.monotonic() - started < 30  # refused, not stopped by the time limit
    if line is not None:
        for word in words:
            assert word in line, line
    assert sorted(p.name for p in shared_tmp.iterdir()) == ["cross.geo"]


def test_mesh_time_limit_stops_gmsh(shared_tmp, capsys, monkeypatch):
    monkeypatch.chdir(shared_tmp)
    if COMM.rank == 0:
        (shared_tmp / "slow.geo").write_text(TRIANGLE + "Sleep 600;\n")
    COMM.Barrier()
    started = time.monotonic()
    status, line = _main_error(["solve", "slow.geo", *COARSE, "-q", "--mesh-time-limit", "1"],
                               capsys)
    assert status == 1
    assert time.monotonic() - started < 20
    if line is not None:
        assert "did not end within the time limit of 1 s" in line, line
        assert "--mesh-time-limit" in line, line
    assert sorted(p.name for p in shared_tmp.iterdir()) == ["slow.geo"]


@pytest.mark.parametrize("value", ["0", "-1", "nan", "soon"])
def test_bad_mesh_time_limit_is_a_usage_error(value, shared_tmp, capsys, monkeypatch):
    monkeypatch.chdir(shared_tmp)
    status, line = _main_error(["solve", "annulus", "--mesh-time-limit", value], capsys)
    assert status == 2
    if line is not None:
        assert "--mesh-time-limit" in line, line
    assert list(shared_tmp.iterdir()) == []


# --- checkpoint and resume (in-process, collective) -------------------------------------------


RESUMABLE = ["solve", "annulus", "--mesh-size", "0.1", "-q"]


def _interrupt_tao_after(monkeypatch, iterates: int) -> None:
    """A SIGINT seen by the run at its ``iterates``-th TAO iterate (no real signal)."""
    real, seen = interrupts.pending, []

    def pending(comm):
        watch = interrupts._WATCH
        if watch is not None and watch.stage.startswith("the TAO solve"):
            seen.append(1)
            if len(seen) >= iterates:
                return signal.SIGINT
        return real(comm)

    monkeypatch.setattr(interrupts, "pending", pending)


def test_resume_gives_the_uninterrupted_result(shared_tmp, capsys, monkeypatch):
    full, out = shared_tmp / "full", shared_tmp / "o"
    assert cli.main([*RESUMABLE, "--out", full]) == 0
    reference = json.loads((full / "summary.json").read_text())
    assert reference["iterations"] > 4 and reference["resumed_from_iteration"] is None

    with monkeypatch.context() as patch:
        _interrupt_tao_after(patch, 4)
        status, line = _main_error([*RESUMABLE, "--out", out], capsys)
    assert status == interrupts.INTERRUPTED_STATUS
    if line is not None:
        assert f"resume with --resume {out}" in line, line
    assert sorted(p.name for p in out.iterdir()) == ["checkpoint"]
    assert [p.name for p in (out / "checkpoint").iterdir()] == ["state.npz"]
    kept = tree(out)

    # Refused, the checkpoint untouched: another run into the folder, other arguments.
    cases = [
        ([*RESUMABLE, "--out", out], 1, ["holds the checkpoint", "--resume"]),
        (["solve", "piano", "--mesh-size", "0.1", "-q", "--resume", out], 1, ["GEOMETRY"]),
        ([*RESUMABLE[:-2], "0.2", "-q", "--resume", out], 1, ["--mesh-size", "0.1", "0.2"]),
        ([*RESUMABLE, "--isotropic", "--resume", out], 1, ["--isotropic"]),
        ([*RESUMABLE, "--resume", out, "-tao_type", "lmvm"], 1, ["PETSc options"]),
        ([*RESUMABLE, "--resume", out, "--out", shared_tmp / "other"], 2, ["--out", "--resume"]),
    ]
    for args, expected, words in cases:
        status, line = _main_error(args, capsys)
        assert status == expected, (args, line)
        if line is not None:
            for word in words:
                assert word in line, (args, line)
        assert tree(out) == kept
    assert sorted(p.name for p in shared_tmp.iterdir()) == ["full", "o"]

    assert cli.main([*RESUMABLE, "--resume", out]) == 0
    resumed = json.loads((out / "summary.json").read_text())
    assert resumed["resumed_from_iteration"] >= 2
    assert resumed["iterations"] == reference["iterations"]
    assert resumed["converged_reason"] == reference["converged_reason"]
    assert resumed["H_final"] == pytest.approx(reference["H_final"], rel=1e-10)
    assert [e["it"] for e in resumed["history"]] == list(range(resumed["iterations"] + 1))
    assert not (out / "checkpoint").exists()
    assert set(resumed["files"]) == {p.name for p in out.iterdir()}
    assert_nothing_partial(shared_tmp)


def test_resume_bad_input(shared_tmp, capsys, monkeypatch):
    monkeypatch.chdir(shared_tmp)
    if COMM.rank == 0:
        (shared_tmp / "empty").mkdir()
        (shared_tmp / "junk" / "checkpoint").mkdir(parents=True)
        (shared_tmp / "junk" / "checkpoint" / "state.npz").write_bytes(b"not a checkpoint")
        (shared_tmp / "file").write_text("x")
    COMM.Barrier()
    before = tree(shared_tmp)
    for folder, words in [("nowhere", ["'nowhere' does not exist"]),
                          ("file", ["not a folder"]),
                          ("empty", ["holds no checkpoint"]),
                          ("junk", ["truncated or not a checkpoint"])]:
        status, line = _main_error([*RESUMABLE, "--resume", folder], capsys)
        assert status == 1, folder
        if line is not None:
            assert "cannot resume" in line, line
            for word in words:
                assert word in line, line
    assert tree(shared_tmp) == before


def test_resume_refuses_a_checkpoint_of_another_mesh(shared_tmp, capsys, monkeypatch):
    out = shared_tmp / "o"
    with monkeypatch.context() as patch:
        _interrupt_tao_after(patch, 3)
        assert cli.main([*RESUMABLE, "--out", out]) == interrupts.INTERRUPTED_STATUS
    capsys.readouterr()
    state = out / "checkpoint" / "state.npz"
    if COMM.rank == 0:  # the same arguments, another mesh (a new Gmsh, say)
        with np.load(state) as data:
            arrays = {k: data[k] for k in data.files}
        meta = json.loads(str(arrays["meta"]))
        meta["mesh_key"] = "0" * 64
        arrays["meta"] = np.array(json.dumps(meta))
        with open(state, "wb") as f:
            np.savez(f, **arrays)
    COMM.Barrier()
    before = tree(out)
    status, line = _main_error([*RESUMABLE, "--resume", out], capsys)
    assert status == 1
    if line is not None:
        assert "another mesh" in line, line
    assert tree(out) == before


# --- the output folder ------------------------------------------------------------------------


def test_force_replaces_only_own_names_and_never_follows_links(shared_tmp):
    out, outside = shared_tmp / "o", shared_tmp / "outside"
    if COMM.rank == 0:
        out.mkdir()
        outside.mkdir()
        (outside / "target.png").write_text("precious")
        (out / "frames.png").symlink_to(outside / "target.png")
        (out / "notes.txt").write_text("mine")
        (out / "frames_p7_000000.vtu").write_text("an earlier run on 8 processes")
        (out / "summary.json").write_text("{}")
    COMM.Barrier()
    assert cli.main(["solve", "annulus", *COARSE, "-q", "--out", out, "--force"]) == 0
    assert (outside / "target.png").read_text() == "precious"
    assert not (out / "frames.png").is_symlink()
    assert (out / "frames.png").read_bytes()[:4] == b"\x89PNG"
    assert (out / "notes.txt").read_text() == "mine"
    assert not (out / "frames_p7_000000.vtu").exists()  # the earlier run's: no mixing
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["files"]) | {"notes.txt"} == {p.name for p in out.iterdir()}
    assert_nothing_partial(shared_tmp)


def test_empty_and_linked_output_folders_are_kept(shared_tmp):
    empty, real, link = shared_tmp / "empty", shared_tmp / "real", shared_tmp / "link"
    if COMM.rank == 0:
        empty.mkdir()
        real.mkdir()
        link.symlink_to(real)
    COMM.Barrier()
    inode = empty.stat().st_ino
    assert cli.main(["solve", "annulus", *COARSE, "-q", "--out", empty]) == 0
    assert empty.stat().st_ino == inode  # filled, not replaced (it may be a working folder)
    assert cli.main(["solve", "annulus", *COARSE, "-q", "--out", link]) == 0
    assert link.is_symlink() and (real / "summary.json").is_file()
    assert_nothing_partial(shared_tmp)


def test_root_output_folder_is_refused(shared_tmp, capsys, monkeypatch):
    monkeypatch.chdir(shared_tmp)
    assert cli.main(["solve", "annulus", *COARSE, "-q", "--out", "/", "--force"]) == 1
    if COMM.rank == 0:
        assert "root" in capsys.readouterr().err
    assert list(shared_tmp.iterdir()) == []


def test_output_folder_refuses_to_replace_another_runs_results(shared_tmp):
    out = shared_tmp / "o"
    first = output.OutputFolder(out, comm=COMM)
    second = output.OutputFolder(out, comm=COMM)
    for folder, text in ((first, "first"), (second, "second")):
        staging = folder.open()
        if COMM.rank == 0:
            (staging / "summary.json").write_text(text)
        COMM.Barrier()
    first.commit()
    with pytest.raises((output.OutputFolderBusy, output.WriteError), match="another run"):
        second.commit()
    second.discard()
    COMM.Barrier()  # discard is rank 0's alone (not collective): wait for it before looking
    assert (out / "summary.json").read_text() == "first"
    assert_nothing_partial(shared_tmp)


def test_output_folder_discard_removes_created_parents(shared_tmp):
    folder = output.OutputFolder(shared_tmp / "a" / "b" / "o", comm=COMM)
    folder.open()
    folder.discard()
    COMM.Barrier()
    assert list(shared_tmp.iterdir()) == []


def test_output_names():
    for name in ("summary.json", "frames.bp", "frames000000.pvtu", "frames_p12_000000.vtu",
                 "frames.png", "convergence.png", "frames.pvd", "checkpoint"):
        assert output.is_output_name(name), name
    for name in ("notes.txt", "frames.png.bak", "my_frames.png", "frames_px_000000.vtu"):
        assert not output.is_output_name(name), name


# --- library checks -----------------------------------------------------------------------------


def test_io_refuses_what_is_not_a_frame_field(shared_tmp):
    import dolfinx
    import dolfinx.fem as fem

    mesh = dolfinx.mesh.create_unit_square(COMM, 2, 2)
    cube = dolfinx.mesh.create_unit_cube(COMM, 1, 1, 1)
    quads = dolfinx.mesh.create_unit_square(COMM, 2, 2, dolfinx.mesh.CellType.quadrilateral)
    bad = {
        "not a Function": mesh,
        "components": fem.Function(fem.functionspace(mesh, ("Lagrange", 1, (2,)))),
        "P1": fem.Function(fem.functionspace(mesh, ("Lagrange", 2, (5,)))),
        "continuous": fem.Function(fem.functionspace(mesh, ("DG", 1, (5,)))),
        "triangle": fem.Function(fem.functionspace(quads, ("Lagrange", 1, (5,)))),
        "2D": fem.Function(fem.functionspace(cube, ("Lagrange", 1, (5,)))),
    }
    for words, q in bad.items():
        for call, first in ((output.write_field, shared_tmp),
                            (output.plot_frames, shared_tmp / "f.png"), (energy.bracket_rms, None)):
            with pytest.raises(ValueError, match=words.split()[-1]):
                call(q) if first is None else call(first, q)
    with pytest.raises(ValueError, match="history"):
        output.plot_convergence(shared_tmp / "c.png", [], comm=COMM)
    with pytest.raises(ValueError, match="dict"):
        output.write_summary(shared_tmp / "s.json", [1, 2], comm=COMM)
    good = fem.Function(fem.functionspace(mesh, ("Lagrange", 1, (5,))))
    energy.check_frame_function(good)
    with pytest.raises(FileNotFoundError):
        output.write_field(shared_tmp / "missing", good)
    assert list(shared_tmp.iterdir()) == []


# --- subprocesses ---------------------------------------------------------------------------------


@pytest.mark.serial
@pytest.mark.parametrize(
    "args, words",
    [
        (["-tao_type", "pounders"], ["pounders"]),  # segfaulted in TAO
        (["-tao_type", "ssils"], ["ssils"]),  # segfaulted in TAO
        (["-tao_nls_pc_type", "nosuch"], ["nosuch"]),
        (["--max-it", "99999999999999999999"], ["--max-it"]),
    ],
)
def test_cli_refuses_bad_options_before_meshing(args, words, tmp_path):
    proc = run_cli("solve", "annulus", "--mesh-size", "0.2", *args, cwd=tmp_path)
    assert_one_line_error(proc, 2, *words)
    assert "meshing" not in proc.stdout
    assert "There are" not in proc.stderr  # no PETSc report of options left unused
    assert list(tmp_path.iterdir()) == []


@pytest.mark.serial
def test_cli_non_utf8_arguments(tmp_path):
    bad = os.fsdecode(b"\xff.geo")
    for args in (["solve", bad], ["solve", "annulus", "--out", os.fsdecode(b"o\xff")]):
        proc = subprocess.run([*_command(), *args], cwd=tmp_path, capture_output=True,
                              timeout=60, env=_env(), check=False)
        proc.stderr = proc.stderr.decode("utf-8", "backslashreplace")
        assert_one_line_error(proc, 2, "UTF-8")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.serial
@pytest.mark.parametrize("script", ["Exit;", "Exit(3);", 'Include "inner.geo";'])
def test_cli_geo_that_calls_exit(script, tmp_path):
    (tmp_path / "inner.geo").write_text(TRIANGLE + "Exit;\n")
    (tmp_path / "shape.geo").write_text(TRIANGLE + "// Exit; in a comment is fine\n" + script)
    before = tree(tmp_path)
    proc = run_cli("solve", "shape.geo", *COARSE, cwd=tmp_path)
    assert_one_line_error(proc, 1, "Exit")
    assert tree(tmp_path) == before


@pytest.mark.serial
@pytest.mark.parametrize(
    "options, words",
    [(MBO_FAILS, ["MBO", "KSP reason"]), (TAO_FAILS, ["TAO", "PETSc error"])],
    ids=["mbo", "tao"],
)
def test_cli_solver_failures(options, words, tmp_path):
    proc = run_cli("solve", "annulus", *COARSE, "-q", "--out", "o", *options, cwd=tmp_path)
    assert_one_line_error(proc, 1, *words)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.serial
def test_cli_debug_variable_shows_the_traceback(tmp_path):
    proc = run_cli("solve", "annulus", *COARSE, "-q", *TAO_FAILS, cwd=tmp_path,
                   env=_env(UFL_FRAMES_DEBUG="1"))
    assert proc.returncode == 1
    assert "Traceback" in proc.stderr
    assert sum(line.startswith(ERROR) for line in proc.stderr.splitlines()) == 1


@pytest.mark.serial
def test_cli_unwritable_output(tmp_path):
    proc = run_cli("solve", "annulus", *COARSE, "-q", "--out", "/proc/ufl-frames-test",
                   cwd=tmp_path)
    assert_one_line_error(proc, 1, "/proc")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.serial
def test_cli_two_runs_to_one_new_folder(tmp_path):
    args = [*_command(), "solve", "annulus", *COARSE, "-q", "--out", "same"]
    procs = [subprocess.Popen(args, cwd=tmp_path, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True, env=_env()) for _ in range(2)]
    results = [(p.wait(timeout=120), p.stderr.read()) for p in procs]
    for p in procs:
        p.stdout.close()
        p.stderr.close()
    # One wins; the other is refused, at the end ("another run") or, if it started after
    # the first had finished, at the start ("not empty").
    assert sorted(status for status, _ in results) == [0, 1], results
    for status, err in results:
        if status == 1:
            assert "another run" in err or "not empty" in err, err
            assert sum(line.startswith(ERROR) for line in err.splitlines()) == 1
    summary = json.loads((tmp_path / "same" / "summary.json").read_text())
    assert set(summary["files"]) == {p.name for p in (tmp_path / "same").iterdir()}
    assert_nothing_partial(tmp_path)


def _interrupt(args, wait_for, signum, cwd, mpi=False, delay=0.0):
    """Start the CLI, send ``signum`` once ``wait_for`` is on stdout; (status, stderr, s)."""
    proc = subprocess.Popen([*_command(mpi), "solve", *args], cwd=cwd, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=_env())
    try:
        for line in proc.stdout:
            if wait_for in line:
                time.sleep(delay)
                proc.send_signal(signum)
                break
        else:
            pytest.fail(f"no {wait_for!r} line: {proc.stderr.read()}")
        sent = time.monotonic()
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, err, time.monotonic() - sent


PIANO = ["piano", "--mesh-size", "0.03", "--max-it", "500", "--out", "o"]


@pytest.mark.serial
@pytest.mark.parametrize(
    "wait_for, signum, stage",
    # The stage is checked where the line waited for is in it (MBO may end first).
    [("  it    2 ", signal.SIGINT, "TAO"), ("MBO initial field", signal.SIGTERM, ""),
     ("meshing", signal.SIGINT, "")],
    ids=["tao-sigint", "mbo-sigterm", "meshing-sigint"],
)
def test_cli_interrupt(wait_for, signum, stage, tmp_path):
    args = PIANO if wait_for != "meshing" else ["piano", "--mesh-size", "0.004", "--out", "o"]
    status, err, seconds = _interrupt(args, wait_for, signum, tmp_path,
                                      delay=0.3 if wait_for == "meshing" else 0.0)
    proc = subprocess.CompletedProcess([], status, "", err)
    line = assert_one_line_error(proc, interrupts.INTERRUPTED_STATUS, "interrupted", signum.name,
                                 stage)
    assert seconds < interrupts.INTERRUPT_GRACE_S + 5
    if stage == "TAO":  # interrupted solves leave their checkpoint, and say so
        assert line.endswith("resume with --resume o"), line
        assert_only_checkpoint(tmp_path / "o")
        assert [p.name for p in tmp_path.iterdir()] == ["o"]
    else:
        assert "nothing written" in line, line
        assert list(tmp_path.iterdir()) == []


def assert_only_checkpoint(out: Path):
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*")) == [
        "checkpoint", "checkpoint/state.npz"]


@pytest.fixture(scope="module")
def piano_reference(tmp_path_factory):
    """summary.json of an uninterrupted serial run on RESUME_PIANO."""
    cwd = tmp_path_factory.mktemp("reference")
    proc = run_cli("solve", *RESUME_PIANO, "--out", "o", "-q", cwd=cwd)
    assert proc.returncode == 0, proc.stderr
    return json.loads((cwd / "o" / "summary.json").read_text())


RESUME_PIANO = ["piano", "--mesh-size", "0.05"]


def _assert_same_result(summary, reference, rel):
    assert summary["resumed_from_iteration"] >= 2
    assert summary["iterations"] == reference["iterations"]
    assert summary["converged_reason"] == reference["converged_reason"]
    assert summary["H_final"] == pytest.approx(reference["H_final"], rel=rel)
    found, expected = summary["singularities"], reference["singularities"]
    assert [s["index"] for s in found] == [s["index"] for s in expected]
    assert [s[k] for s in found for k in "xy"] == pytest.approx(
        [s[k] for s in expected for k in "xy"], rel=1e-6)


@pytest.mark.serial
def test_cli_resume_after_sigint(piano_reference, tmp_path):
    status, err, _ = _interrupt([*RESUME_PIANO, "--out", "o"], "  it    5 ", signal.SIGINT,
                                tmp_path)
    proc = subprocess.CompletedProcess([], status, "", err)
    assert_one_line_error(proc, interrupts.INTERRUPTED_STATUS, "resume with --resume o")
    assert_only_checkpoint(tmp_path / "o")
    proc = run_cli("solve", *RESUME_PIANO, "--resume", "o", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "resuming from the checkpoint at iteration" in proc.stdout
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    _assert_same_result(summary, piano_reference, rel=1e-12)  # measured: equal
    assert not (tmp_path / "o" / "checkpoint").exists()
    assert_nothing_partial(tmp_path)


# --- under mpirun -n 2 ------------------------------------------------------------------------


@pytest.mark.serial
@needs_mpirun
@pytest.mark.parametrize(
    "args, status, words",
    [(["-tao_type", "gpcg"], 2, ["gpcg"]),
     (TAO_FAILS, 1, ["TAO", "PETSc error"]),
     (["--out", "/proc/ufl-frames-test"], 1, ["/proc"])],
    ids=["usage", "tao-fails", "unwritable"],
)
def test_mpirun_failures_are_reported_once(args, status, words, tmp_path):
    proc = run_cli("solve", "annulus", *COARSE, "-q", *args, cwd=tmp_path, mpi=True)
    assert_one_line_error(proc, status, *words)
    assert "MPI_Abort" not in proc.stderr and "aborting" not in proc.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.serial
@needs_mpirun
def test_mpirun_interrupt_and_resume(piano_reference, tmp_path):
    status, err, _ = _interrupt([*RESUME_PIANO, "--out", "o"], "  it    3 ", signal.SIGINT,
                                tmp_path, mpi=True)
    proc = subprocess.CompletedProcess([], status, "", err)
    assert_one_line_error(proc, interrupts.INTERRUPTED_STATUS, "interrupted",
                          "resume with --resume o")
    assert_only_checkpoint(tmp_path / "o")
    proc = run_cli("solve", *RESUME_PIANO, "--resume", "o", "-q", cwd=tmp_path, mpi=True)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    # Two processes sum in another order than one: round-off (measured 5e-13).
    _assert_same_result(summary, piano_reference, rel=1e-9)
    assert summary["num_processes"] == 2
    assert not (tmp_path / "o" / "checkpoint").exists()
    assert_nothing_partial(tmp_path)


@pytest.mark.serial
@needs_mpirun
def test_mpirun_mesh_time_limit(tmp_path):
    (tmp_path / "bowtie.geo").write_text(BOWTIE + "Mesh 2;\n")  # meshed (forever) as it runs
    started = time.monotonic()
    proc = run_cli("solve", "bowtie.geo", *COARSE, "--mesh-time-limit", "2", cwd=tmp_path,
                   mpi=True, timeout=60)
    assert time.monotonic() - started < 30
    assert_one_line_error(proc, 1, "bowtie.geo", "time limit of 2 s", "--mesh-time-limit")
    assert [p.name for p in tmp_path.iterdir()] == ["bowtie.geo"]


# --- issue 40: nothing read without bound, no result lost to a picture, no false refusal ------
#
# Special files run in a child under an address-space limit and a timeout: a regression that
# reads /dev/zero without bound, or blocks on a FIFO, fails its test instead of the machine.

#: Address space (bytes) of a child given special files: a normal run needs about 2 GiB.
CHILD_ADDRESS_SPACE = 4 * 2**30
#: The 1° corner of a triangle: no valid quad mesh at the default quad size.
SLIVER = ("Point(1) = {0, 0, 0}; Point(2) = {1, 0, 0};\n"
          "Point(3) = {Cos(Pi/180), Sin(Pi/180), 0};\n"
          "Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 1};\n"
          "Curve Loop(1) = {1, 2, 3}; Plane Surface(1) = {1};\n")
# Two squares drawn with their own copies of the shared side x = 1 (curves 2 and 8, points
# 2, 3 and 5, 8), a size field restricted to each: Distance to curve 8 (a duplicate that
# the loader's removeAllDuplicates deletes) in surface 1, to point 6 in surface 2.
RESTRICTED = (
    "Point(1) = {0, 0, 0}; Point(2) = {1, 0, 0}; Point(3) = {1, 1, 0}; Point(4) = {0, 1, 0};\n"
    "Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 1};\n"
    "Curve Loop(1) = {1, 2, 3, 4}; Plane Surface(1) = {1};\n"
    "Point(5) = {1, 0, 0}; Point(6) = {2, 0, 0}; Point(7) = {2, 1, 0}; Point(8) = {1, 1, 0};\n"
    "Line(5) = {5, 6}; Line(6) = {6, 7}; Line(7) = {7, 8}; Line(8) = {8, 5};\n"
    "Curve Loop(2) = {5, 6, 7, 8}; Plane Surface(2) = {2};\n"
    "Field[1] = Distance; Field[1].CurvesList = {8};\n"
    "Field[2] = Threshold; Field[2].InField = 1; Field[2].SizeMin = 0.02;\n"
    "Field[2].SizeMax = 0.2; Field[2].DistMin = 0.1; Field[2].DistMax = 0.5;\n"
    "Field[3] = Restrict; Field[3].InField = 2; Field[3].SurfacesList = {1};\n"
    "Field[4] = Distance; Field[4].PointsList = {6};\n"
    "Field[5] = Threshold; Field[5].InField = 4; Field[5].SizeMin = 0.03;\n"
    "Field[5].SizeMax = 0.25; Field[5].DistMin = 0.1; Field[5].DistMax = 0.5;\n"
    "Field[6] = Restrict; Field[6].InField = 5; Field[6].SurfacesList = {2};\n"
    "Field[6].CurvesList = {5, 6, 7, 8};\n"
    "Field[7] = Min; Field[7].FieldsList = {3, 6};\n"
    "Background Field = 7;\n")
# The unit square turned 30° about the x axis: in the plane y sin 30° = z cos 30°.
TILTED_SQUARE = (
    "c = Cos(Pi/6); s = Sin(Pi/6);\n"
    "Point(1) = {0, 0, 0}; Point(2) = {1, 0, 0}; Point(3) = {1, c, s}; Point(4) = {0, c, s};\n"
    "Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 1};\n"
    "Curve Loop(1) = {1, 2, 3, 4}; Plane Surface(1) = {1};\n")
# A 2 x 1 plate with a hole of radius 0.2, turned about (1, 1, 0) and lifted (OpenCASCADE).
TILTED_PLATE = (
    'SetFactory("OpenCASCADE");\n'
    "Rectangle(1) = {0, 0, 0, 2, 1}; Disk(2) = {0.5, 0.5, 0, 0.2};\n"
    "BooleanDifference(3) = {Surface{1}; Delete;}{Surface{2}; Delete;};\n"
    "Rotate {{1, 1, 0}, {0, 0, 0}, Pi/5} { Surface{3}; }\n"
    "Translate {0, 0, 3} { Surface{3}; }\n")
VNOTCH = Path(__file__).parents[2] / "benchmarks" / "shapes" / "vnotch_plate.geo"


def _main_ok(args, capsys) -> int:
    """The status of ``cli.main(args)``, checked to print no error line and no traceback."""
    status = cli.main(args)
    err = capsys.readouterr().err
    assert ERROR not in err and "Traceback" not in err, err
    return status


def _limit_address_space():  # in the child, before it runs
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (CHILD_ADDRESS_SPACE, CHILD_ADDRESS_SPACE))


def run_cli_limited(*args, cwd, mpi=False, timeout=90):
    """:func:`run_cli` under :data:`CHILD_ADDRESS_SPACE` (each rank) and ``timeout``."""
    return subprocess.run([*_command(mpi), *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=timeout, env=_env(), check=False,
                          preexec_fn=_limit_address_space)


def _special_files(folder: Path) -> None:
    """The special inputs of :func:`test_cli_special_files_are_refused`, in ``folder``."""
    os.mkfifo(folder / "fifo.msh")
    os.mkfifo(folder / "fifo.geo")
    (folder / "zero.msh").symlink_to("/dev/zero")
    (folder / "random.geo").symlink_to("/dev/urandom")
    (folder / "zero.geo").symlink_to("/dev/zero")
    (folder / "folder.geo").mkdir()
    (folder / "includes_zero.geo").write_text(TRIANGLE + 'Include "zero.geo";\n')
    (folder / "merges_fifo.geo").write_text(TRIANGLE + 'Merge "fifo.msh";\n')
    (folder / "resume" / "checkpoint").mkdir(parents=True)
    os.mkfifo(folder / "resume" / "checkpoint" / "state.npz")


SPECIAL_FILES = [
    (["fifo.msh"], ["'fifo.msh'", "FIFO", "regular file"]),
    (["fifo.geo"], ["'fifo.geo'", "FIFO"]),
    (["zero.msh"], ["'zero.msh'", "character device"]),
    (["random.geo"], ["'random.geo'", "character device"]),
    (["folder.geo"], ["'folder.geo'", "a folder"]),
    (["includes_zero.geo"], ["zero.geo", "character device"]),
    (["merges_fifo.geo"], ["fifo.msh", "FIFO"]),
    (["annulus", "--resume", "resume"], ["holds no checkpoint"]),
]


@pytest.mark.serial
@pytest.mark.parametrize("mpi", [False, pytest.param(True, marks=needs_mpirun)],
                         ids=["serial", "mpirun"])
def test_cli_special_files_are_refused(mpi, tmp_path):
    _special_files(tmp_path)
    before = tree(tmp_path)
    for args, words in SPECIAL_FILES:
        started = time.monotonic()
        out = [] if "--resume" in args else ["--out", "o"]
        proc = run_cli_limited("solve", *args, *COARSE, "-q", *out, cwd=tmp_path, mpi=mpi)
        assert_one_line_error(proc, 1, *words)
        assert time.monotonic() - started < 60
        assert tree(tmp_path) == before, args  # nothing written, nothing left behind


@pytest.mark.parametrize(
    "name, size, extra, words",
    [("huge.geo", 65 * 2**20, [], ["68157440 bytes", "not read"]),
     ("huge.msh", 65 * 2**20, ["--max-triangles", "1000"], ["68157440 bytes", "1e+03 triangles"]),
     ("huge.step", 1025 * 2**20, [], ["bytes", "not read"])],
    ids=["geo", "msh", "step"],
)
def test_oversized_files_are_refused_unread(name, size, extra, words, shared_tmp, capsys,
                                            monkeypatch):
    monkeypatch.chdir(shared_tmp)
    if COMM.rank == 0:
        with open(shared_tmp / name, "wb") as f:  # sparse: no disk used, nothing to read
            f.truncate(size)
    COMM.Barrier()
    before = tree(shared_tmp)
    status, line = _main_error(["solve", name, *COARSE, "-q", *extra], capsys)
    assert status == 1
    if line is not None:
        for word in [name, *words]:
            assert word in line, line
    assert tree(shared_tmp) == before


@pytest.mark.parametrize("limit", ["10", "2.5"])
@pytest.mark.parametrize("shape, triangles", [("annulus", "2.2e+03"), ("piano", "1.8e+03")])
def test_max_triangles_holds_for_builtin_shapes(shape, triangles, limit, shared_tmp, capsys,
                                                monkeypatch):
    # The estimate: the shape's area over that of an equilateral triangle of edge 0.05.
    monkeypatch.chdir(shared_tmp)
    status, line = _main_error(["solve", shape, "--max-triangles", limit, "-q"], capsys)
    assert status == 1
    if line is not None:
        assert f"about {triangles} triangles, more than the limit {float(limit):g}" in line, line
    assert list(shared_tmp.iterdir()) == []


def test_quad_count_is_refused_before_the_solve(shared_tmp, capsys, monkeypatch):
    monkeypatch.chdir(shared_tmp)
    started = time.monotonic()
    status, line = _main_error(["solve", "annulus", *COARSE, "-q", "--quads", "--quad-size",
                                "1e-4"], capsys)
    assert status == 1
    assert time.monotonic() - started < 30
    if line is not None:  # about the annulus' area 3π/4 over 1e-8 (its mesh's polygon)
        found = re.search(r"gives about (\S+) quads, more than the limit 2e\+06", line)
        assert found and float(found.group(1)) == pytest.approx(0.75 * np.pi / 1e-8, rel=0.05)
        assert "--quad-size" in line and "--max-quads" in line, line
    assert list(shared_tmp.iterdir()) == []
    status, line = _main_error(["solve", "annulus", *COARSE, "-q", "--param", "--quad-size",
                                "0.05", "--max-quads", "100"], capsys)
    assert status == 1  # about 940 quads over a lowered limit
    if line is not None:
        found = re.search(r"gives about (\S+) quads, more than the limit 100:", line)
        assert found and float(found.group(1)) == pytest.approx(0.75 * np.pi / 0.05**2, rel=0.05)
    assert list(shared_tmp.iterdir()) == []


def test_memory_estimate_is_refused_before_the_solve(shared_tmp, capsys, monkeypatch):
    from ufl_frames.app import run as runs

    monkeypatch.chdir(shared_tmp)
    status, line = _main_error(["solve", "annulus", *COARSE, "-q", "--max-memory", "0.1"],
                               capsys)
    assert status == 1
    if line is not None:
        found = re.search(r"needs about (\S+) GiB \((\d+) triangles, 0 quads\), more than the "
                          r"limit \(0\.1 GiB\)", line)
        assert found, line
        need = runs.estimated_memory(int(found.group(2)), 0) / 2**30
        assert float(found.group(1)) == pytest.approx(need, rel=1e-2)
        assert "--max-memory" in line
    assert list(shared_tmp.iterdir()) == []
    monkeypatch.setattr(runs, "available_memory", lambda: 2.0**28)  # a machine of 256 MiB
    status, line = _main_error(["solve", "annulus", *COARSE, "-q", "--quads"], capsys)
    assert status == 1
    if line is not None:
        assert "more than the memory available (0.25 GiB)" in line, line
    assert list(shared_tmp.iterdir()) == []
    assert cli.main(["solve", "annulus", *COARSE, "-q", "--max-memory", "64", "--out", "o"]) == 0


def _read_back(folder: Path):
    """(points (n, 2), cells (m, 3)) of the frame field written in ``folder``."""
    data = output.read_vtk(folder / "frames.pvd")
    return data["points"][:, :2], data["cells"]


def _areas(x, cells):
    e1, e2 = x[cells[:, 1]] - x[cells[:, 0]], x[cells[:, 2]] - x[cells[:, 0]]
    return 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def test_vnotch_plate_is_not_refused(shared_tmp, capsys, monkeypatch):
    out = shared_tmp / "o"
    assert _main_ok(["solve", str(VNOTCH), "--max-it", "3", "-q", "--out", out], capsys) == 0
    summary = json.loads((out / "summary.json").read_text())
    check = summary["poincare_hopf"]
    assert check["euler_characteristic"] == 1 - 3  # one surface, three holes
    # The notch's tip: 360° less the notch's opening 2 atan(0.001 / 0.3).
    tip = 360 - 2 * np.degrees(np.arctan(0.001 / 0.3))
    assert max(check["corner_angles_deg"]) == pytest.approx(tip, abs=1e-4)
    if COMM.rank == 0:  # the plate less the notch's triangle and the holes
        x, cells = _read_back(out)
        exact = 4 - 0.5 * 0.002 * 0.3 - np.pi * (2 * 0.15**2 + 0.1**2)
        # the holes are polygons inscribed in their circles (>= 12 points per turn)
        assert exact < _areas(x, cells).sum() < exact + 0.01


def test_restricted_size_fields_on_duplicated_curves(shared_tmp, capsys, monkeypatch):
    monkeypatch.chdir(shared_tmp)
    if COMM.rank == 0:
        (shared_tmp / "restricted.geo").write_text(RESTRICTED)
    COMM.Barrier()
    # was: "Gmsh crashed on 'restricted.geo' (killed by SIGABRT)"
    assert _main_ok(["solve", "restricted.geo", "--max-it", "3", "-q", "--out", "o"],
                    capsys) == 0
    summary = json.loads((shared_tmp / "o" / "summary.json").read_text())
    assert "2 surfaces meshed as one domain" in summary["loader_notes"][0]
    if COMM.rank == 0:
        x, cells = _read_back(shared_tmp / "o")
        assert _areas(x, cells).sum() == pytest.approx(2.0, rel=1e-12)
        centre = x[cells].mean(axis=1)
        edges = np.linalg.norm(x[cells] - x[np.roll(cells, 1, axis=1)], axis=2).max(axis=1)
        # Field 3 (SizeMin 0.02 within 0.1 of the shared side, in surface 1) still acts:
        # its curve 8 is now curve 2. Far from both fields: SizeMax 0.2.
        near = (centre[:, 0] > 0.93) & (centre[:, 0] < 0.99) & (centre[:, 1] > 0.2) \
            & (centre[:, 1] < 0.8)
        far = (centre[:, 0] < 0.35) & (centre[:, 1] > 0.2) & (centre[:, 1] < 0.8)
        assert near.any() and far.any()
        assert edges[near].max() < 0.05 < 0.1 < edges[far].mean()


@pytest.mark.parametrize(
    "text, area, corners",
    [(TILTED_SQUARE, 1.0, 4), (TILTED_PLATE, 2 - np.pi * 0.2**2, 4)],
    ids=["square", "plate-with-hole"],
)
def test_tilted_plane_is_meshed_in_its_plane(text, area, corners, shared_tmp, capsys,
                                             monkeypatch):
    monkeypatch.chdir(shared_tmp)
    if COMM.rank == 0:
        (shared_tmp / "tilted.geo").write_text(text)
    COMM.Barrier()
    assert _main_ok(["solve", "tilted.geo", "--max-it", "5", "-q", "--out", "o"], capsys) == 0
    summary = json.loads((shared_tmp / "o" / "summary.json").read_text())
    assert any("tilted plane" in note for note in summary["loader_notes"])
    assert summary["poincare_hopf"]["corners"] == corners
    assert summary["poincare_hopf"]["agrees"]
    if COMM.rank == 0:  # lengths and areas kept: a rotation, not a projection
        x, cells = _read_back(shared_tmp / "o")
        found = _areas(x, cells).sum()
        assert area - 1e-9 <= found < area + 0.01  # the hole: a polygon inscribed in it
        if corners == 4 and area == 1.0:
            assert found == pytest.approx(1.0, rel=1e-12)
            assert np.ptp(x, axis=0) == pytest.approx([1.0, 1.0], rel=1e-12)


def test_non_planar_mesh_is_refused(shared_tmp, capsys, monkeypatch):
    monkeypatch.chdir(shared_tmp)
    if COMM.rank == 0:  # a square folded along its diagonal
        (shared_tmp / "folded.msh").write_text(
            "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n4\n1 0 0 0\n2 1 0 0\n3 1 1 0.5\n"
            "4 0 1 0\n$EndNodes\n$Elements\n2\n1 2 2 0 1 1 2 4\n2 2 2 0 1 2 3 4\n$EndElements\n")
    COMM.Barrier()
    status, line = _main_error(["solve", "folded.msh", "--max-it", "3", "-q"], capsys)
    assert status == 1
    if line is not None:
        assert "'folded.msh' is not planar" in line, line
    assert sorted(p.name for p in shared_tmp.iterdir()) == ["folded.msh"]


def test_failed_quads_keep_the_field(shared_tmp, capsys, monkeypatch):
    monkeypatch.chdir(shared_tmp)
    if COMM.rank == 0:
        (shared_tmp / "sliver.geo").write_text(SLIVER)
    COMM.Barrier()
    status = cli.main(["solve", "sliver.geo", "--max-it", "10", "--quads", "--out", "o"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 1
    errors = [line for line in err if line.startswith(ERROR)]
    assert len(errors) == (1 if COMM.rank == 0 else 0), err
    if errors:
        assert errors[0].startswith(f"{ERROR}the quad mesh failed: cannot make quads"), errors
        assert errors[0].endswith("the frame field and summary.json were written to 'o' "
                                  "without it"), errors
        assert any("warning: the quad mesh failed" in line for line in err), err
    out = shared_tmp / "o"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["missing"]["quads"].startswith("cannot make quads")
    assert "quads" not in summary
    assert set(summary["files"]) == {p.name for p in out.iterdir()}
    assert {"frames.png", "convergence.png", "frames.pvd"} <= set(summary["files"])
    assert not any(name.startswith("quads") for name in summary["files"])
    assert_nothing_partial(shared_tmp)


def test_a_figure_that_fails_is_skipped(shared_tmp, capsys, monkeypatch):
    def overflow(*args, **kwargs):
        raise RuntimeError("FT_Render_Glyph (ft2font_wrapper.cpp line 1947) failed with "
                           "error 0x62: raster overflow")

    monkeypatch.setattr(figures, "_frames_figure", overflow)
    out = shared_tmp / "o"
    assert cli.main(["solve", "annulus", *COARSE, "--out", out]) == 0
    err = capsys.readouterr().err
    if COMM.rank == 0:
        assert "warning: frames.png could not be drawn (RuntimeError: FT_Render_Glyph" in err
        assert ERROR not in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["missing"] == {"frames.png": "could not be drawn: RuntimeError: "
                                  "FT_Render_Glyph (ft2font_wrapper.cpp line 1947) failed "
                                  "with error 0x62: raster overflow"}
    assert "frames.png" not in summary["files"] and not (out / "frames.png").exists()
    assert set(summary["files"]) == {p.name for p in out.iterdir()}
    assert_nothing_partial(shared_tmp)


@pytest.mark.parametrize("length", [1000.0, 1e5])
def test_frame_figure_of_a_thin_strip(length, shared_tmp):
    import dolfinx
    import dolfinx.fem as fem

    mesh = dolfinx.mesh.create_rectangle(COMM, [[0, 0], [length, 1]], [200, 2])
    q = fem.Function(fem.functionspace(mesh, ("Lagrange", 1, (5,))))
    q.x.array[:] = np.tile([1.0, 0, 0, 0, 0], q.x.array.size // 5)
    layout = figures.frame_layout((0, 0), (length, 1), title="t")
    assert not layout.equal and min(layout.axes_size) == figures.AXES_SHORT_MIN_IN
    output.plot_frames(shared_tmp / "strip.png", q, title="strip")  # raised in FreeType
    if COMM.rank == 0:
        from PIL import Image

        with Image.open(shared_tmp / "strip.png") as image:
            width, height = image.size
        assert width > 5 * height and height < 2**12


def test_thin_strip_with_quads_is_written_whole(shared_tmp, capsys, monkeypatch):
    monkeypatch.chdir(shared_tmp)
    if COMM.rank == 0:
        (shared_tmp / "strip.geo").write_text(
            "Point(1) = {0, 0, 0}; Point(2) = {1000, 0, 0}; Point(3) = {1000, 1, 0};\n"
            "Point(4) = {0, 1, 0}; Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4};\n"
            "Line(4) = {4, 1}; Curve Loop(1) = {1, 2, 3, 4}; Plane Surface(1) = {1};\n")
    COMM.Barrier()
    assert _main_ok(["solve", "strip.geo", "--mesh-size", "0.5", "--max-it", "5", "--quads",
                     "-q", "--out", "o"], capsys) == 0
    summary = json.loads((shared_tmp / "o" / "summary.json").read_text())
    assert summary["missing"] == {}
    assert {"frames.png", "quads.png", "quads.msh"} <= set(summary["files"])
    found = summary["quads"]
    assert found["valid"]
    # A 1000 x 1 rectangle in quads of edge s: round(1 / s) rows of 1000 / s.
    size = found["quad_size"]
    assert found["quads"] == pytest.approx(round(1 / size) * 1000 / size, rel=0.02)


@pytest.mark.parametrize(
    "damage, words",
    [("truncated", ["truncated or not a checkpoint"]),
     ("empty", ["truncated or not a checkpoint"]),
     ("nan", ["NaN or infinite values in 2 of its"]),
     ("no-q", ["lacks its meta or q record"]),
     ("flags", ["active flags of shape (3,)"])],
)
def test_damaged_checkpoints_are_named(damage, words, shared_tmp, capsys, monkeypatch):
    monkeypatch.chdir(shared_tmp)
    if COMM.rank == 0:
        folder = shared_tmp / "o" / "checkpoint"
        folder.mkdir(parents=True)
        path = folder / "state.npz"
        meta = np.array(json.dumps({"format": checkpoint.FORMAT, "run": {}}))
        q = np.ones((40, 5))
        if damage == "nan":
            q[3, 1], q[7, 0] = np.nan, np.inf
        arrays = {"meta": meta, "q": q}
        if damage == "no-q":
            del arrays["q"]
        if damage == "flags":
            arrays["active"] = np.zeros(3, np.int8)
        np.savez(path, **arrays)
        if damage == "truncated":
            path.write_bytes(path.read_bytes()[:300])
        if damage == "empty":
            path.write_bytes(b"")
    COMM.Barrier()
    before = tree(shared_tmp)
    status, line = _main_error(["solve", "annulus", *COARSE, "-q", "--resume", "o"], capsys)
    assert status == 1
    if line is not None:
        assert "cannot resume: the checkpoint 'o/checkpoint/state.npz'" in line, line
        for word in words:
            assert word in line, line
        assert "internal error" not in line
    assert tree(shared_tmp) == before


def test_unused_petsc_options_are_warned_about(shared_tmp, capsys, monkeypatch):
    monkeypatch.chdir(shared_tmp)
    assert cli.main(["solve", "annulus", *COARSE, "--out", "o", "-tao_nls_ksp_type", "cg",
                     "-tao_mnitor", "-foo_bar", "1"]) == 0
    err = capsys.readouterr().err
    if COMM.rank == 0:
        assert ("warning: PETSc options -tao_mnitor, -foo_bar were not used by any solver of "
                "the run (misspelt?)") in err, err
        assert "-tao_nls_ksp_type" not in err
    assert (shared_tmp / "o" / "summary.json").is_file()


def test_signal_thread_survives_spurious_wakeups(monkeypatch):
    import threading

    class Woken:  # what sigtimedwait returns when a profiler attaches (ptrace)
        si_signo = 34606144

    calls = []

    def sigtimedwait(signals, timeout):
        calls.append(1)
        if len(calls) <= 3:
            return Woken()
        time.sleep(timeout)
        return None

    monkeypatch.setattr(signal, "sigtimedwait", sigtimedwait)
    watch = interrupts.SignalWatch(report=lambda text: None)
    watch._thread = threading.Thread(target=watch._wait, daemon=True)
    watch._thread.start()
    while len(calls) < 5:
        time.sleep(0.01)
    assert watch._thread.is_alive() and watch.received is None
    watch._stop.set()
    watch._thread.join()
    assert str(interrupts.Interrupted(34606144)) == ("interrupted by signal 34606144; "
                                                      "nothing written")


def test_grace_ends_a_stage_that_does_not_stop_within_two_seconds(monkeypatch):
    ended = []
    watch = interrupts.SignalWatch(report=lambda text: None)
    monkeypatch.setattr(watch, "exit_now", lambda signum: ended.append(time.monotonic()))
    watch.stage = "the TAO solve (nls)"  # a stage that asks only at its iterates
    sent = time.monotonic()
    watch._notify(signal.SIGTERM)
    while not ended and time.monotonic() - sent < 10:
        time.sleep(0.01)
    assert interrupts.INTERRUPT_GRACE_S < 2.0
    assert ended and ended[0] - sent < 2.0


@pytest.mark.serial
def test_cli_petsc_help_is_reachable(tmp_path):
    proc = run_cli("solve", "annulus", *COARSE, "-q", "--out", "o", "-help", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "ignored explicit argument" not in proc.stderr
    assert "-tao_type <now nls" in proc.stdout and "-mbo_ksp_type" in proc.stdout
    assert "warning" not in proc.stderr or "-help" not in proc.stderr
    assert (tmp_path / "o" / "summary.json").is_file()


def _staging(folder: Path) -> list[str]:
    return [p.name for p in folder.iterdir() if p.name.startswith(".")]


def _rank_pids(marker: str) -> dict[int, int]:
    """{MPI rank: pid} of the running ``ufl_frames.app`` processes whose command line holds
    ``marker``."""
    found = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes()
            environ = (entry / "environ").read_bytes().split(b"\0")
        except OSError:
            continue
        if b"ufl_frames.app" not in cmdline or marker.encode() not in cmdline \
                or b"mpirun" in cmdline:
            continue
        for item in environ:
            if item.startswith(b"PMI_RANK="):
                found[int(item[len(b"PMI_RANK="):])] = int(entry.name)
    return found


@pytest.mark.serial
@pytest.mark.parametrize(
    "mpi, rank", [(False, 0), pytest.param(True, 0, marks=needs_mpirun),
                  pytest.param(True, 1, marks=needs_mpirun)],
    ids=["serial", "mpirun-rank0", "mpirun-rank1"],
)
def test_cli_killed_while_writing_leaves_no_staging_folder(mpi, rank, tmp_path):
    out = f"o{os.getpid()}x{rank}{int(mpi)}"  # names this job among the processes
    proc = subprocess.Popen([*_command(mpi), "solve", "annulus", "--mesh-size", "0.05",
                             "--max-it", "3", "-q", "--out", out], cwd=tmp_path,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            env=_env())
    try:
        deadline = time.monotonic() + 120
        pids = {}
        while mpi and set(pids) != {0, 1} and time.monotonic() < deadline:
            pids = _rank_pids(out)  # before the run writes: the write is short
        while not _staging(tmp_path) and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.002)
        assert _staging(tmp_path), "the run ended before it wrote"
        if mpi:
            os.kill(pids[rank], signal.SIGKILL)
        else:
            proc.kill()
        proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode != 0
    deadline = time.monotonic() + 5
    while _staging(tmp_path) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert _staging(tmp_path) == []  # removed by the staging folder's guard
    assert not (tmp_path / out).exists()


@pytest.mark.serial
@needs_mpirun
@pytest.mark.parametrize(
    "args, words",
    [(["annulus", "--max-triangles", "10"], ["more than the limit 10"]),
     (["annulus", "--quads", "--quad-size", "1e-4", "--mesh-size", "0.05"],
      ["quads, more than the limit 2e+06"]),
     (["annulus", "--quads", "--quad-size", "1e-4"],
      ["triangles, more than the limit", "choose a larger --quad-size"])],
    ids=["max-triangles", "max-quads", "quad-sized-triangles"],
)
def test_mpirun_size_limits(args, words, tmp_path):
    proc = run_cli("solve", *args, "-q", cwd=tmp_path, mpi=True)
    assert_one_line_error(proc, 1, *words)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.serial
@needs_mpirun
def test_mpirun_failed_quads_keep_the_field(tmp_path):
    (tmp_path / "sliver.geo").write_text(SLIVER)
    proc = run_cli("solve", "sliver.geo", "--max-it", "10", "--quads", "-q", "--out", "o",
                   cwd=tmp_path, mpi=True, timeout=300)
    assert_one_line_error(proc, 1, "the quad mesh failed", "written to 'o' without it")
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["num_processes"] == 2 and "quads" in summary["missing"]
    assert set(summary["files"]) == {p.name for p in (tmp_path / "o").iterdir()}
    assert_nothing_partial(tmp_path)


@pytest.mark.serial
@pytest.mark.parametrize("mpi", [False, pytest.param(True, marks=needs_mpirun)],
                         ids=["serial", "mpirun"])
@pytest.mark.parametrize(
    "wait_for, signum", [("  it    2 ", signal.SIGINT), ("MBO initial field", signal.SIGTERM)],
    ids=["tao-sigint", "mbo-sigterm"])
def test_cli_interrupt_ends_within_two_seconds(mpi, wait_for, signum, tmp_path):
    status, err, seconds = _interrupt(PIANO, wait_for, signum, tmp_path, mpi=mpi)
    proc = subprocess.CompletedProcess([], status, "", err)
    assert_one_line_error(proc, interrupts.INTERRUPTED_STATUS, "interrupted", signum.name)
    assert seconds < 2.0
    assert_nothing_partial(tmp_path)
