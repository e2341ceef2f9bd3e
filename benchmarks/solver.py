"""Cost of the frame-field solver on the annulus, against a plain DOLFINx assembly.

    python benchmarks/solver.py [--triangles 1e5 1e6 | --sizes 0.0076 0.0024] [--repeat 10]
                                [--iterations 3] [--tao-types default bncg] [--study]
                                [PETSc options, e.g. -bench_tao_nls_pc_type hypre]
    mpirun -n 2 python benchmarks/solver.py ...

Meshes: the annulus 0.5 <= r <= 1 (``--triangles``: the Gmsh mesh size is chosen from the
measured 2305 triangles at h = 0.05, N ~ 1/h²; ``--sizes`` gives mesh sizes directly).

First table, per evaluation (best of ``--repeat``), one row per mesh:

* ``grad``: one gradient evaluation of the solver, as TAO's objective/gradient callback does
  it after the retraction: assemble dH (vector, reverse ghost update), H = dH·q/4, project
  dH on the tangent space (``FrameProblem.riemannian_gradient``);
* ``dir``: the reference, a plain DOLFINx assembly of the gradient of the Dirichlet energy
  E = ½∫|∇q|² on the same space (``fem.assemble_vector`` of its derivative + ghost update);
  ``ratio`` = grad / dir (target <= 3), from wall and from CPU times;
* ``retract``: one projection, steps 4-5 of the note (``FrameProblem.retract``);
* ``RSS``: peak resident memory of the process so far (``ru_maxrss``), max over ranks.

Second table, per solver iteration, one row per mesh and TAO type (``--tao-types``;
``default`` is the solver's default, ``bncg`` the note's projected steepest descent):
``solve(max_it=--iterations)`` wall time / iterations, the number of objective evaluations
per iteration (line-search trials) and the peak memory after the solve. The solves use the
options prefix ``bench_``, so ``-bench_tao_...`` options on the command line apply to them.

Times are wall-clock seconds (max over ranks); ``cpu`` columns give the process CPU time of
rank 0, the fairer number on a shared machine. BLAS runs on one thread per process unless
OMP_NUM_THREADS / OPENBLAS_NUM_THREADS say otherwise. The frame field is the exact cross of the
MBO limit (unit lengths, angle atan2(y, x)) perturbed by a smooth rotation, so that H and
its gradient are far from zero; the timings do not depend on it.

``--study`` adds the refinement study of the residual H of the isotropic annulus solve
(from the MBO field, to convergence, ``--study-sizes``, TAO type ``--study-tao-type``): the
residual is the discretisation error of an integrable field and falls as O(h²).
"""

import argparse
import math
import os
import resource
import sys
import time

# One BLAS/OpenMP thread per process, as in the Makefile (set before NumPy loads): with
# threaded OpenBLAS on a loaded machine, a single np.vdot of 1e5 entries takes ~10 ms.
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_name, "1")


def parse_args(argv=None):
    """(benchmark arguments, remaining arguments for PETSc)."""
    parser = argparse.ArgumentParser(
        description="Cost of the frame-field solver on the annulus (see the module docstring).",
        allow_abbrev=False,
    )
    group = parser.add_mutually_exclusive_group()
    group.add_argument(
        "--triangles",
        type=float,
        nargs="+",
        default=[1e5, 1e6],
        help="approximate triangle counts (default 1e5 1e6)",
    )
    group.add_argument("--sizes", type=float, nargs="+", help="Gmsh mesh sizes instead")
    parser.add_argument("--repeat", type=int, default=10, help="timing repeats (best kept)")
    parser.add_argument(
        "--iterations", type=int, default=3, help="solver iterations timed (max_it, default 3)"
    )
    parser.add_argument(
        "--tao-types",
        nargs="+",
        default=["default", "bncg"],
        help="TAO types timed ('default': the solver's; bncg: the note's method)",
    )
    parser.add_argument(
        "--nonisotropic",
        dest="isotropic",
        action="store_false",
        help="free lengths (default: isotropic frames)",
    )
    parser.add_argument("--study", action="store_true", help="also run the refinement study")
    parser.add_argument("--study-sizes", type=float, nargs="+", default=[0.1, 0.05, 0.025])
    parser.add_argument("--study-tao-type", default="default")
    parser.add_argument("--study-max-it", type=int, default=1000)
    return parser.parse_known_args(argv)


