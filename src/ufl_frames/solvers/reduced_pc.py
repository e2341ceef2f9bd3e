r"""The default preconditioner of the Newton systems: the model's pre-matrix inverted in
reduced tangent coordinates, with one factorisation of a 3N × 3N matrix (2N isotropic)."""

from contextlib import contextmanager

from ufl_frames.bootstrap import init_petsc

init_petsc()

from petsc4py import PETSc  # noqa: E402

from ufl_frames.solvers.hessian import GaussNewtonModel  # noqa: E402

__all__ = ["ReducedFactorPC"]


class ReducedFactorPC:
    r"""Preconditioner of the Newton systems in reduced tangent coordinates (PC python
    context; the default of the Newton TAO types, see
    :func:`ufl_frames.solvers.tao.newton_pc_options`).

    Applies the exact inverse of the model's pre-matrix P G P + μ (I − P) (− σ I for the
    exact model's sphere, + TAO's shift s) without factorising that 5N × 5N matrix: with
    the tangent basis T of :meth:`GaussNewtonModel.reduced_operator`,

        y = T R⁻¹ Tᵀ r + (r − T Tᵀ r) / (μ − σ + s),   R = Tᵀ G T (+ μ on absent columns, + s − σ),

    R being 3N × 3N (2N isotropic). So the Krylov iterations are those of the factorised
    pre-matrix (2 per step), for about a fifth of the factorisation's flops and a third
    of its memory. R is solved by an inner KSP under the prefix ``<newton prefix>reduced_``
    (default ``preonly`` + sparse Cholesky, MUMPS where PETSc has it), so
    ``-tao_nls_reduced_pc_type gamg`` and the like act on R. ``-tao_nls_pc_type
    cholesky`` (or any other PC) goes back to factorising the pre-matrix itself.
    """

    #: The Newton model of the solve that runs under each KSP options prefix
    #: (:meth:`solving`): :meth:`setUp` of a context without one takes it from here, so
    #: that it does not matter when PETSc makes the context. TAO's ``bntr`` applies the
    #: options again inside its solve, which makes a new one (with the model given to the
    #: first context only, that solve failed with PETSc error 101).
    _solving: dict = {}

    @classmethod
    @contextmanager
    def solving(cls, model: GaussNewtonModel, prefix: str):
        """Within it, a context of this class made for a PC under ``prefix`` uses ``model``."""
        cls._solving[prefix] = model
        try:
            yield
        finally:
            cls._solving.pop(prefix, None)

    def __init__(self):
        self.model, self.ksp, self.work = None, None, None

    def attach(self, model: GaussNewtonModel, prefix: str) -> None:
        """Use ``model``'s reduced operator; the inner KSP gets ``prefix + 'reduced_'``."""
        self.model = model
        comm = model.problem.constraints.comm
        self.ksp = PETSc.KSP().create(comm)
        self.ksp.setOptionsPrefix(prefix + "reduced_")
        self.ksp.setType(PETSc.KSP.Type.PREONLY)
        pc = self.ksp.getPC()
        if PETSc.Sys.hasExternalPackage("mumps"):
            pc.setType(PETSc.PC.Type.CHOLESKY)
            pc.setFactorSolverType("mumps")
        elif comm.size == 1:
            pc.setType(PETSc.PC.Type.CHOLESKY)
        else:
            self.ksp.setType(PETSc.KSP.Type.CG)
            pc.setType(PETSc.PC.Type.GAMG)
        self.ksp.setFromOptions()

    def setUp(self, pc):
        prefix = None if pc is None else pc.getOptionsPrefix() or ""
        if self.model is None and prefix in self._solving:
            self.attach(self._solving[prefix], prefix)
        if self.model is None:
            raise RuntimeError("ReducedFactorPC needs the Newton model: use it through "
                               "ufl_frames.solvers.solve")
        T, R = self.model.reduced_operator()
        self.ksp.setOperators(R)
        if self.work is None:
            self._count_inertia()
        self.ksp.setUp()
        safeguarded = self.model.safeguarded
        self.model.exact_checks += int(safeguarded and self.model.exact)
        if safeguarded and self.model.exact and self.negative_pivots():
            self._correct_inertia()
        if safeguarded and self.negative_pivots() and self.model.gauss_newton_step():
            T, R = self.model.reduced_operator()
            self.ksp.setOperators(R)
            self.ksp.setUp()
        if self.work is None:
            self.work = (R.createVecRight(), R.createVecRight(), T.createVecLeft())

    def _count_inertia(self) -> None:
        """Make MUMPS count the negative pivots of R in parallel too (ICNTL(13) = 1: no
        ScaLAPACK on the elimination tree's root), unless the user set
        ``-<newton prefix>reduced_mat_mumps_icntl_13``; before R's first factorisation.

        With ICNTL(13) = 0, MUMPS' default, a root factorised by ScaLAPACK is missing from
        INFOG(12) (PETSc's ``MatGetInertia`` refuses it in parallel for that reason), and
        :meth:`negative_pivots` read 0 on indefinite exact models: on the sized piano at
        98 146 triangles on 2 ranks none of the finest level's 81 exact factorisations was
        shifted or fell back, and 29 of its 45 Newton steps were the gradient steps of
        ``DIVERGED_INDEFINITE_PC`` at the Krylov solve's start; with the root counted, 10
        steps, as serially (benchmarks/README, "Why the sized piano's Newton steps stopped
        at Krylov iteration 0 on 2 ranks").
        """
        pc = self.ksp.getPC()
        if self.ksp.getComm().getSize() == 1 or pc.getType() != PETSc.PC.Type.CHOLESKY \
                or pc.getFactorSolverType() != "mumps":
            return
        if PETSc.Options(self.ksp.getOptionsPrefix() or "").hasName("mat_mumps_icntl_13"):
            return  # the user's choice (MUMPS reads it at the factorisation)
        pc.setFactorSetUpSolverType()
        pc.getFactorMatrix().setMumpsIcntl(13, 1)

    def _correct_inertia(self) -> bool:
        """Refactorise an indefinite exact model with the shifts of
        :meth:`GaussNewtonModel.inertia_shift` until R has no negative pivot (at most
        ``inertia_shifts`` times); the model keeps the shift that did it. Returns whether
        one did (if not, the shift is taken off again and the Gauss–Newton fallback
        follows)."""
        model, added = self.model, 0.0
        for tries in range(model.inertia_shifts):
            delta = model.inertia_shift(tries)
            model.shift_value += delta
            added += delta
            self.ksp.setOperators(model.reduced_operator()[1])
            self.ksp.setUp()
            model.shift_factorisations += 1
            if not self.negative_pivots():
                model.shifted += 1
                return True
        model.shift_value -= added
        return False

    def negative_pivots(self) -> int:
        """The negative pivots of the last factorisation of R (MUMPS' INFOG(12), over all
        ranks); 0 where the factorisation is not MUMPS' (no inertia to read)."""
        pc = self.ksp.getPC()
        if pc.getType() != PETSc.PC.Type.CHOLESKY or pc.getFactorSolverType() != "mumps":
            return 0
        return int(pc.getFactorMatrix().getMumpsInfog(12))

    def apply(self, pc, r, y):
        """y = T R⁻¹ Tᵀ r + (r − T Tᵀ r) / (μ − σ + s): the pre-matrix's inverse applied.

        Args:
            pc: the PC this is the context of.
            r: the residual.
            y: the result.
        """
        T, R = self.model.reduced_operator()
        t, s, w = self.work
        T.multTranspose(r, t)           # t = Tᵀ r
        self.ksp.solve(t, s)            # s = R⁻¹ t
        T.mult(t, w)                    # w = T Tᵀ r (the tangent part of r)
        T.mult(s, y)                    # y = T R⁻¹ Tᵀ r
        normal = self.model.mu - self.model.sphere + self.model.shift_value
        y.axpy(1.0 / normal, r)
        y.axpy(-1.0 / normal, w)

    def destroy(self, pc):
        if self.ksp is not None:
            self.ksp.destroy()
        for v in self.work or ():
            v.destroy()
        self.ksp, self.work, self.model = None, None, None
