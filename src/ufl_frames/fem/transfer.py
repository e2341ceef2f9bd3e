"""A P1 frame field carried from one mesh of a domain to another (nested iteration).

The meshes need not be nested: a coarse and a fine Gmsh mesh of the same CAD model are
two independent triangulations, and the fine one's boundary vertices lie on the curves,
up to O(h²) outside the coarse polygon where the boundary is curved. DOLFINx's
non-matching interpolation evaluates the coarse field at the fine vertices; the points
outside every coarse cell are found within a padding of a few coarse mesh sizes and
evaluated in the closest cell (linear extrapolation over O(h²)). The result is a P1
field, not yet on the frame manifold: the solver's retraction (the note's steps 4–5)
puts it there.

Between independent meshes the result is not the coarse function: fine triangles that
straddle a coarse edge mix the jump of its gradient there, and the integrability energy
of the transferred field rises in bands along the coarse mesh's rows (7.7x the coarse H
on the piano from 6.3·10³ to 2.5·10⁴ triangles). On nested meshes
(:func:`ufl_frames.mesh.build_nested`) the interpolation is exact.
"""

from ufl_frames.bootstrap import init_petsc

init_petsc()

import dolfinx.fem as fem  # noqa: E402
import numpy as np  # noqa: E402
from mpi4py import MPI  # noqa: E402

from ufl_frames.fem.energy import check_frame_function, frame_space  # noqa: E402
from ufl_frames.fem.scales import mean_cell_edge  # noqa: E402

__all__ = ["interpolate_field"]


def interpolate_field(q_from: fem.Function, mesh_to, padding: float | None = None) -> fem.Function:
    """``q_from`` (P1 frame field on one mesh) interpolated at the vertices of ``mesh_to``:
    a new P1 frame field there (collective over both meshes' communicator).

    Args:
        q_from: the P1 frame field on the source mesh (checked).
        mesh_to: the target mesh, of the same domain and on the same communicator.
        padding: how far outside the source mesh a target vertex may lie (default: 4 mean
            cell edges of the source mesh, enough for a curved boundary's O(h²) bulge).

    Returns:
        A new P1 frame field ``q`` on ``mesh_to`` (ghosts updated), not yet on the frame
        manifold.

    Raises:
        ValueError: a target vertex lies farther than ``padding`` from the source mesh
            (the meshes are not of the same domain).
    """
    check_frame_function(q_from, "q_from")
    V_from = q_from.function_space
    V_to = frame_space(mesh_to)
    if padding is None:
        padding = 4.0 * mean_cell_edge(V_from.mesh)
    tdim = mesh_to.topology.dim
    cell_map = mesh_to.topology.index_map(tdim)
    cells = np.arange(cell_map.size_local + cell_map.num_ghosts, dtype=np.int32)
    # Two passes: a tight search for all cells (a padded one costs ~15x more: 3.3 s
    # instead of 0.2 s at 7.5e3 triangles), then a padded one for the few cells with a
    # vertex outside the source mesh (along a curved boundary), which rewrites all their
    # vertices; a vertex inside gets the same value from every cell around it.
    data = fem.create_interpolation_data(V_to, V_from, cells, padding=1e-10 * padding)
    q = fem.Function(V_to, name="q")
    q.interpolate_nonmatching(q_from, cells, data)
    per_cell = V_to.element.interpolation_points.shape[0]
    near = cells[np.unique(np.flatnonzero(data.src_owner < 0) // per_cell)]
    if mesh_to.comm.allreduce(len(near), op=MPI.SUM):
        data = fem.create_interpolation_data(V_to, V_from, near, padding=padding)
        lost = mesh_to.comm.allreduce(int(np.count_nonzero(data.src_owner < 0)), op=MPI.SUM)
        if lost:  # DOLFINx would give those points the value 0: a zero frame, silently
            raise ValueError(f"{lost} interpolation points of the target mesh lie farther "
                             f"than {padding:.3g} from the source mesh: not the same domain")
        q.interpolate_nonmatching(q_from, near, data)
    q.x.scatter_forward()
    return q
