"""Writing on rank 0 with its errors raised on every rank, and the run summary.

* :func:`on_root` — runs a write on rank 0 of a communicator; an error there (a full
  disk, a folder that went away) is raised on every rank alike: rank 0 raises its own
  exception, the others :class:`WriteError` with its message.
* :func:`write_summary` — a JSON file (rank 0 writes it).
"""

import json
from pathlib import Path

from ufl_frames.bootstrap import init_petsc

init_petsc()

import numpy as np  # noqa: E402
from mpi4py import MPI  # noqa: E402

__all__ = ["WriteError", "on_root", "write_summary"]


class WriteError(OSError):
    """Writing results failed (on this rank, or on rank 0 while this rank waited)."""


def on_root(comm: MPI.Comm, action) -> None:
    """Run ``action()`` on rank 0 of ``comm``; its exception, if any, on every rank (collective).

    Rank 0 re-raises its own exception; the other ranks raise :class:`WriteError` with
    its message (a ``KeyboardInterrupt`` stays one). Returns only when rank 0 is done,
    like a barrier.
    """
    failure = None
    if comm.rank == 0:
        try:
            action()
        except BaseException as e:  # noqa: BLE001  (re-raised below, on every rank)
            failure = e
    if comm.size > 1:
        message = None
        if failure is not None:
            message = (isinstance(failure, KeyboardInterrupt), _one_line(failure))
        message = comm.bcast(message, root=0)
        if comm.rank != 0 and message is not None:
            interrupted, text = message
            raise KeyboardInterrupt(text) if interrupted else WriteError(text)
    if failure is not None:
        raise failure


def _one_line(e: BaseException) -> str:
    text = " ".join(str(e).split())
    return text or type(e).__name__


def _json_default(value):
    """NumPy scalars and arrays, and paths, as plain JSON values."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def write_summary(path, data: dict, comm: MPI.Comm = MPI.COMM_WORLD) -> None:
    """Write ``data`` as indented JSON to ``path`` on rank 0 of ``comm`` (collective).

    Non-finite floats are written as ``NaN``/``Infinity`` (Python's JSON dialect). A
    failure (a value JSON cannot hold, a write error) is raised on every rank.

    Args:
        path: the file (rank 0's).
        data: a dict of JSON values, NumPy scalars and arrays, and paths.
        comm: the communicator whose rank 0 writes.
    """
    if not isinstance(data, dict):
        raise ValueError(f"data must be a dict, got {type(data).__name__}")

    def write():
        text = json.dumps(data, indent=2, default=_json_default)
        Path(path).write_text(text + "\n")

    on_root(comm, write)
