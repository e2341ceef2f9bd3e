"""Interrupts (SIGINT, SIGTERM) during a run, turned into a clean stop.

:class:`SignalWatch` takes the signals in a helper thread, so they are seen while the
main thread is in C (Gmsh, a KSP solve); the run asks at its stop points
(:func:`raise_if_interrupted`: every MBO level and TAO iteration, between stages) and stops
there with :class:`Interrupted`, or, past :data:`INTERRUPT_GRACE_S`, the helper thread ends the
process with :data:`INTERRUPTED_STATUS` after removing the staging folder. A run that
has written a checkpoint (:func:`note_checkpoint`) says how to resume it.
"""

import os
import signal
import sys
import threading
import time

__all__ = ["INTERRUPTED_STATUS", "INTERRUPT_GRACE_S", "Interrupted", "SignalWatch",
           "note_checkpoint", "pending", "raise_if_interrupted", "set_stage"]

#: Exit status of an interrupted run (SIGINT or SIGTERM).
INTERRUPTED_STATUS = 130
#: Seconds an interrupt waits for the run to stop cleanly at its next MBO level or TAO
#: iteration before the process exits anyway (the staging folder removed first).
INTERRUPT_GRACE_S = 1.5

class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM, acted on at a point where the run can stop cleanly."""

    def __init__(self, signum: int, stage: str = "", resume: str | None = None):
        self.signum = signum
        self.stage = stage
        #: The output folder holding the run's checkpoint (None: nothing written).
        self.resume = resume
        super().__init__(signum)

    def __str__(self) -> str:
        where = f" during {self.stage}" if self.stage else ""
        what = ("nothing written" if self.resume is None else
                f"resume with --resume {self.resume}")
        try:
            name = signal.Signals(self.signum).name
        except ValueError:
            name = f"signal {self.signum}"
        return f"interrupted by {name}{where}; {what}"


class SignalWatch:
    """SIGINT and SIGTERM during a run, turned into :class:`Interrupted` where it is safe.

    The signals are blocked in the main thread and taken by a helper thread
    (``sigtimedwait``), so that they are seen even while the main thread is in C (Gmsh,
    a KSP solve). A Python exception raised inside a PETSc callback (TAO's objective or
    Hessian product) is turned by PETSc into an error and, today, a crash; so the run
    itself asks, at its stop points (each MBO level and TAO iteration, between stages:
    :func:`raise_if_interrupted`), and raises there. If it does not ask within
    :data:`INTERRUPT_GRACE_S` seconds (a long Gmsh or compilation step), or at once in
    the ``"meshing"`` stage or on a second signal, the helper thread reports, removes the
    staging folder and ends the process with :data:`INTERRUPTED_STATUS`. During the
    ``"commit"`` stage (the output folder being put in place) and after it, a signal
    does not stop the run: its results are complete.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)
    #: Stages a signal ends at once (nothing on disk, nothing to unwind).
    AT_ONCE = ("start-up", "meshing")
    #: Stages a signal does not stop: the output folder being put in place, and after.
    UNINTERRUPTIBLE = ("commit", "done")

    def __init__(self, comm=None, report=None):
        #: One-line reporter of the interrupt (default: stderr).
        self.report = report or (lambda text: print(text, file=sys.stderr, flush=True))
        self.comm = comm  # set once MPI runs; None: rank 0
        self.stage = "start-up"
        self.received: int | None = None
        self.handled = threading.Event()
        self.output = None  # the io.OutputFolder being written, removed on a hard exit
        self.resume = None  # the output folder once a checkpoint is in it (note_checkpoint)
        self._stop = threading.Event()
        self._thread = None
        self._saved_mask = None
        self._saved_handlers = {}

    def __enter__(self):
        if threading.current_thread() is not threading.main_thread():
            return self  # signals go to the main thread only: nothing to take over
        for signum in self.SIGNALS:  # should a signal reach the main thread anyway
            self._saved_handlers[signum] = signal.signal(signum, self._handler)
        self._saved_handlers[signal.SIGPIPE] = signal.getsignal(signal.SIGPIPE)
        self._saved_mask = signal.pthread_sigmask(signal.SIG_BLOCK, self.SIGNALS)
        self._thread = threading.Thread(target=self._wait, name="ufl-frames-signals",
                                        daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            signal.pthread_sigmask(signal.SIG_SETMASK, self._saved_mask)
            for signum, handler in self._saved_handlers.items():
                signal.signal(signum, handler)
        return False

    def _handler(self, signum, frame):
        self._notify(signum)

    def reinstall(self) -> None:
        """Put the handlers back (Gmsh, PETSc or MPI may have reset them at C level)."""
        if self._thread is not None:
            for signum in self.SIGNALS:
                signal.signal(signum, self._handler)
            # Python's own choice, which MPI undoes: a closed stdout (`| head`) is an
            # error to handle (_printer), not a death by SIGPIPE mid-run.
            signal.signal(signal.SIGPIPE, signal.SIG_IGN)

    def _wait(self):
        while not self._stop.is_set():
            try:
                info = signal.sigtimedwait(self.SIGNALS, 0.1)
            except InterruptedError:
                continue
            # A debugger or profiler attaching (ptrace) wakes sigtimedwait without one
            # of our signals: si_signo is then anything, and is not ours to act on.
            if info is not None and info.si_signo in self.SIGNALS:
                self._notify(info.si_signo)

    def _notify(self, signum: int) -> None:
        first = self.received is None
        if first:
            self.received = signum
        if self.stage in self.UNINTERRUPTIBLE:
            return
        if not first or self.stage in self.AT_ONCE:
            self.exit_now(signum)
        threading.Thread(target=self._grace, args=(signum,), daemon=True).start()

    def _grace(self, signum: int) -> None:
        if not self.handled.wait(INTERRUPT_GRACE_S) and self.stage not in self.UNINTERRUPTIBLE:
            self.exit_now(signum)

    def exit_now(self, signum: int) -> None:
        """Report, remove the staging folder, end the process (any thread)."""
        if self.output is not None:
            self.output.discard()
        if self.comm is None or self.comm.rank == 0:
            self.report(str(Interrupted(signum, self.stage, self.resume)))
        else:
            time.sleep(0.5)  # rank 0, signalled too, prints first
        os._exit(INTERRUPTED_STATUS)


_WATCH: SignalWatch | None = None  # the current run's (see activate)


def activate(watch: SignalWatch | None) -> None:
    """Make ``watch`` the one :func:`set_stage` and :func:`raise_if_interrupted` use
    (None: none)."""
    global _WATCH
    _WATCH = watch


def attach_output(folder) -> None:
    """The staging folder the current watch removes on a hard exit (None: none)."""
    if _WATCH is not None:
        _WATCH.output = folder


def set_stage(stage: str) -> None:
    if _WATCH is not None:
        _WATCH.stage = stage
        _WATCH.reinstall()


def note_checkpoint(folder) -> None:
    """The run's checkpoint is now in the output folder ``folder`` (None: no longer): an
    interrupt from now on says to resume it."""
    if _WATCH is not None:
        _WATCH.resume = None if folder is None else str(folder)


def pending(comm) -> int:
    """The signal any rank has received (0: none), the same on every rank (collective)."""
    if _WATCH is None:
        return 0
    signum = _WATCH.received or 0
    if comm.size > 1:
        from mpi4py import MPI

        signum = comm.allreduce(signum, op=MPI.MAX)
    return signum


def raise_if_interrupted(comm, signum: int | None = None) -> None:
    """Raise :class:`Interrupted` on every rank if any rank was signalled (collective;
    ``signum``: what :func:`pending` said just before, not asked again)."""
    signum = pending(comm) if signum is None else signum
    if signum:
        if _WATCH is not None:
            _WATCH.handled.set()
        raise Interrupted(signum, _WATCH.stage if _WATCH is not None else "",
                          _WATCH.resume if _WATCH is not None else None)
