"""A ``.geo`` that draws its surfaces with a ``Function`` (the gallery's two I-beams):
Gmsh's parser keeps the function for the life of the process, so a parse in this process
(the file's sizes, :func:`~ufl_frames.mesh.sizes.read_file_sizes`) made the loader's
parse in a child forked from it a redefinition, and Gmsh crashed. Serial and MPI.

Truth: two rectangles drawn by one function, their area (2 × 1 + 0.5 × 1) and their
point size (the file's ``lc``) in closed form.
"""

import math

import numpy as np
import pytest

from ufl_frames.bootstrap import init_petsc

init_petsc([])  # not pytest's command line

from mpi4py import MPI  # noqa: E402

from ufl_frames.mesh import load  # noqa: E402
from ufl_frames.mesh.sizes import read_file_sizes  # noqa: E402

COMM = MPI.COMM_WORLD
LC = 0.1
TWO_SLABS = f"""Function Slab
  p1 = newp; Point(p1) = {{x0, 0, 0, lc}};
  p2 = newp; Point(p2) = {{x0 + w, 0, 0, lc}};
  p3 = newp; Point(p3) = {{x0 + w, 1, 0, lc}};
  p4 = newp; Point(p4) = {{x0, 1, 0, lc}};
  l1 = newl; Line(l1) = {{p1, p2}};
  l2 = newl; Line(l2) = {{p2, p3}};
  l3 = newl; Line(l3) = {{p3, p4}};
  l4 = newl; Line(l4) = {{p4, p1}};
  loop = newll; Curve Loop(loop) = {{l1, l2, l3, l4}};
  face = news; Plane Surface(face) = {{loop}};
Return
lc = {LC};
x0 = 0; w = 2; Call Slab;
x0 = 3; w = 0.5; Call Slab;
"""


@pytest.fixture
def two_slabs(tmp_path_factory):
    folder = tmp_path_factory.mktemp(f"rank{COMM.rank}")
    path = folder / "two_slabs.geo"
    path.write_text(TWO_SLABS)
    return path


def test_file_sizes_then_the_mesh_of_a_geo_with_a_function(two_slabs):
    """The sizes read first (as ``solve`` does for a non-isotropic field), then the mesh:
    both components, their exact area, and the file's point size as its only size."""
    samples = read_file_sizes(str(two_slabs)) if COMM.rank == 0 else None
    if COMM.rank == 0:
        assert samples is not None
        assert np.allclose(samples[:, 2], LC, rtol=1e-12)
    domain = load(COMM, two_slabs)
    mesh = domain.mesh
    x = mesh.geometry.x
    cells = mesh.geometry.dofmaps[0]
    p = x[cells][:, :, :2]
    area = 0.5 * np.abs((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
                        - (p[:, 1, 1] - p[:, 0, 1]) * (p[:, 2, 0] - p[:, 0, 0]))
    owned = mesh.topology.index_map(2).size_local
    total = COMM.allreduce(float(area[:owned].sum()), op=MPI.SUM)
    assert math.isclose(total, 2.5, rel_tol=1e-12)
    # both rectangles meshed: the cells left of x = 2.5 are the first one
    left = COMM.allreduce(float(area[:owned][p[:owned, :, 0].mean(axis=1) < 2.5].sum()),
                          op=MPI.SUM)
    assert math.isclose(left, 2.0, rel_tol=1e-12)
