"""Preconditioners for the reduced Newton matrix R, and whether any is linear in the mesh.

    python benchmarks/newton_pc.py [--levels 2 3 4] [--coarse-size 0.05] [--ratios 1e-3 1e-2]

The default solver factorises R = Tᵀ W⁻¹ (JᵀJ + λ (K + M/A)) W⁻¹ T (3 unknowns a vertex)
once per Newton step with MUMPS, whose cost grows like N^1.5. This script asks which
iterative preconditioner could replace it. For each ``L`` of ``--levels`` it builds the
nested piano meshes (``ufl_frames.mesh.build_nested``: Gmsh meshes the coarsest at
``--coarse-size``, every finer level splits each triangle into 4), solves the
non-isotropic field there by nested iteration (at most ``--max-it`` Newton steps a
level: the matrix of a field near a minimum is what the late steps factorise), builds
the lean Gauss–Newton model on the finest level with the damping at ``ratio`` × its
natural scale (``-frames_gn_damping_min``; the solver's floor is 1e-3, where it spends
its last steps), and solves R y = b (b random, seeded) to a relative residual of 1e-6
with:

* ``direct``: MUMPS Cholesky (the default solver's preconditioner; one application);
* ``gamg``: CG with PETSc's smoothed aggregation, block size 3;
* ``mg-<smoother>``: FGMRES with a geometric V-cycle over the nested levels
  (``PCMG``, Galerkin coarse matrices Pᵀ R P, the coarsest factorised). The prolongation
  of level k − 1 to level k carries a reduced step to a step of the frames and back:
  P = T_kᵀ W_k Π W_{k−1}⁻¹ T_{k−1}, Π the P1 interpolation of the 5 coefficients (exact on
  nested meshes), W the square roots of the lumped masses, T_j the tangent basis of the
  finest field sampled at level j's vertices (the finest level's own T holds the aspect
  bound's active set). Smoothers: ``sor`` (SSOR), ``pbjacobi`` (3 × 3 blocks), ``asm``
  (overlapping blocks of about 4 000 unknowns, overlap 4, Cholesky in each); 3 GMRES
  iterations a level.

Printed per size, ratio and method: Krylov iterations (for 1e-6 and for 1e-2, the
tolerance of an inexact Newton step), setup and solve seconds. Serial only (the
interpolation is built with one process's mesh). What it showed on 2026-12-05 is in
benchmarks/README.md ("Why no algebraic multigrid, and what a geometric one does").
"""

import argparse
import os
import time

import matplotlib.tri as mtri
import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

METHODS = ("direct", "gamg", "mg-sor", "mg-pbjacobi", "mg-asm")


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    parser.add_argument("--levels", type=int, nargs="+", default=[2, 3, 4],
                        help="numbers of nested levels (finest: coarse size / 2^(L-1))")
    parser.add_argument("--coarse-size", type=float, default=0.05,
                        help="Gmsh mesh size of the coarsest level")
    parser.add_argument("--ratios", type=float, nargs="+", default=[1e-3, 1e-2],
                        help="damping λ as a multiple of its natural scale")
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    parser.add_argument("--max-it", type=int, default=60, help="Newton steps a level at most")
    return parser.parse_known_args(argv)


def p1_interpolation(V_coarse, V_fine):
    """The P1 interpolation of one scalar from ``V_coarse``'s vertices to ``V_fine``'s (a
    SciPy CSR matrix, fine × coarse): barycentric weights in the coarse triangle holding
    each fine vertex; a fine vertex outside every coarse triangle (a curved boundary's
    bulge, O(h²) out) is extrapolated linearly from the triangle at the nearest coarse
    vertex that it is least outside of (exact for linear functions, as inside)."""
    fine = V_fine.tabulate_dof_coordinates()[:, :2]
    coarse = V_coarse.tabulate_dof_coordinates()[:, :2]
    triangles = V_coarse.dofmap.list
    found = mtri.Triangulation(coarse[:, 0], coarse[:, 1], triangles).get_trifinder()(
        fine[:, 0], fine[:, 1])
    outside = np.flatnonzero(found < 0)
    if len(outside):  # the incident triangle of the nearest vertex with the largest min weight
        nearest = cKDTree(coarse).query(fine[outside])[1]
        for i, vertex in zip(outside, nearest, strict=True):
            incident = np.flatnonzero((triangles == vertex).any(axis=1))
            weights = barycentric(coarse, triangles[incident],
                                  np.repeat(fine[i:i + 1], len(incident), axis=0))
            found[i] = incident[np.argmax(weights.min(axis=1))]
    corners = triangles[found]
    weights = barycentric(coarse, corners, fine)
    rows = np.repeat(np.arange(len(fine)), 3)
    cols, vals = corners.ravel(), weights.ravel()
    return sp.csr_matrix((vals, (rows, cols)), shape=(len(fine), len(coarse)))


