"""The ``ufl-frames`` command: integrable frame field on a geometry, from the shell.

::

    ufl-frames solve GEOMETRY [--isotropic] [--mesh-size H] [--max-it N]
                              [--mesh-time-limit SECONDS] [--out DIR] [--force]
                              [--resume DIR] [-q] [PETSc options ...]
    ufl-frames info
    ufl-frames --version

GEOMETRY is ``annulus``, ``piano`` or a ``.geo``/``.msh``/``.step``/``.brep`` file
(:func:`ufl_frames.geometry.build`). The run is: mesh → MBO initial field
(:mod:`ufl_frames.solvers.mbo`) → TAO minimisation of H (:mod:`ufl_frames.solvers`) →
singularities → results in DIR (default ``out_<geometry stem>``):

* ``summary.json`` — energies, iterations, TAO's converged reason, mesh size and
  counts, singularities, history (written last: its presence means a complete run);
* ``frames.bp`` — the field for ParaView (``frames.xdmf`` without ADIOS2) and the
  same as ``frames.pvd`` (ASCII VTU, readable back with :func:`ufl_frames.io.read_vtk`),
  see :func:`ufl_frames.io.write_field`;
* ``frames.png`` — the crosses coloured by length (note Fig. 1);
* ``convergence.png`` — H and E against the iteration (note Fig. 2).

Every other option with a single dash goes to PETSc: ``-tao_type lmvm``,
``-tao_monitor``, ``-tao_max_it 3`` (wins over ``--max-it``), ``-mbo_ksp_type``...
Put them after GEOMETRY (an option's value is the token right after it).

Every failure ends with one line ``ufl-frames: error: ...`` on stderr (once per job
under ``mpirun``) and a status, never a traceback (``UFL_FRAMES_DEBUG=1`` prints it too):

* 2, command-line usage: bad arguments, a PETSc option with a value it cannot take
  (``-tao_type`` outside :data:`ufl_frames.petsc_options.TAO_TYPES`, a KSP/PC/line-search
  type PETSc does not have, ``-tao_max_it`` not a positive integer ...), checked before
  anything is meshed;
* 1, the run cannot be done: unknown geometry, unreadable or 3D mesh, a ``.geo`` that
  would act outside the run, a boundary that crosses itself, meshing past
  ``--mesh-time-limit``, an unusable output folder, a ``--resume`` folder without a
  checkpoint of this run, and failures on the way (an MBO or TAO solve PETSc fails, a
  write error);
* 130, interrupted (SIGINT, Ctrl-C, or SIGTERM): at the next MBO level or TAO iteration,
  or within :data:`ufl_frames.interrupts.INTERRUPT_GRACE_S` seconds, whatever runs
  (meshing at once).

Nothing is written unless the run completes: the results go to a hidden folder next to
DIR, renamed into place at the end (:class:`ufl_frames.io.OutputFolder`). The one
exception is the TAO solve's checkpoint, ``DIR/checkpoint/`` (:mod:`ufl_frames.checkpoint`):
kept by an interrupted run, for ``--resume DIR``; removed when the run completes or fails.
Under ``mpirun`` an error every rank meets alike is reported once by rank 0 and every rank
exits; one that a rank meets alone is printed by that rank, which then aborts the job
(the others would wait for it forever).
"""

import argparse
import hashlib
import math
import os
import re
import sys
import time
import traceback
from pathlib import Path

from ufl_frames import __version__, interrupts
from ufl_frames.bootstrap import init_petsc, options_scope, petsc_initialised
from ufl_frames.frames2d.aspect import DEFAULT_MAX_ASPECT
from ufl_frames.interrupts import INTERRUPTED_STATUS, Interrupted
from ufl_frames.mesh.hierarchy import MAX_LEVELS, check_levels, nested_domains
from ufl_frames.petsc_options import MAX_INT, petsc_option_problem

PROG = "ufl-frames"
DEFAULT_MESH_SIZE = None  # relative to the shape: see ufl_frames.geometry.load
DEFAULT_MAX_IT = 500
#: Under MPI, seconds a rank that failed waits for the others to fail too (an error
#: every rank meets) before it aborts the job (an error of its own).
AGREEMENT_TIMEOUT_S = 10.0
DEBUG_VARIABLE = "UFL_FRAMES_DEBUG"


class UsageError(Exception):
    """Bad command line: exit status 2."""


class InputError(ValueError):
    """The geometry, a parameter or the output folder is unusable (same on every rank)."""


class OutputFolderError(InputError):
    """The output folder cannot be used (exists and is not empty, not writable...)."""


class RunError(RuntimeError):
    """The run failed after it started (a solve, a write): exit status 1, one line."""


