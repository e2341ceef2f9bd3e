r"""The aspect bound's active set of the Newton model: which frames a Newton step holds on
the bound |l1/l2| ≤ a of non-isotropic frames.

:class:`ActiveSetRules` is a base of :class:`~ufl_frames.solvers.hessian.GaussNewtonModel`:
its rules run in the model's :meth:`~ufl_frames.solvers.hessian.GaussNewtonModel.update`,
before (:meth:`~ActiveSetRules._start_active_set`, :meth:`~ActiveSetRules._hold_active_set`)
and after (:meth:`~ActiveSetRules._consistent_active_set`) the model's assembly, and use the
model's problem, products and preconditioner.
"""

from ufl_frames.bootstrap import init_petsc

init_petsc()

import numpy as np  # noqa: E402
from mpi4py import MPI  # noqa: E402
from petsc4py import PETSc  # noqa: E402

__all__ = ["CONSISTENT_ROUNDS", "CONSISTENT_TOLERANCE", "RELEASE_RATIO", "ActiveSetRules"]

#: η of the aspect bound's release rule (``-frames_active_release``; 0: off), see
#: :meth:`ActiveSetRules._hold_active_set`.
RELEASE_RATIO = 1.0
#: Factorisations of a face more at most per Newton step in
#: :meth:`ActiveSetRules._consistent_active_set` (``-frames_active_rounds r``). On the
#: non-isotropic piano 1 round took as few Newton steps as 2 (and 2 as few as 4 or 6),
#: with fewer factorisations; 0 rounds more steps and a higher H (benchmarks/README,
#: "One active-set round a step").
CONSISTENT_ROUNDS = 1
#: … and none where the step pushes no more than this fraction of the held frames off the
#: bound: those the retraction clamps, and the step's releases wait for the next Newton
#: step (a round for every release, or for every pushed frame, cost more at every size:
#: benchmarks/README, "Releases left to the next Newton step").
CONSISTENT_TOLERANCE = 0.05


