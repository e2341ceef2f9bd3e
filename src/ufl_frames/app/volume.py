"""``ufl-frames solve`` on a volume: a 3D frame field by MBO and its singular graph.

The 3D path of the command (:func:`run_volume`) takes a 3D built-in (:data:`BUILTINS`:
a box, a hollow cylinder, a ball) or a file that defines volumes, meshes it with
tetrahedra (:mod:`ufl_frames.mesh.volumes`), computes the boundary-aligned smooth frame
field (:func:`ufl_frames.pipeline.volume.solve_volume`) and writes ``frames3d.vtu``,
``singular.vtu``, ``singular.png`` and ``summary.json`` into the output folder, whole or
not at all. The 2D options that have no 3D counterpart yet (the integrability solve, the
map, the quads, sizes) are refused with one line.
"""

import time
from dataclasses import fields
from pathlib import Path

from ufl_frames.bootstrap import init_petsc

__all__ = ["BUILTINS", "defines_volumes", "run_volume"]

#: The 3D built-in shapes by name: their builder in :mod:`ufl_frames.mesh.volumes`.
BUILTINS = {"box": "box", "cylinder": "hollow_cylinder", "ball": "ball"}
#: Mesh size of the built-ins when none is asked for.
BUILTIN_MESH_SIZE = 0.15
#: RunConfig fields of the 2D pipeline that the 3D path does not have: refused unless at
#: their defaults.
_NOT_IN_3D = ("isotropic", "conformal", "param", "quads", "quad_size", "quad_count", "size",
              "resume", "levels", "nested_meshes", "free_singularities")


def defines_volumes(path, time_limit: float | None = None) -> bool:
    """Whether the geometry file ``path`` defines volumes (rank 0 work; a ``.msh``: holds
    tetrahedra; a STEP file: names a solid). The file is screened first as the 2D loader
    screens it (a regular file of bounded size; a ``.geo`` script's commands that act
    outside, refused before Gmsh runs it); a ``.geo`` or ``.brep`` is then opened in Gmsh,
    without meshing, in a child process stopped after ``time_limit`` seconds (default
    :func:`~ufl_frames.mesh.files.mesh_time_limit`). A refusal raises
    :class:`~ufl_frames.mesh.domain.GeometryError`."""
    import math
    import os

    from ufl_frames.mesh import files
    from ufl_frames.mesh.distribute import _in_child

    files.check_input_file(path)
    suffix = Path(path).suffix.lower()
    if suffix in (".step", ".stp"):  # a text file: its solids are named, no need to load it
        return _step_has_solids(path)
    if suffix in files.GEO_EXTENSIONS:
        files._check_geo_script(Path(path))  # what the script may do, before Gmsh runs it
    limit = files.mesh_time_limit() if time_limit is None else time_limit
    if math.isfinite(limit) and hasattr(os, "fork"):
        return _in_child(lambda: _open_and_look(path), str(path), limit)
    return _open_and_look(path)


def _open_and_look(path) -> bool:
    """Gmsh's look at ``path``: volumes in the model, or tetrahedra in a ``.msh``."""
    from ufl_frames.gmsh_scratch import scratch_model

    with scratch_model("ufl_frames_probe") as gmsh:
        gmsh.merge(str(path))
        if Path(path).suffix.lower() == ".msh":
            return bool(gmsh.model.mesh.getElementsByType(4)[0].size)
        return bool(gmsh.model.getEntities(3))


#: STEP entities of solids (ISO 10303-42).
_STEP_SOLIDS = (b"MANIFOLD_SOLID_BREP", b"BREP_WITH_VOIDS", b"FACETED_BREP")


def _step_has_solids(path) -> bool:
    """Whether the STEP file ``path`` names a solid (read in blocks, once)."""
    tail = b""
    with open(path, "rb") as f:
        while block := f.read(1 << 20):
            text = tail + block.upper()
            if any(name in text for name in _STEP_SOLIDS):
                return True
            tail = text[-32:]
    return False


def run_volume(config, comm=None) -> dict:
    """The 3D frame field of ``config.geometry`` written to the output folder; the summary
    (collective).

    Args:
        config: a :class:`~ufl_frames.app.run.RunConfig` (its geometry, mesh_size, out,
            force and quiet; the 2D pipeline's options must be at their defaults).
        comm: the communicator (default ``MPI.COMM_WORLD``).

    Returns:
        The record written to ``summary.json``.

    Raises:
        InputError: on every rank, for a 2D option, a geometry that cannot be meshed, or
            an output folder that cannot be used.
    """
    init_petsc()
    from mpi4py import MPI

    from ufl_frames.app.failures import InputError
    from ufl_frames.app.run import Printer, check_output_folder
    from ufl_frames.mesh import volumes
    from ufl_frames.mesh.domain import GeometryError
    from ufl_frames.output.folder import OutputFolder
    from ufl_frames.output.report import write_summary
    from ufl_frames.pipeline.volume import solve_volume, write_volume

    comm = MPI.COMM_WORLD if comm is None else comm
    say = Printer(comm, config.quiet)
    start = time.perf_counter()
    defaults = {f.name: f.default for f in fields(config)}
    asked = [name.replace("_", "-") for name in _NOT_IN_3D
             if name in defaults and getattr(config, name) != defaults[name]]
    if asked:
        raise InputError(f"{', '.join(asked)}: not available for 3D frame fields yet (the "
                         "3D field is the smooth boundary-aligned MBO field)")
    out = Path(config.out) if config.out is not None else Path(
        f"out_{Path(config.geometry).stem}")
    check_output_folder(out, config.force, comm)
    say(f"meshing {config.geometry} (tetrahedra) ...")
    try:
        if config.geometry in BUILTINS:
            build = getattr(volumes, BUILTINS[config.geometry])
            size = BUILTIN_MESH_SIZE if config.mesh_size is None else config.mesh_size
            volume = build(comm, mesh_size=size)
        else:
            volume = volumes.load(comm, config.geometry, mesh_size=config.mesh_size)
    except GeometryError as e:
        raise InputError(str(e)) from e
    say(f"  {volume.num_cells} tetrahedra (mean edge {volume.mesh_size:.3g}), {comm.size} "
        f"process{'es' if comm.size > 1 else ''}")
    aligned, sharp = volume.num_boundary_vertices
    say(f"  boundary: {aligned} vertices aligned with their surface's normal, {sharp} on "
        "sharp edges and corners (frames held)")
    say("MBO initial field (15 coefficients) ...")
    result = solve_volume(volume, say=say)
    graph = result.summary["singular_graph"]
    say(f"singular graph: {graph['edges']} singular edges in {graph['chains']} chains, "
        f"{graph['open_ends']} ends inside the volume")
    summary = {**result.summary, "seconds": time.perf_counter() - start,
               "files": ["frames3d.vtu", "singular.vtu", "singular.png", "summary.json"]}
    folder = OutputFolder(out, force=config.force, comm=comm)
    staging = folder.open()
    try:
        write_volume(result, staging, comm)
        write_summary(staging / "summary.json", summary, comm)
        folder.commit()
    except BaseException:
        folder.discard()
        raise
    say(f"wrote {out}/: {', '.join(summary['files'])}")
    return summary