# --- argument parsing ----------------------------------------------------------------


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors raise :class:`UsageError` (reported on one line by main)."""

    def error(self, message):
        raise UsageError(message)


def _float_option(text: str, zero_allowed: bool) -> float:
    """A finite number > 0 (>= 0 with ``zero_allowed``) from the command line."""
    words = "a number >= 0" if zero_allowed else "a positive number"
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {words}, got {text!r}") from None
    if not (math.isfinite(value) and (value > 0 or (zero_allowed and value == 0))):
        raise argparse.ArgumentTypeError(f"must be {words}, got {text!r}")
    return value


def _positive_float(text: str) -> float:
    return _float_option(text, zero_allowed=False)


def _non_negative_float(text: str) -> float:
    return _float_option(text, zero_allowed=True)


def _levels(text: str):
    """``--levels``: 'auto' or a whole number from 1 to MAX_LEVELS."""
    if text == "auto":
        return text
    value = _positive_int(text)
    if value > MAX_LEVELS:
        raise argparse.ArgumentTypeError(f"must be 'auto' or at most {MAX_LEVELS}, got {text!r}")
    return value


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text!r}")
    if value > MAX_INT:
        raise argparse.ArgumentTypeError(f"must be at most {MAX_INT}, got {text!r}")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog=PROG,
        description="Integrable 2D frame fields (Odeco tensors, DOLFINx, PETSc/TAO).",
        epilog="Options with a single dash (-tao_type lmvm, -tao_monitor, -mbo_ksp_type cg, "
        "...) are passed to PETSc; put them after GEOMETRY.",
    )
    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND")

    solve = commands.add_parser(
        "solve",
        help="compute an integrable frame field on a geometry",
        description="Mesh GEOMETRY, build the MBO initial field, minimise the integrability "
        "energy H with TAO and write summary.json, frames.bp/.pvd, frames.png and "
        "convergence.png to the output folder.",
        epilog="Any option with a single dash is passed to PETSc, e.g. -tao_type lmvm "
        "-tao_monitor -tao_max_it 50 -mbo_ksp_type cg; put them after GEOMETRY.",
    )
    solve.add_argument("geometry", metavar="GEOMETRY",
                       help="'annulus', 'piano' or a .geo/.msh/.step/.stp/.brep file")
    solve.add_argument("--isotropic", action="store_true",
                       help="isotropic frames (l1 = l2, crosses); default: general frames")
    solve.add_argument("--mesh-size", type=_positive_float, default=DEFAULT_MESH_SIZE,
                       metavar="H", help="largest element size, in the geometry's units "
                       "(default: relative to the shape: 0.05 for the built-in shapes, a "
                       "file's own sizes where it sets any, else about 2000 triangles; "
                       "ignored for .msh files)")
    solve.add_argument("--size-factor", type=_positive_float, default=1.0, metavar="F",
                       help="scale the mesh size, the default's or a file's own (< 1 refines)")
    solve.add_argument("--max-triangles", type=_positive_float, default=None, metavar="N",
                       help="refuse, before meshing, sizes estimated to give more triangles "
                       "(default 4e6)")
    solve.add_argument("--mesh-time-limit", type=_seconds, default=None, metavar="SECONDS",
                       help="stop reading and meshing a geometry file after this many "
                       "seconds (default 300, more in proportion with --max-triangles above "
                       "4e6; 'inf' for none)")
    solve.add_argument("--max-it", type=_positive_int, default=DEFAULT_MAX_IT, metavar="N",
                       help=f"TAO iterations at most (default {DEFAULT_MAX_IT}; "
                       "-tao_max_it wins)")
    solve.add_argument("--out", metavar="DIR", default=None,
                       help="output folder (default out_<geometry stem>); must not exist "
                       "or be empty unless --force")
    solve.add_argument("--force", action="store_true",
                       help="write into an existing non-empty output folder, replacing files")
    solve.add_argument("--resume", metavar="DIR", default=None,
                       help="go on from the checkpoint an interrupted run left in its output "
                       "folder DIR (give the same GEOMETRY and options); the results go to DIR")
    solve.add_argument("--max-aspect", type=_aspect, default=DEFAULT_MAX_ASPECT, metavar="A",
                       help=f"bound on l_max/l_min of non-isotropic frames (default "
                       f"{DEFAULT_MAX_ASPECT:g}; 'inf' for none: the energy then has degenerate "
                       "minimisers where a branch collapses)")
    solve.add_argument("--param", action="store_true",
                       help="also integrate the field into a seamless parametrisation (U, V): "
                       "param.png (integer iso-lines), param.vtu and 'param' in summary.json")
    solve.add_argument("--conformal", action="store_true",
                       help="isotropic frames of the MBO directions with the conformal scale "
                       "(one Poisson solve instead of TAO: the integrable isotropic field, "
                       "whose lengths follow the singularities' cones)")
    solve.add_argument("--quads", action="store_true",
                       help="also make a quad mesh of the field (integer-grid map, iso-line "
                       "extraction): quads.msh (Gmsh MSH 4.1), quads.vtu, quads.png and "
                       "'quads' in summary.json")
    solve.add_argument("--quad-size", type=_positive_float, default=None, metavar="S",
                       help="the quads' mean edge length (default: with --quads the triangles' "
                       "mean edge length; with --param only, about one quad per 8 triangles)")
    solve.add_argument("--free-singularities", action="store_true",
                       help="let the solver move, create and annihilate singularities "
                       "(default: the cross orientation is held on the MBO field's singular "
                       "triangles)")
    solve.add_argument("--pin-radius", type=_non_negative_float, default=0.0, metavar="R",
                       help="also hold the cross orientation at every vertex closer than R to "
                       "a singular triangle, on every level of --levels (default 0: the "
                       "triangles' vertices only, which a fine mesh can escape by creating "
                       "a pair of singularities next to them)")
    solve.add_argument("--levels", type=_levels, default="auto", metavar="L",
                       help="nested iteration over L meshes: MBO and a solve on the mesh of "
                       "size 2^(L-1) times the requested one, then each finer mesh from the "
                       "coarser solution (default 'auto': as many as keep the coarsest mesh "
                       "at 1500 triangles or more, one mesh for a .msh or --conformal)")
    solve.add_argument("--nested-meshes", action="store_true",
                       help="with --levels: mesh the coarsest level only and make each finer "
                       "one by splitting every triangle into 4 (exact transfer between levels, "
                       "fewer Newton steps on the finer ones), but the split meshes end at an "
                       "8-30%% higher H than meshes of the same size made by Gmsh (default: "
                       "every level meshed by Gmsh)")
    solve.add_argument("-q", "--quiet", action="store_true", help="no progress output")

    commands.add_parser("info", help="print the versions of the libraries in use",
                        description="Print the versions of ufl_frames, DOLFINx, PETSc, "
                        "MPI, Gmsh and friends.")
    return parser


def _aspect(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number >= 1 or 'inf', got {text!r}") from None
    if not value >= 1:  # also rejects NaN
        raise argparse.ArgumentTypeError(f"must be >= 1 (or 'inf'), got {text!r}")
    return value


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number of seconds or 'inf', "
                                         f"got {text!r}") from None
    if not value > 0:  # also rejects NaN
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds, got {text!r}")
    return value


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def split_petsc_options(extras: list[str]) -> list[tuple[str, str | None]]:
    """PETSc options ``(name, value or None)`` from the arguments argparse did not know.

    ``-name`` (one dash) starts an option; the next token is its value unless it starts
    with a dash (negative numbers are values). Anything else is a usage error.
    """
    options: list[tuple[str, str | None]] = []
    expecting_value = False
    for token in extras:
        is_option = token.startswith("-") and not _is_number(token)
        if is_option and not token.startswith("--") and len(token) > 1:
            options.append((token[1:], None))
            expecting_value = True
        elif expecting_value and not is_option:
            options[-1] = (options[-1][0], token)
            expecting_value = False
        else:
            raise UsageError(f"unrecognized arguments: {' '.join(extras)}")
    return options


def _petsc_argv(options: list[tuple[str, str | None]]) -> list[str]:
    argv = []
    for name, value in options:
        argv.append(f"-{name}")
        if value is not None:
            argv.append(value)
    return argv


def check_petsc_options(options) -> None:
    """Raise :class:`UsageError` if :func:`petsc_option_problem` finds one."""
    problem = petsc_option_problem(options)
    if problem is not None:
        raise UsageError(problem)


def _check_text(args: list[str]) -> None:
    """Arguments must be valid UTF-8 (Gmsh, DOLFINx and ADIOS2 take UTF-8 paths)."""
    for arg in args:
        try:
            arg.encode("utf-8")
        except UnicodeEncodeError:
            raise UsageError(
                f"argument {ascii(arg)} is not valid UTF-8 (rename the file or folder)"
            ) from None


# --- output -----------------------------------------------------------------------------


def _printer(comm, quiet: bool):
    """print on rank 0 (flushed), or nothing when ``quiet``."""

    closed = False

    def say(text: str) -> None:
        nonlocal closed
        if not quiet and not closed and comm.rank == 0:
            try:
                print(text, flush=True)
            except BrokenPipeError:  # `ufl-frames ... | head`: the run goes on, silent
                closed = True
                devnull = os.open(os.devnull, os.O_WRONLY)
                os.dup2(devnull, sys.stdout.fileno())
                os.close(devnull)

    return say


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
    """
    problem = _output_folder_problem(Path(out), force, resuming) if comm.rank == 0 else None
    problem = comm.bcast(problem, root=0)
    if problem is not None:
        raise OutputFolderError(problem)


