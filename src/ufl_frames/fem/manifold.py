r"""The frame manifold 𝓜 as one object: closest point, retraction, tangent spaces, curvature.

In the unknowns x_v = √m_v q_v (m_v the lumped mass of vertex v) the solver works on

    𝓜 = { x : x_v on the Odeco variety (isotropic: l1 = l2) at every vertex v,
              its orientation fixed at the fixed rows (boundary, pinned vertices),
              l_max/l_min ≤ A (non-isotropic frames, an active set),  |x|² = ρ² }

(note §3). The Euclidean inner product of x is the lumped L² product of q, so step
sizes and tolerances do not depend on the mesh. The pointwise parts (variety, fixed
orientation, aspect bound) commute with the scaling — the variety is a cone — so they
act on q and x alike; only the sphere |x| = ρ couples the vertices.

:class:`FrameManifold` gathers what a Riemannian method needs of 𝓜, in the manner of
pymanopt's manifolds (and in their words: :meth:`~FrameManifold.projection` is the
projection onto a tangent space, :meth:`~FrameManifold.retraction` moves a point along a
tangent vector):

* :meth:`~FrameManifold.closest_point` and :meth:`~FrameManifold.retraction`: steps 4 and
  4–5 of the note's loop (pointwise closest frame, then the uniform normalisation);
* :meth:`~FrameManifold.tangent_basis`: per vertex an orthonormal basis (count × columns,
  zero columns where a direction is absent) of the pointwise tangent space;
* :meth:`~FrameManifold.projection` (step 2) and
  :meth:`~FrameManifold.riemannian_gradient` (step 2 and the sphere's tangent);
* :meth:`~FrameManifold.pushed_off_bound`: the frames a step would push across the
  aspect bound;
* :meth:`~FrameManifold.curvature_blocks` and :meth:`~FrameManifold.sphere_curvature`:
  the second-order terms that turn a Euclidean Hessian into the Riemannian one;
* :meth:`~FrameManifold.inner` and :meth:`~FrameManifold.norm2`: the metric, reduced over
  MPI ranks.

Arrays are the local rows (owned and ghost, shape (N, count)) of a P1 frame field; every
pointwise operation is deterministic, so ghost rows stay equal to their owners' without
communication. The pointwise maps are the constraints' frame algebra's
(:mod:`ufl_frames.frames2d.algebra`). Only NumPy and MPI reductions: no DOLFINx object is
touched here.
"""

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from mpi4py import MPI

from ufl_frames.fem.constraints import FrameConstraints

__all__ = ["FrameManifold"]


