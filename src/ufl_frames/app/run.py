"""One run of ``ufl-frames solve``: a :class:`RunConfig`, and :func:`run` doing
mesh → field → stages → report → folder.

::

    summary = run(RunConfig("piano", mesh_size=0.05, param=True, out="out_piano"))

Importing this module starts nothing (no PETSc, no DOLFINx): :func:`run` starts PETSc
(without command-line options, unless the caller started it first) when it is called.
"""

import math
import os
import re
import sys
import time
from dataclasses import dataclass, fields, replace
from pathlib import Path

from ufl_frames import __version__, interrupts
from ufl_frames.app.failures import InputError, OutputFolderError, RunError, failures
from ufl_frames.bootstrap import init_petsc, options_scope
from ufl_frames.frames2d.aspect import DEFAULT_MAX_ASPECT
from ufl_frames.petsc_options import MAX_INT, petsc_option_problem

__all__ = ["IncompleteRun", "RunConfig", "check_output_folder", "default_output_folder",
           "estimated_quads", "run", "sized_for_quads"]

PROG = "ufl-frames"
DEFAULT_MESH_SIZE = None  # relative to the shape: see ufl_frames.mesh.load
DEFAULT_MAX_IT = 500
#: Largest estimated quad count (the domain's area over the squared ``quad_size``) made
#: without asking (``max_quads``); the quad stage's memory grows with it.
MAX_QUADS = 2_000_000
#: What a run's peak memory grows by per triangle of its mesh and per quad of its quad
#: stage, and what it takes at least (bytes; serial runs on the annulus, 3.5e4 to 1.4e5
#: triangles and 2.6e5 to 1e6 quads, rounded up): :func:`estimated_memory`.
BYTES_PER_TRIANGLE = 6000
BYTES_PER_QUAD = 1200
BASE_BYTES = 300 * 2**20


class IncompleteRun(RunError):
    """The run wrote its results, but a stage that was asked for failed and is missing
    from them (exit status 1; ``summary`` is what was written)."""

    def __init__(self, message: str, summary: dict):
        super().__init__(message)
        self.summary = summary


@dataclass(frozen=True)
class RunConfig:
    """What one run is asked to do: the options of ``ufl-frames solve``.

    ``geometry`` is a built-in shape's name or a file (:func:`ufl_frames.mesh.build`);
    ``out`` the output folder (default ``out_<geometry stem>``; with ``resume``, the
    folder resumed from); the rest as the command's options of the same names
    (``ufl-frames solve --help``). Checked by :func:`run`, not here.
    """

    geometry: str
    isotropic: bool = False
    mesh_size: float | None = DEFAULT_MESH_SIZE
    size_factor: float = 1.0
    max_triangles: float | None = None
    mesh_time_limit: float | None = None
    max_it: int = DEFAULT_MAX_IT
    out: str | Path | None = None
    force: bool = False
    resume: str | Path | None = None
    max_aspect: float = DEFAULT_MAX_ASPECT
    free_singularities: bool = False
    pin_radius: float = 0.0
    levels: int | str = "auto"
    nested_meshes: bool = False
    conformal: bool = False
    param: bool = False
    quads: bool = False
    quad_size: float | None = None
    max_quads: float | None = None
    max_memory: float | None = None
    quiet: bool = False
    #: The quads' count asked for instead of their size (the stage scales the size to it).
    quad_count: int | None = None
    #: Write the field's files (frames.*, convergence.png); ``ufl-frames mesh`` does not.
    field_files: bool = True
    #: Move the quads' boundary and curve nodes onto the CAD curves
    #: (:mod:`ufl_frames.mesh.cad`): ``solve --quads`` and ``mesh`` both do.
    on_cad: bool = True
    #: Where no valid quad mesh comes out at the default quad size, take a smaller one
    #: that gives one (``ufl-frames mesh`` without a size or count asked).
    adapt_quad_size: bool = False
    #: ``--size``: an expression, 'file', 'uniform', 'none', or None (the file's sizes
    #: where it sets any, else uniform); ``--size-weight`` (None: the default w).
    size: str | None = None
    size_weight: float | None = None
    #: ``mesh_size`` is the quads' size, not one the user asked for: the triangles are
    #: still capped where the shape is thin or tightly curved (``resolve_features`` of
    #: :func:`ufl_frames.mesh.load`).
    resolve_features: bool = False

    def __post_init__(self):
        object.__setattr__(self, "geometry", str(self.geometry))

    @classmethod
    def from_args(cls, args) -> "RunConfig":
        """The config of parsed ``solve`` arguments (an argparse namespace)."""
        return cls(**{item.name: getattr(args, item.name) for item in fields(cls)
                      if hasattr(args, item.name)})

    @classmethod
    def for_mesh(cls, geometry, quad_size: float | None = None,
                 quad_count: int | None = None, **options) -> "RunConfig":
        """The config of ``ufl-frames mesh``: a mesher's defaults — the integrable
        isotropic field (the conformal scale, one mesh), its quads, their boundary nodes on
        the CAD curves, only the quads' files. A ``quad_size`` is also the triangles'
        size; ``quad_count`` N gives about N quads. With a ``size`` (an expression in x, y,
        or ``file``: the file's own sizes) the field is the sized non-isotropic one, whose
        lengths follow it (:mod:`ufl_frames.mesh.sizes`), instead of the conformal scale.

        Args:
            geometry: a built-in shape's name or a geometry file.
            quad_size: the quads' mean edge length (None: the triangles').
            quad_count: the number of quads asked for instead (None: by size).
            options: other fields (``out``, ``force``, ``quiet``, ``mesh_time_limit``,
                ``size``, ``size_weight``).
        """
        size = options.pop("size", None)
        sized = size not in (None, "none")
        return cls(geometry=geometry, conformal=not sized, size=size if sized else None,
                   levels=1, quads=True, quad_size=quad_size, quad_count=quad_count,
                   mesh_size=quad_size, resolve_features=True, field_files=False, on_cad=True,
                   adapt_quad_size=quad_size is None and quad_count is None, **options)

    @property
    def label(self) -> str:
        """The geometry's stem, for figure titles."""
        return Path(self.geometry).stem


# --- progress ---------------------------------------------------------------------------