def default_output_folder(geometry: str) -> Path:
    """``out_<stem>``: ``out_piano`` for ``piano``, ``out_part`` for ``meshes/part.step``."""
    return Path(f"out_{Path(str(geometry)).stem}")


# --- the pipeline -------------------------------------------------------------------------


def _finite_real(value) -> bool:
    """Whether ``value`` is a finite int or float (not a bool)."""
    real = isinstance(value, (int, float)) and not isinstance(value, bool)
    return real and math.isfinite(value)


def _check_parameters(mesh_size, max_it) -> None:
    if mesh_size is not None and not (_finite_real(mesh_size) and mesh_size > 0):
        raise InputError(f"mesh size must be a positive number, got {mesh_size!r}")
    if isinstance(max_it, bool) or not isinstance(max_it, int) or not 0 < max_it <= MAX_INT:
        raise InputError(f"max-it must be a positive integer at most {MAX_INT}, got {max_it!r}")


def _check_pin_radius(pin_radius, free_singularities: bool) -> None:
    if not (_finite_real(pin_radius) and pin_radius >= 0):
        raise InputError(f"pin radius must be a number >= 0, got {pin_radius!r}")
    if pin_radius > 0 and free_singularities:
        raise InputError("--pin-radius holds pinned singularities: it cannot be combined "
                         "with --free-singularities")