def barycentric(points, corners, targets):
    """Barycentric coordinates (n, 3) of ``targets`` (n, 2) in the triangles ``corners``
    (n, 3 indices into ``points``); outside a triangle some are negative."""
    a, b, c = (points[corners[:, i]] for i in range(3))
    det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    dx, dy = targets[:, 0] - a[:, 0], targets[:, 1] - a[:, 1]
    l1 = (dx * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * dy) / det
    l2 = ((b[:, 0] - a[:, 0]) * dy - dx * (b[:, 1] - a[:, 1])) / det
    return np.stack([1 - l1 - l2, l1, l2], axis=1)


def to_scipy(A):
    indptr, indices, values = A.getValuesCSR()
    return sp.csr_matrix((values, indices, indptr), shape=A.getSize())


def to_petsc(A):
    return PETSc.Mat().createAIJ(size=A.shape, csr=(A.indptr, A.indices, A.data),
                                 comm=MPI.COMM_SELF)


class Hierarchy:
    """The finest field's Newton model and one lean model per coarser level (for its tangent
    basis at the finest field sampled there); :meth:`prolongations` at the current models."""

    def __init__(self, domains, finest):
        from ufl_frames.fem.transfer import interpolate_field

        self.fields = []
        for domain in domains[:-1]:
            field = FrameField.initial(domain)
            field.q.x.array[:] = interpolate_field(finest.q, domain.mesh).x.array
            self.fields.append(field)
        self.fields.append(finest)
        self.problems, self.models, self.templates = [], [], []
        for field in self.fields:
            problem = solvers.frame_problem(field.q, constraints=field.constraints)
            template = dolfinx.fem.petsc.create_vector(problem.q.function_space)
            problem.write_x(template)
            self.problems.append(problem)
            self.templates.append(template)
            self.models.append(GaussNewtonModel(problem, template, lean=True))
        spaces = [field.q.function_space for field in self.fields]
        self.interpolations = [
            sp.kron(p1_interpolation(spaces[k], spaces[k + 1]), sp.eye(5), format="csr")
            for k in range(len(spaces) - 1)]

    def assemble(self, ratio: float):
        """Every model at damping ``ratio``; returns the finest R (the model's own)."""
        for model in self.models:
            model.damping_min, model.gnorm0 = ratio, 1.0
            model.assemble(gnorm=0.0)
        return self.models[-1].reduced_operator()[1]

    def prolongations(self):
        bases = [to_scipy(model.reduced_operator()[0]) for model in self.models]
        result = []
        for k in range(len(self.models) - 1):
            fine, coarse = self.problems[k + 1], self.problems[k]
            scale_fine = sp.diags(np.repeat(fine.sqrt_mass[: fine.owned], 5))
            unscale_coarse = sp.diags(np.repeat(1.0 / coarse.sqrt_mass[: coarse.owned], 5))
            P = bases[k + 1].T @ scale_fine @ self.interpolations[k] @ unscale_coarse @ bases[k]
            result.append(to_petsc(P.tocsr()))
        return result

    def free(self):
        for model in self.models:
            model.free()
        for template in self.templates:
            template.destroy()


