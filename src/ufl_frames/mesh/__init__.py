"""Planar domains for frame-field computations, built or read with Gmsh.

Every builder returns a :class:`Domain`: the distributed P1 triangle mesh
(``gdim = 2``), its boundary facets tagged by the curve they lie on, its regions (the
surface of every cell), the facets on model curves inside it (interfaces, embedded
curves), the model points and the file's physical groups, the curve directions, corners
and junctions of the CAD model where one exists, the Euler characteristic, the mesh size
actually used and notes on what the loader changed.

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
* :mod:`~ufl_frames.mesh.cad`: a quad mesh's boundary nodes moved onto the CAD curves
  and points of the geometry (rank 0).

Gmsh runs on rank 0 only; errors are raised on every rank as :class:`GeometryError`
with a one-line message.
"""

import importlib

from ufl_frames.bootstrap import init_petsc

#: The public names and their modules. They are imported on first use (PEP 562), so that
#: :mod:`ufl_frames.mesh.hierarchy`'s constants can be read while the command line is
#: parsed, before PETSc is initialised with its options.
_EXPORTS = {
    "build": "builders", "build_nested": "builders",
    "KNOWN_GEOMETRIES": "builtin", "annulus": "builtin", "piano": "builtin",
    "piano_area": "builtin", "piano_perimeter": "builtin", "piano_points": "builtin",
    "Corner": "domain", "Domain": "domain", "GeometryError": "domain",
    "Junction": "domain", "PhysicalGroup": "domain",
    "MeshTimeLimit": "domain", "load": "files", "mesh_time_limit": "files",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name not in _EXPORTS:
        raise AttributeError(f"module 'ufl_frames.mesh' has no attribute {name!r}")
    init_petsc()  # before the submodules import DOLFINx or Gmsh
    value = getattr(importlib.import_module(f"ufl_frames.mesh.{_EXPORTS[name]}"), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))
