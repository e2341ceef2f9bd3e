"""Checkpoints of a solve in the output folder, to resume it (``--resume DIR``).

While TAO runs, the CLI writes ``DIR/checkpoint/state.npz`` every
:data:`CHECKPOINT_EVERY` Newton steps and when interrupted; an interrupted run leaves
only that folder, a completed one removes it (:class:`ufl_frames.output.OutputFolder`,
``ours``). The file, written by rank 0 as a whole (a temporary file renamed over the
last), holds:

* ``q``, ``active``, ``held``, ``released``: the iterate and the Newton model's active sets
  (:class:`ufl_frames.solvers.SolverState`) per vertex, in the mesh's input node order:
  the order of rank 0's Gmsh mesh, which meshing the same geometry with the same
  options gives again, whatever the number of processes;
* ``meta``: JSON with the format, the run's arguments (:func:`check_run` compares them
  with the resuming run's), :func:`mesh_key` of the mesh, the state's scalars and history.
"""

import hashlib
import json
import os
import zipfile
import zlib
from pathlib import Path

import numpy as np

from ufl_frames.fem.gather import gather_rows, input_node_order
from ufl_frames.output.folder import create_missing
from ufl_frames.solvers.results import SolverState

__all__ = ["CHECKPOINT_EVERY", "FOLDER", "CheckpointError", "CheckpointFolder",
           "CheckpointWriteError", "check_run", "mesh_key", "read", "restore"]

#: Folder of the checkpoint inside the output folder, and its file.
FOLDER = "checkpoint"
FILE = "state.npz"
#: Newton steps between two checkpoints (an interrupt writes one too).
CHECKPOINT_EVERY = 10
#: Version of the file's layout; another is refused.
FORMAT = 1


class CheckpointError(ValueError):
    """No usable checkpoint, or one of another run (one-line message)."""


class CheckpointWriteError(RuntimeError):
    """A checkpoint could not be written (one-line message; a failure of the run)."""


def mesh_key(mesh) -> str:
    """SHA-256 of the mesh's vertex coordinates in input node order and its cell count
    (collective; the same on every rank): a checkpoint of another mesh is refused."""
    comm = mesh.comm
    geometry = mesh.geometry
    nodes = np.asarray(geometry.input_global_indices, dtype=np.int64)
    x = gather_rows(comm, np.ascontiguousarray(geometry.x[:, :2]), index=nodes)
    cells = mesh.topology.index_map(2).size_global
    key = None
    if comm.rank == 0:
        count = x.shape[0]
        digest = hashlib.sha256(np.int64([count, cells]).tobytes())
        digest.update(np.ascontiguousarray(x).tobytes())
        key = digest.hexdigest()
    return comm.bcast(key, root=0)


