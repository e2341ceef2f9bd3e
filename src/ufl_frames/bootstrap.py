"""Start PETSc with the command line, before DOLFINx is imported.

DOLFINx imports ``petsc4py.PETSc`` when it loads, which initialises PETSc with
no options. To honour ``-tao_type``, ``-tao_monitor``, ``-mbo_ksp_type`` and the
rest, ``petsc4py.init(argv)`` must run first. With the ``dolfinx-solver-real``
wheel, ``import dolfinx_solver`` must come before anything else: it loads the
MPI library that petsc4py links against. Conda-forge and Docker installs have no
``dolfinx_solver`` and need nothing extra.

Every module of this package that imports DOLFINx calls :func:`init_petsc` at
import time; scripts call it themselves, first, to pass their ``argv``.
"""

import sys

_initialised = False


def init_petsc(argv: list[str] | None = None) -> None:
    """Initialise petsc4py with ``argv`` (default ``sys.argv``) once per process."""
    global _initialised
    if _initialised:
        return
    try:
        import dolfinx_solver  # noqa: F401  (loads MPI for the binary wheel)
    except ImportError:
        pass
    import petsc4py

    petsc4py.init(sys.argv if argv is None else argv)
    _initialised = True
