"""Time and memory of 3D MBO frame fields at several mesh sizes (issue 41).

    python benchmarks/mbo3d.py [--shape ball|box|cylinder] [--sizes 0.2 0.1 0.05]
    mpirun -n 2 python benchmarks/mbo3d.py ...

Per mesh size: tetrahedra and vertices, seconds to mesh, seconds of MBO split into the
diffusion solves (with the KSP iterations per solve) and the pointwise projections,
seconds of the singular graph (rank 0, gathered field), its edges and chains, and the peak
resident memory of rank 0 after each stage (meshing, MBO, graph: the process's high-water
mark, so a stage's number includes the earlier ones').
"""

import argparse
import resource
import time

import numpy as np
from mpi4py import MPI

from ufl_frames.fem.gather import gather_p1_field
from ufl_frames.frames3d import singular
from ufl_frames.mesh import volumes
from ufl_frames.solvers import mbo
from ufl_frames.solvers.mbo3d import mbo_frame_field_3d

SHAPES = {"ball": volumes.ball, "box": volumes.box, "cylinder": volumes.hollow_cylinder}


class _Counters:
    """Seconds and KSP iterations of the diffusion solves, wrapped around
    :meth:`ScalarDiffusion.solve`."""

    def __init__(self):
        self.solve_seconds = 0.0
        self.solves = 0
        self.iterations = 0
        original = mbo.ScalarDiffusion.solve

        def timed(diffusion, previous, j):
            start = time.perf_counter()
            out = original(diffusion, previous, j)
            self.solve_seconds += time.perf_counter() - start
            self.solves += 1
            self.iterations += diffusion._ksp.getIterationNumber()
            return out

        mbo.ScalarDiffusion.solve = timed


def _peak_mb() -> float:
    """This process's peak resident memory so far (MB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shape", choices=sorted(SHAPES), default="ball")
    parser.add_argument("--sizes", type=float, nargs="+", default=[0.2, 0.1, 0.05])
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    counters = _Counters()
    if comm.rank == 0:
        print(f"{args.shape} on {comm.size} rank(s)")
        print("| h | tets | vertices | mesh s | MBO s | solves s | KSP its/solve | project s "
              "| graph s | singular edges | chains | open ends | peak MB after mesh / MBO / graph "
              "(rank 0) |")
        print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for h in args.sizes:
        start = time.perf_counter()
        volume = SHAPES[args.shape](comm, mesh_size=h)
        meshed = time.perf_counter()
        peaks = [_peak_mb()]
        counters.solve_seconds, counters.solves, counters.iterations = 0.0, 0, 0
        q = mbo_frame_field_3d(volume)
        solved = time.perf_counter()
        peaks.append(_peak_mb())
        x, cells, rows = gather_p1_field(q)
        if comm.rank == 0:
            begun = time.perf_counter()
            graph = singular.singular_graph(cells, rows, x)
            graph_s = time.perf_counter() - begun
            mbo_s = solved - meshed
            its = counters.iterations / max(counters.solves, 1)
            peaks.append(_peak_mb())
            print(f"| {h:g} | {cells.shape[0]} | {x.shape[0]} | {meshed - start:.1f} | "
                  f"{mbo_s:.1f} | {counters.solve_seconds:.1f} | {its:.1f} | "
                  f"{mbo_s - counters.solve_seconds:.1f} | {graph_s:.1f} | {len(graph.edges)} | "
                  f"{graph.num_chains} | {graph.open_ends.size} | "
                  f"{' / '.join(f'{p:.0f}' for p in peaks)} |", flush=True)
        del q, x, cells, rows
    np.random.seed(0)


if __name__ == "__main__":
    main()
