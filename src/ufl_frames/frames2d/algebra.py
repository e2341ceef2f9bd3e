r"""The frame algebra of 2D frames as one object: what the FEM layer and the solvers receive.

The finite-element code (:mod:`ufl_frames.fem`), the solvers and the generated element
kernels never import :mod:`~ufl_frames.frames2d.odeco` by name: they are handed a frame
algebra, :data:`ALGEBRA` (a :class:`FrameAlgebra2D`) unless told otherwise, and read
from it the number of coefficients a vertex, the spatial dimension, the Lie bracket's
table and the pointwise maps. A 3D algebra (a ``frames3d`` package: frames of three
orthogonal branches, 15 spherical-harmonic coefficients of a fourth-order tensor on
tetrahedra) plugs in by providing the same protocol (:class:`FrameAlgebra`):

* ``count`` — coefficients per frame (5 here, 15 in 3D); every (N, count) array;
* ``dim`` — the spatial dimension (2 here, 3 in 3D): ∇q is (count, dim);
* ``cell`` and ``cell_vertices`` — the DOLFINx cell name and its vertex count
  ("triangle", 3; "tetrahedron", 4), for the mesh checks and the element kernels;
* ``bracket_components`` and ``bracket_entries`` — the integrability residual
  r_i = C_ijkl q_l ∂_k q_j as a sparse table ((i, j, k, l), C_ijkl), i < bracket_components
  (here [u, v], 2 components; in 3D the three brackets [u, v], [v, w], [w, u]: 9),
  j, l < count, k < dim;
* ``tangent_columns``, ``rotation_columns``, ``anisotropy_columns`` — the columns of
  :meth:`tangent_basis`: all of them, those that rotate the frame (absent where its
  orientation is fixed) and those that change the lengths' ratios (absent for isotropic
  frames and, in the active set, at the aspect bound);
* ``frames_to_q``, ``q_to_frames`` (lengths and orientation: angles here, rotations in
  3D), ``orientation`` (the directions a fixed row keeps),
  ``unit_frames``, ``closest_unit_isotropic`` (MBO's template), ``project`` (the closest
  frame, optionally isotropic and aspect-bounded), ``project_aligned`` (the closest frame
  with a given orientation), ``variety_residual``, ``tangent_basis``, ``tangent_project``,
  ``tangent_curvature``, ``pushed_off_bound``, ``aspect_bound`` — pointwise, vectorised over rows.

This object is a thin face over :mod:`~ufl_frames.frames2d.odeco`,
:mod:`~ufl_frames.frames2d.aspect` and :mod:`~ufl_frames.frames2d.bracket`: the maths
stays there. Pure NumPy.
"""

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from ufl_frames.frames2d import aspect, odeco
from ufl_frames.frames2d._bracket_table import BRACKET_ENTRIES

__all__ = ["ALGEBRA", "FrameAlgebra", "FrameAlgebra2D"]


class FrameAlgebra(Protocol):
    """What a frame algebra provides (the module docstring says what each thing is)."""

    count: int
    dim: int
    cell: str
    cell_vertices: int
    bracket_components: int
    bracket_entries: tuple
    tangent_columns: int
    rotation_columns: tuple
    anisotropy_columns: tuple

    def frames_to_q(self, lengths, angles) -> np.ndarray: ...
    def q_to_frames(self, q): ...
    def orientation(self, q) -> np.ndarray: ...
    def unit_frames(self, directions) -> np.ndarray: ...
    def closest_unit_isotropic(self, q) -> np.ndarray: ...
    def variety_residual(self, q) -> np.ndarray: ...
    def project(self, q, isotropic=False, max_aspect=None) -> np.ndarray: ...
    def project_aligned(self, q, directions, isotropic=False, max_aspect=None): ...
    def tangent_basis(self, q, max_aspect=None, gradient=None, on_variety=False, held=None,
                      only_held=False) -> np.ndarray: ...
    def tangent_project(self, q, dq) -> np.ndarray: ...
    def tangent_curvature(self, q, gradient, max_aspect=None, isotropic=False,
                          active_gradient=None, active=None) -> np.ndarray: ...
    def pushed_off_bound(self, q, direction, max_aspect) -> np.ndarray: ...
    def aspect_bound(self, isotropic, max_aspect) -> float | None: ...


