"""A run's output folder, written whole or not at all.

:class:`OutputFolder`: the files go to a hidden sibling folder, renamed into place when
complete; two runs replacing files in one folder take turns (an ``flock``).
"""

import contextlib
import errno
import fcntl
import os
import re
import secrets
import shutil
import subprocess
import sys
import time
from pathlib import Path

from ufl_frames.bootstrap import init_petsc

init_petsc()

from mpi4py import MPI  # noqa: E402

from ufl_frames.output.report import WriteError, on_root  # noqa: E402

__all__ = ["LOCK_WAIT_S", "OUTPUT_NAMES", "OutputFolder", "OutputFolderBusy", "create_missing",
           "is_output_name", "output_target"]

#: The names a run writes into its output folder (regular expressions, whole names):
#: with ``force``, :meth:`OutputFolder.commit` replaces exactly these, nothing else.
OUTPUT_NAMES = (
    r"summary\.json", r"frames\.bp", r"frames\.pvd", r"frames\d+\.pvtu", r"frames_p\d+_\d+\.vtu",
    r"frames\.xdmf", r"frames\.h5", r"frames\.png", r"convergence\.png",
    r"param\.png", r"param\.vtu",  # FrameField.write_param
    r"quads\.msh", r"quads\.vtu", r"quads\.png",  # FrameField.write_quads
    r"frames3d\.vtu", r"singular\.vtu", r"singular\.png",  # a 3D field (output.volume)
    r"checkpoint",  # ufl_frames.checkpoint: an unfinished run's, removed when it completes
)
_OUTPUT_NAME = re.compile("|".join(f"(?:{name})" for name in OUTPUT_NAMES))
#: Seconds :meth:`OutputFolder.commit` waits for another run replacing files in the same
#: folder (``--force``) before it gives up.
LOCK_WAIT_S = 30.0


def is_output_name(name: str) -> bool:
    """Whether ``name`` is one the files a run writes (:data:`OUTPUT_NAMES`)."""
    return _OUTPUT_NAME.fullmatch(name) is not None


def output_target(path) -> Path:
    """The folder ``path`` names: absolute, normalised (``a/..``), a link to a folder
    resolved (the output goes to its target)."""
    path = Path(path)
    return path.resolve() if path.is_symlink() else Path(os.path.abspath(path))


def create_missing(folder: Path) -> list[Path]:
    """Create ``folder`` and whichever of its parents are missing; the folders created,
    outermost first (so that a caller can remove exactly those)."""
    missing = []
    while not folder.exists():
        missing.append(folder)
        folder = folder.parent
    for created in reversed(missing):
        created.mkdir()
    return missing[::-1]


class OutputFolderBusy(OSError):
    """The output folder changed under this run (another run wrote it meanwhile)."""


