"""The ``ufl-frames`` command: integrable frame field on a geometry, from the shell.

::

    ufl-frames solve GEOMETRY [--isotropic] [--mesh-size H] [--max-it N]
                              [--mesh-time-limit SECONDS] [--out DIR] [--force]
                              [--resume DIR] [-q] [PETSc options ...]
    ufl-frames mesh GEOMETRY [--out DIR] [--quad-size S | --quads N] [--force]
                             [--mesh-time-limit SECONDS] [-q] [PETSc options ...]
    ufl-frames info
    ufl-frames --version

``mesh`` is the mesher's command: geometry in, quad mesh out (``quads.msh``,
``quads.vtu``, ``quads.png``, ``summary.json``), with the integrable isotropic field
(the conformal scale) and the quads' boundary nodes on the CAD curves
(:meth:`ufl_frames.app.run.RunConfig.for_mesh`); the same errors and statuses as ``solve``.

GEOMETRY is ``annulus``, ``piano`` or a ``.geo``/``.msh``/``.step``/``.brep`` file
(:func:`ufl_frames.mesh.build`). The run is: mesh → MBO initial field
(:mod:`ufl_frames.solvers.mbo`) → TAO minimisation of H (:mod:`ufl_frames.solvers`) →
singularities → results in DIR (default ``out_<geometry stem>``):

* ``summary.json`` — energies, iterations, TAO's converged reason, mesh size and
  counts, singularities, history (written last: its presence means a complete run);
* ``frames.bp`` — the field for ParaView (``frames.xdmf`` without ADIOS2) and the
  same as ``frames.pvd`` (ASCII VTU, readable back with :func:`ufl_frames.output.read_vtk`),
  see :func:`ufl_frames.output.write_field`;
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
  write error); a stage asked for (``--param``, ``--quads``) that fails, after the field
  and the summary are written without it;
* 130, interrupted (SIGINT, Ctrl-C, or SIGTERM): at the next MBO level or TAO iteration,
  or within :data:`ufl_frames.interrupts.INTERRUPT_GRACE_S` seconds, whatever runs
  (meshing at once).

Nothing is written unless the run completes: the results go to a hidden folder next to
DIR, renamed into place at the end (:class:`ufl_frames.output.OutputFolder`). The one
exception is the TAO solve's checkpoint, ``DIR/checkpoint/`` (:mod:`ufl_frames.checkpoint`):
kept by an interrupted run, for ``--resume DIR``; removed when the run completes or fails.
Under ``mpirun`` an error every rank meets alike is reported once by rank 0 and every rank
exits; one that a rank meets alone is printed by that rank, which then aborts the job
(the others would wait for it forever).
"""

import argparse
import math
import os
import sys
import time
import traceback

from ufl_frames import __version__, interrupts
from ufl_frames.app.failures import DEBUG_VARIABLE, InputError, UsageError, failure_status
from ufl_frames.app.run import DEFAULT_MAX_IT, DEFAULT_MESH_SIZE, PROG, RunConfig, run
from ufl_frames.app.volume import run_volume
from ufl_frames.bootstrap import init_petsc, options_scope, petsc_initialised
from ufl_frames.frames2d.aspect import DEFAULT_MAX_ASPECT
from ufl_frames.petsc_options import MAX_INT, petsc_option_problem

__all__ = ["build_parser", "check_petsc_options", "main", "split_petsc_options", "versions"]

#: Under MPI, seconds a rank that failed waits for the others to fail too (an error
#: every rank meets) before it aborts the job (an error of its own).
AGREEMENT_TIMEOUT_S = 10.0


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
    from ufl_frames.mesh.hierarchy import MAX_LEVELS

    if text == "auto":
        return text
    value = _positive_int(text)
    if value > MAX_LEVELS:
        raise argparse.ArgumentTypeError(f"must be 'auto' or at most {MAX_LEVELS}, got {text!r}")
    return value


def _size(text: str) -> str:
    """``--size``: 'file', 'uniform', 'none' or a size expression (checked here)."""
    from ufl_frames.mesh.sizes import SIZE_WORDS, SizeExpressionError, parse_size_expression

    if text.strip() in SIZE_WORDS:
        return text.strip()
    try:
        parse_size_expression(text)
    except SizeExpressionError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return text


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
    """The parser of the ``ufl-frames`` command line (its errors raise :class:`UsageError`)."""
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
    _add_solve_arguments(solve)
    _add_mesh_command(commands)
    commands.add_parser("info", help="print the versions of the libraries in use",
                        description="Print the versions of ufl_frames, DOLFINx, PETSc, "
                        "MPI, Gmsh and friends.")
    return parser