class ActiveSetRules:
    """The rules that decide the aspect bound's active set of a Newton model: a base of
    :class:`~ufl_frames.solvers.hessian.GaussNewtonModel`, whose state it reads and sets.

    The model provides ``problem`` (the :class:`~ufl_frames.fem.problem.FrameProblem`),
    ``active`` (the frames held at the last assembly), ``released``, ``bound_rounds``,
    ``release``, ``bound_steps``, ``rounds`` and ``_model_product`` (y = G v, G the
    model's matrix).
    """

    def _free_basis(self) -> np.ndarray | None:
        """The tangent basis at the current q with the aspect bound's active set decided by
        the gradient alone (nothing held), which the bound rules compare with the last
        Newton step's; None where neither rule is on, without a bound or before the first
        Newton step."""
        problem = self.problem
        if (not (self.release or self.bound_steps) or self.active is None
                or problem.constraints.isotropic
                or problem.constraints.max_aspect is None):
            return None
        return problem.manifold.tangent_basis(problem.rows, problem.evaluation().gradient_x)

    def _reached_bound(self, free: np.ndarray | None) -> bool:
        """Whether the last step put frames on the aspect bound that the last Newton step
        left free (collective): frames on it now, pushed outwards, not active then.

        The retraction clamps such frames onto the bound, so the step taken bends away
        from the Newton step and the line search shortens it; that is the bound's kink,
        not a poor model, and growing the damping for it was the wrong answer: on the
        non-isotropic piano at h = 0.05 / 0.025 / 0.0125 the damping then alternated
        between a = 1 and 0.1 for most of the solve. Counting such a step as a whole
        one (with the Armijo line search, :data:`~ufl_frames.solvers.tao.BOUNDED_OPTIONS`)
        took the Newton steps from 45 / 72 / 122 to 24 / 42 / 67, to the same H.
        ``-frames_gn_adapt_bound false`` grows the damping after every shortened step.
        """
        if free is None:
            return False
        problem = self.problem
        active = problem.manifold.on_bound(free)
        n = problem.owned
        new = bool(np.any(active[:n] & ~self.active[:n]))
        return problem.constraints.comm.allreduce(new, op=MPI.LOR)

    def _hold_active_set(self, g: PETSc.Vec, free: np.ndarray | None) -> None:
        """The anti-zigzag rule of the aspect bound (``-frames_active_release η``), where
        the active set is not decided with the step (:meth:`_consistent_active_set`: the
        other Newton types and PCs, or ``-frames_active_consistent false``).

        Frames on the bound that were active at the last Newton step stay held there,
        even where the gradient now points inwards, unless releasing them would add more
        gradient than is left on the current face (|g_free − g_face| > η |g_face|): leave
        a face only once it is nearly optimal on it (Moré–Toraldo). Without it, frames at
        the bound flipped in and out at every step (141 vertices, 1212 changes in 99 steps
        on the piano at h = 0.05) and the line search cut the steps. With a held set, TAO's
        gradient ``g`` is recomputed on that face, so that the Newton system, the line
        search and the stopping test see the same one. ``free``: :meth:`_free_basis`.
        """
        problem = self.problem
        problem.held, problem.held_only = None, False
        if not self.release or free is None:
            return
        manifold, rows = problem.manifold, problem.rows
        gradient = problem.evaluation().gradient_x
        free = manifold.projection(rows, gradient, basis=free)
        face = manifold.projection(rows, gradient, held=self.active)
        on_face = np.sqrt(manifold.inner(face, face))
        released = np.sqrt(manifold.inner(free - face, free - face))
        if released == 0.0 or released > self.release * on_face:
            return
        problem.held = self.active
        problem.riemannian_gradient(g)

    def _pushed_off_bound(self, pc: PETSc.PC, g: PETSc.Vec,
                          step: PETSc.Vec | None = None) -> np.ndarray:
        """Owned frames on the aspect bound that the step −(PC⁻¹ g) pushes outwards.

        Args:
            pc: the Newton KSP's preconditioner, set up (≈ B⁻¹).
            g: the gradient.
            step: where PC⁻¹ g is put, a work vector of the caller; None: a new one.

        Returns:
            A boolean array over the owned frames.
        """
        work = g.duplicate() if step is None else step
        try:
            pc.apply(g, work)  # ≈ B⁻¹ g: the Newton direction is −work
            return self.problem.manifold.pushed_off_bound(
                self.problem.rows,
                -work.getArray(readonly=True).reshape(-1, self.problem.algebra.count))
        finally:
            if step is None:
                work.destroy()

    def _bounded(self) -> bool:
        """Whether the frames have an aspect bound that an active set applies to."""
        c = self.problem.constraints
        return not c.isotropic and c.max_aspect is not None

    def _start_active_set(self, g: PETSc.Vec, free: np.ndarray | None) -> None:
        """The face a Newton step of :meth:`_consistent_active_set` starts from: the frames
        the gradient holds on the bound and those the last step ended with (while still
        on it), less those the last step released without a round (:attr:`released`),
        held exactly (:attr:`FrameProblem.held_only`); ``g`` is put on that face.
        ``free``: :meth:`_free_basis` (None: computed here)."""
        problem = self.problem
        problem.held, problem.held_only = None, False
        if self.active is None or not self._bounded():
            return
        if free is None:
            free = problem.manifold.tangent_basis(problem.rows,
                                                  problem.evaluation().gradient_x)
        held = problem.manifold.on_bound(free) | self.active
        if self.released is not None:
            held &= ~self.released
            self.released = None
        problem.held, problem.held_only = held, True
        problem.riemannian_gradient(g)

    def _consistent_active_set(self, ksp: PETSc.KSP, H: PETSc.Mat, P: PETSc.Mat,
                               g: PETSc.Vec) -> None:
        """The aspect bound's active set decided by the Newton step itself
        (``-frames_active_consistent``, the default of ``nls``; collective): primal–dual
        active-set rounds on the model's quadratic problem, with the preconditioner the
        Krylov solve then reuses (exact with the default
        :class:`~ufl_frames.solvers.reduced_pc.ReducedFactorPC` or a factorisation of the
        pre-matrix).

        The gradient decides the active set frame by frame, the step couples them: a
        frame on the bound whose gradient points inwards can still be carried outwards
        by its neighbours' step, and the retraction then clamps it back, bending the path
        away from the Newton step (after a release on the non-isotropic piano at 3·10⁴
        triangles H rose by 22 times the predicted decrease at the full step, and fell by
        0.3 of it along the same step without the clamp). And a held frame is released
        here by the model's multiplier, not by the gradient: once the step is taken, is
        the model's gradient g_free + G δ (g_free: the gradient with no bound, G the
        model's matrix, δ the step) still pointing outwards? The gradient alone released
        a third of the set per step and a sixth came back, so a region of the bound
        unwound from its edge over tens of steps.

        From the face of :meth:`_start_active_set`, the step δ on the current face is
        factorised and solved; the first round releases the held frames whose multiplier
        is negative and holds the frames δ pushes off the bound, later rounds (at most
        ``rounds`` factorisations more, ``-frames_active_rounds``, default
        :data:`CONSISTENT_ROUNDS`; none for a few pushed frames:
        :data:`CONSISTENT_TOLERANCE`) only hold pushed ones, so the set settles. Where no
        round follows the first (few frames pushed, or ``rounds`` = 0), its releases are
        left to the next Newton step
        (:attr:`released`, see :meth:`_start_active_set`): a refactorisation for a few
        released frames cost more than the step they wait (the same steps and H,
        benchmarks/README). ``g`` follows the face.
        :attr:`bound_rounds` records (released, pushed) per round of the last step. On the
        non-isotropic piano the finest level's Newton steps no longer grow with the mesh:
        36 / 27 / 29 at 10⁴ / 3·10⁴ / 10⁵ triangles, against 58 / 36 / 60 with the
        hold-and-release rule (benchmarks/README).

        Args:
            ksp: TAO's Newton KSP, whose PC is set up on each face.
            H: the model's shell (TAO's Hessian).
            P: the pre-matrix the PC is made from.
            g: TAO's gradient, put on the face the rounds end on.
        """
        problem = self.problem
        pc = ksp.getPC()
        self.bound_rounds = []
        if self.active is None or not self._bounded():
            return
        manifold, comm, n = problem.manifold, problem.constraints.comm, problem.owned
        evaluation = problem.evaluation()
        rows = problem.rows
        unbounded = manifold.riemannian_gradient(  # only_held with nothing held: no bound
            rows, evaluation.gradient_x, held=np.zeros(rows.shape[0], bool), only_held=True)
        held = (self.active if problem.held is None else problem.held).copy()
        ksp.setOperators(H, P)
        step, product = g.duplicate(), g.duplicate()
        try:
            for round_ in range(self.rounds + 1):
                pc.setUp()
                pushed = self._pushed_off_bound(pc, g, step) & ~held[:n]
                released = np.zeros(n, dtype=bool)
                if round_ == 0:
                    self._model_product(step, product)  # G (−δ)
                    model_gradient = unbounded - product.getArray(readonly=True).reshape(
                        -1, problem.algebra.count)
                    # the multiplier ≥ 0 where the model gradient still pushes outwards
                    released = self.active[:n] & ~manifold.pushed_off_bound(rows,
                                                                            -model_gradient)
                counts = (comm.allreduce(int(np.count_nonzero(released)), op=MPI.SUM),
                          comm.allreduce(int(np.count_nonzero(pushed)), op=MPI.SUM))
                self.bound_rounds.append(counts)
                if counts == (0, 0):
                    break
                held_count = comm.allreduce(int(np.count_nonzero(self.active[:n])), op=MPI.SUM)
                if round_ == self.rounds or counts[1] <= CONSISTENT_TOLERANCE * held_count:
                    # a few frames clamped by the retraction cost less than a round (or no
                    # round is left), and the released frames can wait for the next
                    # step's face (only the first round releases)
                    if counts[0]:
                        self.released = np.zeros(rows.shape[0], dtype=bool)
                        self.released[:n] = released
                    break
                held = held.copy()
                held[:n] = (held[:n] & ~released) | pushed
                problem.held, problem.held_only = held, True
                problem.riemannian_gradient(g)
                self._assemble_tangent(self.assembled, evaluation)
        finally:
            step.destroy()
            product.destroy()
        pc.setUp()

