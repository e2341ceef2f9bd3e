"""A P1 frame field carried from one mesh of a domain to another (nested iteration).

The meshes need not be nested: a coarse and a fine Gmsh mesh of the same CAD model are
two independent triangulations, and the fine one's boundary vertices lie on the curves,
up to O(h²) outside the coarse polygon where the boundary is curved. DOLFINx's
non-matching interpolation evaluates the coarse field at the fine vertices; the points
outside every coarse cell are found within a padding of a few coarse mesh sizes and
evaluated in the closest cell (linear extrapolation over O(h²)). The result is a P1
field, not yet on the frame manifold: the solver's retraction (the note's steps 4–5)
puts it there.
"""

from ufl_frames.bootstrap import init_petsc

init_petsc()

import dolfinx.fem as fem  # noqa: E402
import numpy as np  # noqa: E402
from mpi4py import MPI  # noqa: E402

from ufl_frames.fem.energy import check_frame_function, frame_space  # noqa: E402

__all__ = ["interpolate_field"]


def interpolate_field(q_from: fem.Function, mesh_to, padding: float | None = None) -> fem.Function:
    """``q_from`` (P1 frame field on one mesh) interpolated at the vertices of ``mesh_to``:
    a new P1 frame field there (collective over both meshes' communicator).

    ``padding`` (default: 4 mean edge lengths of the source mesh, enough for a curved
    boundary's O(h²) bulge) is how far outside the source mesh a target vertex may lie.
    Raises ValueError if a vertex is farther (the meshes are not of the same domain).
    """
    check_frame_function(q_from, "q_from")
    V_from = q_from.function_space
    V_to = frame_space(mesh_to)
    mesh_from = V_from.mesh
    if padding is None:
        padding = 4.0 * _mean_edge(mesh_from)
    tdim = mesh_to.topology.dim
    cell_map = mesh_to.topology.index_map(tdim)
    cells = np.arange(cell_map.size_local + cell_map.num_ghosts, dtype=np.int32)
    # Two passes: a tight one for the cells inside the source mesh (a padded search costs
    # ~15x more: 3.3 s instead of 0.2 s at 7.5e3 triangles), then the padded one for the
    # few cells with a vertex outside it (along a curved boundary).
    data = fem.create_interpolation_data(V_to, V_from, cells, padding=1e-10 * padding)
    per_cell = V_to.element.interpolation_points.shape[0]
    outside = np.unique(np.flatnonzero(data.src_owner < 0) // per_cell).astype(np.int32)
    q = fem.Function(V_to, name="q")
    if mesh_to.comm.allreduce(len(outside), op=MPI.SUM) == 0:
        q.interpolate_nonmatching(q_from, cells, data)
    else:
        inside = np.setdiff1d(cells, cells[outside]).astype(np.int32)
        data = fem.create_interpolation_data(V_to, V_from, inside, padding=1e-10 * padding)
        q.interpolate_nonmatching(q_from, inside, data)
        near = cells[outside]
        data = fem.create_interpolation_data(V_to, V_from, near, padding=padding)
        lost = mesh_to.comm.allreduce(int(np.count_nonzero(data.src_owner < 0)), op=MPI.SUM)
        if lost:  # DOLFINx would give those points the value 0: a zero frame, silently
            raise ValueError(f"{lost} interpolation points of the target mesh lie farther "
                             f"than {padding:.3g} from the source mesh: not the same domain")
        values = q.x.array.copy()
        q.interpolate_nonmatching(q_from, near, data)
        # interpolate_nonmatching writes the dofs of its cells only; keep the inner pass's
        # values elsewhere (a vertex shared by both kinds of cells gets the same value).
        touched = np.unique(V_to.dofmap.list[near].ravel())
        keep = np.setdiff1d(np.arange(len(values) // V_to.dofmap.index_map_bs), touched)
        bs = V_to.dofmap.index_map_bs
        rows = q.x.array.reshape(-1, bs)
        rows[keep] = values.reshape(-1, bs)[keep]
    q.x.scatter_forward()
    return q


def _mean_edge(mesh) -> float:
    """Mean length of the owned edges of a triangle mesh (collective)."""
    from dolfinx.mesh import entities_to_geometry

    mesh.topology.create_entities(1)
    n_owned = mesh.topology.index_map(1).size_local
    nodes = entities_to_geometry(mesh, 1, np.arange(n_owned, dtype=np.int32))
    x = mesh.geometry.x
    total = mesh.comm.allreduce(float(np.linalg.norm(x[nodes[:, 0]] - x[nodes[:, 1]],
                                                     axis=1).sum()), op=MPI.SUM)
    count = mesh.comm.allreduce(int(n_owned), op=MPI.SUM)
    return total / max(count, 1)