class Printer:
    """``say(text)``: print on rank 0 (flushed), or nothing when ``quiet``; a closed
    stdout (``ufl-frames ... | head``) silences it and the run goes on."""

    def __init__(self, comm, quiet: bool):
        self.comm, self.quiet, self.closed = comm, quiet, False

    def __call__(self, text: str) -> None:
        if self.quiet or self.closed or self.comm.rank != 0:
            return
        try:
            print(text, flush=True)
        except BrokenPipeError:  # `ufl-frames ... | head`: the run goes on, silent
            self.closed = True
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
            os.close(devnull)


def warn(comm, quiet: bool, text: str) -> None:
    """``ufl-frames: warning: <text>`` on stderr (rank 0, unless ``quiet``).

    Args:
        comm: the run's communicator (only its rank 0 writes).
        quiet: write nothing.
        text: the warning, without the ``ufl-frames: warning:`` prefix.
    """
    if not quiet and comm.rank == 0:
        print(f"{PROG}: warning: {text}", file=sys.stderr)


# --- checks before anything is computed ---------------------------------------------------


def _nearest_existing(path: Path) -> Path:
    path = path.absolute()
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def _output_folder_problem(out: Path, force: bool, resuming: bool = False) -> str | None:
    """Why ``out`` cannot be the output folder, or None (checked on one rank); when
    ``resuming``, its ``checkpoint`` folder is the run's own."""
    if out.is_symlink() and not out.exists():
        return f"output path {str(out)!r} is a broken symbolic link"
    target = Path(os.path.abspath(out)) if not out.is_symlink() else out.resolve()
    if target.parent == target:
        return f"output folder {str(out)!r} is a file system root: choose a folder in it"
    if out.exists():
        if not out.is_dir():
            return f"output path {str(out)!r} exists and is not a folder"
        entries = {p.name for p in out.iterdir()}
        if not force and entries == {"checkpoint"} and not resuming:
            return (f"output folder {str(out)!r} holds the checkpoint of an interrupted run: "
                    f"resume it with --resume {out}, or start again with --force")
        if not force and entries - ({"checkpoint"} if resuming else set()):
            return f"output folder {str(out)!r} exists and is not empty (use --force to overwrite)"
        if not os.access(out, os.W_OK | os.X_OK):
            return f"output folder {str(out)!r} is not writable"
        if not os.access(target.parent, os.W_OK | os.X_OK):
            return (f"cannot write to output folder {str(out)!r}: the results are written next "
                    f"to it first, and {str(target.parent)!r} is not writable")
        return None
    parent = _nearest_existing(out)
    if not parent.is_dir():
        return f"cannot create output folder {str(out)!r}: {str(parent)!r} is not a folder"
    if not os.access(parent, os.W_OK | os.X_OK):
        return f"cannot create output folder {str(out)!r}: {str(parent)!r} is not writable"
    return None


def check_output_folder(out, force: bool, comm, resuming: bool = False) -> None:
    """Raise :class:`OutputFolderError` on every rank if ``out`` cannot be used (collective).

    Checked on rank 0 and broadcast, so that all ranks agree even when another rank
    has already started writing.

    Args:
        out: the output folder (a path; it need not exist yet).
        force: a folder that exists and is not empty may be overwritten.
        comm: the run's communicator.
        resuming: the run resumes from ``out``: its ``checkpoint`` folder is the run's own
            and is allowed there.

    Raises:
        OutputFolderError: ``out`` is a broken link, a file, a file system root, not empty
            (without ``force``), holds an interrupted run's checkpoint (neither ``force``
            nor ``resuming``), or cannot be created or written (nor its parent).
    """
    problem = _output_folder_problem(Path(out), force, resuming) if comm.rank == 0 else None
    problem = comm.bcast(problem, root=0)
    if problem is not None:
        raise OutputFolderError(problem)


def default_output_folder(geometry: str) -> Path:
    """``out_<stem>``: ``out_piano`` for ``piano``, ``out_part`` for ``meshes/part.step``."""
    return Path(f"out_{Path(str(geometry)).stem}")


def _output_path(config: RunConfig) -> Path:
    """The folder the run writes to: ``resume``'s, else ``out``, else the default."""
    out = config.out
    if config.resume is not None:
        if out is not None and os.path.abspath(out) != os.path.abspath(config.resume):
            raise InputError("out and resume name different folders")
        out = config.resume
    return default_output_folder(config.geometry) if out is None else Path(out)


def _finite_real(value) -> bool:
    """Whether ``value`` is a finite int or float (not a bool)."""
    real = isinstance(value, (int, float)) and not isinstance(value, bool)
    return real and math.isfinite(value)


def _check_config(config: RunConfig, petsc_options: dict) -> None:
    """Raise :class:`InputError` for a parameter or PETSc option the run cannot take."""
    from ufl_frames.mesh.hierarchy import check_levels

    mesh_size, max_it, pin_radius = config.mesh_size, config.max_it, config.pin_radius
    if mesh_size is not None and not (_finite_real(mesh_size) and mesh_size > 0):
        raise InputError(f"mesh size must be a positive number, got {mesh_size!r}")
    if isinstance(max_it, bool) or not isinstance(max_it, int) or not 0 < max_it <= MAX_INT:
        raise InputError(f"max-it must be a positive integer at most {MAX_INT}, got {max_it!r}")
    try:
        check_levels(config.levels, config.geometry, config.conformal)
    except ValueError as e:
        raise InputError(str(e)) from e
    if not (_finite_real(pin_radius) and pin_radius >= 0):
        raise InputError(f"pin radius must be a number >= 0, got {pin_radius!r}")
    count = config.quad_count
    if count is not None and (isinstance(count, bool) or not isinstance(count, int)
                              or not 0 < count <= MAX_INT):
        raise InputError(f"quad count must be a positive integer, got {count!r}")
    if count is not None and config.quad_size is not None:
        raise InputError("give the quads' size or their count, not both")
    if pin_radius > 0 and config.free_singularities:
        raise InputError("--pin-radius holds pinned singularities: it cannot be combined "
                         "with --free-singularities")
    if config.size not in (None, "none") and (config.isotropic or config.conformal):
        raise InputError("--size is followed by non-isotropic frames only: isotropic "
                         "frames (--isotropic, --conformal) have their scale fixed by their "
                         "directions")
    if config.quad_count is not None and not config.quads:
        raise InputError("--quad-count needs --quads")
    for name in ("quad_size", "max_quads", "max_memory"):
        value = getattr(config, name)
        if value is not None and not (_finite_real(value) and value > 0):
            raise InputError(f"{name.replace('_', ' ')} must be a positive number, got {value!r}")
    problem = petsc_option_problem(petsc_options)
    if problem is not None:
        raise InputError(problem)


