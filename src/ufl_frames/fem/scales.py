"""Length scales of a distributed mesh, reduced over MPI ranks (all collective).

One home for what MBO's diffusion schedule, the solver's stopping scales and the figures'
glyph spacing read off a mesh.
"""

import math

from ufl_frames.bootstrap import init_petsc

init_petsc()

import dolfinx.fem as fem  # noqa: E402
import numpy as np  # noqa: E402
import ufl  # noqa: E402
from mpi4py import MPI  # noqa: E402

__all__ = ["area", "bounding_box", "length_scales", "mean_cell_edge"]


def area(mesh) -> float:
    """The mesh's area (its volume in 3D), ∫ 1 dx."""
    return mesh.comm.allreduce(fem.assemble_scalar(fem.form(1.0 * ufl.dx(domain=mesh))),
                               op=MPI.SUM)


def bounding_box(mesh) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) of the mesh's vertices (x, y; and z in 3D) over all ranks."""
    dim = mesh.topology.dim
    x = mesh.geometry.x[:, :dim]
    lo, hi = np.empty(dim), np.empty(dim)
    mesh.comm.Allreduce(x.min(axis=0, initial=np.inf), lo, op=MPI.MIN)
    mesh.comm.Allreduce(x.max(axis=0, initial=-np.inf), hi, op=MPI.MAX)
    return lo, hi


def mean_cell_edge(mesh, mesh_area: float | None = None) -> float:
    """h: the edge of an equilateral triangle of the mean cell area (in 3D: of a regular
    tetrahedron of the mean cell volume)."""
    mesh_area = area(mesh) if mesh_area is None else mesh_area
    cells = mesh.topology.index_map(mesh.topology.dim).size_global
    if mesh.topology.dim == 3:
        return (6 * math.sqrt(2) * mesh_area / cells) ** (1 / 3)
    return math.sqrt(4 * mesh_area / (math.sqrt(3) * cells))


def length_scales(mesh) -> tuple[float, float]:
    """(diameter of the bounding box, h of :func:`mean_cell_edge`)."""
    lo, hi = bounding_box(mesh)
    return float(np.linalg.norm(hi - lo)), mean_cell_edge(mesh)
