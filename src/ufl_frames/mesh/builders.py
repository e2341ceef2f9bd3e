"""One entry point for a geometry given by name (a built-in shape) or by path (a file),
and the nested meshes of one geometry."""

import numbers
from pathlib import Path

from ufl_frames.bootstrap import init_petsc

init_petsc()

from mpi4py import MPI  # noqa: E402

from ufl_frames.mesh.builtin import BUILTIN_MESH_SIZE, KNOWN_GEOMETRIES  # noqa: E402
from ufl_frames.mesh.domain import Domain, GeometryError, check_mesh_size, check_positive  # noqa: E402
from ufl_frames.mesh.files import CAD_EXTENSIONS, GEO_EXTENSIONS, MESH_EXTENSIONS, load  # noqa: E402
from ufl_frames.mesh.meshing import MAX_TRIANGLES  # noqa: E402


def build(
    comm: MPI.Comm,
    name_or_path,
    mesh_size: float | None = None,
    size_factor: float = 1.0,
    max_triangles: int = MAX_TRIANGLES,
    time_limit: float | None = None,
    refinements: int = 0,
    resolve_features: bool = False,
) -> Domain:
    """A built-in geometry by name (:data:`KNOWN_GEOMETRIES`) or a file for :func:`load`.

    Args:
        comm: The communicator the mesh is distributed over (collective).
        name_or_path: A name of :data:`KNOWN_GEOMETRIES`, or a file's path.
        mesh_size: Built-in shapes take it (default :data:`BUILTIN_MESH_SIZE`) times
            ``size_factor``; for a file as :func:`load`.
        size_factor: Scales the size (< 1 refines).
        max_triangles: As for :func:`load` (built-in shapes too).
        time_limit: As for :func:`load` (files only).
        refinements: With k, Gmsh meshes at 2^k times the size and splits every triangle
            into 4, k times (new boundary points on the curves): the mesh is then a
            refinement of the one ``size_factor`` · 2^k and ``refinements`` 0 give, as
            :func:`build_nested` needs.
        resolve_features: As for :func:`load` (files only).

    Returns:
        The distributed domain.

    Raises:
        GeometryError: On every rank, with a one-line message (an unknown name too).
    """
    key = str(name_or_path)
    if key in KNOWN_GEOMETRIES:
        h = BUILTIN_MESH_SIZE if mesh_size is None else check_mesh_size(mesh_size)
        factor = check_positive("size_factor", size_factor)
        return KNOWN_GEOMETRIES[key](comm, mesh_size=h * factor, refinements=refinements,
                                     max_triangles=check_positive("max_triangles",
                                                                  max_triangles))
    path = Path(key)
    looks_like_file = path.suffix.lower() in GEO_EXTENSIONS + MESH_EXTENSIONS + CAD_EXTENSIONS
    # Decided on rank 0, which reads the file: every rank must take the same branch.
    is_file = (looks_like_file or path.exists()) if comm.rank == 0 else None
    if comm.bcast(is_file, root=0):
        return load(comm, path, mesh_size, size_factor, max_triangles, time_limit,
                    refinements, resolve_features)
    raise GeometryError(
        f"unknown geometry {key!r}: not a file; known names are "
        f"{', '.join(sorted(KNOWN_GEOMETRIES))}"
    )


def build_nested(
    comm: MPI.Comm,
    name_or_path,
    levels: int,
    mesh_size: float | None = None,
    size_factor: float = 1.0,
    max_triangles: int = MAX_TRIANGLES,
    time_limit: float | None = None,
    resolve_features: bool = False,
) -> list[Domain]:
    """``levels`` nested meshes of one geometry, coarse to fine.

    Gmsh meshes the coarsest at 2^(levels−1) times the size :func:`build` would use, and
    level k is that mesh split k times (every triangle into 4, new boundary points on the
    curves); the finest has about the size asked for. The meshes of nested iteration
    (:meth:`~ufl_frames.pipeline.FrameField.nested`): on nested meshes a coarse P1 field
    is a fine one, while interpolation onto an independent Gmsh mesh mixes the jumps of
    its gradient across coarse edges into the fine triangles that straddle them, in
    bands along the coarse mesh's rows. Split meshes are worse meshes for H, though: a
    one-mesh solve ends higher than on a Gmsh mesh of the same size.

    Args:
        comm: The communicator the meshes are distributed over (collective).
        name_or_path: As for :func:`build`.
        levels: How many meshes (≥ 1).
        mesh_size: As for :func:`build`, of the finest level.
        size_factor: As for :func:`build`, of the finest level.
        max_triangles: As for :func:`build`.
        time_limit: As for :func:`build`, for each level.
        resolve_features: As for :func:`build`.

    Returns:
        The domains, coarsest first.
    """
    if isinstance(levels, bool) or not isinstance(levels, numbers.Integral) or levels < 1:
        raise GeometryError(f"levels must be a positive integer, got {levels!r}")
    return [build(comm, name_or_path, mesh_size, size_factor * 2.0 ** (levels - 1 - k),
                  max_triangles, time_limit, refinements=k, resolve_features=resolve_features)
            for k in range(levels)]
