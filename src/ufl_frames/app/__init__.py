"""The ``ufl-frames`` command.

* :mod:`ufl_frames.app.cli`: argument parsing, PETSc option checks, exit codes, ``main``;
* :mod:`ufl_frames.app.run`: a :class:`~ufl_frames.app.run.RunConfig` and
  :func:`~ufl_frames.app.run.run`: mesh → field → stages → report → output folder;
* :mod:`ufl_frames.app.failures`: the exceptions a run raises and the exit status and
  one line each failure becomes.

Importing any of them starts nothing (no PETSc, no DOLFINx), so that ``main`` can start
PETSc with the command line's options first.
"""