def _add_solve_arguments(solve: argparse.ArgumentParser) -> None:
    """The arguments of ``solve``: those of :class:`~ufl_frames.app.run.RunConfig`."""
    solve.add_argument("geometry", metavar="GEOMETRY",
                       help="'annulus', 'piano' (2D), 'box', 'cylinder', 'ball' (3D) or a "
                       ".geo/.msh/.step/.stp/.brep file (a file with volumes: 3D)")
    solve.add_argument("--dim", type=int, choices=(2, 3), default=None,
                       help="2D (surfaces) or 3D (volumes: the smooth boundary-aligned MBO "
                       "frame field and its singular graph); default: from the geometry")
    solve.add_argument("--isotropic", action="store_true",
                       help="isotropic frames (l1 = l2, crosses); default: general frames")
    solve.add_argument("--mesh-size", type=_positive_float, default=DEFAULT_MESH_SIZE,
                       metavar="H", help="largest element size, in the geometry's units "
                       "(default: relative to the shape: 0.05 for the built-in shapes, a "
                       "file's own sizes where it sets any, else about 2000 triangles, "
                       "either made finer to 3 elements across thin parts and 12 per turn "
                       "of curved boundaries; with --quads --quad-size S, S; ignored for "
                       ".msh files)")
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
                       "'quads' in summary.json; the quads' boundary and curve nodes are "
                       "moved onto the CAD curves, as by the mesh command")
    solve.add_argument("--quad-size", type=_positive_float, default=None, metavar="S",
                       help="the quads' mean edge length (default: with --quads the triangles' "
                       "mean edge length; with --param only, about one quad per 8 triangles)")
    solve.add_argument("--size", type=_size, default=None, metavar="EXPR",
                       help="the quads' size h(x, y) that non-isotropic frames follow, up to "
                       "a global factor: a NumPy expression in x and y (e.g. "
                       "\"0.02 + 0.1*hypot(x, y)\"), 'file' (the file's own point sizes, "
                       "MeshSize and size fields, as Gmsh evaluates them), 'uniform', or "
                       "'none' (no size target: the degenerate problem). Default: the file's "
                       "sizes where it sets any, else uniform")
    solve.add_argument("--size-weight", type=_non_negative_float, default=None, metavar="W",
                       help="w of the sized energy H + w H_s M (default 0.3)")
    solve.add_argument("--quad-count", type=_positive_int, default=None, metavar="N",
                       help="with --quads: about N quads (instead of --quad-size)")
    solve.add_argument("--max-quads", type=_positive_float, default=None, metavar="N",
                       help="refuse, before the solve, a --quad-size estimated to give more "
                       "quads (area / size^2; default 2e6)")
    solve.add_argument("--max-memory", type=_positive_float, default=None, metavar="GIB",
                       help="refuse, before the solve, a mesh and quads estimated to need "
                       "more memory (GiB; default: the memory available)")
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


def _add_mesh_command(commands) -> None:
    """``mesh``: geometry in, quad mesh out (:meth:`RunConfig.for_mesh`)."""
    mesh = commands.add_parser(
        "mesh",
        help="make a quad mesh of a geometry (quads.msh, quads.vtu, quads.png)",
        description="Mesh GEOMETRY with quadrilaterals: the integrable isotropic frame field "
        "(its conformal scale), its seamless map and quads, their boundary nodes moved onto "
        "the CAD curves; writes quads.msh (Gmsh MSH 4.1), quads.vtu, quads.png and "
        "summary.json to the output folder.",
    )
    mesh.add_argument("geometry", metavar="GEOMETRY",
                      help="'annulus', 'piano' or a .geo/.msh/.step/.stp/.brep file")
    size = mesh.add_mutually_exclusive_group()
    size.add_argument("--quad-size", type=_positive_float, default=None, metavar="S",
                      help="the quads' mean edge length, in the geometry's units (also the "
                      "triangles' size; default: about 2000 triangles, or the file's own "
                      "sizes, and quads of their mean edge length)")
    size.add_argument("--quads", dest="quad_count", type=_positive_int, default=None,
                      metavar="N", help="about N quads: quad size sqrt(area / N)")
    mesh.add_argument("--size", type=_size, default=None, metavar="EXPR",
                      help="quads graded by a size h(x, y): a NumPy expression in x and y "
                      "(e.g. \"0.02 + 0.1*hypot(x, y)\") or 'file' (the file's point sizes, "
                      "MeshSize and size fields, as Gmsh evaluates them); the field is then "
                      "the sized non-isotropic one. Default: uniform quads of the "
                      "integrable isotropic field")
    mesh.add_argument("--out", metavar="DIR", default=None,
                      help="output folder (default out_<geometry stem>); must not exist "
                      "or be empty unless --force")
    mesh.add_argument("--force", action="store_true",
                      help="write into an existing non-empty output folder, replacing files")
    mesh.add_argument("--mesh-time-limit", type=_seconds, default=None, metavar="SECONDS",
                      help="stop reading and meshing a geometry file after this many "
                      "seconds (default 300; 'inf' for none)")
    mesh.add_argument("-q", "--quiet", action="store_true", help="no progress output")


