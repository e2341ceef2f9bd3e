"""ufl_frames: integrable 2D frame fields from Odeco tensors.

* :mod:`ufl_frames.frames2d`: the pointwise algebra of frames, pure NumPy;
* :mod:`ufl_frames.fem`: the P1 space, UFL energies, constraints and the frame
  manifold (DOLFINx);
* :mod:`ufl_frames.solvers`: the MBO initial field and the TAO minimisation;
* :mod:`ufl_frames.mesh`, :mod:`ufl_frames.pipeline` (``FrameField``, its stages),
  :mod:`ufl_frames.output`, :mod:`ufl_frames.app`: meshing, the field and what is made of
  it, files, the command.

Everything outside ``frames2d`` needs DOLFINx; import :mod:`ufl_frames.bootstrap` first
(and call :func:`~ufl_frames.bootstrap.init_petsc` with ``sys.argv``) so that PETSc
options from the command line are honoured.
"""

__version__ = "0.1.0"