def run_solve(
    geometry: str,
    isotropic: bool = False,
    mesh_size: float = DEFAULT_MESH_SIZE,
    max_it: int = DEFAULT_MAX_IT,
    out=None,
    force: bool = False,
    quiet: bool = False,
    comm=None,
    max_aspect: float = DEFAULT_MAX_ASPECT,
    free_singularities: bool = False,
    size_factor: float = 1.0,
    max_triangles: float | None = None,
    mesh_time_limit: float | None = None,
    param: bool = False,
    quad_size: float | None = None,
    quads: bool = False,
    conformal: bool = False,
    resume=None,
    levels: int | str = "auto",
    nested_meshes: bool = False,
    pin_radius: float = 0.0,
) -> dict:
    """Mesh → MBO → TAO → singularities (→ with ``param``, the map (U, V) of
    :meth:`~ufl_frames.pipeline.FrameField.parametrise`; with ``quads``, the quad mesh of
    :meth:`~ufl_frames.pipeline.FrameField.quadrangulate`) → files in ``out``; return the
    summary (all ranks).

    Collective over ``comm`` (default ``MPI.COMM_WORLD``). Raises :class:`InputError`
    (for a :class:`ufl_frames.geometry.GeometryError`, a bad parameter or PETSc option in
    the database, an existing non-empty ``out``) on every rank, before anything is
    computed or written, when the input is unusable; ``levels`` > 1: nested iteration
    (:meth:`~ufl_frames.pipeline.FrameField.nested`) over meshes of size factors
    2^(levels-1) … 1 of ``size_factor`` ('auto': :func:`auto_levels` of the requested
    mesh, one level for a ``.msh`` or ``conformal``; a coarse mesh that fails or loses a
    hole ends the coarsening there; with ``nested_meshes`` the levels of
    :func:`ufl_frames.geometry.build_nested` instead, one level fewer where its coarsest
    fails or loses a hole); :class:`RunError` when a solve or
    writing the results fails on every rank alike (a PETSc error, a full disk); other
    exceptions are bugs and keep their type. ``out`` is written whole or not at all
    (:class:`ufl_frames.io.OutputFolder`). PETSc options in the database
    (``-tao_type`` ...) are honoured; the defaults the solvers add to the database are
    removed afterwards.
    """
    init_petsc()
    from mpi4py import MPI
    from petsc4py import PETSc

    from ufl_frames import checkpoint as checkpoints
    from ufl_frames import geometry as geometry_module

    comm = MPI.COMM_WORLD if comm is None else comm
    say = _printer(comm, quiet)
    start = time.perf_counter()
    user_options = PETSc.Options().getAll()
    geometry = str(geometry)
    if resume is not None:
        if out is not None and os.path.abspath(out) != os.path.abspath(resume):
            raise InputError("out and resume name different folders")
        out = resume
    out = default_output_folder(geometry) if out is None else Path(out)
    _check_parameters(mesh_size, max_it)
    try:
        check_levels(levels, geometry, conformal)
    except ValueError as e:
        raise InputError(str(e)) from e
    _check_pin_radius(pin_radius, free_singularities)
    problem = petsc_option_problem(user_options)
    if problem is not None:
        raise InputError(problem)
    run = _run_record(geometry, comm, isotropic=isotropic, mesh_size=mesh_size,
                      size_factor=size_factor, max_triangles=max_triangles,
                      max_aspect=max_aspect, free_singularities=free_singularities,
                      pin_radius=float(pin_radius),
                      max_it=max_it, conformal=conformal, levels=levels,
                      nested_meshes=nested_meshes, petsc_options=user_options)
    saved = None
    if resume is not None:
        try:
            saved = checkpoints.read(out, comm)
            checkpoints.check_run(saved, run, out)
        except checkpoints.CheckpointError as e:
            raise InputError(str(e)) from e
    check_output_folder(out, force, comm, resuming=resume is not None)
    size = "relative to the shape" if mesh_size is None else f"mesh size {mesh_size:g}"
    say(f"meshing {geometry} ({size}) ...")
    limit = {} if max_triangles is None else {"max_triangles": max_triangles}
    limit["time_limit"] = mesh_time_limit
    interrupts.set_stage("meshing")
    try:
        domain = geometry_module.build(comm, geometry, mesh_size, size_factor, **limit)
    except geometry_module.MeshTimeLimit as e:  # raised identically on every rank
        raise InputError(f"{e}; a larger --mesh-time-limit allows more") from e
    except geometry_module.GeometryError as e:  # raised identically on every rank
        raise InputError(str(e)) from e
    try:
        domains = nested_domains(comm, geometry, domain, 1 if conformal and levels == "auto"
                                 else levels, mesh_size, size_factor,
                                 nested_meshes=nested_meshes, say=say, **limit)
    except geometry_module.GeometryError as e:  # raised identically on every rank
        raise InputError(str(e)) from e
    coarse, domain = domains[:-1], domains[-1]  # nested iteration: coarsest first
    interrupts.set_stage("the MBO initial field")
    interrupts.checkpoint(comm)
    for note in domain.notes:
        say(f"  note: {note}")
    say(f"  {domain.num_vertices} vertices, {domain.num_cells} triangles (mean edge "
        f"{domain.mesh_size:.3g}), {comm.size} process{'es' if comm.size > 1 else ''}")
    key = checkpoints.mesh_key(domain.mesh)
    if saved is not None and saved["mesh_key"] != key:
        raise InputError(f"cannot resume: the checkpoint in {str(out)!r} is of another mesh "
                         "(the geometry or its meshing changed); start again with --force")
    store = checkpoints.CheckpointFolder(out, comm, run, key, existing=saved is not None)
    interrupts.note_checkpoint(out if saved is not None else None)
    try:
        return _solve_and_write(domain, store, saved, say, start, out, geometry, comm,
                                isotropic=isotropic, max_it=max_it, force=force, quiet=quiet,
                                max_aspect=max_aspect, free_singularities=free_singularities,
                                pin_radius=pin_radius,
                                size_factor=size_factor, param=param, quad_size=quad_size,
                                quads=quads, conformal=conformal, user_options=user_options,
                                coarse=coarse)
    except KeyboardInterrupt:  # Interrupted too: the checkpoint, if any, is for --resume
        raise
    except BaseException:
        store.discard()  # a failed run leaves nothing (a checkpoint resumed from stays)
        raise
    finally:
        interrupts.note_checkpoint(None)


