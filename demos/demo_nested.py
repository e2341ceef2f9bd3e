# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: light
#       format_version: '1.5'
#       jupytext_version: 1.16.0
# ---

# # Fine meshes by nested iteration
#
# On one mesh the Newton solver starts from the smooth MBO field, which is far from
# integrable: on the non-isotropic piano it needs 31, 39 and 52 Newton steps at
# h = 0.05, 0.025 and 0.0125, each step a sparse factorisation. *Nested iteration*
# starts each fine mesh from the solution of a coarser one instead:
#
# 1. Gmsh meshes the geometry at sizes $2^{L-1}h, \dots, 2h, h$ (independent meshes of
#    the same CAD model, not refinements of each other);
# 2. MBO and a solve on the coarsest mesh;
# 3. on each finer mesh, the coarser solution interpolated at its vertices
#    (`ufl_frames.fem.transfer.interpolate_field`: non-matching P1 interpolation, a
#    vertex on a curved boundary just outside the coarse polygon is evaluated in the
#    nearest coarse cell), put back on the frame manifold by the solver's retraction,
#    and solved from there.
#
# Every level stops at the accuracy asked of the whole solve: its gradient test is
# relative to the *coarsest* start's gradient, not to its own (already small) one. The
# singular triangles of each level's start are pinned, so MBO's singularities are carried
# down to the finest mesh. `ufl-frames solve` does this by default (`--levels auto`).
#
# Run it with `python demo_nested.py` or `mpirun -n 2 python demo_nested.py`; output in
# `out_demo_nested/`. With `CI` set, the meshes are coarse.

# +
import sys

from ufl_frames.bootstrap import init_petsc

init_petsc(sys.argv)

import os  # noqa: E402
from pathlib import Path  # noqa: E402

from mpi4py import MPI  # noqa: E402

from ufl_frames import output  # noqa: E402
from ufl_frames.mesh import build  # noqa: E402
from ufl_frames.pipeline import FrameField  # noqa: E402

comm = MPI.COMM_WORLD
CI = os.environ.get("CI", "").strip().lower() not in ("", "0", "false")
h, levels = (0.05, 2) if CI else (0.0125, 3)
out = Path("out_demo_nested")
if comm.rank == 0:
    out.mkdir(exist_ok=True)
comm.Barrier()


def say(text):
    if comm.rank == 0:
        print(text, flush=True)


# -

# ## The meshes
#
# `size_factor` scales the mesh size Gmsh is asked for; a factor 2 gives about a quarter
# of the triangles.

# +
domains = [build(comm, "piano", mesh_size=h, size_factor=2.0**k)
           for k in range(levels - 1, -1, -1)]
for domain in domains:
    say(f"mesh: {domain.num_cells} triangles, mean edge {domain.mesh_size:.4f}")
# -

# ## Coarse to fine
#
# `FrameField.nested` returns the field on the finest mesh; `levels` records each
# solve. The H printed is each mesh's own: the interpolated coarse solution has a higher
# H on the finer mesh than on its own (the finer mesh sees more of its bracket), which
# the fine solve then brings below the coarse value.

# +
nested = FrameField.nested(
    domains, max_it=500,
    level_monitor=lambda e: say(f"  {e['triangles']:6d} triangles: {e['iterations']:3d} "
                                f"Newton steps, H {e['H']:.4e}, {e['reason']}, "
                                f"{e['seconds']:.1f} s"))
starts = [history[0]["H"] for history in nested.level_histories]
say("H at the start of each level: " + ", ".join(f"{H:.3e}" for H in starts))
# -

# ## Against a cold start on the finest mesh
#
# The same finest mesh from its own MBO field. Both converge; nested iteration needs
# fewer Newton steps on the finest mesh (where each costs most) and, on the piano,
# reaches a lower H: the coarse solution leads to another, better local minimum with the
# same two singularities.

# +
cold = FrameField.initial(domains[-1])
result = cold.solve(max_it=500)
fine = nested.levels[-1]
say(f"finest mesh, cold start: {result.iterations} Newton steps, H {result.H_final:.4e}")
say(f"finest mesh, nested:     {fine['iterations']} Newton steps, H {fine['H']:.4e}")
say(f"singularities, nested: {output.describe_singularities(nested.singularities)}")
say(f"singularities, cold:   {output.describe_singularities(cold.singularities)}")
assert all(e["reason"].startswith("CONVERGED") for e in nested.levels)
assert sorted(s["index"] for s in nested.singularities) == \
    sorted(s["index"] for s in cold.singularities)
# -

# ## Pictures
#
# `convergence_nested.png` shows every level one after the other, the jump of H at each
# transfer and the short solve that follows; `convergence_cold.png` the single solve.

# +
levels_plot = [(f"{e['triangles']} triangles", part)
               for e, part in zip(nested.levels, nested.level_histories, strict=True)]
output.plot_convergence(out / "convergence_nested.png", nested.result.history,
                    title="piano, non-isotropic, nested iteration", comm=comm,
                    levels=levels_plot)
output.plot_convergence(out / "convergence_cold.png", result.history,
                    title="piano, non-isotropic, one mesh from MBO", comm=comm)
output.plot_frames(out / "frames_nested.png", nested.q, title="piano, nested iteration",
               singularities=nested.singularities)
say(f"wrote {out}/convergence_nested.png, convergence_cold.png, frames_nested.png")
# -
