"""Finite elements of frame fields (DOLFINx): the P1 space and UFL energies
(:mod:`~ufl_frames.fem.energy`), the boundary and pinned constraints
(:mod:`~ufl_frames.fem.constraints`), the frame manifold 𝓜
(:mod:`~ufl_frames.fem.manifold`), the energy on it (:mod:`~ufl_frames.fem.problem`),
the compiled element kernels of its Newton model's matrices (:mod:`~ufl_frames.fem.kernels`)
and the rows of all ranks gathered onto one (:mod:`~ufl_frames.fem.gather`).
"""
