"""Is the note's isotropic-piano stall a true local minimum? (issue: second-order solvers)

For each mesh size, from the same MBO field, the default Gauss–Newton solver is run
isotropically twice: with the singularities pinned (cross orientation held on the
MBO field's singular triangles) and free. Prints H, iterations, the converged reason,
the relative gradient and where the singularities end up.

    python benchmarks/isotropic_piano.py [--sizes 0.1 0.05 0.025] [--max-it 500]

If the pinned H grows under refinement, no isotropic integrable field has
singularities where MBO put them: the stall is a genuine (constrained) local
minimum. If the free H falls, moving the singularities is the way past it.
"""

import argparse
import sys

from ufl_frames.bootstrap import init_petsc

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--sizes", type=float, nargs="+", default=[0.1, 0.05, 0.025])
parser.add_argument("--max-it", type=int, default=500)
args, petsc_args = parser.parse_known_args()
init_petsc([sys.argv[0], *petsc_args])

from mpi4py import MPI  # noqa: E402

from ufl_frames import solvers  # noqa: E402
from ufl_frames.fem import energy  # noqa: E402
from ufl_frames.frames2d import singularities  # noqa: E402
from ufl_frames.mesh import piano  # noqa: E402
from ufl_frames.solvers import mbo  # noqa: E402


def describe(found):
    return ", ".join(f"{s['index']:+.2f}@({s['x']:.2f},{s['y']:.2f})" for s in found) or "none"


comm = MPI.COMM_WORLD
say = print if comm.rank == 0 else (lambda *a, **k: None)
say(f"{'h':>6} {'pinned':>7} {'its':>5} {'H':>10} {'rel |g|':>9} {'reason':<22} singularities")
for h in args.sizes:
    mesh = piano(comm, mesh_size=h).mesh
    V = energy.frame_space(mesh)
    initial = mbo.mbo_frame_field(V)
    for pinned in (True, False):
        q = initial.copy()
        problem = solvers.frame_problem(q, isotropic=True, pin_singularities=pinned)
        result = solvers.solve(problem, max_it=args.max_it)
        rel = result.history[-1]["gnorm"] / result.history[0]["gnorm"]
        found = singularities.locate_singularities(q)
        say(f"{h:6.3f} {str(pinned):>7} {result.iterations:5d} {result.H_final:10.4g} {rel:9.1e} "
            f"{result.converged_reason:<22} {len(found)}: {describe(found)[:90]}", flush=True)