def options(method: str, levels: int, unknowns: int) -> dict:
    if method == "direct":
        return {"ksp_type": "preonly", "pc_type": "cholesky",
                "pc_factor_mat_solver_type": "mumps"}
    if method == "gamg":
        return {"ksp_type": "cg", "pc_type": "gamg"}
    smoother = method.split("-", 1)[1]
    result = {"ksp_type": "fgmres", "pc_type": "mg", "pc_mg_levels": levels,
              "pc_mg_galerkin": "both", "mg_levels_ksp_type": "gmres",
              "mg_levels_ksp_max_it": 3, "mg_levels_pc_type": smoother,
              "mg_coarse_pc_type": "cholesky"}
    if smoother == "asm":
        result.update({"mg_levels_pc_asm_overlap": 4, "mg_levels_sub_pc_type": "cholesky",
                       "mg_levels_pc_asm_blocks": max(1, unknowns // 4000)})
    return result


def run(method, R, prolongations, levels, rhs, rtol, tag):
    """(iterations, setup s, solve s) of one method on R y = rhs."""
    prefix = f"npc_{tag}_"
    database, settings = PETSc.Options(), options(method, levels, R.getSize()[0])
    for key, value in settings.items():
        database[prefix + key] = value
    ksp = PETSc.KSP().create(MPI.COMM_SELF)
    try:
        ksp.setOptionsPrefix(prefix)
        ksp.setOperators(R)  # block size 3 (the reduced space's), which GAMG uses
        ksp.setTolerances(rtol=rtol, max_it=2000)
        ksp.setFromOptions()
        if method.startswith("mg-"):
            for k, P in enumerate(prolongations):
                ksp.getPC().setMGInterpolation(k + 1, P)
        y = rhs.duplicate()
        start = time.perf_counter()
        ksp.setUp()
        setup = time.perf_counter() - start
        start = time.perf_counter()
        ksp.solve(rhs, y)
        solve = time.perf_counter() - start
        y.destroy()
        its = ksp.getIterationNumber() if ksp.getConvergedReason() > 0 else float("nan")
        return (1 if method == "direct" else its), setup, solve
    finally:
        ksp.destroy()
        for key in settings:
            database.delValue(prefix + key)


def main(argv=None):
    args, petsc_args = parse_args(argv)
    import sys

    sys.argv = [sys.argv[0], *petsc_args]
    if MPI.COMM_WORLD.size > 1:
        raise SystemExit("newton_pc.py runs in one process (its interpolation is serial)")
    rows = []
    for levels in args.levels:
        domains = build_nested(MPI.COMM_SELF, "piano", levels=levels,
                               mesh_size=args.coarse_size / 2 ** (levels - 1))
        finest = FrameField.nested(domains, max_it=args.max_it)
        hierarchy = Hierarchy(domains, finest)
        try:
            for ratio in args.ratios:
                R = hierarchy.assemble(ratio)
                prolongations = hierarchy.prolongations()
                rhs = R.createVecRight()
                generator = PETSc.Random().create(MPI.COMM_SELF)
                generator.setSeed(12345)
                rhs.setRandom(generator)
                generator.destroy()
                for method in args.methods:
                    tight = run(method, R, prolongations, levels, rhs, 1e-6, "t")
                    loose = run(method, R, prolongations, levels, rhs, 1e-2, "l")
                    rows.append((domains[-1].num_cells, R.getSize()[0], ratio, method,
                                 tight, loose[0]))
                    print(f"{rows[-1][0]} triangles, λ ratio {ratio:g}, {method}: "
                          f"{tight[0]} its ({loose[0]} to 1e-2), setup {tight[1]:.2f} s, "
                          f"solve {tight[2]:.2f} s", flush=True)
                rhs.destroy()
                for P in prolongations:
                    P.destroy()
        finally:
            hierarchy.free()
    print("\n| triangles | unknowns | λ ratio | method | its (1e-6) | its (1e-2) "
          "| setup s | solve s |")
    print("|---|---|---|---|---|---|---|---|")
    for triangles, unknowns, ratio, method, (its, setup, solve), loose in rows:
        print(f"| {triangles} | {unknowns} | {ratio:g} | {method} | {its} | {loose} "
              f"| {setup:.2f} | {solve:.2f} |")


if __name__ == "__main__":
    from ufl_frames.bootstrap import init_petsc

    init_petsc()
    import dolfinx.fem.petsc
    from mpi4py import MPI
    from petsc4py import PETSc

    from ufl_frames import solvers
    from ufl_frames.mesh import build_nested
    from ufl_frames.pipeline import FrameField
    from ufl_frames.solvers.hessian import GaussNewtonModel

    main()