@dataclass(frozen=True)
class FrameAlgebra2D:
    """The pointwise algebra of 2D frames (Odeco tensors with 5 circular-harmonic
    coefficients) on straight triangles; the protocol it follows is the module's."""

    #: Coefficients per frame (:data:`~ufl_frames.frames2d.odeco.NUM_COEFFICIENTS`).
    count: int = odeco.NUM_COEFFICIENTS
    #: The spatial dimension: ∇q has ``count`` × ``dim`` components.
    dim: int = 2
    #: The cell the fields live on and its number of vertices (P1: one row a vertex).
    cell: str = "triangle"
    cell_vertices: int = 3
    #: Components of the integrability residual r = [u, v].
    bracket_components: int = 2
    #: ((i, j, k, l), C_ijkl) of r_i = C_ijkl q_l ∂_k q_j (note eq. 10), the non-zero
    #: entries in the table's order.
    bracket_entries: tuple = field(default=tuple(BRACKET_ENTRIES.items()), repr=False)
    #: Columns of :meth:`tangent_basis`: e_s (total length), e_d (length difference),
    #: rotation.
    tangent_columns: int = 3
    #: Columns that rotate the frame: absent where the orientation is fixed.
    rotation_columns: tuple = (2,)
    #: Columns that change the ratio of the lengths: absent for isotropic frames.
    anisotropy_columns: tuple = (1,)

    # --- frames <-> coefficients ---------------------------------------------------------

    def frames_to_q(self, lengths, angles) -> np.ndarray:
        """Coefficients (N, 5) of frames: lengths (N, 2), angles (N,) (see
        :func:`~ufl_frames.frames2d.odeco.frames_to_q`)."""
        return odeco.frames_to_q(lengths, angles)

    def q_to_frames(self, q) -> tuple[np.ndarray, np.ndarray]:
        """Lengths (N, 2) and angles (N,) of the frames nearest to q (see
        :func:`~ufl_frames.frames2d.odeco.q_to_frames`)."""
        return odeco.q_to_frames(q)

    def orientation(self, q) -> np.ndarray:
        """Unit directions (N, 2) of the first branch of the frames nearest to q: what
        :meth:`project_aligned` and :meth:`unit_frames` take."""
        _, angles = odeco.q_to_frames(q)
        return np.stack([np.cos(angles), np.sin(angles)], axis=1)

    def unit_frames(self, directions) -> np.ndarray:
        """Coefficients (N, 5) of the isotropic frames of unit lengths with one branch along
        ``directions`` (N, 2)."""
        directions = np.asarray(directions)
        angles = np.arctan2(directions[:, 1], directions[:, 0])
        return odeco.frames_to_q(np.ones((angles.size, 2)), angles)

    def closest_unit_isotropic(self, q) -> np.ndarray:
        """The isotropic frames of unit lengths closest in orientation to q (N, 5)."""
        _, angles = odeco.q_to_frames(odeco.project(q, isotropic=True))
        return odeco.frames_to_q(np.ones((q.shape[0], 2)), angles)

    # --- the variety and the closest point -----------------------------------------------

    def variety_residual(self, q) -> np.ndarray:
        """The variety equations at q (see :func:`~ufl_frames.frames2d.odeco.variety_residual`)."""
        return odeco.variety_residual(q)

    def project(self, q, isotropic: bool = False, max_aspect: float | None = None) -> np.ndarray:
        """The closest frames to q (isotropic ones with ``isotropic``; with ``max_aspect``
        the lengths fitted under the aspect bound): :func:`~ufl_frames.frames2d.odeco.project`.

        Args:
            q: coefficients (N, 5), none zero.
            isotropic: the closest frames with l1 = l2.
            max_aspect: the aspect bound A (None: no bound).

        Returns:
            The projected coefficients (N, 5).
        """
        return odeco.project(q, isotropic=isotropic, max_aspect=max_aspect)

    def project_aligned(self, q, directions, isotropic: bool = False,
                        max_aspect: float | None = None) -> np.ndarray:
        """The closest frames to q with one branch along ``directions`` (N, 2), lengths free:
        :func:`~ufl_frames.frames2d.odeco.project_aligned`.

        Args:
            q: coefficients (N, 5).
            directions: the direction of one branch at each frame (N, 2), non-zero.
            isotropic: the lengths fitted with l1 = l2.
            max_aspect: the aspect bound A (None: no bound).

        Returns:
            The projected coefficients (N, 5).
        """
        return odeco.project_aligned(q, directions, isotropic=isotropic, max_aspect=max_aspect)

    # --- tangent spaces and curvature ------------------------------------------------------

    def tangent_basis(self, q, max_aspect: float | None = None, gradient=None,
                      on_variety: bool = False, held=None, only_held: bool = False) -> np.ndarray:
        """Orthonormal basis (N, 5, 3) of the tangent space at the frames nearest q, the
        aspect bound an active set: :func:`~ufl_frames.frames2d.odeco.tangent_basis`.

        Args:
            q: coefficients (N, 5), none zero.
            max_aspect: the aspect bound A (None: no bound).
            gradient: (N, 5), decides which frames on the bound are active (None: none).
            on_variety: q lies on the variety (the frame read off directly).
            held: (N,) bool, frames kept active while on the bound (None: none).
            only_held: the ``held`` frames on the bound are the active set.

        Returns:
            The basis (N, 5, 3): e_s, e_d, rotation; a column absent is zero.
        """
        return odeco.tangent_basis(q, max_aspect=max_aspect, gradient=gradient,
                                   on_variety=on_variety, held=held, only_held=only_held)

    def tangent_project(self, q, dq) -> np.ndarray:
        """``dq`` projected onto the variety's tangent spaces at q:
        :func:`~ufl_frames.frames2d.odeco.tangent_project`."""
        return odeco.tangent_project(q, dq)

    def tangent_curvature(self, q, gradient, max_aspect: float | None = None,
                          isotropic: bool = False, active_gradient=None,
                          active=None) -> np.ndarray:
        """Σ_k g_k ∂²q_k in the tangent basis, (N, 3, 3):
        :func:`~ufl_frames.frames2d.odeco.tangent_curvature`.

        Args:
            q: coefficients (N, 5) on the variety.
            gradient: g, the energy's gradient in q (N, 5).
            max_aspect: the aspect bound A (None: no bound).
            isotropic: frames with l1 = l2 (no e_d direction).
            active_gradient: (N, 5), decides the active set (None: ``gradient``).
            active: (N,) bool, the active set given instead (None: decided).

        Returns:
            W (N, 3, 3), in the columns of :meth:`tangent_basis`.
        """
        return odeco.tangent_curvature(q, gradient, max_aspect, isotropic,
                                       active_gradient=active_gradient, active=active)

    def pushed_off_bound(self, q, direction, max_aspect: float) -> np.ndarray:
        """Frames on the aspect bound that ``direction`` pushes outwards (N,) bool:
        :func:`~ufl_frames.frames2d.odeco.pushed_off_bound`.

        Args:
            q: coefficients (N, 5) on the variety.
            direction: the step (N, 5).
            max_aspect: the aspect bound A.

        Returns:
            (N,) bool.
        """
        return odeco.pushed_off_bound(q, direction, max_aspect)

    # --- the aspect bound --------------------------------------------------------------------

    def aspect_bound(self, isotropic: bool, max_aspect: float | None) -> float | None:
        """The bound A the projection and the solver get (None: none):
        :func:`~ufl_frames.frames2d.aspect.aspect_bound`."""
        return aspect.aspect_bound(isotropic, max_aspect)


#: The 2D frame algebra: the default wherever an algebra is taken.
ALGEBRA = FrameAlgebra2D()