class CheckpointFolder:
    """``out/checkpoint`` of a run (collective over ``comm``).

    :meth:`save` writes a :class:`~ufl_frames.solvers.SolverState` there, creating the
    folders it needs; :meth:`discard` removes what this run created (a checkpoint that
    was there before, the one resumed from, stays).
    """

    def __init__(self, out, comm, run: dict, key: str, existing: bool = False):
        self.out = Path(out)
        self.path = self.out / FOLDER
        self.comm, self.run, self.key = comm, run, key
        self.existing = existing
        self.saved = False  # by this run
        self._created: list[Path] = []  # folders save() made, outermost first

    def save(self, state: SolverState, V) -> None:
        """Write ``state`` of the field on the P1 space ``V`` (collective)."""
        n = V.dofmap.index_map.size_local
        order = input_node_order(V)[:n]
        total = V.dofmap.index_map.size_global

        def gather(values):  # the owned rows of every rank, in input node order
            return gather_rows(self.comm, np.asarray(values)[:n], index=order, size=total)

        q = gather(state.rows)
        flags = {}
        for name in ("active", "held", "released"):
            array = getattr(state, name)
            present = self.comm.allreduce(array is not None)
            flags[name] = gather(np.zeros(n, np.int8) if array is None
                                 else array[:n].astype(np.int8)) if present else None
        error = None
        if self.comm.rank == 0:
            meta = {
                "format": FORMAT, "run": self.run, "mesh_key": self.key,
                "history": state.history, "tao_iterations": state.tao_iterations,
                "tao_gnorm0": state.tao_gnorm0, "wall_time_s": state.wall_time_s,
                "step": state.step, "adaptation": state.adaptation,
                "model_gnorm0": state.model_gnorm0, "exact_hessian": state.exact_hessian,
                "held_only": state.held_only,
                "num_processes": self.comm.size,
            }
            arrays = {"q": q, **{k: v for k, v in flags.items() if v is not None}}
            try:
                self._write(json.dumps(meta), arrays)
            except OSError as e:
                error = f"cannot write the checkpoint in {str(self.path)!r}: {e.strerror or e}"
        error = self.comm.bcast(error, root=0)
        if error is not None:
            raise CheckpointWriteError(error)
        self.saved = True

    def _write(self, meta: str, arrays: dict) -> None:
        self._created += create_missing(self.path)
        temporary = self.path / f".{FILE}.{os.getpid()}.tmp"
        try:
            with open(temporary, "wb") as f:
                np.savez(f, meta=np.array(meta), **arrays)
                f.flush()
                os.fsync(f.fileno())
            os.replace(temporary, self.path / FILE)
        finally:
            if temporary.exists():
                temporary.unlink()

    @property
    def written(self) -> bool:
        """Whether a checkpoint is there (one saved by this run, or the one resumed)."""
        return self.existing or self.saved

    def discard(self) -> None:
        """Remove the checkpoint and the folders this run created for it, unless it was
        there before the run (rank 0; any thread)."""
        if self.comm.rank != 0 or self.existing:
            return
        for name in (FILE, *(p.name for p in self.path.glob(f".{FILE}.*.tmp"))):
            try:
                (self.path / name).unlink()
            except OSError:
                pass
        while self._created:
            try:
                self._created.pop().rmdir()  # only if empty
            except OSError:
                break


def read(out, comm) -> dict:
    """The checkpoint in the output folder ``out``: its ``meta`` dict on every rank, its
    arrays (``q``, ``active``, ``held``, ``released``) under ``"arrays"`` on rank 0
    (collective).
    Raises :class:`CheckpointError` on every rank when there is none or it is unusable."""
    out = Path(out)
    result, error = None, None
    if comm.rank == 0:
        path = out / FOLDER / FILE
        if not out.exists():
            error = f"cannot resume: {str(out)!r} does not exist"
        elif not out.is_dir():
            error = f"cannot resume: {str(out)!r} is not a folder"
        elif not path.is_file():
            error = (f"cannot resume: {str(out)!r} holds no checkpoint ({FOLDER}/{FILE}): only "
                     "an interrupted run leaves one")
        else:
            try:
                result = _load(path)
            except zipfile.BadZipFile:
                error = (f"cannot resume: the checkpoint {str(path)!r} is truncated or not a "
                         "checkpoint (not a whole .npz file); start again with --force")
            except _Invalid as e:
                error = f"cannot resume: the checkpoint {str(path)!r} {e}; start again with --force"
            except (OSError, ValueError, KeyError, EOFError, zlib.error) as e:
                error = f"cannot resume: the checkpoint {str(path)!r} is unreadable ({e})"
    error = comm.bcast(error, root=0)
    if error is not None:
        raise CheckpointError(" ".join(error.split()))
    meta = comm.bcast(result[0] if result else None, root=0)
    meta["arrays"] = result[1] if result else None
    return meta


class _Invalid(ValueError):
    """A checkpoint file that reads but holds no usable state (says what is wrong)."""


def _load(path: Path) -> tuple[dict, dict]:
    """(meta, arrays) of a checkpoint file, checked: a whole file, its format, finite
    values of the right shapes.

    Raises:
        zipfile.BadZipFile: not a whole ``.npz`` (truncated, or another file).
        _Invalid: the contents are not a usable state.
    """
    try:
        data = np.load(path, allow_pickle=False)
    except (ValueError, EOFError):  # empty, or another kind of file
        raise zipfile.BadZipFile("not an .npz archive") from None
    if not isinstance(data, np.lib.npyio.NpzFile):
        raise zipfile.BadZipFile("not an .npz archive")
    with data:
        if "meta" not in data.files or "q" not in data.files:
            raise _Invalid("lacks its meta or q record")
        meta = json.loads(str(data["meta"]))
        arrays = {k: data[k] for k in data.files if k != "meta"}
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise _Invalid(f"has an unknown format (not {FORMAT})")
    q = arrays["q"]
    if q.ndim != 2 or q.shape[0] == 0 or not np.issubdtype(q.dtype, np.floating):
        raise _Invalid(f"holds a field of shape {q.shape} and type {q.dtype}, not rows of numbers")
    bad = int(np.count_nonzero(~np.isfinite(q).all(axis=1)))
    if bad:
        raise _Invalid(f"holds NaN or infinite values in {bad} of its {q.shape[0]} rows")
    for name in ("active", "held", "released"):
        if name in arrays and arrays[name].shape != (q.shape[0],):
            raise _Invalid(f"holds {name} flags of shape {arrays[name].shape}, not ({q.shape[0]},)")
    return meta, arrays


