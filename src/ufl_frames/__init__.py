"""ufl_frames: integrable 2D frame fields from Odeco tensors.

The pointwise mathematics (:mod:`ufl_frames.odeco`, :mod:`ufl_frames.bracket`) is
pure NumPy. Everything that assembles or solves (:mod:`ufl_frames.energy`,
:mod:`ufl_frames.mbo`, :mod:`ufl_frames.solver`, ...) needs DOLFINx; import
:mod:`ufl_frames.bootstrap` first (and call :func:`~ufl_frames.bootstrap.init_petsc`
with ``sys.argv``) so that PETSc options from the command line are honoured.
"""

__version__ = "0.1.0"