def sized_for_quads(config: RunConfig) -> tuple[RunConfig, bool]:
    """``config`` with the triangles' size tied to the quads' where ``--quads --quad-size S``
    is asked without ``--mesh-size``: mesh size S (the largest triangle edge, a file's
    finer sizes kept; a built-in shape's only where S is under its default), as
    ``ufl-frames mesh`` does, so that every quad covers a few
    triangles (a map on triangles larger than the quads is too coarse to quantise: its
    quads fold). Returns (the config, whether it was changed)."""
    from ufl_frames.mesh.builtin import BUILTIN_MESH_SIZE, KNOWN_GEOMETRIES

    if not (config.quads and config.quad_size is not None and config.mesh_size is None) \
            or str(config.geometry).lower().endswith(".msh"):
        return config, False
    if config.geometry in KNOWN_GEOMETRIES:  # their default is known: never coarser
        if config.quad_size >= BUILTIN_MESH_SIZE:
            return config, False
    return replace(config, mesh_size=config.quad_size, resolve_features=True), True


def estimated_quads(area: float, quad_size: float) -> float:
    """Quads of mean edge ``quad_size`` that cover ``area``: ``area / quad_size²``."""
    return area / (quad_size * quad_size)


def estimated_memory(triangles: float, quads: float) -> float:
    """Bytes a run of ``triangles`` triangles and ``quads`` quads needs at its peak, all
    processes together (:data:`BASE_BYTES`, :data:`BYTES_PER_TRIANGLE`,
    :data:`BYTES_PER_QUAD`)."""
    return BASE_BYTES + BYTES_PER_TRIANGLE * triangles + BYTES_PER_QUAD * quads


def available_memory() -> float | None:
    """Bytes of memory available now (``MemAvailable`` of ``/proc/meminfo``; None where
    it cannot be read)."""
    try:
        with open("/proc/meminfo", "rb") as f:
            for line in f.read(65536).decode("ascii", "replace").splitlines():
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _check_sizes(config: RunConfig, domain, comm) -> None:
    """Raise :class:`InputError` (collective) before the field is solved where
    ``quad_size`` asks for more quads than ``max_quads`` (default :data:`MAX_QUADS`), or
    the mesh and the quads would need more memory (:func:`estimated_memory`) than
    ``max_memory`` GiB (default: what :func:`available_memory` says on rank 0)."""
    from ufl_frames.fem.scales import area

    quads = 0.0
    if config.param or config.quads:
        total = area(domain.mesh)
        size = domain.mesh_size if config.quad_size is None else config.quad_size
        quads = (estimated_quads(total, size) if config.quad_count is None
                 else float(config.quad_count))
        limit = MAX_QUADS if config.max_quads is None else config.max_quads
        if config.quad_count is not None and quads > limit:
            raise InputError(f"{config.quad_count} quads asked for, more than the limit "
                             f"{limit:.3g} (raise --max-quads)")
        if config.quad_size is not None and quads > limit:
            raise InputError(
                f"quad size {config.quad_size:g} on a domain of area {total:.3g} gives about "
                f"{quads:.2g} quads, more than the limit {limit:.3g}: choose a larger "
                "--quad-size (or raise --max-quads)")
    need = estimated_memory(domain.num_cells, quads)
    if config.max_memory is not None:
        limit, which = config.max_memory * 2**30, "the limit"
    else:
        limit, which = comm.bcast(available_memory() if comm.rank == 0 else None, root=0), \
            "the memory available"
    if limit is not None and need > limit:
        raise InputError(
            f"the run needs about {need / 2**30:.3g} GiB ({domain.num_cells} triangles, "
            f"{quads:.2g} quads), more than {which} ({limit / 2**30:.3g} GiB): choose a "
            "larger --mesh-size or --quad-size (or set --max-memory)")


#: PETSc options that change what a run prints, not what it computes: not compared
#: when resuming.
_OUTPUT_ONLY_OPTION = re.compile(r"monitor|view|^log|^options_left$|^help$|^info$")


def run_record(config: RunConfig, comm, petsc_options: dict) -> dict:
    """The settings that decide a run's result, for its checkpoint (collective): the
    geometry by name or by the SHA-256 of its file, the PETSc options but for monitors.

    Args:
        config: the run's settings.
        comm: the run's communicator (rank 0 reads the geometry file and broadcasts).
        petsc_options: the PETSc options of the run (name to value); those that only
            change what is printed (monitors, views, logs) are left out.

    Returns:
        A JSON-ready dict: ``geometry`` and ``geometry_id`` (the built-in name,
        ``"sha256:<hex>"`` of the file, or None if it cannot be read), the settings that
        decide the result (sizes as floats) and ``petsc_options`` as sorted
        ``[name, value]`` pairs; compared by :func:`ufl_frames.checkpoint.check_run`.
    """
    from ufl_frames import mesh as geometry_module

    geometry, identity = config.geometry, None
    if geometry in geometry_module.KNOWN_GEOMETRIES:
        identity = geometry
    elif comm.rank == 0:  # None: not a regular file, too large or unreadable (meshing says)
        from ufl_frames.mesh.files import file_digest
        from ufl_frames.mesh.meshing import MAX_TRIANGLES

        limit = MAX_TRIANGLES if config.max_triangles is None else config.max_triangles
        identity = file_digest(geometry, limit)
    identity = comm.bcast(identity, root=0)
    record = {"geometry": geometry, "geometry_id": identity}
    for name in ("isotropic", "mesh_size", "size_factor", "max_triangles", "max_aspect",
                 "free_singularities", "pin_radius", "max_it", "conformal", "levels",
                 "nested_meshes", "size", "size_weight"):
        record[name] = getattr(config, name)
    record["pin_radius"] = float(record["pin_radius"])
    record["petsc_options"] = sorted([name, value] for name, value in petsc_options.items()
                                     if not _OUTPUT_ONLY_OPTION.search(name))
    for name in ("mesh_size", "size_factor", "max_triangles", "max_aspect"):
        if record[name] is not None:
            record[name] = float(record[name])
    return record


