r"""The frame algebra of 3D frames as one object, beside the 2D one
(:mod:`ufl_frames.frames2d.algebra`).

It carries the sizes (15 coefficients, tetrahedra) and the pointwise maps MBO needs:
frames ↔ q, the unit isotropic frames (free, or with one axis along a boundary normal),
the projections, the variety's equations and tangent spaces. The 3D Lie bracket of the
scaled branches (the integrability residual, three brackets) is not part of it yet:
``bracket_components`` is 0 until it is derived (the note, §5: it is not linear in q as
in 2D). Pure NumPy.
"""

from dataclasses import dataclass

import numpy as np

from ufl_frames.frames3d import odeco

__all__ = ["ALGEBRA3D", "FrameAlgebra3D"]


@dataclass(frozen=True)
class FrameAlgebra3D:
    """The pointwise algebra of 3D frames (Odeco tensors, 15 spherical-harmonic
    coefficients) on straight tetrahedra."""

    count: int = odeco.NUM_COEFFICIENTS
    dim: int = 3
    cell: str = "tetrahedron"
    cell_vertices: int = 4
    #: The integrability residual is not derived in 3D yet (module docstring).
    bracket_components: int = 0
    bracket_entries: tuple = ()

    def frames_to_q(self, lengths, rotations) -> np.ndarray:
        """Coefficients (N, 15) of frames: lengths (N, 3), rotations (N, 3, 3) (their
        columns the directions)."""
        return odeco.frames_to_q(lengths, rotations)

    def q_to_frames(self, q):
        """Lengths (N, 3) and rotations (N, 3, 3) of the frames closest to q."""
        return odeco.q_to_frames(q)

    def orientation(self, q) -> np.ndarray:
        """The rotations (N, 3, 3) of the frames closest to q."""
        return odeco.q_to_frames(q)[1]

    def unit_frames(self, rotations) -> np.ndarray:
        """Coefficients (N, 15) of the isotropic unit frames with the axes of ``rotations``."""
        rotations = np.asarray(rotations, dtype=np.float64)
        return odeco.frames_to_q(np.ones((rotations.shape[0], 3)), rotations)

    def closest_unit_isotropic(self, q) -> np.ndarray:
        """The isotropic unit frames closest in orientation to q (N, 15)."""
        _, R = odeco.q_to_frames(q, isotropic=True)
        return self.unit_frames(R)

    def closest_unit_aligned(self, q, normals) -> np.ndarray:
        """The isotropic unit frames with one axis along ``normals`` (N, 3), closest in
        orientation to q (N, 15)."""
        return self.unit_frames(odeco.aligned_frames(q, normals, isotropic=True)[1])

    def variety_residual(self, q) -> np.ndarray:
        """The 27 variety equations at q (N, 27)."""
        return odeco.variety_residual(q)

    def project(self, q, isotropic: bool = False) -> np.ndarray:
        """The closest frames to q (N, 15)."""
        return odeco.project(q, isotropic=isotropic)

    def project_aligned(self, q, normals, isotropic: bool = False) -> np.ndarray:
        """The closest frames to q with one axis along ``normals`` (N, 3)."""
        return odeco.project_aligned(q, normals, isotropic=isotropic)

    def tangent_basis(self, q) -> np.ndarray:
        """Orthonormal bases (N, 15, 6) of the variety's tangent spaces at the frames
        closest to q."""
        return odeco.tangent_basis(q)


#: The 3D frame algebra.
ALGEBRA3D = FrameAlgebra3D()