#: The run's arguments that must match to resume, and how a user names them.
_COMPARED = {
    "geometry_id": "GEOMETRY (another file, or the file changed)",
    "isotropic": "--isotropic",
    "mesh_size": "--mesh-size",
    "size_factor": "--size-factor",
    "max_triangles": "--max-triangles",
    "max_aspect": "--max-aspect",
    "free_singularities": "--free-singularities",
    "pin_radius": "--pin-radius",
    "max_it": "--max-it",
    "petsc_options": "the PETSc options",
}

#: Run arguments older checkpoints do not record, and the value those runs had.
_ADDED_LATER = {"pin_radius": 0.0}


def check_run(meta: dict, run: dict, out) -> None:
    """Raise :class:`CheckpointError` if the checkpoint ``meta`` is of a run with other
    arguments than ``run`` (the first that differs is named).

    Args:
        meta: the checkpoint (:func:`read`); its ``"run"`` record is compared (arguments
            older checkpoints do not record take the value those runs had).
        run: the record of the run that would resume
            (:func:`ufl_frames.app.run.run_record`).
        out: the output folder holding the checkpoint (named in the message).

    Raises:
        CheckpointError: a compared argument differs.
    """
    saved = {**_ADDED_LATER, **meta.get("run", {})}
    for key, label in _COMPARED.items():
        if saved.get(key) != run.get(key):
            was, now = saved.get(key), run.get(key)
            detail = "" if key == "geometry_id" else f": {was!r} then, {now!r} now"
            raise CheckpointError(
                f"cannot resume: the checkpoint in {str(out)!r} is of a run with other "
                f"arguments ({label} differs{detail}); resume with the same GEOMETRY and "
                "options, or start again with --force"
            )


def restore(meta: dict, V, comm) -> SolverState:
    """The :class:`~ufl_frames.solvers.SolverState` of a checkpoint (:func:`read`) on this
    rank's rows of the P1 space ``V`` (collective).

    Args:
        meta: the checkpoint (:func:`read`); its arrays, on rank 0 only, are broadcast.
        V: the P1 frame space of the mesh the run resumes on.
        comm: the communicator of ``V``.

    Returns:
        The solver state with ``rows`` this rank's owned rows of q (and the flags its
        local rows, ghosts included), in ``V``'s order.

    Raises:
        CheckpointError: the checkpoint's field does not fit the mesh of ``V``.
    """
    arrays = comm.bcast(meta["arrays"] if comm.rank == 0 else None, root=0)
    order = input_node_order(V)
    n = V.dofmap.index_map.size_local
    if arrays["q"].shape[0] != V.dofmap.index_map.size_global or order.min() < 0:
        raise CheckpointError("cannot resume: the checkpoint's field does not fit the mesh")

    def flags(name):
        return arrays[name][order].astype(bool) if name in arrays else None

    return SolverState(
        rows=np.ascontiguousarray(arrays["q"][order[:n]]),
        history=meta["history"], tao_iterations=int(meta["tao_iterations"]),
        tao_gnorm0=float(meta["tao_gnorm0"]), wall_time_s=float(meta["wall_time_s"]),
        step=float(meta["step"]),
        adaptation=None if meta["adaptation"] is None else float(meta["adaptation"]),
        model_gnorm0=None if meta["model_gnorm0"] is None else float(meta["model_gnorm0"]),
        active=flags("active"), held=flags("held"), released=flags("released"),
        held_only=bool(meta.get("held_only", False)),  # absent before the consistent rule
        exact_hessian=meta.get("exact_hessian"),  # absent in checkpoints before the hybrid
    )