ARGS, PETSC_ARGV = parse_args() if __name__ == "__main__" else (None, [])

from ufl_frames.bootstrap import init_petsc  # noqa: E402

init_petsc(sys.argv[:1] + PETSC_ARGV)  # PETSc options (-tao_type ...) are honoured

import dolfinx  # noqa: E402
import dolfinx.fem as fem  # noqa: E402
import dolfinx.fem.petsc  # noqa: E402, F401
import numpy as np  # noqa: E402
from _common import best_time, mesh_size_for  # noqa: E402
from mpi4py import MPI  # noqa: E402

from ufl_frames import solvers  # noqa: E402
from ufl_frames.fem import energy  # noqa: E402
from ufl_frames.mesh import annulus  # noqa: E402
from ufl_frames.solvers import mbo  # noqa: E402


def peak_rss_mb(comm) -> float:
    return comm.allreduce(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, op=MPI.MAX) / 1024


def test_field(x):
    r, phi = np.hypot(x[0], x[1]), np.arctan2(x[1], x[0])
    return 1.0, 1.0, phi + 0.3 * np.sin(2 * phi) * np.sin(2 * np.pi * r)


def bench_size(comm, h, args):
    start = time.perf_counter()
    mesh = annulus(comm, mesh_size=h).mesh
    t_mesh = comm.allreduce(time.perf_counter() - start, op=MPI.MAX)
    V = energy.frame_space(mesh)
    start = time.perf_counter()
    q = energy.interpolate_frames(V, test_field)
    problem = solvers.frame_problem(q, isotropic=args.isotropic)
    t_setup = comm.allreduce(time.perf_counter() - start, op=MPI.MAX)
    q0 = q.x.array.copy()

    g = dolfinx.fem.petsc.create_vector(V)

    def gradient_evaluation():
        problem.riemannian_gradient(g)  # returns H too (Euler: dH(q)[q] = 4 H)

    dirichlet_gradient = fem.form(energy.gradient_form(energy.dirichlet_energy_form(q), q))

    def dirichlet_assembly():
        b = fem.assemble_vector(dirichlet_gradient)
        b.scatter_reverse(dolfinx.la.InsertMode.add)

    def retraction():
        q.x.array[:] = q0
        problem.retract()

    t_grad = best_time(gradient_evaluation, args.repeat, comm)
    t_dir = best_time(dirichlet_assembly, args.repeat, comm)
    t_retract = best_time(retraction, args.repeat, comm)

    rss_components = peak_rss_mb(comm)

    # Solver iterations: count objective evaluations through the problem's energy().
    evaluations = [0]
    plain_energy = problem.energy

    def counted_energy():
        evaluations[0] += 1
        return plain_energy()

    problem.energy = counted_energy
    solves = []
    for tao_type in args.tao_types:
        q.x.array[:] = q0
        evaluations[0] = 0
        start_cpu = time.process_time()
        result = solvers.solve(
            problem,
            max_it=args.iterations,
            options_prefix="bench_",
            defaults=None if tao_type == "default" else {"tao_type": tao_type},
        )
        cpu_solve = time.process_time() - start_cpu
        its = max(result.iterations, 1)
        solves.append(
            {
                "type": solvers.DEFAULT_OPTIONS["tao_type"] if tao_type == "default" else tao_type,
                "iter": (result.wall_time_s / its, cpu_solve / its),
                "evals": evaluations[0] / its,
                "its": result.iterations,
                "reason": result.converged_reason,
                "H": (result.H_initial, result.H_final),
                "rss": peak_rss_mb(comm),
            }
        )
    problem.energy = plain_energy
    g.destroy()
    return {
        "triangles": mesh.topology.index_map(2).size_global,
        "vertices": mesh.topology.index_map(0).size_global,
        "mesh": t_mesh,
        "setup": t_setup,
        "grad": t_grad,
        "dir": t_dir,
        "retract": t_retract,
        "rss": rss_components,
        "solves": solves,
    }