def _mesh_config(args) -> RunConfig:
    """The :class:`RunConfig` of parsed ``mesh`` arguments."""
    return RunConfig.for_mesh(args.geometry, quad_size=args.quad_size,
                              quad_count=args.quad_count, size=args.size, out=args.out,
                              force=args.force,
                              mesh_time_limit=args.mesh_time_limit, quiet=args.quiet)


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


#: PETSc options read by PETSc itself, not by an object of the run: never "unused".
_PETSC_OWN_OPTIONS = ("help", "options_left", "log_view", "malloc_debug", "info")


def _warn_unused(options, comm, quiet: bool) -> None:
    """Warn (rank 0) about the command line's PETSc options no solver of the run read:
    misspelt, or for a solver the run does not make (PETSc's ``-options_left``)."""
    from petsc4py import PETSc

    db = PETSc.Options()
    unused = [f"-{name}" for name, _ in options
              if name not in _PETSC_OWN_OPTIONS and not db.used(name)]
    if unused and not quiet and comm.rank == 0:
        print(f"{PROG}: warning: PETSc option{'s' if len(unused) > 1 else ''} "
              f"{', '.join(dict.fromkeys(unused))} {'were' if len(unused) > 1 else 'was'} not "
              "used by any solver of the run (misspelt?)", file=sys.stderr, flush=True)


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
    status, message, expected = failure_status(exc)
    if _debug():
        traceback.print_exception(exc, file=sys.stderr)
    if comm.size == 1 or _all_failed(agreement, AGREEMENT_TIMEOUT_S):
        if comm.rank == 0:
            _print_error(message)
        return status
    _print_error(f"{message} (on rank {comm.rank} alone: aborting the job)")
    comm.Abort(status)
    return status  # not reached


def _is_volume(args, comm) -> bool:
    """Whether ``solve`` runs the 3D path: ``--dim 3``, a 3D built-in's name, or a file
    that defines volumes (rank 0 looks; collective). ``--dim 2`` keeps the 2D path."""
    from ufl_frames.app.volume import BUILTINS, defines_volumes
    from ufl_frames.mesh import KNOWN_GEOMETRIES

    if args.dim == 2:
        return False
    if args.geometry in BUILTINS:
        return True
    if args.geometry in KNOWN_GEOMETRIES:
        if args.dim == 3:
            raise InputError(f"{args.geometry!r} is a 2D shape: the 3D built-ins are "
                             f"{', '.join(sorted(BUILTINS))}")
        return False
    if args.dim == 3:
        return True
    found = None
    if comm.rank == 0:
        try:
            found = defines_volumes(args.geometry, getattr(args, "mesh_time_limit", None))
        except Exception:  # the 2D loader says what is wrong with the file
            found = False
    return bool(comm.bcast(found, root=0))


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
        # PETSc's -help is not argparse's -h with the value "elp": PETSc's, for the run.
        petsc_help = [("help", None)] if "-help" in argv else []
        argv = [a for a in argv if a != "-help"]
        args, extras = build_parser().parse_known_args(argv)
        options = split_petsc_options(extras) + petsc_help
        if args.command is None:
            raise UsageError("missing command: use 'solve', 'mesh' or 'info' (see ufl-frames "
                             "--help)")
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
                    if args.command == "solve" and _is_volume(args, comm):
                        run_volume(RunConfig.from_args(args), comm=comm)
                    else:
                        run(_mesh_config(args) if args.command == "mesh"
                            else RunConfig.from_args(args), comm=comm)
                    _warn_unused(options, comm, args.quiet)
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
