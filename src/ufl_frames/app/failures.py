"""What can go wrong in a run, and the exit status and one line each failure becomes.

The classes a run raises on purpose (:class:`UsageError`, :class:`InputError`,
:class:`RunError`), the stage guard that turns the failures a user can meet into a
:class:`RunError` (:class:`failures`), and the mapping of any exception to an exit
status and a message (:func:`failure_status`). Importing this module starts nothing (no
PETSc, no DOLFINx).
"""

import re
import sys

from ufl_frames.interrupts import INTERRUPTED_STATUS, Interrupted

__all__ = ["DEBUG_VARIABLE", "InputError", "OutputFolderError", "RunError", "UsageError",
           "describe_exception", "failure_status", "failures"]

#: The environment variable that makes a failure print its traceback too.
DEBUG_VARIABLE = "UFL_FRAMES_DEBUG"
#: Exit status of a command-line usage error.
USAGE_STATUS = 2
#: Exit status of a run that cannot be done or failed.
FAILURE_STATUS = 1


class UsageError(Exception):
    """Bad command line: exit status 2."""


class InputError(ValueError):
    """The geometry, a parameter or the output folder is unusable (same on every rank)."""


class OutputFolderError(InputError):
    """The output folder cannot be used (exists and is not empty, not writable...)."""


class RunError(RuntimeError):
    """The run failed after it started (a solve, a write): exit status 1, one line."""


def _petsc_error_class():
    """petsc4py's ``PETSc.Error`` where petsc4py is loaded (else no exception is one)."""
    petsc = sys.modules.get("petsc4py.PETSc")
    return getattr(petsc, "Error", None)


def _output_folder_busy_class():
    """:class:`ufl_frames.output.OutputFolderBusy` where its module is loaded (else no
    exception is one)."""
    folder = sys.modules.get("ufl_frames.output.folder")
    return getattr(folder, "OutputFolderBusy", None)


def _is_instance(exc: BaseException, kind) -> bool:
    return kind is not None and isinstance(exc, kind)


class failures:
    """Turn the failures a user can meet in a stage into :class:`RunError` (one line).

    PETSc errors (a solve PETSc gives up on), RuntimeError (raised for failed MBO
    solves), and, when ``writing``, OSError (a full disk, a path under /proc); the
    original stays as ``__cause__`` for the traceback of ``UFL_FRAMES_DEBUG``.
    """

    def __init__(self, stage: str, writing: bool = False):
        self.stage = stage
        self.writing = writing

    def __enter__(self):
        return self

    def __exit__(self, kind, exc, tb):
        if exc is None or not isinstance(exc, Exception) or isinstance(exc, (InputError,
                                                                              RunError)):
            return False
        if _is_instance(exc, _output_folder_busy_class()):  # says it all
            raise RunError(exc.strerror) from exc
        text = describe_exception(exc)
        if self.writing and isinstance(exc, OSError):
            raise RunError(f"{self.stage} failed: {text}") from exc
        if isinstance(exc, RuntimeError):  # petsc4py.PETSc.Error is one
            raise RunError(f"{self.stage} failed: {text}") from exc
        if self.writing and isinstance(exc, (ValueError, TypeError)):  # e.g. encoding
            raise RunError(f"{self.stage} failed: {text}") from exc
        return False


def describe_exception(exc: BaseException) -> str:
    """``exc`` on one line; PETSc errors as their code, class and message."""
    text = str(exc)
    if _is_instance(exc, _petsc_error_class()):
        lines = [re.sub(r"^\[\d+\]\s*", "", line).strip() for line in text.splitlines()]
        first = lines[0] if lines else ""
        messages = [line for line in lines[1:] if line and not re.search(r"\(\) at \S+:\d+$",
                                                                          line)]
        code = getattr(exc, "ierr", None)
        text = f"PETSc error {code}" if code is not None else first
        if messages:
            text += ": " + ": ".join(messages)
    elif isinstance(exc, OSError) and exc.strerror:
        text = f"{exc.strerror}: {str(exc.filename)!r}" if exc.filename else exc.strerror
    text = " ".join(text.split())
    if not text:
        return type(exc).__name__
    return text


def failure_status(exc: BaseException) -> tuple[int, str, bool]:
    """(exit status, one-line message, expected) for an exception out of a run: 130 for
    an interrupt, 1 for a :class:`InputError`, :class:`RunError` or MemoryError, 1 and
    "internal error" for anything else (a bug: not expected)."""
    if isinstance(exc, KeyboardInterrupt):
        if isinstance(exc, Interrupted):
            return INTERRUPTED_STATUS, str(exc), True
        return INTERRUPTED_STATUS, "interrupted; nothing written", True
    if isinstance(exc, (InputError, RunError)):
        return FAILURE_STATUS, str(exc), True
    if isinstance(exc, MemoryError):
        return FAILURE_STATUS, "out of memory (try a larger --mesh-size or more processes)", True
    return FAILURE_STATUS, (f"internal error: {type(exc).__name__}: {describe_exception(exc)} "
                            f"(set {DEBUG_VARIABLE}=1 for the traceback)"), False