#: PETSc options that change what a run prints, not what it computes: not compared
#: when resuming.
_OUTPUT_ONLY_OPTION = re.compile(r"monitor|view|^log|^options_left$|^help$|^info$")


def _run_record(geometry: str, comm, **arguments) -> dict:
    """The arguments that decide a run's result, for its checkpoint (collective): the
    geometry by name or by the SHA-256 of its file, the PETSc options but for monitors."""
    from ufl_frames import geometry as geometry_module

    identity = None
    if geometry in geometry_module.KNOWN_GEOMETRIES:
        identity = geometry
    elif comm.rank == 0:
        try:
            identity = "sha256:" + hashlib.sha256(Path(geometry).read_bytes()).hexdigest()
        except OSError:
            identity = None  # meshing reports it
    identity = comm.bcast(identity, root=0)
    options = arguments.pop("petsc_options")
    record = {"geometry": geometry, "geometry_id": identity, **arguments}
    record["petsc_options"] = sorted([name, value] for name, value in options.items()
                                     if not _OUTPUT_ONLY_OPTION.search(name))
    for name in ("mesh_size", "size_factor", "max_triangles", "max_aspect"):
        if record[name] is not None:
            record[name] = float(record[name])
    return record


def _solve_and_write(domain, store, saved, say, start, out, geometry, comm, *, isotropic,
                     max_it, force, quiet, max_aspect, free_singularities, size_factor,
                     pin_radius, param, quad_size, quads, conformal, user_options,
                     coarse=()) -> dict:
    """MBO → TAO (from ``saved``, a checkpoint, if given; checkpoints into ``store``) →
    singularities → files in ``out``: the rest of :func:`run_solve`. With ``coarse``
    domains, nested iteration from the coarsest to ``domain`` instead."""
    from mpi4py import MPI
    from petsc4py import PETSc

    from ufl_frames import checkpoint as checkpoints
    from ufl_frames import io, solvers
    from ufl_frames.pipeline import FrameField

    def mbo_monitor(level, tau, change):
        say(f"  level {level}: sqrt(tau) {math.sqrt(tau):.3g}, max change {change:.2e}")
        interrupts.checkpoint(comm)

    def tao_monitor(e):  # interrupts are taken by keep(), called just before
        say(f"  it {e['it']:4d}  H {e['H']:.6e}  E {e['E']:.6e}  |grad| {e['gnorm']:.3e}"
            + (f"  ksp {e['ksp_its']}" if "ksp_its" in e else "")
            + (f"  factorisations {e['factorisations']}"
               if e.get("factorisations", 1) > 1 else ""))

    def keep(state, V=None):
        """Save ``state`` (of the field on ``V``, default the field's) every
        CHECKPOINT_EVERY steps and when interrupted, then stop if interrupted (at each TAO
        iterate, before the monitor prints)."""
        signum = interrupts.pending(comm)
        if state.iterations > 0 and (signum or
                                     state.iterations % checkpoints.CHECKPOINT_EVERY == 0):
            store.save(state, field.q.function_space if V is None else V)
            interrupts.note_checkpoint(out)
        interrupts.checkpoint(comm, signum)

    def restore(V):
        """The checkpoint resumed from, on the space ``V`` (None without one)."""
        if saved is None:
            return None
        try:
            state = checkpoints.restore(saved, V, comm)
        except checkpoints.CheckpointError as e:
            raise InputError(str(e)) from e
        say(f"resuming from the checkpoint at iteration {state.iterations} ...")
        return state

    with options_scope():  # the solvers' defaults end with the run
        if not coarse:  # nested iteration runs MBO on its coarsest mesh only
            say("MBO initial field ...")
            with _failures("the MBO initial field"):
                field = FrameField.initial(domain, isotropic=isotropic, max_aspect=max_aspect,
                                           monitor=mbo_monitor)
        tao_type = PETSc.Options().getString("tao_type", solvers.DEFAULT_OPTIONS["tao_type"])
        kind = "isotropic frames" if isotropic else "frames"
        state = None  # the checkpoint resumed from
        if conformal:
            tao_type = None
            interrupts.set_stage("the conformal scale")
            say("conformal scale (isotropic frames of the MBO directions) ...")
            with _failures("the conformal-scale solve"):
                field.conformal()
            result = None
        elif coarse:
            interrupts.set_stage(f"the TAO solve ({tao_type}), nested")
            interrupts.checkpoint(comm)

            finest_space = []

            def restore_finest(V):
                nonlocal state
                finest_space.append(V)
                state = restore(V)
                return state

            def keep_finest(state, finest):  # checkpoints of the finest mesh only
                if finest:
                    keep(state, finest_space[-1])
                else:
                    interrupts.checkpoint(comm, interrupts.pending(comm))

            def level_done(entry):
                say(f"mesh {entry['level'] + 1}/{len(coarse) + 1}: {entry['triangles']} "
                    f"triangles, {entry['reason']} after {entry['iterations']} iterations "
                    f"({entry['seconds']:.2f} s), H {entry['H']:.4e}")

            say(f"solving ({kind}, TAO {tao_type}), nested over {len(coarse) + 1} meshes "
                f"from {coarse[0].num_cells} triangles ...")
            with _failures(f"the TAO solve ({tao_type})"):
                field = FrameField.nested(
                    [*coarse, domain], isotropic=isotropic, max_aspect=max_aspect,
                    pin_singularities=not free_singularities, max_it=max_it,
                    pin_radius=pin_radius, monitor=tao_monitor, mbo_monitor=mbo_monitor,
                    level_monitor=level_done,
                    checkpoint=keep_finest, restore=restore_finest)
            result = field.result
        else:
            interrupts.set_stage(f"the TAO solve ({tao_type})")
            interrupts.checkpoint(comm)
            state = restore(field.q.function_space)
            say(f"solving ({kind}, TAO {tao_type}) ...")
            with _failures(f"the TAO solve ({tao_type})"):
                result = field.solve(pin_singularities=not free_singularities, max_it=max_it,
                                     pin_radius=pin_radius, monitor=tao_monitor,
                                     checkpoint=keep, resume=state)
        max_it = PETSc.Options().getInt("tao_max_it", max_it)  # -tao_max_it wins
    interrupts.set_stage("writing the results")
    interrupts.checkpoint(comm)
    if result is not None:
        converged = result.converged_reason.startswith("CONVERGED")
        say(f"{result.converged_reason} after {result.iterations} iterations "
            f"({result.wall_time_s:.2f} s): H {result.H_initial:.4e} -> {result.H_final:.4e}")
        if not converged and not quiet and comm.rank == 0:
            print(f"{PROG}: warning: TAO stopped with {result.converged_reason}",
                  file=sys.stderr)

    say(f"singularities: {io.describe_singularities(field.singularities)}")
    index_check = field.index_theorem()  # also in the summary
    if not index_check["agrees"] and not quiet and comm.rank == 0:
        print(f"{PROG}: warning: the singularities' indices sum to {index_check['index_sum']:g}, "
              f"Poincaré–Hopf says {index_check['expected']:g} (Euler characteristic "
              f"{domain.euler_characteristic}, {index_check['corners']} corners): the boundary "
              "is too coarse for the field somewhere; try a smaller --mesh-size",
              file=sys.stderr)

    if param:
        with _failures("the parametrisation"):
            quality = field.parametrise(quad_size=quad_size)
        say(f"parametrisation: misfit {quality['misfit']:.4f}, "
            f"{quality['flipped_triangles']} flipped triangles, {quality['cuts']} cut(s) "
            f"of length {quality['cut_length']:.3g}")
        interrupts.checkpoint(comm)
    if quads:
        interrupts.set_stage("the quad mesh")
        say("quad mesh ...")
        with _failures("the quad mesh"):
            try:
                found = field.quadrangulate(quad_size=quad_size)
            except ValueError as e:  # no valid integer-grid map: the same on every rank
                raise RunError(str(e)) from e
        say(f"  {found['quads']} quads, {found['irregular_vertices']} irregular vertices, "
            f"SJ min {found['min_sj']:.3f} mean {found['mean_sj']:.3f}, mean edge "
            f"{found['mean_edge_length']:.3g} (target {found['quad_size']:.3g})"
            + ("" if found["valid"] else f"; INVALID: {'; '.join(found['problems'])}"))
        interrupts.checkpoint(comm)

    ours = (checkpoints.FOLDER,) if store.written else ()
    folder = io.OutputFolder(out, force=force, comm=comm, ours=ours)
    try:
        with _failures(f"writing the results to {str(out)!r}", writing=True):
            staging = folder.open()
            interrupts.attach_output(folder)
            files = field.write(staging, label=Path(geometry).stem, tao_type=tao_type)
            if param:
                files += field.write_param(staging, label=Path(geometry).stem)
            if quads:
                files += field.write_quads(staging, label=Path(geometry).stem)
            files.append("summary.json")
            record = field.summary()
            summary = {
                "ufl_frames_version": __version__,
                "geometry": geometry,
                **{key: record.pop(key) for key in ("isotropic", "max_aspect",
                                                    "pinned_singularities", "mesh_size",
                                                    "requested_mesh_size")},
                "size_factor": float(size_factor),
                "loader_notes": list(domain.notes),
                "max_it": int(max_it),
                "num_processes": comm.size,
                "tao_type": tao_type,
                "petsc_options": user_options,
                "resumed_from_iteration": None if state is None else state.iterations,
                **record,
                "total_time_s": comm.allreduce(time.perf_counter() - start, op=MPI.MAX),
                "files": files,
            }
            io.write_summary(staging / "summary.json", summary, comm=comm)
            interrupts.checkpoint(comm)
            interrupts.set_stage("commit")
            folder.commit()
    except BaseException:
        folder.discard(here=True)  # every rank that fails: perhaps one alone, then aborting
        raise
    finally:
        interrupts.attach_output(None)
    interrupts.set_stage("done")
    say(f"wrote {out}/: {', '.join(files)}")
    return summary


