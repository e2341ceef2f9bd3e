"""Start PETSc with the command line, before DOLFINx is imported.

DOLFINx imports ``petsc4py.PETSc`` when it loads, which initialises PETSc with
no options. To honour ``-tao_type``, ``-tao_monitor``, ``-mbo_ksp_type`` and the
rest, ``petsc4py.init(argv)`` must run first. With the ``dolfinx-solver-real``
wheel, ``import dolfinx_solver`` must come before anything else: it loads the
MPI library that petsc4py links against. Conda-forge and Docker installs have no
``dolfinx_solver`` and need nothing extra.

Every module of this package that imports DOLFINx calls :func:`init_petsc` at
import time, without options; scripts and entry points call it themselves, first,
with their ``argv``, so that PETSc reads the command line (a library import must not
parse the command line of whatever program imported it, pytest's for instance).
"""

import warnings
from contextlib import contextmanager

_initialised = False


def petsc_initialised() -> bool:
    """Whether :func:`init_petsc` has run in this process."""
    return _initialised


def init_petsc(argv: list[str] | None = None) -> None:
    """Initialise petsc4py with ``argv`` (default: no options) once per process.

    Later calls do nothing; options in their ``argv`` (beyond the program name) are not
    read then, which is said with a :class:`RuntimeWarning` (use :func:`options_scope`
    to put options in the database of a running PETSc).
    """
    global _initialised
    if _initialised:
        if argv is not None and len(argv) > 1:
            warnings.warn(
                f"PETSc is already initialised: options {' '.join(argv[1:])!r} are not read; "
                "use ufl_frames.bootstrap.options_scope", RuntimeWarning, stacklevel=2,
            )
        return
    try:
        import dolfinx_solver  # noqa: F401  (loads MPI for the binary wheel)
    except ImportError:
        pass
    import petsc4py

    petsc4py.init([] if argv is None else argv)
    _initialised = True


@contextmanager
def petsc_defaults(prefix: str, defaults: dict):
    """Set PETSc options of ``prefix`` that the user did not give; remove them on exit.

    The options database is global: defaults left behind would leak into the next
    solve in the same process (a second ``solve(max_it=...)`` would keep the first).
    """
    from petsc4py import PETSc

    opts = PETSc.Options(prefix)
    added = [key for key in defaults if not opts.hasName(key)]
    for key in added:
        opts[key] = defaults[key]
    try:
        yield opts
    finally:
        for key in added:
            opts.delValue(key)


@contextmanager
def options_scope(options=()):
    """Put ``options`` (``(name, value or None)`` pairs, no leading dash) in the global
    PETSc options database, and on exit put the whole database back as it was: what
    was added inside is removed, what was changed restored.

    The one mechanism for the database besides :func:`petsc_defaults` (which only adds
    defaults): the CLI scopes a run's command-line options and the solvers' defaults
    with it, the tests each test, so nothing leaks into the next solve in the process.
    """
    from petsc4py import PETSc

    db = PETSc.Options()
    before = db.getAll()
    for name, value in options:
        db.setValue(name, value)
    try:
        yield db
    finally:
        after = db.getAll()
        for name in after.keys() - before.keys():
            db.delValue(name)
        for name, value in before.items():
            if after.get(name) != value:
                db.setValue(name, value)
