"""Cost of one Newton model: the reduced matrix R = Tᵀ G T assembled directly, against G
(5N × 5N) assembled and multiplied by the tangent basis (PETSc's PtAP).

    python benchmarks/newton_model.py [--sizes 0.0217 0.0069 0.0022] [--repeat 5]
    mpirun -n 2 python benchmarks/newton_model.py ...

On the non-isotropic piano from its MBO field (the solver's start) at each Gmsh mesh size
(the defaults are ``scaling.py``'s 10⁴ / 10⁵ / 10⁶ triangles), one
:class:`~ufl_frames.solvers.hessian.GaussNewtonModel` per path:

* ``direct``: the lean model of the default solver (``nls`` with ``ReducedFactorPC``): the
  compiled kernel of ``kernels.reduced_model_form`` writes R (3N × 3N);
* ``ptap``: the model the other Newton types and PCs use: G by ``kernels.
  damped_gauss_newton_form``, scaled, then Tᵀ G T by ``MatPtAP``.

Per path and mesh, the best of ``--repeat`` of ``model.assemble()`` followed by
``model.reduced_operator()`` (what a Newton step's ``update`` does before the
factorisation: the tangent bases, the matrices; wall time, max over ranks), the same for
the exact Hessian (the hybrid model's tail), and the memory the model holds (resident
memory after the Gauss–Newton repetitions minus before the model, max over ranks). Both
paths build the same R, and the largest relative difference of their entries is printed as
a check.
"""

import argparse
import os
import resource
import time

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_name, "1")


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    parser.add_argument("--sizes", type=float, nargs="+", default=[0.02172, 0.006868, 0.002172],
                        help="Gmsh mesh sizes of the piano (default: about 10⁴, 10⁵, 10⁶ "
                             "triangles)")
    parser.add_argument("--repeat", type=int, default=5, help="timed repetitions per path")
    return parser.parse_known_args(argv)


def resident_mb() -> float:
    """This process's resident memory now (Linux)."""
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * resource.getpagesize() / 2**20


def timed(comm, work, repeat: int) -> float:
    """Best wall time of ``work()`` over ``repeat`` runs (max over ranks)."""
    best = float("inf")
    for _ in range(repeat):
        comm.barrier()
        start = time.perf_counter()
        work()
        comm.barrier()
        best = min(best, comm.allreduce(time.perf_counter() - start, op=MPI.MAX))
    return best


def measure(problem, template, lean: bool, repeat: int, comm):
    """(seconds Gauss–Newton, seconds exact, MB held, R's values) of one path."""
    before = resident_mb()
    with GaussNewtonModel(problem, template, lean=lean) as model:
        def step():
            model.assemble()
            model.reduced_operator()

        gauss_newton = timed(comm, step, repeat)
        held = comm.allreduce(resident_mb() - before, op=MPI.MAX)
        _, R = model.reduced_operator()
        values = R.copy()
        model._use_exact()
        exact = timed(comm, step, repeat)
    return gauss_newton, exact, held, values


def main(argv=None):
    args, petsc_args = parse_args(argv)
    import sys

    sys.argv = [sys.argv[0], *petsc_args]
    comm = MPI.COMM_WORLD
    rows = []
    for h in args.sizes:
        domain = build(comm, "piano", mesh_size=h)
        field = FrameField.initial(domain)
        problem = solvers.frame_problem(field.q, constraints=field.constraints)
        template = dolfinx.fem.petsc.create_vector(problem.q.function_space)
        problem.write_x(template)
        triangles = domain.mesh.topology.index_map(2).size_global
        results = {}
        for path, lean in (("direct", True), ("ptap", False)):
            results[path] = measure(problem, template, lean, args.repeat, comm)
        difference = results["ptap"][3]
        scale = difference.norm(PETSc.NormType.FROBENIUS)
        difference.axpy(-1.0, results["direct"][3],
                        structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
        relative = difference.norm(PETSc.NormType.FROBENIUS) / scale
        for path in results:
            seconds, exact, added, _ = results[path]
            rows.append((triangles, path, seconds, exact, added, relative))
            results[path][3].destroy()
        template.destroy()
        if comm.rank == 0:
            print(f"h = {h}: {triangles} triangles done", flush=True)
    if comm.rank == 0:
        print(f"\n{comm.size} process(es), best of {args.repeat}")
        print("| triangles | path | Gauss–Newton s | exact s | MB held "
              "| |R_ptap − R_direct| / |R| |")
        print("|---|---|---|---|---|---|")
        for triangles, path, seconds, exact, added, relative in rows:
            print(f"| {triangles} | {path} | {seconds:.3f} | {exact:.3f} | {added:.0f} | "
                  f"{relative:.1e} |")


if __name__ == "__main__":
    from ufl_frames.bootstrap import init_petsc

    init_petsc()
    import dolfinx.fem.petsc
    from mpi4py import MPI
    from petsc4py import PETSc

    from ufl_frames import solvers
    from ufl_frames.mesh import build
    from ufl_frames.pipeline import FrameField
    from ufl_frames.solvers.hessian import GaussNewtonModel

    main()