def _saved_checkpoint(config: RunConfig, out: Path, record: dict, comm) -> dict | None:
    """The checkpoint ``--resume`` goes on from (checked against ``record``), or None."""
    from ufl_frames import checkpoint as checkpoints

    if config.resume is None:
        return None
    try:
        saved = checkpoints.read(out, comm)
        checkpoints.check_run(saved, record, out)
    except checkpoints.CheckpointError as e:
        raise InputError(str(e)) from e
    return saved


# --- the run ---------------------------------------------------------------------------------


def _quads_asked(config: RunConfig, domain, comm) -> float | None:
    """The number of quads a run asks for: ``quad_count``, or the domain's area over the
    squared ``quad_size``; None where it asks for neither (or no quads)."""
    from mpi4py import MPI

    if not config.quads or (config.quad_count is None and config.quad_size is None):
        return None
    if config.quad_count is not None:
        return float(config.quad_count)
    _, _, areas = _cell_measures(domain)
    return comm.allreduce(float(areas.sum()), op=MPI.SUM) / config.quad_size**2


def _cell_measures(domain) -> tuple:
    """The owned cells' centroids (m, 2), mean edge lengths (m,) and areas (m,)."""
    import numpy as np

    mesh = domain.mesh
    owned = mesh.topology.index_map(mesh.topology.dim).size_local
    corners = mesh.geometry.x[mesh.geometry.dofmaps[0][:owned]][:, :, :2]  # (m, 3, 2)
    edges = np.linalg.norm(np.roll(corners, -1, axis=1) - corners, axis=2).mean(axis=1)
    a, b = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    areas = 0.5 * np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    return corners.mean(axis=1), edges, areas


def _resolving_factor(config: RunConfig, target, domain, comm) -> float:
    """The factor (≤ 1) by which the triangles must shrink to resolve the quads of a
    non-uniform size target (:func:`ufl_frames.mesh.sizes.resolving_factor`); 1 for a
    uniform target, no target, or quads of no given count or size (collective)."""
    import numpy as np

    from ufl_frames.mesh.sizes import resolving_factor

    if target is None or target.is_uniform or str(config.geometry).lower().endswith(".msh"):
        return 1.0  # (a .msh file cannot be meshed again)
    quads = _quads_asked(config, domain, comm)
    if quads is None:
        return 1.0
    centroids, edges, areas = _cell_measures(domain)
    h = target(centroids) if len(centroids) else np.zeros(0)
    gathered = comm.gather((h, edges, areas), root=0)
    factor = None
    if comm.rank == 0:
        h, edges, areas = (np.concatenate(a) for a in zip(*gathered, strict=True))
        factor = resolving_factor(h, edges, areas, quads)
    return comm.bcast(factor, root=0)


def _mesh(config: RunConfig, comm, say) -> tuple[list, object]:
    """The meshes of the run, coarsest first (:func:`ufl_frames.mesh.hierarchy.nested_domains`
    of the mesh at the size asked for; one for ``conformal`` with 'auto' levels), and the
    run's size target (:func:`size_target`, read once the geometry meshes).

    With a non-uniform size target and a number (or size) of quads asked for, a mesh
    whose triangles are too coarse for those quads is made again at a smaller size factor
    (:func:`_resolving_factor`; a note says so)."""
    from ufl_frames import mesh as geometry_module
    from ufl_frames.mesh.hierarchy import nested_domains
    from ufl_frames.mesh.sizes import TRIANGLES_PER_QUAD_EDGE

    size = ("relative to the shape" if config.mesh_size is None
            else f"mesh size {config.mesh_size:g}")
    say(f"meshing {config.geometry} ({size}) ...")
    limit = {} if config.max_triangles is None else {"max_triangles": config.max_triangles}
    limit["time_limit"] = config.mesh_time_limit
    if config.resolve_features:
        limit["resolve_features"] = True
    interrupts.set_stage("meshing")
    size_factor = config.size_factor
    try:
        domain = geometry_module.build(comm, config.geometry, config.mesh_size,
                                       size_factor, **limit)
        target = size_target(config, comm)
        _check_size_target(target, domain, comm)
        factor = _resolving_factor(config, target, domain, comm)
        if factor < 1.0:
            size_factor *= factor
            say(f"  {domain.num_cells} triangles are too coarse for the quads of the size "
                f"target: meshing again at size factor {size_factor:.3g} ...")
            domain = geometry_module.build(comm, config.geometry, config.mesh_size,
                                           size_factor, **limit)
            note = (f"triangles at size factor {size_factor:.3g} (not {config.size_factor:g})"
                    f" so that each quad edge spans at least {TRIANGLES_PER_QUAD_EDGE:g} "
                    "triangle edges")
            domain = replace(domain, notes=(*domain.notes, note))
    except geometry_module.MeshTimeLimit as e:  # raised identically on every rank
        raise InputError(f"{e}; a larger --mesh-time-limit allows more") from e
    except geometry_module.GeometryError as e:  # raised identically on every rank
        raise InputError(str(e)) from e
    levels = 1 if config.conformal and config.levels == "auto" else config.levels
    try:
        return nested_domains(comm, config.geometry, domain, levels, config.mesh_size,
                              size_factor, nested_meshes=config.nested_meshes,
                              say=say, **limit), target
    except geometry_module.GeometryError as e:  # raised identically on every rank
        raise InputError(str(e)) from e


