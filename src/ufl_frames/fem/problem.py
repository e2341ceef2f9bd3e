r"""The integrability energy on the frame manifold: what a solver evaluates (note §3).

A :class:`FrameProblem` holds a P1 frame field ``q``, its compiled UFL forms (H, dH/dq,
the Dirichlet energy) and the manifold 𝓜 of :mod:`ufl_frames.fem.manifold`, and
evaluates at the point ``q = R(x/√m)`` of an iterate x:

* H(q), assembled by DOLFINx from the UFL form;
* the Riemannian gradient in x (the note's steps 1–2 and the sphere's tangent).

What a step needs is passed explicitly: :meth:`FrameProblem.evaluation` returns the
energy and Euclidean gradient at the current ``q`` as an :class:`Evaluation`, cached on
the version of ``q`` while a solver tracks it (:meth:`FrameProblem.tracking`), so that
TAO's callbacks at one iterate (gradient, update, monitor, Hessian) share one retraction
and one assembly instead of relying on whichever was evaluated last.
"""

from contextlib import contextmanager
from dataclasses import dataclass, field

from ufl_frames.bootstrap import init_petsc

init_petsc()

import dolfinx  # noqa: E402
import dolfinx.fem as fem  # noqa: E402
import numpy as np  # noqa: E402
from mpi4py import MPI  # noqa: E402
from petsc4py import PETSc  # noqa: E402

from ufl_frames.fem import energy  # noqa: E402
from ufl_frames.fem.constraints import FrameConstraints, frame_constraints  # noqa: E402
from ufl_frames.fem.constraints import pin_singularities as _pin_singular_vertices  # noqa: E402
from ufl_frames.fem.manifold import FrameManifold  # noqa: E402
from ufl_frames.frames2d.algebra import ALGEBRA  # noqa: E402
from ufl_frames.frames2d.aspect import DEFAULT_MAX_ASPECT  # noqa: E402

__all__ = ["Evaluation", "FrameProblem", "frame_problem"]


@dataclass(frozen=True)
class Evaluation:
    """H and its Euclidean gradient ∂H/∂x (local rows, (N, count); ghost rows are partial
    sums, meaningful only pointwise) at one version of ``q``."""

    energy: float
    gradient_x: np.ndarray = field(repr=False)