class OutputFolder:
    """A run's output folder, complete or untouched (collective over ``comm``).

    :meth:`open` creates a fresh hidden folder next to ``path`` (same parent, so that a
    rename moves it), where the run writes (:attr:`staging`); :meth:`commit` puts it in
    place, :meth:`discard` removes it (and the parent folders :meth:`open` created). A
    run killed meanwhile (SIGKILL, a rank of its MPI job killed) leaves no staging folder
    either: a small guard process (:func:`_start_guard`) removes it when rank 0 dies
    before :meth:`commit` or :meth:`discard`.

    * ``path`` does not exist: the staging folder is renamed to it in one step. If
      another run created it meanwhile, nothing is replaced: :class:`OutputFolderBusy`.
    * ``path`` is an empty folder: the files are renamed into it, ``summary.json`` last
      (the folder itself stays: it may be a mount point or a shell's working folder).
    * ``path`` has files and ``force``: the run's own names (:data:`OUTPUT_NAMES`) in it
      are replaced, all of them (those of an earlier run that this one did not write
      go too, so that two runs never mix), ``summary.json`` last; other files stay.
      Entries are renamed, never opened, so a symbolic link (``frames.png`` → elsewhere)
      is replaced itself and its target is not touched. Two runs replacing in the same
      folder take turns (an ``flock`` on the folder).
    * ``path`` has files without ``force``: :class:`OutputFolderBusy` (checked again
      at the end: another run may have written it meanwhile).

    Args:
        path: the output folder; a symbolic link to a folder stands for its target.
        force: replace the run's own names in a folder that has files.
        comm: the communicator; its rank 0 does the file work.
        ours: names in ``path`` that this run wrote there itself (its ``checkpoint``
            folder): they do not make the folder non-empty, and go when the results are
            put in place.
    """

    def __init__(self, path, force: bool = False, comm: MPI.Comm = MPI.COMM_WORLD,
                 ours: tuple[str, ...] = ()):
        self.path = Path(path)
        self.force = force
        self.comm = comm
        self.ours = tuple(ours)
        self.staging: Path | None = None
        self._created: list[Path] = []  # parent folders made by open(), innermost last
        self._guard = None  # the guard process of the staging folder (rank 0)

    def _target(self) -> Path:
        return output_target(self.path)

    def open(self) -> Path:
        """Create the staging folder; its path (on every rank). Collective."""
        result = None

        def make():
            nonlocal result
            target = self._target()
            self._created += create_missing(target.parent)
            token = f"{os.getpid():x}{secrets.token_hex(4)}"
            staging = target.parent / f".{target.name}.ufl-frames-{token}.partial"
            self._guard = _start_guard(staging)  # first: no moment the folder is unguarded
            try:
                staging.mkdir()
            except OSError as e:
                self._stop_guard()
                raise WriteError(e.errno, f"cannot create a folder in {str(target.parent)!r} "
                                 f"({e.strerror})") from e
            result = str(staging)

        on_root(self.comm, make)
        self.staging = Path(self.comm.bcast(result, root=0))
        return self.staging

    def discard(self, here: bool = False) -> None:
        """Remove the staging folder and the parents :meth:`open` created: on rank 0, or on
        this rank if ``here`` (a rank that fails alone, before it aborts the job). Safe to
        call more than once, from any thread, on one rank alone (not collective)."""
        if self.comm.rank != 0 and not here:
            return
        staging, self.staging = self.staging, None
        if staging is not None:
            for _ in range(3):  # another thread or rank may still be adding files
                shutil.rmtree(staging, ignore_errors=True)
                if not os.path.lexists(staging):
                    break
                time.sleep(0.05)
        while self._created:
            try:
                self._created.pop().rmdir()  # only if still empty
            except OSError:
                break
        self._stop_guard()

    def commit(self) -> None:
        """Put the staging folder's files in place (see the class); collective."""
        try:
            on_root(self.comm, self._publish)
        except BaseException:
            if self.staging is None or not os.path.lexists(self.staging):
                self._stop_guard()
            raise
        self.staging = None
        self._created = []
        self._stop_guard()

    def _stop_guard(self) -> None:
        """Tell the guard process its work is done (the staging folder is gone)."""
        guard, self._guard = self._guard, None
        if guard is not None:
            with contextlib.suppress(OSError, ValueError):
                guard.stdin.write(b"done")
                guard.stdin.close()
            with contextlib.suppress(subprocess.TimeoutExpired):
                guard.wait(timeout=2.0)

    def _publish(self) -> None:
        staging, target = self.staging, self._target()
        if not os.path.lexists(target):
            try:
                os.rename(staging, target)
                return
            except OSError as e:
                if e.errno not in (errno.EEXIST, errno.ENOTEMPTY, errno.EISDIR, errno.ENOTDIR):
                    raise
                # Created meanwhile: decided below, with the lock.
        if not target.is_dir():
            raise OutputFolderBusy(errno.EEXIST, f"output path {str(self.path)!r} was created "
                                   "meanwhile and is not a folder; results discarded")
        with _locked(target, self.path):
            entries = os.listdir(target)
            if all(name in self.ours for name in entries):
                # Moved in, not renamed over it: it may be someone's cwd.
                old = target.parent / f"{staging.name[:-len('.partial')]}.old"
                old.mkdir()
                moved = []
                try:
                    for name in entries:
                        os.rename(target / name, old / name)
                        moved.append(name)
                    for name in sorted(os.listdir(staging), key=lambda n: n == "summary.json"):
                        os.rename(staging / name, target / name)
                    staging.rmdir()
                except BaseException:
                    for name in moved:  # this run's checkpoint stays, as it was
                        with contextlib.suppress(OSError):
                            os.rename(old / name, target / name)
                    raise
                finally:
                    shutil.rmtree(old, ignore_errors=True)
                return
            if not self.force:
                raise OutputFolderBusy(
                    errno.ENOTEMPTY, f"output folder {str(self.path)!r} was written by another "
                    "run meanwhile; not replaced (results discarded; use --force to replace)"
                )
            old = target.parent / f"{staging.name[:-len('.partial')]}.old"
            old.mkdir()
            try:
                for name in entries:
                    if is_output_name(name):
                        os.rename(target / name, old / name)
                names = sorted(os.listdir(staging), key=lambda n: n == "summary.json")
                for name in names:
                    os.rename(staging / name, target / name)
                staging.rmdir()
            finally:
                shutil.rmtree(old, ignore_errors=True)


#: The guard process (:func:`_start_guard`): waits for its stdin to end; removes the
#: staging folder unless it was told "done" first (the run died).
_GUARD = """
import os, shutil, sys
said = sys.stdin.buffer.read()
path = sys.argv[1]
if said != b"done" and path.endswith(".partial") and os.path.isdir(path):
    shutil.rmtree(path, ignore_errors=True)
"""


def _start_guard(staging: Path):
    """A process of its own session (a job's kill does not reach it) that removes
    ``staging`` when this process dies without saying it is done; None where it cannot
    start (the run goes on unguarded)."""
    try:
        return subprocess.Popen([sys.executable, "-S", "-c", _GUARD, str(staging)],
                                stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, start_new_session=True,
                                env={"PATH": os.environ.get("PATH", "")})
    except OSError:
        return None


@contextlib.contextmanager
def _locked(folder: Path, shown: Path):
    """An exclusive ``flock`` on ``folder`` (waits up to :data:`LOCK_WAIT_S`)."""
    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    try:
        deadline = time.monotonic() + LOCK_WAIT_S
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    raise OutputFolderBusy(
                        errno.EBUSY, f"output folder {str(shown)!r} is being written by "
                        "another run; results discarded") from None
                time.sleep(0.1)
        yield
    finally:
        os.close(fd)