@dataclass(frozen=True)
class FrameManifold:
    """𝓜 for the ``constraints`` of a frame space, on the sphere |x|² = ``radius2``.

    ``radius2`` = ρ² = Σ_v m_v |q_v|² over the owned vertices (None: the cone of frames
    only, for :meth:`closest_point` and the tangent spaces; :meth:`retraction` needs ρ).
    """

    constraints: FrameConstraints
    radius2: float | None = None

    # --- the embedding: x = √m q --------------------------------------------------

    @cached_property
    def sqrt_mass(self) -> np.ndarray:
        """√m_v for every local row."""
        return np.sqrt(self.constraints.weights)

    @property
    def owned(self) -> int:
        return self.constraints.owned

    @property
    def algebra(self):
        """The frame algebra of the field (the constraints')."""
        return self.constraints.algebra

    def to_x(self, rows: np.ndarray) -> np.ndarray:
        """x = √m q for the owned rows (the unknowns the solver sees)."""
        n = self.owned
        return rows[:n] * self.sqrt_mass[:n, None]

    def from_x(self, x_rows: np.ndarray) -> np.ndarray:
        """q = x / √m for the owned rows."""
        n = x_rows.shape[0]
        return x_rows / self.sqrt_mass[:n, None]

    # --- metric --------------------------------------------------------------------

    def inner(self, a: np.ndarray, b: np.ndarray) -> float:
        """Σ a·b over the owned rows of two arrays in x, summed over ranks."""
        n = self.owned
        return self.constraints.comm.allreduce(float(np.vdot(a[:n], b[:n])), op=MPI.SUM)

    def norm2(self, rows: np.ndarray) -> float:
        """|x|² = Σ_v m_v |q_v|² of the field ``rows`` (q), the lumped L² norm squared."""
        n = self.owned
        local = float(np.dot(self.constraints.weights[:n],
                             np.einsum("ni,ni->n", rows[:n], rows[:n])))
        return self.constraints.comm.allreduce(local, op=MPI.SUM)

    # --- points: closest point and retraction ---------------------------------------------

    def closest_point(self, rows: np.ndarray) -> np.ndarray:
        """Step 4 of note §3: the closest frame at every vertex, with its orientation fixed
        at the fixed rows (boundary, pinned) and the aspect bound applied (pointwise)."""
        c, algebra = self.constraints, self.algebra
        out = np.empty_like(rows)
        free, fixed = c.free, c.fixed
        out[free] = algebra.project(rows[free], isotropic=c.isotropic, max_aspect=c.max_aspect)
        out[fixed] = algebra.project_aligned(rows[fixed], c.directions, isotropic=c.isotropic,
                                             max_aspect=c.max_aspect)
        return out

    def normalise(self, rows: np.ndarray) -> np.ndarray:
        """Step 5 of note §3: ``rows`` scaled uniformly onto the sphere |x|² = ρ²."""
        if self.radius2 is None:
            raise ValueError("this FrameManifold has no sphere (radius2 is None)")
        return rows * np.sqrt(self.radius2 / self.norm2(rows))

    def retraction(self, point: np.ndarray, tangent: np.ndarray | None = None) -> np.ndarray:
        """R(point + tangent): steps 4–5 of note §3, the point of 𝓜 that the note's loop
        takes ``point`` moved by ``tangent`` to (rows in q; no ``tangent``: R(point))."""
        moved = point if tangent is None else point + tangent
        return self.normalise(self.closest_point(moved))

    # --- tangent spaces ----------------------------------------------------------------

    def tangent_basis(self, rows: np.ndarray, gradient: np.ndarray | None = None,
                      held: np.ndarray | None = None, only_held: bool = False) -> np.ndarray:
        """Orthonormal basis (N, count, columns) of the pointwise tangent space at ``rows``
        (on 𝓜).

        In 2D the columns are e_s (total length), e_d (length difference), rotation; zero
        where the direction is absent: the rotation at fixed rows, e_d (the algebra's
        anisotropy columns) for isotropic frames and for frames on the aspect bound that
        ``gradient`` pushes outwards (see :func:`ufl_frames.frames2d.aspect.active_bound`;
        ``held``: rows kept on the bound whatever the gradient; with ``only_held`` the held
        rows alone are active).
        Same in q and in x.

        Args:
            rows: local rows (N, count), on 𝓜.
            gradient: a gradient (N, count) that decides which frames on the aspect bound
                are held there (those it pushes outwards); None: the aspect bound is
                not active.
            held: (N,) bool, rows kept on the bound whatever ``gradient``; None: none.
            only_held: only the ``held`` rows are on the bound, whatever ``gradient``.

        Returns:
            The basis (N, count, columns), the algebra's ``tangent_columns``.
        """
        c, algebra = self.constraints, self.algebra
        basis = algebra.tangent_basis(rows, max_aspect=c.max_aspect, gradient=gradient,
                                      on_variety=True, held=held, only_held=only_held)
        for column in algebra.rotation_columns:
            basis[c.fixed, :, column] = 0.0  # orientation held: no rotation
        if c.isotropic:
            for column in algebra.anisotropy_columns:
                basis[:, :, column] = 0.0
        return basis

    def projection(self, rows: np.ndarray, dq: np.ndarray,
                   gradient: np.ndarray | None = None, held: np.ndarray | None = None,
                   basis: np.ndarray | None = None, only_held: bool = False) -> np.ndarray:
        """Step 2 of note §3: the pointwise tangent part of ``dq`` at ``rows``; the active
        aspect bounds are decided by ``gradient`` (default: ``dq`` itself, a gradient)
        and ``held`` (``only_held``: see :meth:`tangent_basis`), unless ``basis``
        (:meth:`tangent_basis` at ``rows``) is given.

        Args:
            rows: local rows (N, count), on 𝓜.
            dq: the vectors to project (N, count), in q or in x.
            gradient: decides the active aspect bounds (N, count); None: ``dq``.
            held: (N,) bool, rows kept on the bound (:meth:`tangent_basis`).
            basis: the tangent basis (N, count, columns) to project on; None: made here.
            only_held: only the ``held`` rows are on the bound.

        Returns:
            The tangent part (N, count), in the units of ``dq``.
        """
        if basis is None:
            basis = self.tangent_basis(rows, dq if gradient is None else gradient, held,
                                       only_held)
        return np.einsum("nik,nk->ni", basis, np.einsum("nik,ni->nk", basis, dq))

    def riemannian_gradient(self, rows: np.ndarray, gradient_x: np.ndarray,
                            held: np.ndarray | None = None,
                            only_held: bool = False) -> np.ndarray:
        """grad f on 𝓜 at ``rows`` from the Euclidean gradient ``gradient_x`` = ∂f/∂x (local
        rows): pointwise tangent part, then the component along x removed (the sphere's
        tangent). Owned rows, in x. ``held``, ``only_held``: the aspect bound's active set
        as in :meth:`tangent_basis` (``only_held`` with no row held: no bound at all).

        Args:
            rows: local rows (N, count) in q, on 𝓜.
            gradient_x: ∂f/∂x at the local rows (N, count); it also decides the active
                aspect bounds.
            held: (N,) bool, rows kept on the bound; None: none.
            only_held: only the ``held`` rows are on the bound.

        Returns:
            The Riemannian gradient (owned, count) in x (collective: the sphere's part is
            reduced over ranks).
        """
        n = self.owned
        tangent = self.projection(rows, gradient_x, held=held, only_held=only_held)[:n]
        x = self.to_x(rows)
        return tangent - (self.inner(tangent, x) / self.inner(x, x)) * x

    def on_bound(self, basis: np.ndarray) -> np.ndarray:
        """The rows a tangent basis (:meth:`tangent_basis`) holds on the aspect bound:
        its anisotropy columns absent (N,) bool."""
        columns = list(self.algebra.anisotropy_columns)
        return np.linalg.norm(basis[:, :, columns], axis=(1, 2)) == 0

    def pushed_off_bound(self, rows: np.ndarray, step: np.ndarray) -> np.ndarray:
        """Owned rows on the aspect bound that ``step`` (owned rows, in x or q) pushes
        outwards to first order, which the retraction would clamp back (all False without
        a bound or for isotropic frames)."""
        c, n = self.constraints, self.owned
        if c.isotropic or c.max_aspect is None:
            return np.zeros(n, dtype=bool)
        return self.algebra.pushed_off_bound(rows[:n], step[:n], c.max_aspect)

    # --- curvature ---------------------------------------------------------------------

    def curvature_blocks(self, rows: np.ndarray, basis: np.ndarray,
                         gradient_x: np.ndarray) -> np.ndarray:
        """Per owned vertex the count × count block B W Bᵀ / m: the pointwise part of the Weingarten
        map, which the Riemannian Hessian adds to the Euclidean one (in x).

        W (the algebra's ``tangent_curvature``) pairs the second
        fundamental form of the variety with the normal part of the Euclidean gradient
        in q (``gradient_x`` · √m); zero where the orientation is fixed (the chart is
        linear there). ``basis``: :meth:`tangent_basis` at ``rows`` with ``gradient_x``.
        The sphere's part is :meth:`sphere_curvature`.

        Args:
            rows: local rows (N, count) in q, on 𝓜.
            basis: :meth:`tangent_basis` at ``rows`` (N, count, columns); its absent
                anisotropy columns give the aspect bound's active set.
            gradient_x: the Euclidean gradient ∂f/∂x at the local rows (N, count).

        Returns:
            The blocks (owned, count, count), in x.
        """
        c, n = self.constraints, self.owned
        gradient_q = gradient_x * self.sqrt_mass[:, None]
        # Only the normal part pairs with the second fundamental form; the tangent part is
        # the sphere's (radial) at a critical point, counted in sphere_curvature.
        normal = gradient_q - np.einsum("nia,na->ni", basis,
                                        np.einsum("nia,ni->na", basis, gradient_q))
        # the active set the basis was made with (e_d absent), whatever decided it
        active = None if c.isotropic else self.on_bound(basis)
        curvature = self.algebra.tangent_curvature(rows, normal, c.max_aspect, c.isotropic,
                                                   active_gradient=gradient_x, active=active)
        curvature[c.fixed] = 0.0
        blocks = np.einsum("nia,nab,njb->nij", basis, curvature, basis)[:n]
        return blocks / c.weights[:n, None, None]

    def sphere_curvature(self, energy: float) -> float:
        """The sphere's part of the Hessian of a quartic f at x ∈ 𝓜: −(x·∇f)/ρ² = −4f/ρ²
        (Euler: x·∇f = 4f) on the sphere's tangent space; returned as the positive 4f/ρ²."""
        if self.radius2 is None:
            raise ValueError("this FrameManifold has no sphere (radius2 is None)")
        return 4.0 * energy / self.radius2