@dataclass
class FrameProblem:
    """A frame field ``q``, its compiled energies and the manifold it is kept on."""

    q: fem.Function
    manifold: FrameManifold
    integrability: fem.Form
    gradient: fem.Form
    dirichlet: fem.Form
    #: The domain's area, Σ_v m_v.
    area: float
    #: Local rows held on the aspect bound whatever the gradient says (None: the gradient
    #: decides), set by a solver for the current iterate (the Newton model's anti-zigzag
    #: rule); :meth:`riemannian_gradient` and the Newton model's tangent basis use it.
    held: np.ndarray | None = field(default=None, repr=False)
    #: With it, :attr:`held` is the active set itself (rows on the bound): the gradient
    #: adds none (the Newton model's ``-frames_active_consistent`` rule).
    held_only: bool = field(default=False, repr=False)
    #: Counts the changes of q made here (retractions); keys the cached evaluation.
    _version: int = field(default=0, repr=False)
    _evaluated: tuple | None = field(default=None, repr=False)  # (version, Evaluation)
    #: During a solve: the (vector, PETSc state) that q is R of, and the tracking flag.
    _synced: tuple | None = field(default=None, repr=False)
    _tracking: bool = field(default=False, repr=False)
    #: During a solve: the iterate last written with ``keep`` ((vector, state), rows).
    _kept: tuple | None = field(default=None, repr=False)

    @property
    def constraints(self) -> FrameConstraints:
        return self.manifold.constraints

    @property
    def norm2(self) -> float:
        """ρ² = Σ_v m_v |q_v|², kept by the retraction."""
        return self.manifold.radius2

    @property
    def algebra(self):
        """The frame algebra of q (the constraints')."""
        return self.manifold.algebra

    @property
    def sqrt_mass(self) -> np.ndarray:
        return self.manifold.sqrt_mass

    @property
    def rows(self) -> np.ndarray:
        """Local rows (owned and ghost) of q, a (N, count) view."""
        return self.q.x.array.reshape(-1, self.algebra.count)

    @property
    def owned(self) -> int:
        return self.constraints.owned

    @property
    def energy_scale(self) -> float:
        """H_s = (ρ²/A)², ρ² = Σ m_v |q_v|², A the area: H of a field turning by O(1) across
        the domain, up to an O(1) factor (MBO's on the annulus: H = 1.4 H_s).

        Homogeneous of degree 4 in q like H, and, like H, independent of the mesh and of
        the domain's size (x → s x: ρ² and A scale by s², H is invariant).
        """
        return (self.norm2 / self.area) ** 2

    @property
    def gradient_scale(self) -> float:
        """G = H_s / ρ: the scale of the Riemannian gradient norm |g| in the unknowns x.

        |g| ρ bounds the first-order change of H under a relative change 1 of the field
        (x·∇H = 4H), so |g| / G, like H / H_s, is free of the mesh and of the domain's
        size (|g| scales by 1/s under x → s x, as G does). MBO on the annulus: |g| ≈ 25-35 G.
        """
        return self.energy_scale / np.sqrt(self.norm2)

    # --- q and the iterate x --------------------------------------------------------

    @contextmanager
    def tracking(self):
        """Within it, :meth:`set_from_x` skips the retraction when x is the vector, in the
        same PETSc state, that q was last set from or written to (TAO changes x only
        through PETSc, which counts every change), and :meth:`evaluation` reuses its
        assembly while q is unchanged. Only for code that changes q through
        :meth:`set_from_x` and :meth:`retract` alone, such as the TAO callbacks.

        An iterate written with :meth:`write_x` (``keep``) is recognised until the vector
        changes, whatever was evaluated in between: q is then put back as it was, not
        retracted again (R(R(q)) is R(q) only up to round-off)."""
        self._tracking, self._synced, self._evaluated, self.held = True, None, None, None
        self.held_only = False
        self._kept = None
        try:
            yield self
        finally:
            self._tracking, self._synced, self._evaluated, self.held = False, None, None, None
            self.held_only = False
            self._kept = None

    def _mark_synced(self, x: PETSc.Vec) -> None:
        if self._tracking:
            self._synced = (x.getId(), x.stateGet())

    def set_from_x(self, x: PETSc.Vec) -> None:
        """q ← R(x / √m): unscale, fill ghosts, retract (steps 4–5)."""
        if self._tracking and self._synced == (x.getId(), x.stateGet()):
            return  # q is R(x) already
        if self._tracking and self._kept is not None and self._kept[0] == (x.getId(),
                                                                          x.stateGet()):
            self.rows[:] = self._kept[1]  # the iterate x was written from
            self._version += 1
            self._mark_synced(x)
            return
        n = self.owned
        self.rows[:n] = self.manifold.from_x(
            x.getArray(readonly=True).reshape(-1, self.algebra.count))
        self.q.x.scatter_forward()
        self.retract()
        self._mark_synced(x)

    def retract(self) -> None:
        """q ← R(q): steps 4–5 of note §3 in place."""
        self.rows[:] = self.manifold.retraction(self.rows)
        self._version += 1
        self._synced = None

    def write_x(self, x: PETSc.Vec, keep: bool = False) -> None:
        """x ← √m q (owned rows); with ``keep`` (while tracking), x is the solver's iterate:
        :meth:`set_from_x` of it gives this q back, until x changes."""
        x.getArray()[:] = self.manifold.to_x(self.rows).ravel()
        self._mark_synced(x)
        if keep and self._tracking:
            self._kept = ((x.getId(), x.stateGet()), self.rows.copy())

    # --- energies and gradients ------------------------------------------------------

    def energy(self) -> float:
        """H(q), assembled."""
        return self.q.function_space.mesh.comm.allreduce(
            fem.assemble_scalar(self.integrability), op=MPI.SUM
        )

    def dirichlet_energy(self) -> float:
        """E(q) = ½∫|∇q|², assembled."""
        return self.q.function_space.mesh.comm.allreduce(
            fem.assemble_scalar(self.dirichlet), op=MPI.SUM
        )

    def evaluation(self) -> Evaluation:
        """H and ∂H/∂x at the current q: one vector assembly (cached while tracked).

        H comes free with the gradient: the discrete H is a homogeneous quartic in the
        coefficients of q, so dH(q)[q] = 4 H(q) (Euler) — no second assembly.
        """
        if self._tracking and self._evaluated is not None \
                and self._evaluated[0] == self._version:
            return self._evaluated[1]
        b = fem.assemble_vector(self.gradient)
        b.scatter_reverse(dolfinx.la.InsertMode.add)
        owned = self.algebra.count * self.owned
        H = self.constraints.comm.allreduce(
            float(np.dot(b.array[:owned], self.q.x.array[:owned])), op=MPI.SUM) / 4
        # Ghost rows of b are partial sums: used pointwise (active sets), never summed.
        gradient_x = b.array.reshape(-1, self.algebra.count) / self.sqrt_mass[:, None]
        result = Evaluation(energy=H, gradient_x=gradient_x)
        if self._tracking:
            self._evaluated = (self._version, result)
        return result

    def riemannian_gradient(self, g: PETSc.Vec) -> float:
        """g ← the gradient of H on 𝓜 at q, in the scaled unknowns x (steps 1–2); returns H."""
        evaluation = self.evaluation()
        g.getArray()[:] = self.manifold.riemannian_gradient(
            self.rows, evaluation.gradient_x, held=self.held, only_held=self.held_only).ravel()
        return evaluation.energy


