"""Planar domains for frame-field computations, built or read with Gmsh.

Every builder returns a :class:`Domain`: the distributed P1 triangle mesh
(``gdim = 2``), its boundary facets tagged by the curve they lie on, the boundary
directions and corners of the CAD model where one exists, the Euler characteristic,
the mesh size actually used and notes on what the loader changed.

* :mod:`~ufl_frames.mesh.domain`: :class:`Domain`, :class:`Corner`, :class:`GeometryError`;
* :mod:`~ufl_frames.mesh.builtin`: the built-in shapes :func:`annulus` and :func:`piano`;
* :mod:`~ufl_frames.mesh.files`: :func:`load` (``.geo``, ``.msh``, ``.step``/``.stp``,
  ``.brep``) and the screening of its input;
* :mod:`~ufl_frames.mesh.builders`: :func:`build` (a built-in name or a file) and
  :func:`build_nested` (the nested meshes of one geometry);
* :mod:`~ufl_frames.mesh.meshing`: the sizing policy and the overrides of a file's
  meshing requests;
* :mod:`~ufl_frames.mesh.arrays`: the Gmsh mesh as checked arrays, corners, CAD
  directions;
* :mod:`~ufl_frames.mesh.distribute`: Gmsh on rank 0 (in a child process under a time
  limit) and the DOLFINx mesh across the ranks.

Gmsh runs on rank 0 only; errors are raised on every rank as :class:`GeometryError`
with a one-line message.
"""

from ufl_frames.bootstrap import init_petsc

init_petsc()  # before the submodules import DOLFINx or Gmsh

from ufl_frames.mesh.builders import build, build_nested  # noqa: E402
from ufl_frames.mesh.builtin import (  # noqa: E402
    KNOWN_GEOMETRIES,
    annulus,
    piano,
    piano_area,
    piano_perimeter,
    piano_points,
)
from ufl_frames.mesh.domain import Corner, Domain, GeometryError, MeshTimeLimit  # noqa: E402
from ufl_frames.mesh.files import load, mesh_time_limit  # noqa: E402

__all__ = [
    "Corner",
    "Domain",
    "GeometryError",
    "KNOWN_GEOMETRIES",
    "MeshTimeLimit",
    "annulus",
    "build",
    "build_nested",
    "load",
    "mesh_time_limit",
    "piano",
    "piano_area",
    "piano_perimeter",
    "piano_points",
]