def run(config: RunConfig, comm=None) -> dict:
    """Mesh → MBO → TAO (or the conformal scale) → singularities (→ the map (U, V), the
    quad mesh) → files in the output folder; the summary, on every rank (collective).

    Args:
        config: what to do.
        comm: the communicator (default ``MPI.COMM_WORLD``).

    Returns:
        The record written to ``summary.json``.

    Raises:
        InputError: on every rank, before anything is computed or written, when the
            input is unusable (a :class:`ufl_frames.mesh.GeometryError`, a bad
            parameter or PETSc option in the database, an existing non-empty output
            folder, a coarse level of a given ``levels`` that fails or loses a hole).
        RunError: a solve or writing the results fails on every rank alike (a PETSc
            error, a full disk).
        IncompleteRun: a stage asked for (the map, the quads) failed (no valid quad mesh
            at the size): the field, its figures and the summary (its ``missing`` says
            what and why) are written all the same, and the summary is the exception's.

    A figure that cannot be drawn is left out with a warning (``missing`` in the
    summary). Other exceptions are bugs and keep their type. The output folder is written whole or
    not at all (:class:`ufl_frames.output.OutputFolder`). PETSc options in the database
    (``-tao_type`` ...) are honoured; the defaults the solvers add to the database are
    removed afterwards.
    """
    init_petsc()
    from mpi4py import MPI
    from petsc4py import PETSc

    from ufl_frames import checkpoint as checkpoints

    comm = MPI.COMM_WORLD if comm is None else comm
    say = Printer(comm, config.quiet)
    start = time.perf_counter()
    petsc_options = PETSc.Options().getAll()
    out = _output_path(config)
    _check_config(config, petsc_options)
    config, sized = sized_for_quads(config)
    if sized:
        say(f"mesh size {config.mesh_size:g}: the quad size (triangles no larger than the "
            "quads, as 'ufl-frames mesh'; --mesh-size sets it apart)")
    record = run_record(config, comm, petsc_options)
    saved = _saved_checkpoint(config, out, record, comm)
    check_output_folder(out, config.force, comm, resuming=config.resume is not None)
    from ufl_frames.mesh.domain import TooManyTriangles

    try:
        domains, target = _mesh(config, comm, say)
    except InputError as e:
        if sized and isinstance(e.__cause__, TooManyTriangles):
            raise InputError(f"{e} (with --quads --quad-size {config.quad_size:g} the "
                             "triangles are no larger than the quads: choose a larger "
                             "--quad-size, or set --mesh-size)") from e
        raise
    meshed = time.perf_counter()
    domain = domains[-1]
    _check_sizes(config, domain, comm)
    interrupts.set_stage("the MBO initial field")
    interrupts.raise_if_interrupted(comm)
    for note in domain.notes:
        say(f"  note: {note}")
    say(f"  {domain.num_vertices} vertices, {domain.num_cells} triangles (mean edge "
        f"{domain.mesh_size:.3g}), {comm.size} process{'es' if comm.size > 1 else ''}")
    key = checkpoints.mesh_key(domain.mesh)
    if saved is not None and saved["mesh_key"] != key:
        raise InputError(f"cannot resume: the checkpoint in {str(out)!r} is of another mesh "
                         "(the geometry or its meshing changed); start again with --force")
    store = checkpoints.CheckpointFolder(out, comm, record, key, existing=saved is not None)
    interrupts.note_checkpoint(out if saved is not None else None)
    try:
        solve = _Solve(config, comm, say, out, store, saved, target)
        solve.seconds["mesh"] = meshed - start  # with reading the geometry and checks
        begun = time.perf_counter()
        solve.solve(domains)
        solve.seconds["field"] = time.perf_counter() - begun
        begun = time.perf_counter()
        solve.report()
        solve.seconds["report"] = time.perf_counter() - begun
        begun = time.perf_counter()
        solve.stages()
        solve.seconds["param and quads"] = time.perf_counter() - begun
        summary = solve.write(start, petsc_options)
    except KeyboardInterrupt:  # Interrupted too: the checkpoint, if any, is for --resume
        raise
    except BaseException:
        store.discard()  # a failed run leaves nothing (a checkpoint resumed from stays)
        raise
    finally:
        interrupts.note_checkpoint(None)
    solve.check_complete(summary)
    return summary


def size_target(config: RunConfig, comm):
    """The run's :class:`~ufl_frames.mesh.sizes.SizeTarget` (collective), None for
    isotropic frames, the conformal scale and ``--size none``.

    Without ``--size``, a geometry file that sets sizes of its own (point sizes,
    ``MeshSize``, size fields) gets them (the triangles are made with them too, see
    :mod:`ufl_frames.mesh.meshing`), anything else the uniform target. ``--size file``
    on a file that sets none is an input error.
    """
    from ufl_frames import mesh as geometry_module
    from ufl_frames.mesh.sizes import DEFAULT_SIZE_WEIGHT, SizeTarget, read_file_sizes

    if config.isotropic or config.conformal or config.size == "none":
        return None
    weight = DEFAULT_SIZE_WEIGHT if config.size_weight is None else config.size_weight
    if config.size not in (None, "file"):
        if config.size == "uniform":
            return SizeTarget.uniform(weight)
        return SizeTarget.expression(config.size, weight)
    samples = None
    if config.geometry not in geometry_module.KNOWN_GEOMETRIES:
        error = None
        if comm.rank == 0:
            try:
                samples = read_file_sizes(config.geometry, config.mesh_time_limit)
            except Exception as e:  # a file Gmsh meshed already: should not happen
                error = f"reading the sizes of {config.geometry}: {e}"
        samples, error = comm.bcast((samples, error), root=0)
        if error is not None:
            raise RunError(error)
    if samples is None:
        if config.size == "file":
            raise InputError(f"--size file: {config.geometry} sets no sizes (point sizes, "
                             f"MeshSize or size fields)")
        return SizeTarget.uniform(weight)
    return SizeTarget.of_samples(samples, weight)


def _check_size_target(target, domain, comm) -> None:
    """Raise :class:`InputError` on every rank where ``target`` is not finite and positive
    at a vertex of ``domain`` on some rank (collective; nothing to check for None)."""
    if target is None:
        return
    problem = None
    try:
        target(domain.mesh.geometry.x[:, :2])
    except (ValueError, TypeError, ArithmeticError) as e:
        problem = str(e).splitlines()[0] if str(e) else type(e).__name__
    problems = [p for p in comm.allgather(problem) if p]
    if problems:
        raise InputError(problems[0])


def plane_record(plane) -> dict:
    """``summary.json``'s ``plane``: the :class:`~ufl_frames.mesh.domain.Plane` of a
    geometry in a tilted plane (its origin, axes and normal) and ``plane_note`` on which
    files are in which coordinates; both None for a geometry in z = const."""
    if plane is None:
        return {"plane": None, "plane_note": None}
    return {"plane": plane.record(),
            "plane_note": "the geometry lies in a tilted plane: quads.msh and quads.vtu are "
                          "in its original 3D coordinates; the frame field's files (frames.*, "
                          "param.*) and the figures are in the plane's coordinates (u, v) = "
                          "((p - origin)·e1, (p - origin)·e2)"}