class _failures:
    """Turn the failures a user can meet in a stage into :class:`RunError` (one line).

    PETSc errors (a solve PETSc gives up on), RuntimeError (raised for failed MBO
    solves), and, when ``writing``, OSError (a full disk, a path under /proc); the
    original stays as ``__cause__`` for the traceback of ``UFL_FRAMES_DEBUG``.
    """

    def __init__(self, stage: str, writing: bool = False):
        self.stage = stage
        self.writing = writing

    def __enter__(self):
        return self

    def __exit__(self, kind, exc, tb):
        if exc is None or not isinstance(exc, Exception) or isinstance(exc, (InputError,
                                                                              RunError)):
            return False
        if type(exc).__name__ == "OutputFolderBusy":  # ufl_frames.io: says it all
            raise RunError(exc.strerror) from exc
        text = describe_exception(exc)
        if self.writing and isinstance(exc, OSError):
            raise RunError(f"{self.stage} failed: {text}") from exc
        if isinstance(exc, RuntimeError):  # petsc4py.PETSc.Error is one
            raise RunError(f"{self.stage} failed: {text}") from exc
        if self.writing and isinstance(exc, (ValueError, TypeError)):  # e.g. encoding
            raise RunError(f"{self.stage} failed: {text}") from exc
        return False


