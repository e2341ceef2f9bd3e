"""The pointwise algebra of 2D frames, pure NumPy (no DOLFINx, PETSc or MPI needed).

* :mod:`~ufl_frames.frames2d.algebra`: the above as one object, :data:`ALGEBRA`, which the
  FEM layer, the solvers and the element kernels receive (a 3D algebra replaces it);
* :mod:`~ufl_frames.frames2d.odeco`: frames ↔ circular-harmonic coefficients q ∈ R⁵, the
  Odeco variety, its exact closest-point projection, tangent spaces and curvature;
* :mod:`~ufl_frames.frames2d.aspect`: the bound l_max/l_min ≤ A of non-isotropic frames;
* :mod:`~ufl_frames.frames2d.bracket`: the Lie bracket [u, v] = C q ∂q as a tensor C;
* :mod:`~ufl_frames.frames2d.singularities`: indices of singular triangles, Poincaré–Hopf.
"""
