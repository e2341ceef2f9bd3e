"""The ``ufl-frames`` command: integrable frame field on a geometry, from the shell.

::

    ufl-frames solve GEOMETRY [--isotropic] [--mesh-size H] [--max-it N]
                              [--out DIR] [--force] [-q] [PETSc options ...]
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

Errors the user can fix (bad arguments, unknown geometry, unreadable or 3D mesh,
existing output folder) give one line ``ufl-frames: error: ...`` on stderr and exit
status 2 (command-line usage) or 1 (the run cannot be done), with nothing written.
Under ``mpirun`` they are detected identically on every rank (or broadcast from
rank 0) and reported once. Unexpected errors keep their traceback; in parallel the
job is then aborted so that no rank hangs.
"""

import argparse
import math
import os
import sys
import time
from pathlib import Path

from ufl_frames import __version__
from ufl_frames.bootstrap import init_petsc, options_scope, petsc_initialised
from ufl_frames.frames2d.aspect import DEFAULT_MAX_ASPECT

PROG = "ufl-frames"
DEFAULT_MESH_SIZE = None  # relative to the shape: see ufl_frames.geometry.load
DEFAULT_MAX_IT = 500


class UsageError(Exception):
    """Bad command line: exit status 2."""


class InputError(ValueError):
    """The geometry, a parameter or the output folder is unusable (same on every rank)."""


class OutputFolderError(InputError):
    """The output folder cannot be used (exists and is not empty, not writable...)."""