def describe_exception(exc: BaseException) -> str:
    """``exc`` on one line; PETSc errors as their code, class and message."""
    text = str(exc)
    if type(exc).__name__ == "Error" and type(exc).__module__.startswith("petsc4py"):
        lines = [re.sub(r"^\[\d+\]\s*", "", line).strip() for line in text.splitlines()]
        first = lines[0] if lines else ""
        messages = [line for line in lines[1:] if line and not re.search(r"\(\) at \S+:\d+$",
                                                                          line)]
        code = getattr(exc, "ierr", None)
        text = f"PETSc error {code}" if code is not None else first
        if messages:
            text += ": " + ": ".join(messages)
    elif isinstance(exc, OSError) and exc.strerror:
        text = f"{exc.strerror}: {str(exc.filename)!r}" if exc.filename else exc.strerror
    text = " ".join(text.split())
    if not text:
        return type(exc).__name__
    return text


# --- info -------------------------------------------------------------------------------


def versions() -> dict:
    """Versions of the libraries in use (PETSc initialised first)."""
    init_petsc()
    import basix
    import dolfinx
    import dolfinx.io
    import ffcx
    import gmsh
    import numpy
    import ufl
    from mpi4py import MPI
    from petsc4py import PETSc

    petsc = ".".join(str(v) for v in PETSc.Sys.getVersion())
    return {
        "ufl_frames": __version__,
        "python": sys.version.split()[0],
        "dolfinx": dolfinx.__version__,
        "ufl": ufl.__version__,
        "basix": basix.__version__,
        "ffcx": ffcx.__version__,
        "petsc": f"{petsc} ({PETSc.ScalarType.__name__})",
        "mpi": " ".join(MPI.Get_library_version().split()[:4]),
        "gmsh": gmsh.__version__,
        "numpy": numpy.__version__,
        "adios2 (VTXWriter)": "yes" if dolfinx.io.has_adios2 else "no",
    }


def _info(comm) -> int:
    table = versions()
    if comm.rank == 0:
        width = max(len(k) for k in table)
        for key, value in table.items():
            print(f"{key:<{width}}  {value}")
    return 0


# --- entry point ----------------------------------------------------------------------------


def _rank() -> int:
    init_petsc([PROG])
    from mpi4py import MPI

    return MPI.COMM_WORLD.rank


def _debug() -> bool:
    return os.environ.get(DEBUG_VARIABLE, "").strip().lower() not in ("", "0", "false", "no")


def _print_error(message: str) -> None:
    text = " ".join(str(message).split())
    try:
        print(f"{PROG}: error: {text}", file=sys.stderr, flush=True)
    except (OSError, ValueError):  # stderr closed: nothing more to do
        pass


def _fail(message: str, status: int) -> int:
    """Report ``message`` once (rank 0) as one line on stderr; return ``status``."""
    if _rank() == 0:
        _print_error(message)
    _quiet_petsc_finalize()
    return status


def _quiet_petsc_finalize() -> None:
    """No "options you set that were not used" report from PETSc after a failed run."""
    from petsc4py import PETSc

    db = PETSc.Options()
    if not db.hasName("options_left"):
        db.setValue("options_left", "no")