class _Solve:
    """The run after meshing: the field's solve with its monitors and checkpoints, the
    report, the stages and the output folder (the steps of :func:`run`).

    ``store`` is the checkpoint folder the solve saves to, ``saved`` the checkpoint
    resumed from (None without ``--resume``).
    """

    def __init__(self, config: RunConfig, comm, say, out: Path, store, saved: dict | None,
                 target=None):
        self.config, self.comm, self.say, self.out = config, comm, say, out
        self.store, self.saved = store, saved
        self.field = None
        self.result = None  # the TAO solve's (None for the conformal scale)
        self.state = None  # the checkpoint resumed from
        self.tao_type = None
        self.max_it = config.max_it  # -tao_max_it wins
        self.param = self.quads = None  # the stages' records
        self.size_target = target  # the solve's SizeTarget (None: H alone)
        self.missing: dict[str, str] = {}  # what was asked for and is not written: why
        self.skipped: list[tuple[str, str]] = []  # figures that could not be drawn
        self.seconds: dict[str, float] = {}  # wall seconds per step of the run (rank 0's)
        self._finest_space = None
        self._levels = 1

    # --- monitors and checkpoints ---

    def mbo_monitor(self, level, tau, change):
        """Say one MBO step (``sqrt(tau)``, max change) of mesh ``level``; take interrupts.

        Args:
            level: the index of the mesh in the hierarchy, coarsest 0.
            tau: the diffusion time of the step.
            change: the largest change of the field in the step.
        """
        self.say(f"  level {level}: sqrt(tau) {math.sqrt(tau):.3g}, max change {change:.2e}")
        interrupts.raise_if_interrupted(self.comm)

    def tao_monitor(self, e):  # interrupts are taken by keep(), called just before
        self.say(f"  it {e['it']:4d}  H {e['H']:.6e}  E {e['E']:.6e}  |grad| {e['gnorm']:.3e}"
                 + (f"  ksp {e['ksp_its']}" if "ksp_its" in e else "")
                 + (f"  factorisations {e['factorisations']}"
                    if e.get("factorisations", 1) > 1 else ""))

    def level_monitor(self, entry):
        self.say(f"mesh {entry['level'] + 1}/{self._levels}: {entry['triangles']} "
                 f"triangles, {entry['reason']} after {entry['iterations']} iterations "
                 f"({entry['seconds']:.2f} s), H {entry['H']:.4e}")

    def keep(self, state, V=None):
        """Save ``state`` (of the field on ``V``, default the field's) every
        CHECKPOINT_EVERY steps and when interrupted, then stop if interrupted (at each TAO
        iterate, before the monitor prints)."""
        from ufl_frames import checkpoint as checkpoints

        signum = interrupts.pending(self.comm)
        if state.iterations > 0 and (signum or
                                     state.iterations % checkpoints.CHECKPOINT_EVERY == 0):
            self.store.save(state, self.field.q.function_space if V is None else V)
            interrupts.note_checkpoint(self.out)
        interrupts.raise_if_interrupted(self.comm, signum)

    def restore(self, V):
        """The checkpoint resumed from, on the space ``V`` (None without one)."""
        from ufl_frames import checkpoint as checkpoints

        if self.saved is None:
            return None
        try:
            state = checkpoints.restore(self.saved, V, self.comm)
        except checkpoints.CheckpointError as e:
            raise InputError(str(e)) from e
        self.say(f"resuming from the checkpoint at iteration {state.iterations} ...")
        return state

    def restore_finest(self, V):
        """:meth:`restore` for the finest level of nested iteration (its space kept)."""
        self._finest_space = V
        self.state = self.restore(V)
        return self.state

    def keep_finest(self, state, finest):
        """:meth:`keep` for nested iteration: checkpoints of the finest mesh only."""
        if finest:
            self.keep(state, self._finest_space)
        else:
            interrupts.raise_if_interrupted(self.comm, interrupts.pending(self.comm))

    # --- the solve ---

    def solve(self, domains: list) -> None:
        """MBO → TAO (from the checkpoint, if any) on ``domains[-1]``; nested iteration
        over ``domains`` where there are several; the conformal scale instead of TAO."""
        from petsc4py import PETSc

        from ufl_frames import solvers
        from ufl_frames.pipeline import FrameField

        config = self.config
        if self.size_target is not None:
            _check_size_target(self.size_target, domains[-1], self.comm)
            self.say(f"size target: {self.size_target.describe()} "
                     f"(weight {self.size_target.weight:g})")
        with options_scope():  # the solvers' defaults end with the run
            if len(domains) == 1:  # nested iteration runs MBO on its coarsest mesh only
                self.say("MBO initial field ...")
                with failures("the MBO initial field"):
                    self.field = FrameField.initial(domains[0], isotropic=config.isotropic,
                                                    max_aspect=config.max_aspect,
                                                    monitor=self.mbo_monitor,
                                                    size=self.size_target)
            self.tao_type = PETSc.Options().getString("tao_type",
                                                      solvers.DEFAULT_OPTIONS["tao_type"])
            if config.conformal:
                self._conformal()
            elif len(domains) > 1:
                self._nested(domains)
            else:
                self._single()
            self.max_it = PETSc.Options().getInt("tao_max_it", config.max_it)

    @property
    def _kind(self) -> str:
        return "isotropic frames" if self.config.isotropic else "frames"

    def _conformal(self) -> None:
        self.tao_type = None
        interrupts.set_stage("the conformal scale")
        self.say("conformal scale (isotropic frames of the MBO directions) ...")
        with failures("the conformal-scale solve"):
            self.field = self.field.conformal()

    def _nested(self, domains: list) -> None:
        from ufl_frames.pipeline import FrameField

        config, tao_type = self.config, self.tao_type
        interrupts.set_stage(f"the TAO solve ({tao_type}), nested")
        interrupts.raise_if_interrupted(self.comm)
        self._levels = len(domains)
        self.say(f"solving ({self._kind}, TAO {tao_type}), nested over {len(domains)} meshes "
                 f"from {domains[0].num_cells} triangles ...")
        with failures(f"the TAO solve ({tao_type})"):
            self.field = FrameField.nested(
                domains, isotropic=config.isotropic, max_aspect=config.max_aspect,
                pin_singularities=not config.free_singularities, max_it=config.max_it,
                pin_radius=config.pin_radius, monitor=self.tao_monitor,
                mbo_monitor=self.mbo_monitor, level_monitor=self.level_monitor,
                checkpoint=self.keep_finest, restore=self.restore_finest,
                size=self.size_target)
        self.result = self.field.result

    def _single(self) -> None:
        config, tao_type = self.config, self.tao_type
        interrupts.set_stage(f"the TAO solve ({tao_type})")
        interrupts.raise_if_interrupted(self.comm)
        self.state = self.restore(self.field.q.function_space)
        self.say(f"solving ({self._kind}, TAO {tao_type}) ...")
        with failures(f"the TAO solve ({tao_type})"):
            self.result = self.field.solve(
                pin_singularities=not config.free_singularities, max_it=config.max_it,
                pin_radius=config.pin_radius, monitor=self.tao_monitor,
                checkpoint=self.keep, resume=self.state)

    # --- what was found ---

    def report(self) -> None:
        """The solve's outcome, the singularities and Poincaré–Hopf, on stdout (and a
        warning on stderr where TAO did not converge or the indices do not add up)."""
        from ufl_frames import output

        interrupts.set_stage("writing the results")
        interrupts.raise_if_interrupted(self.comm)
        result, quiet = self.result, self.config.quiet
        if result is not None:
            self.say(f"{result.converged_reason} after {result.iterations} iterations "
                     f"({result.wall_time_s:.2f} s): H {result.H_initial:.4e} -> "
                     f"{result.H_final:.4e}")
            if not result.converged_reason.startswith("CONVERGED"):
                warn(self.comm, quiet, f"TAO stopped with {result.converged_reason}")
        self.say(f"singularities: {output.describe_singularities(self.field.singularities)}")
        check = self.field.index_theorem()  # also in the summary
        if not check["agrees"]:
            warn(self.comm, quiet,
                 f"the singularities' indices sum to {check['index_sum']:g}, Poincaré–Hopf "
                 f"says {check['expected']:g} (Euler characteristic "
                 f"{self.field.domain.euler_characteristic}, {check['corners']} corners): the "
                 "boundary is too coarse for the field somewhere; try a smaller --mesh-size")

    def stages(self) -> None:
        """With ``param``, the seamless map; with ``quads``, the quad mesh: both from one
        gather of the field and one cut mesh on rank 0."""
        from ufl_frames.pipeline import stages

        config, say = self.config, self.say
        root = None
        if config.param:
            try:
                with failures("the parametrisation"):
                    root = stages.RootField(self.field)
                    self.param = stages.parametrise(root, quad_size=config.quad_size)
            except RunError as e:  # the same on every rank: the field is written without it
                self._stage_failed("param", "the parametrisation", e)
            interrupts.raise_if_interrupted(self.comm)
        if self.param is not None:
            quality = self.param.quality
            say(f"parametrisation: misfit {quality['misfit']:.4f}, "
                f"{quality['flipped_triangles']} flipped triangles, {quality['cuts']} cut(s) "
                f"of length {quality['cut_length']:.3g}")
            self._say_pairs(quality)
        if config.quads:
            interrupts.set_stage("the quad mesh")
            quad_size = self._quad_size()
            say("quad mesh ..." if config.quad_count is None else
                f"quad mesh ({config.quad_count} quads: size {quad_size:.3g}) ...")
            try:
                with failures("the quad mesh"):
                    try:
                        root = stages.RootField(self.field) if root is None else root
                        self.quads = stages.quadrangulate(
                            root, quad_size=config.quad_size, quad_count=config.quad_count,
                            adapt_size=config.adapt_quad_size)
                    except ValueError as e:  # no valid integer-grid map: alike on every rank
                        raise RunError(str(e)) from e
            except RunError as e:  # the same on every rank: the field is written without it
                self._stage_failed("quads", "the quad mesh", e)
            interrupts.raise_if_interrupted(self.comm)
            if self.quads is not None and config.on_cad:
                self._onto_cad()
        if self.quads is not None:
            found = self.quads.quality
            adapted = found.get("adapted_size")
            if adapted is not None:
                say(f"  no valid quads at the default quad size {adapted['asked']:.3g}; "
                    f"{adapted['used']:.3g} used ({adapted['why']})")
            say(f"  {found['quads']} quads, {found['irregular_vertices']} irregular vertices, "
                f"SJ min {found['min_sj']:.3f} mean {found['mean_sj']:.3f}, mean edge "
                f"{found['mean_edge_length']:.3g} (target {found['quad_size']:.3g})"
                + ("" if found["valid"] else f"; INVALID: {'; '.join(found['problems'])}"))
            say("  " + stages.quantisation_line(found))
            self._say_pairs(found, "  ")

    def _say_pairs(self, quality: dict, indent: str = "") -> None:
        """The log line of the ± pairs removed before the map (none where none was close)."""
        from ufl_frames.param.pairs import describe

        line = describe(quality.get("removed_pairs"))
        if line is not None:
            self.say(indent + line)

    def _stage_failed(self, key: str, stage: str, error: BaseException) -> None:
        """Record that ``stage`` (summary key ``key``) failed with ``error``, and warn: the
        run goes on to write the field without it, and ends with status 1."""
        reason = str(error).removeprefix(f"{stage} failed: ")
        self.missing[key] = reason
        warn(self.comm, self.config.quiet, f"{stage} failed; the frame field is written "
             "without it (the reason ends the run)")

    def check_complete(self, summary: dict) -> None:
        """Raise :class:`IncompleteRun` where a stage asked for is missing from the
        results written (their summary ``summary``)."""
        if not self.missing:
            return
        what = {"param": "the parametrisation", "quads": "the quad mesh"}
        key, reason = next(iter(self.missing.items()))
        raise IncompleteRun(
            f"{what[key]} failed: {reason}; the frame field and summary.json were written to "
            f"{str(self.out)!r} without it", summary)

    def _quad_size(self) -> float | None:
        """The quad size asked for: ``quad_size``, or sqrt(area / ``quad_count``)."""
        count = self.config.quad_count
        if count is None:
            return self.config.quad_size
        import dolfinx.fem
        import ufl
        from mpi4py import MPI

        mesh = self.field.domain.mesh
        one = dolfinx.fem.Constant(mesh, 1.0)
        area = self.comm.allreduce(dolfinx.fem.assemble_scalar(
            dolfinx.fem.form(one * ufl.dx(domain=mesh))), op=MPI.SUM)
        return math.sqrt(area / count)

    def _onto_cad(self) -> None:
        """The quads' boundary nodes onto the geometry's CAD curves, on rank 0
        (:func:`ufl_frames.mesh.cad.snap_to_cad`); the measures again, on every rank."""
        from dataclasses import replace

        from ufl_frames.mesh.files import mesh_time_limit
        from ufl_frames.quads.measures import quad_quality

        interrupts.set_stage("the quads' nodes onto the CAD curves")
        quads, failure, quality = self.quads, None, None
        if self.comm.rank == 0:
            from ufl_frames.mesh.cad import snap_to_cad
            from ufl_frames.mesh.domain import GeometryError

            mesh = quads.mesh
            limit = self.config.mesh_time_limit
            try:
                snap = snap_to_cad(
                    self.config.geometry, mesh.points, mesh.quads,
                    **{name: getattr(mesh, name, None) for name in (
                        "curve_edges", "edge_curve", "point_nodes", "point_tag")},
                    time_limit=mesh_time_limit() if limit is None else limit,
                    plane=self.field.domain.plane)
            except GeometryError as e:
                failure = str(e)
            else:
                mesh = replace(mesh, points=snap.points)
                quality = {**quads.quality, **quad_quality(mesh.points, mesh.quads),
                           "cad": snap.record()}
                quads = replace(quads, mesh=mesh)
        failure = self.comm.bcast(failure, root=0)
        if failure is not None:
            raise RunError(f"the quads' nodes onto the CAD curves: {failure}")
        quality = self.comm.bcast(quality, root=0)
        self.quads = replace(quads, quality=quality)
        cad = quality["cad"]
        if cad["note"]:
            self.say(f"  note: {cad['note']}")
        else:
            self.say(f"  {cad['moved']} boundary nodes onto the CAD curves (up to "
                     f"{cad['max_move']:.2g} off), {cad['refused']} moves refused (they would "
                     f"invert a quad); SJ min {quality['min_sj']:.3f}")

    # --- the output folder ---

    def write(self, start: float, petsc_options: dict) -> dict:
        """The files and ``summary.json`` into the output folder, whole or not at all; the
        summary."""
        from ufl_frames import checkpoint as checkpoints
        from ufl_frames import output

        config, comm, out = self.config, self.comm, self.out
        ours = (checkpoints.FOLDER,) if self.store.written else ()
        folder = output.OutputFolder(out, force=config.force, comm=comm, ours=ours)
        try:
            with failures(f"writing the results to {str(out)!r}", writing=True):
                staging = folder.open()
                interrupts.attach_output(folder)
                files = self.write_files(staging)
                summary = self.summary(start, petsc_options, files)
                output.write_summary(staging / "summary.json", summary, comm=comm)
                interrupts.raise_if_interrupted(comm)
                interrupts.set_stage("commit")
                folder.commit()
        except BaseException:
            folder.discard(here=True)  # every rank that fails: perhaps one alone, aborting
            raise
        finally:
            interrupts.attach_output(None)
        interrupts.set_stage("done")
        self.say(f"wrote {out}/: {', '.join(files)}")
        return summary

    def write_files(self, staging: Path) -> list[str]:
        """The field's and the stages' files into ``staging``; their names, and
        ``summary.json`` (written last, by :meth:`write`)."""
        from ufl_frames.pipeline import files

        label, comm = self.config.label, self.comm
        skipped = self.skipped
        names = []
        if self.config.field_files:
            names += files.write_field(staging, self.field, label=label,
                                       tao_type=self.tao_type, skipped=skipped)
        if self.param is not None:
            names += files.write_param(staging, self.param, label, comm, skipped=skipped)
        if self.quads is not None:
            names += files.write_quads(staging, self.quads, label, comm,
                                       groups=self.field.domain.physical_groups,
                                       skipped=skipped, plane=self.field.domain.plane)
        for name, reason in skipped:
            warn(comm, self.config.quiet, f"{name} could not be drawn ({reason}): left out")
        return [*names, "summary.json"]

    def size_summary(self) -> dict | None:
        """The ``sizes`` record (:func:`ufl_frames.pipeline.sizes.size_record`) of a sized
        solve, None without a size target (collective)."""
        from ufl_frames.pipeline.sizes import size_record

        if self.size_target is None or self.field is None or self.field.isotropic:
            return None
        return size_record(self.field, self.size_target,
                           param=None if self.param is None else self.param.quality,
                           quads=None if self.quads is None else self.quads.quality,
                           quad_mesh=None if self.quads is None else self.quads.mesh,
                           quad_count=self.config.quad_count)

    def summary(self, start: float, petsc_options: dict, files: list[str]) -> dict:
        """The record for ``summary.json`` (collective): the field's kind, the run's
        settings, the findings, the time and the files.

        Args:
            start: the run's start, a :func:`time.perf_counter` value (the total time is
                the slowest rank's).
            petsc_options: the PETSc options of the run (name to value), recorded as given.
            files: the names of the files written into the output folder.

        Returns:
            The JSON-ready dict written as ``summary.json``.
        """
        from mpi4py import MPI

        from ufl_frames.pipeline.report import findings_record, frames_record

        config, comm = self.config, self.comm
        return {
            "ufl_frames_version": __version__,
            "geometry": config.geometry,
            **frames_record(self.field),
            "size_factor": float(config.size_factor),
            "loader_notes": list(self.field.domain.notes),
            **plane_record(self.field.domain.plane),
            "max_it": int(self.max_it),
            "num_processes": comm.size,
            "tao_type": self.tao_type,
            "petsc_options": petsc_options,
            "resumed_from_iteration": None if self.state is None else self.state.iterations,
            **findings_record(self.field, self.param, self.quads),
            "sizes": self.size_summary(),
            "missing": {**self.missing, **{name: f"could not be drawn: {reason}"
                                           for name, reason in self.skipped}},
            "total_time_s": comm.allreduce(time.perf_counter() - start, op=MPI.MAX),
            "stage_seconds": comm.bcast(dict(self.seconds), root=0),
            "files": files,
        }
