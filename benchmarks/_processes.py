"""Subprocesses for the benchmark scripts: run one in its own process group (so that a
timeout kills it and whatever it started), and the last line of its output."""

import contextlib
import os
import signal
import subprocess
import time


def run_in_group(cmd: list[str], timeout: float, env: dict | None = None,
                 cwd=None) -> tuple[int | None, str, str, float]:
    """Run ``cmd``; (exit status, stdout, stderr, seconds), the status None on timeout
    (the whole process group is killed)."""
    start = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=cwd, env=env, start_new_session=True)
    try:
        out, err = proc.communicate(timeout=timeout)
        rc = proc.returncode
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
        rc = None
    return rc, out, err, time.perf_counter() - start


def last_line(text: str) -> str:
    """The last non-blank line of ``text`` ('' if none), stripped."""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return lines[-1] if lines else ""
