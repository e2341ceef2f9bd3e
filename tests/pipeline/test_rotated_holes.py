"""Concave corners of small rotated holes (issue 37: Gmsh's full-quad example).

Truth: the 10 × 10 square less four rectangular holes (2 × 1, 1 × 2 turned 45°, 1 × 1
turned 60°, 2 × 2) has area 100 − 9 = 91 exactly; the quads are checked by the
independent :func:`ufl_frames.quads.measures.check_quad_mesh` (conforming, none inverted,
area within 0.5 %). Before :meth:`ufl_frames.param.seamless.SeamlessSystem.open_corners`
the conformal field's seamless map folded the 60° hole's corner at (1.63, 7.37) shut (its
boundary ran backwards next to it, no triangle of the corner inverted): the tracer took
the 270° corner as convex, and the layout refused ("1 faces of the traces are not
rectangles (corner quarter turns [[1, 1, 1, 1, 3, 1]])") at 400 quads, as at 800; greedy
rounding folded too.
"""

from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from ufl_frames.mesh import load
from ufl_frames.pipeline import FrameField
from ufl_frames.pipeline.stages import quadrangulate
from ufl_frames.quads.measures import check_quad_mesh

COMM = MPI.COMM_WORLD
FULL_QUAD = Path(__file__).parents[2] / "meshes" / "gallery" / "gmsh_full_quad.geo"
AREA = 91.0


@pytest.mark.parametrize("quads", [400, 800])
def test_the_rotated_holes_corners_are_split_by_the_layout(quads):
    size = float(np.sqrt(AREA / quads))
    domain = load(COMM, FULL_QUAD, size)  # the triangles as solve --quads --quad-size makes
    field = FrameField.initial(domain, isotropic=True).conformal()
    result = quadrangulate(field, size)
    quality = result.quality
    assert quality["valid"] and quality["problems"] == []
    assert quality["quantisation"] == "layout"
    assert quality["min_sj"] >= 0.3
    if COMM.rank == 0:
        points, cells = result.mesh.points[:, :2], result.mesh.quads
        assert check_quad_mesh(points, cells, area=AREA, rtol=0.005) == []
        assert 0.85 * quads <= cells.shape[0] <= 1.15 * quads