def _failure_status(exc: BaseException) -> tuple[int, str, bool]:
    """(exit status, one-line message, expected) for an exception out of a run."""
    if isinstance(exc, KeyboardInterrupt):
        if isinstance(exc, Interrupted):
            return INTERRUPTED_STATUS, str(exc), True
        return INTERRUPTED_STATUS, "interrupted; nothing written", True
    if isinstance(exc, (InputError, RunError)):
        return 1, str(exc), True
    if isinstance(exc, MemoryError):
        return 1, "out of memory (try a larger --mesh-size or more processes)", True
    return 1, (f"internal error: {type(exc).__name__}: {describe_exception(exc)} (set "
               f"{DEBUG_VARIABLE}=1 for the traceback)"), False


def _all_failed(agreement, timeout: float) -> bool:
    """Whether every rank of ``agreement`` (a communicator used for nothing else) reaches
    this point within ``timeout`` seconds: an error all ranks met, not one rank's own."""
    request = agreement.Ibarrier()
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if request.Test():
            return True
        time.sleep(0.01)
    return False


def _report_failure(exc: BaseException, comm, agreement) -> int:
    """One line for ``exc`` (once per job), the traceback with ``UFL_FRAMES_DEBUG``; the
    exit status. Under MPI a failure every rank met returns on every rank; one a rank met
    alone is printed by it and aborts the job."""
    status, message, expected = _failure_status(exc)
    if _debug():
        traceback.print_exception(exc, file=sys.stderr)
    if comm.size == 1 or _all_failed(agreement, AGREEMENT_TIMEOUT_S):
        if comm.rank == 0:
            _print_error(message)
        return status
    _print_error(f"{message} (on rank {comm.rank} alone: aborting the job)")
    comm.Abort(status)
    return status  # not reached


def main(argv: list[str] | None = None) -> int:
    """Run the ``ufl-frames`` command with ``argv`` (default ``sys.argv[1:]``); exit status."""
    argv = sys.argv[1:] if argv is None else [str(a) for a in argv]
    try:
        os.getcwd()
    except OSError as e:  # PETSc would fail to start, with a page of errors
        if os.environ.get("PMI_RANK", "0") == "0":
            _print_error(f"the current folder is not usable ({e.strerror}): cd elsewhere")
        return 1
    try:
        _check_text(argv)
        args, extras = build_parser().parse_known_args(argv)
        options = split_petsc_options(extras)
        if args.command is None:
            raise UsageError("missing command: use 'solve' or 'info' (see ufl-frames --help)")
        if args.command == "solve" and args.resume is not None and args.out is not None \
                and os.path.abspath(args.out) != os.path.abspath(args.resume):
            raise UsageError("--out and --resume name different folders: the resumed run "
                             "writes to its --resume folder")
    except UsageError as e:
        return _fail(str(e), 2)

    if args.command == "info":
        if not petsc_initialised():
            init_petsc([PROG, *_petsc_argv(options)])
        from mpi4py import MPI

        return _info(MPI.COMM_WORLD)

    status = 0
    # The signals are taken over before PETSc and MPI start: threads they start inherit
    # the blocked signals (one that did not would die of SIGTERM).
    with interrupts.SignalWatch(report=_print_error) as watch:
        # PETSc reads its options now, before anything imports dolfinx (start-up options
        # such as -log_view work only so); called in-process, options_scope puts them in.
        if not petsc_initialised():
            init_petsc([PROG, *_petsc_argv(options)])
        from mpi4py import MPI

        comm = watch.comm = MPI.COMM_WORLD
        try:
            check_petsc_options(options)  # before anything is meshed
        except UsageError as e:
            return _fail(str(e), 2)
        agreement = comm.Dup() if comm.size > 1 else None  # for failures only
        try:
            with options_scope(options):  # this run's options, removed afterwards
                interrupts.activate(watch)
                try:
                    run_solve(
                        args.geometry,
                        isotropic=args.isotropic,
                        mesh_size=args.mesh_size,
                        max_it=args.max_it,
                        out=args.out,
                        force=args.force,
                        quiet=args.quiet,
                        comm=comm,
                        max_aspect=args.max_aspect,
                        free_singularities=args.free_singularities,
                        size_factor=args.size_factor,
                        max_triangles=args.max_triangles,
                        mesh_time_limit=args.mesh_time_limit,
                        resume=args.resume,
                        param=args.param,
                        quad_size=args.quad_size,
                        quads=args.quads,
                        conformal=args.conformal,
                        levels=args.levels, nested_meshes=args.nested_meshes,
                        pin_radius=args.pin_radius,
                    )
                except Exception as e:
                    watch.stage = "reporting the failure"
                    status = _report_failure(e, comm, agreement)
                except KeyboardInterrupt as e:
                    watch.stage = "reporting the failure"
                    watch.handled.set()  # a second signal now ends the process
                    status = _report_failure(e, comm, agreement)
                finally:
                    interrupts.activate(None)
        finally:
            if agreement is not None:
                agreement.Free()
    if status:
        _quiet_petsc_finalize()  # after options_scope, which would take it out again
    return status


if __name__ == "__main__":
    sys.exit(main())