def frame_problem(
    q: fem.Function,
    isotropic: bool = False,
    pin_singularities: bool = True,
    max_aspect: float | None = DEFAULT_MAX_ASPECT,
    boundary_angles: np.ndarray | None = None,
    constraints: FrameConstraints | None = None,
    pin_radius: float = 0.0,
    algebra=ALGEBRA,
) -> FrameProblem:
    """Compile the energies of ``q``, find its constraints and retract it onto 𝓜.

    The sphere of 𝓜 is through the closest point of ``q`` (step 5 keeps its lumped L²
    norm).

    Args:
        q: The frame field (:func:`~ufl_frames.fem.energy.frame_space`); set to its
            retraction.
        isotropic: Whether the frames are isotropic (l1 = l2).
        pin_singularities: Hold the cross orientation at the vertices of the singular
            triangles of ``q`` and at every vertex closer than ``pin_radius`` to one (see
            :func:`~ufl_frames.fem.constraints.pin_singularities`).
        max_aspect: The bound l_max/l_min of non-isotropic frames (``math.inf`` or None:
            no bound, which the non-isotropic energy answers with degenerate frames; see
            :mod:`ufl_frames.frames2d.aspect`).
        boundary_angles: Exact boundary cross angles per local row (see
            :func:`~ufl_frames.fem.constraints.frame_constraints`).
        constraints: Constraints already found for ``q``'s space (e.g. the MBO field's),
            reused with ``isotropic`` and ``max_aspect`` set from here;
            ``boundary_angles`` is then not needed.
        pin_radius: See ``pin_singularities``.
        algebra: The frame algebra of ``q`` (that of ``constraints`` where given).

    Returns:
        The problem, ``q`` on 𝓜.
    """
    V = q.function_space
    if constraints is None:
        constraints = frame_constraints(V, isotropic=isotropic, max_aspect=max_aspect,
                                        boundary_angles=boundary_angles, algebra=algebra)
    else:
        constraints = constraints.for_frames(isotropic, max_aspect)
    algebra = constraints.algebra
    rows = q.x.array.reshape(-1, algebra.count)
    if pin_singularities:
        constraints = _pin_singular_vertices(V, constraints, rows, radius=pin_radius)
    cone = FrameManifold(constraints)  # no sphere yet: it passes through the closest point
    projected = cone.closest_point(rows)
    manifold = FrameManifold(constraints, radius2=cone.norm2(projected))
    H = energy.integrability_energy_form(q, algebra)
    problem = FrameProblem(
        q=q,
        manifold=manifold,
        integrability=fem.form(H),
        gradient=fem.form(energy.gradient_form(H, q)),
        dirichlet=fem.form(energy.dirichlet_energy_form(q)),
        area=constraints.comm.allreduce(float(constraints.weights[: constraints.owned].sum()),
                                        op=MPI.SUM),
    )
    q.x.array[:] = projected.ravel()
    return problem