def print_table(rows, comm, args):
    if comm.rank != 0:
        return
    header = (
        f"{'triangles':>10} {'vertices':>9} {'mesh s':>7} {'setup s':>7} "
        f"{'grad ms':>8} {'(cpu)':>7} {'dir ms':>7} {'(cpu)':>7} {'ratio':>6} {'(cpu)':>6} "
        f"{'retract ms':>10} {'(cpu)':>7} {'RSS MB':>7}"
    )
    print("\nPer evaluation (best of --repeat):")
    print(header)
    print("-" * len(header))
    for r in rows:
        print(
            f"{r['triangles']:>10d} {r['vertices']:>9d} {r['mesh']:>7.1f} {r['setup']:>7.1f} "
            f"{1e3 * r['grad'][0]:>8.1f} {1e3 * r['grad'][1]:>7.1f} "
            f"{1e3 * r['dir'][0]:>7.1f} {1e3 * r['dir'][1]:>7.1f} "
            f"{r['grad'][0] / r['dir'][0]:>6.2f} {r['grad'][1] / r['dir'][1]:>6.2f} "
            f"{1e3 * r['retract'][0]:>10.1f} {1e3 * r['retract'][1]:>7.1f} {r['rss']:>7.0f}"
        )
    header = (
        f"{'triangles':>10} {'TAO type':>8} {'its':>4} {'s/iter':>8} {'(cpu)':>8} "
        f"{'evals/it':>8} {'H initial':>10} {'H final':>10} {'RSS MB':>7}  reason"
    )
    print(f"\nPer solver iteration (solve with max_it = {args.iterations}, PETSc prefix bench_):")
    print(header)
    print("-" * len(header))
    for r in rows:
        for v in r["solves"]:
            print(
                f"{r['triangles']:>10d} {v['type']:>8} {v['its']:>4d} {v['iter'][0]:>8.2f} "
                f"{v['iter'][1]:>8.2f} {v['evals']:>8.2f} {v['H'][0]:>10.4e} {v['H'][1]:>10.4e} "
                f"{v['rss']:>7.0f}  {v['reason']}"
            )
    print("(RSS: peak resident memory of the process so far, max over ranks)")


def refinement_study(comm, args):
    tao_type = args.study_tao_type
    rows = []
    for h in args.study_sizes:
        mesh = annulus(comm, mesh_size=h).mesh
        q = mbo.mbo_frame_field(energy.frame_space(mesh))
        problem = solvers.frame_problem(q, isotropic=True)
        result = solvers.solve(
            problem,
            max_it=args.study_max_it,
            options_prefix="study_",
            defaults=None if tao_type == "default" else {"tao_type": tao_type},
        )
        rows.append((h, mesh.topology.index_map(2).size_global, result))
    if comm.rank != 0:
        return
    name = solvers.DEFAULT_OPTIONS["tao_type"] if tao_type == "default" else tao_type
    print(f"\nResidual H of the isotropic annulus (from MBO, TAO {name}):")
    print(f"{'h':>8} {'triangles':>10} {'H residual':>12} {'rate':>6} {'its':>5} {'s':>7}  reason")
    previous = None
    for h, cells, result in rows:
        rate = ""
        if previous is not None:
            # h ~ cells^(-1/2): rate = log(H ratio) / log(h ratio)
            value = 2 * math.log(previous[1] / result.H_final) / math.log(cells / previous[0])
            rate = f"{value:.2f}"
        print(
            f"{h:>8.4f} {cells:>10d} {result.H_final:>12.4e} {rate:>6} {result.iterations:>5d} "
            f"{result.wall_time_s:>7.1f}  {result.converged_reason}"
        )
        previous = (cells, result.H_final)
    print("(rate: of H against the mean edge length, h ~ triangles^(-1/2))")


def main(args):
    comm = MPI.COMM_WORLD
    sizes = args.sizes or [mesh_size_for("annulus", n) for n in args.triangles]
    if comm.rank == 0:
        print(
            f"annulus 0.5 <= r <= 1, {comm.size} rank(s), mesh sizes "
            f"{', '.join(f'{h:.4g}' for h in sizes)}, best of {args.repeat}, "
            f"{'isotropic' if args.isotropic else 'non-isotropic'}",
            flush=True,
        )
    rows = []
    for h in sizes:
        rows.append(bench_size(comm, h, args))
        if comm.rank == 0:
            print(f"  h = {h:.4g}: {rows[-1]['triangles']} triangles done", flush=True)
    print_table(rows, comm, args)
    if args.study:
        refinement_study(comm, args)


if __name__ == "__main__":
    main(ARGS)
