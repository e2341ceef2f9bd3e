"""Run every demo in ``demos/`` as a subprocess, serially and under ``mpirun -n 2``.

Modelled on DOLFINx's ``python/demo/test.py``. The demos run in CI mode (environment
variable ``CI=1``: coarse mesh, a few iterations) with the current directory a fresh
``tmp_path``, where they write their ``out_<demo>/`` folder; the test checks the exit
status and the figures. The tests are marked ``serial``: they start their own MPI
jobs, so they must not run inside one (they are skipped under ``mpirun``).
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest

DEMO_DIR = Path(__file__).resolve().parents[2] / "demos"
DEMOS = sorted(DEMO_DIR.glob("demo_*.py"))

#: The PNG files each demo must write into out_<demo>/.
EXPECTED_PNGS = {
    "demo_annulus.py": [
        "frames_initial.png", "frames_isotropic.png", "frames_nonisotropic.png",
        "convergence_isotropic.png", "convergence_nonisotropic.png", "checks.png",
    ],
    "demo_nested.py": ["convergence_nested.png", "convergence_cold.png", "frames_nested.png"],
    "demo_regions.py": ["regions.png", "temperature.png"],
    "demo_param.py": ["param_annulus.png", "param_piano_mbo.png", "param_piano_optimised.png"],
    "demo_quads.py": ["quads_piano_non-isotropic.png", "quads_piano_isotropic.png",
                      "quads_piano_conformal.png"],
    "demo_piano.py": [
        "frames_initial.png", "frames_isotropic.png", "frames_isotropic_free.png",
        "frames_nonisotropic.png", "convergence_isotropic.png",
        "convergence_isotropic_free.png", "convergence_nonisotropic.png", "histories.png",
    ],
}

#: Per-run time limit (s): the CI runs take seconds; a hang should fail, not block.
TIMEOUT = 120


def _environment() -> dict:
    env = {**os.environ, "CI": "1", "MPLBACKEND": "agg"}
    # A PETSc options variable of the caller would change the demos' solves.
    env.pop("PETSC_OPTIONS", None)
    return env


def _run(command: list[str], cwd: Path) -> None:
    result = subprocess.run(command, cwd=cwd, env=_environment(), capture_output=True, check=False,
                            text=True, timeout=TIMEOUT)
    assert result.returncode == 0, (
        f"{' '.join(command)} exited with {result.returncode}\n"
        f"--- stdout ---\n{result.stdout[-4000:]}\n--- stderr ---\n{result.stderr[-4000:]}"
    )


def _check_outputs(demo: Path, cwd: Path) -> None:
    out = cwd / f"out_{demo.stem}"
    assert out.is_dir(), f"{demo.name} wrote no {out.name}/"
    for name in EXPECTED_PNGS[demo.name]:
        png = out / name
        assert png.is_file(), f"{demo.name} did not write {out.name}/{name}"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", f"{png} is not a PNG file"


def test_every_demo_is_listed():
    assert {d.name for d in DEMOS} == set(EXPECTED_PNGS)


@pytest.mark.serial
@pytest.mark.parametrize("demo", DEMOS, ids=lambda d: d.name)
def test_demo_serial(demo, tmp_path):
    _run([sys.executable, str(demo)], tmp_path)
    _check_outputs(demo, tmp_path)


@pytest.mark.serial
@pytest.mark.parametrize("demo", DEMOS, ids=lambda d: d.name)
def test_demo_mpi(demo, tmp_path):
    mpirun = Path(sys.prefix) / "bin" / "mpirun"
    if not mpirun.exists():
        pytest.skip(f"no {mpirun}")
    _run([str(mpirun), "-n", "2", sys.executable, str(demo)], tmp_path)
    _check_outputs(demo, tmp_path)