# --- argument parsing ----------------------------------------------------------------


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors raise :class:`UsageError` (reported on one line by main)."""

    def error(self, message):
        raise UsageError(message)


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
    return value


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text!r}")
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
    solve.add_argument("--max-it", type=_positive_int, default=DEFAULT_MAX_IT, metavar="N",
                       help=f"TAO iterations at most (default {DEFAULT_MAX_IT}; "
                       "-tao_max_it wins)")
    solve.add_argument("--out", metavar="DIR", default=None,
                       help="output folder (default out_<geometry stem>); must not exist "
                       "or be empty unless --force")
    solve.add_argument("--force", action="store_true",
                       help="write into an existing non-empty output folder, replacing files")
    solve.add_argument("--max-aspect", type=_aspect, default=DEFAULT_MAX_ASPECT, metavar="A",
                       help=f"bound on l_max/l_min of non-isotropic frames (default "
                       f"{DEFAULT_MAX_ASPECT:g}; 'inf' for none: the energy then has degenerate "
                       "minimisers where a branch collapses)")
    solve.add_argument("--free-singularities", action="store_true",
                       help="let the solver move, create and annihilate singularities "
                       "(default: the cross orientation is held on the MBO field's singular "
                       "triangles)")
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


# --- output -----------------------------------------------------------------------------


def _printer(comm, quiet: bool):
    """print on rank 0 (flushed), or nothing when ``quiet``."""

    def say(text: str) -> None:
        if not quiet and comm.rank == 0:
            print(text, flush=True)

    return say


def _nearest_existing(path: Path) -> Path:
    path = path.absolute()
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def _output_folder_problem(out: Path, force: bool) -> str | None:
    """Why ``out`` cannot be the output folder, or None (checked on one rank)."""
    if out.exists():
        if not out.is_dir():
            return f"output path {str(out)!r} exists and is not a folder"
        if not force and any(out.iterdir()):
            return f"output folder {str(out)!r} exists and is not empty (use --force to overwrite)"
        if not os.access(out, os.W_OK | os.X_OK):
            return f"output folder {str(out)!r} is not writable"
        return None
    parent = _nearest_existing(out)
    if not parent.is_dir():
        return f"cannot create output folder {str(out)!r}: {str(parent)!r} is not a folder"
    if not os.access(parent, os.W_OK | os.X_OK):
        return f"cannot create output folder {str(out)!r}: {str(parent)!r} is not writable"
    return None


def check_output_folder(out, force: bool, comm) -> None:
    """Raise :class:`OutputFolderError` on every rank if ``out`` cannot be used (collective).

    Checked on rank 0 and broadcast, so that all ranks agree even when another rank
    has already started writing.
    """
    problem = _output_folder_problem(Path(out), force) if comm.rank == 0 else None
    problem = comm.bcast(problem, root=0)
    if problem is not None:
        raise OutputFolderError(problem)


def default_output_folder(geometry: str) -> Path:
    """``out_<stem>``: ``out_piano`` for ``piano``, ``out_part`` for ``meshes/part.step``."""
    return Path(f"out_{Path(str(geometry)).stem}")


# --- the pipeline -------------------------------------------------------------------------


def _check_parameters(mesh_size, max_it) -> None:
    real = isinstance(mesh_size, (int, float)) and not isinstance(mesh_size, bool)
    if mesh_size is not None and not (real and math.isfinite(mesh_size) and mesh_size > 0):
        raise InputError(f"mesh size must be a positive number, got {mesh_size!r}")
    if isinstance(max_it, bool) or not isinstance(max_it, int) or max_it <= 0:
        raise InputError(f"max-it must be a positive integer, got {max_it!r}")


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
) -> dict:
    """Mesh → MBO → TAO → singularities → files in ``out``; return the summary (all ranks).

    Collective over ``comm`` (default ``MPI.COMM_WORLD``). Raises :class:`InputError`
    (for a :class:`ufl_frames.geometry.GeometryError`, a bad parameter, an existing
    non-empty ``out``) on every rank, before anything is computed or written, when the
    input is unusable; other exceptions are bugs or failures and keep their type.
    PETSc options in the database (``-tao_type`` ...) are honoured; the defaults the
    solvers add to the database are removed afterwards.
    """
    init_petsc()
    from mpi4py import MPI
    from petsc4py import PETSc

    from ufl_frames import geometry as geometry_module
    from ufl_frames import io, solvers
    from ufl_frames.pipeline import FrameField

    comm = MPI.COMM_WORLD if comm is None else comm
    say = _printer(comm, quiet)
    start = time.perf_counter()
    user_options = PETSc.Options().getAll()
    geometry = str(geometry)
    out = default_output_folder(geometry) if out is None else Path(out)
    _check_parameters(mesh_size, max_it)
    check_output_folder(out, force, comm)
    size = "relative to the shape" if mesh_size is None else f"mesh size {mesh_size:g}"
    say(f"meshing {geometry} ({size}) ...")
    limit = {} if max_triangles is None else {"max_triangles": max_triangles}
    try:
        domain = geometry_module.build(comm, geometry, mesh_size, size_factor, **limit)
    except geometry_module.GeometryError as e:  # raised identically on every rank
        raise InputError(str(e)) from e
    for note in domain.notes:
        say(f"  note: {note}")
    say(f"  {domain.num_vertices} vertices, {domain.num_cells} triangles (mean edge "
        f"{domain.mesh_size:.3g}), {comm.size} process{'es' if comm.size > 1 else ''}")

    with options_scope():  # the solvers' defaults end with the run
        say("MBO initial field ...")
        field = FrameField.initial(
            domain, isotropic=isotropic, max_aspect=max_aspect,
            monitor=lambda level, tau, change: say(
                f"  level {level}: sqrt(tau) {math.sqrt(tau):.3g}, max change {change:.2e}"
            ),
        )
        tao_type = PETSc.Options().getString("tao_type", solvers.DEFAULT_OPTIONS["tao_type"])
        kind = "isotropic frames" if isotropic else "frames"
        say(f"solving ({kind}, TAO {tao_type}) ...")
        result = field.solve(
            pin_singularities=not free_singularities,
            max_it=max_it,
            monitor=lambda e: say(
                f"  it {e['it']:4d}  H {e['H']:.6e}  E {e['E']:.6e}  |grad| {e['gnorm']:.3e}"
                + (f"  ksp {e['ksp_its']}" if "ksp_its" in e else "")
            ),
        )
        max_it = PETSc.Options().getInt("tao_max_it", max_it)  # -tao_max_it wins
    converged = result.converged_reason.startswith("CONVERGED")
    say(f"{result.converged_reason} after {result.iterations} iterations "
        f"({result.wall_time_s:.2f} s): H {result.H_initial:.4e} -> {result.H_final:.4e}")
    if not converged and not quiet and comm.rank == 0:
        print(f"{PROG}: warning: TAO stopped with {result.converged_reason}", file=sys.stderr)

    say(f"singularities: {io.describe_singularities(field.singularities)}")
    index_check = field.index_theorem()  # also in the summary
    if not index_check["agrees"] and not quiet and comm.rank == 0:
        print(f"{PROG}: warning: the singularities' indices sum to {index_check['index_sum']:g}, "
              f"Poincaré–Hopf says {index_check['expected']:g} (Euler characteristic "
              f"{domain.euler_characteristic}, {index_check['corners']} corners): the boundary "
              "is too coarse for the field somewhere; try a smaller --mesh-size",
              file=sys.stderr)

    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
    comm.Barrier()
    files = field.write(out, label=Path(geometry).stem, tao_type=tao_type) + ["summary.json"]
    record = field.summary()
    summary = {
        "ufl_frames_version": __version__,
        "geometry": geometry,
        **{key: record.pop(key) for key in ("isotropic", "max_aspect", "pinned_singularities",
                                            "mesh_size", "requested_mesh_size")},
        "size_factor": float(size_factor),
        "loader_notes": list(domain.notes),
        "max_it": int(max_it),
        "num_processes": comm.size,
        "tao_type": tao_type,
        "petsc_options": user_options,
        **record,
        "total_time_s": comm.allreduce(time.perf_counter() - start, op=MPI.MAX),
        "files": files,
    }
    io.write_summary(out / "summary.json", summary, comm=comm)
    say(f"wrote {out}/: {', '.join(files)}")
    return summary


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


def _fail(message: str, status: int) -> int:
    """Report ``message`` once (rank 0) as one line on stderr; return ``status``."""
    if _rank() == 0:
        text = " ".join(str(message).split())
        print(f"{PROG}: error: {text}", file=sys.stderr, flush=True)
    return status


def main(argv: list[str] | None = None) -> int:
    """Run the ``ufl-frames`` command with ``argv`` (default ``sys.argv[1:]``); exit status."""
    argv = sys.argv[1:] if argv is None else [str(a) for a in argv]
    try:
        args, extras = build_parser().parse_known_args(argv)
        options = split_petsc_options(extras)
        if args.command is None:
            raise UsageError("missing command: use 'solve' or 'info' (see ufl-frames --help)")
    except UsageError as e:
        return _fail(str(e), 2)

    # PETSc reads its options now, before anything imports dolfinx (start-up options such
    # as -log_view work only so); called in-process, options_scope puts them in below.
    if not petsc_initialised():
        init_petsc([PROG, *_petsc_argv(options)])
    from mpi4py import MPI

    comm = MPI.COMM_WORLD
    if args.command == "info":
        return _info(comm)

    with options_scope(options):  # this run's options, removed afterwards
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
            )
        except InputError as e:  # raised on every rank alike (geometry, parameters, folder)
            return _fail(str(e), 1)
        except Exception:
            # Unexpected: keep the traceback. One rank failing alone would leave the others
            # waiting in a collective call, so abort the whole job.
            if comm.size > 1:
                import traceback

                traceback.print_exc()
                sys.stderr.flush()
                comm.Abort(1)
            raise
    return 0


if __name__ == "__main__":
    sys.exit(main())
