"""The size term's matrix in the Newton model's reduced matrix: one compiled kernel
(``kernels.reduced_model_form`` with a ``SizeKernel``) against the model before it (H's
reduced kernel, the size misfit's UFL matrix assembled apart, scaled and projected with
the tangent basis by a PtAP, added).

    python benchmarks/size_kernel.py [--mesh-size 0.0125] [--repeat 5]

On the sized piano (uniform target) at the MBO field, a random tangent basis (3 columns
a vertex): prints per variant the CPU seconds of one reduced matrix (best of
``--repeat``), exact and Gauss–Newton, and the largest difference between the two
matrices relative to their norm (they are the same matrix).
"""

import argparse
import time

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mesh-size", type=float, default=0.0125)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()

    import dolfinx.fem as fem
    import dolfinx.fem.petsc
    from mpi4py import MPI
    from petsc4py import PETSc

    from ufl_frames.fem import kernels
    from ufl_frames.mesh import build
    from ufl_frames.mesh.sizes import SizeTarget
    from ufl_frames.pipeline import FrameField
    from ufl_frames.solvers.hessian import _block_diagonal, _ptap

    comm = MPI.COMM_WORLD
    field = FrameField.initial(build(comm, "piano", mesh_size=args.mesh_size),
                               size=SizeTarget.uniform())
    from ufl_frames import solvers

    q = field.q
    problem = solvers.frame_problem(q, max_aspect=field.max_aspect, size=field.size,
                                    boundary_angles=field.boundary_angles,
                                    constraints=field.constraints)
    size = problem.size
    V, mesh = q.function_space, q.function_space.mesh
    n = V.dofmap.index_map.size_local
    rng = np.random.default_rng(1)
    blocks = rng.standard_normal((n, 5, 3))
    basis = fem.Function(fem.functionspace(mesh, ("Lagrange", 1, (15,))))
    basis.x.array.reshape(-1, 5, 3)[:n] = blocks
    basis.x.scatter_forward()
    space = fem.functionspace(mesh, ("Lagrange", 1, (3,)))
    damping = fem.Constant(mesh, PETSc.ScalarType(1e-3))
    inverse_area = fem.Constant(mesh, PETSc.ScalarType(1.0 / problem.area))
    mode = fem.Constant(mesh, PETSc.ScalarType(0))
    kernel = kernels.SizeKernel(size.log_h, size.coefficient, size.inverse_area, mode)
    T = _block_diagonal(blocks, V.dofmap.index_map, comm)
    triangles = mesh.topology.index_map(2).size_global
    print(f"sized piano, {triangles} triangles, {comm.size} rank(s), best of {args.repeat}")
    print("| model | one matrix (kernel) CPU s | before (kernel + UFL matrix + PtAP) CPU s "
          "| relative difference |")
    print("|---|---|---|---|")
    for exact in (False, True):
        mode.value = kernels.SIZE_EXACT if exact else kernels.SIZE_GAUSS_NEWTON
        one = kernels.reduced_model_form(q, basis, space, damping, inverse_area, exact,
                                         size=kernel)
        alone = kernels.reduced_model_form(q, basis, space, damping, inverse_area, exact)
        misfit = fem.form(size.hessian_ufl(q, exact))
        R1 = dolfinx.fem.petsc.create_matrix(one)
        R0 = dolfinx.fem.petsc.create_matrix(alone)
        G = dolfinx.fem.petsc.create_matrix(misfit)
        unscale = G.createVecLeft()
        unscale.set(1.0)
        products = []

        def new(R1=R1, one=one):
            R1.zeroEntries()
            dolfinx.fem.petsc.assemble_matrix(R1, one)
            R1.assemble()

        def old(R0=R0, alone=alone, G=G, misfit=misfit, unscale=unscale, products=products):
            R0.zeroEntries()
            dolfinx.fem.petsc.assemble_matrix(R0, alone)
            R0.assemble()
            G.zeroEntries()
            dolfinx.fem.petsc.assemble_matrix(G, misfit)
            G.assemble()
            G.diagonalScale(unscale, unscale)
            product = _ptap(G, T, products[0] if products else None)
            products[:] = [product]
            R0.axpy(1.0, product, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)

        times = {}
        for name, run in (("new", new), ("old", old)):
            best = float("inf")
            for _ in range(args.repeat):
                start = time.process_time()
                run()
                best = min(best, time.process_time() - start)
            times[name] = comm.allreduce(best, op=MPI.MAX)
        difference = R0.copy()
        difference.axpy(-1.0, R1, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
        relative = difference.norm(PETSc.NormType.FROBENIUS) / R1.norm(
            PETSc.NormType.FROBENIUS)
        print(f"| {'exact' if exact else 'Gauss–Newton'} | {times['new']:.3f} "
              f"| {times['old']:.3f} | {relative:.1e} |")
        for obj in (R1, R0, G, unscale, *products, difference):
            obj.destroy()


if __name__ == "__main__":
    main()
