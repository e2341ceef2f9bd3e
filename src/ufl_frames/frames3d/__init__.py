"""3D frames as Odeco tensors with 15 spherical-harmonic coefficients (pure NumPy).

:mod:`~ufl_frames.frames3d.harmonics` holds the coefficients' basis and the Mandel form;
:mod:`~ufl_frames.frames3d.odeco` the frames, the variety's 27 equations and the
projections.
"""
