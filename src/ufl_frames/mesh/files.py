"""Geometry files: :func:`load`, and the screening of what it is given.

A Gmsh script ``.geo`` is run, then meshed in 2D; a mesh ``.msh`` is read as it is;
CAD ``.step``/``.stp``/``.brep`` is imported with OpenCASCADE, then meshed in 2D. What
real files contain is handled so that the frame field gets a conforming P1 triangle
mesh of the whole planar domain:

- points no triangle uses (circle centres, spline control points, free curves and
  points) are dropped;
- several surfaces form one domain: OpenCASCADE surfaces are fragmented first (shared
  curves become interior, overlapping faces are split), built-in ones made coherent;
  surfaces that still touch without sharing nodes are refused;
- requests for quadrilaterals (``Recombine``, transfinite or quasi-structured quad
  meshing, subdivision) and for second order are overridden: triangles are what the
  field needs; quadrilaterals in a ``.msh`` are split into two triangles each;
- second-order triangles of a ``.msh`` are split into four P1 triangles on their own
  nodes (curved boundaries keep their nodes); higher orders keep their corners;
- mesh size: see :func:`load` and :mod:`ufl_frames.mesh.meshing`;
- a ``.geo`` that would act outside the run (``Exit``, ``SystemCall``, ``Save``, ...:
  :func:`_check_geo_script`) is refused before Gmsh runs it, and a surface whose
  boundary curves cross (:func:`~ufl_frames.mesh.meshing.check_crossings`) before it is
  meshed;
- reading and meshing run in a child process, stopped after a time limit
  (:func:`mesh_time_limit`, :class:`~ufl_frames.mesh.domain.MeshTimeLimit`);
- only regular files (or links to one) are opened, and only up to a size a geometry can
  have (:func:`max_file_bytes`): a FIFO, a device (``/dev/zero``, ``/dev/urandom``) or a
  folder is refused before anything reads it (:func:`check_input_file`), also where a
  ``.geo`` includes or merges it.

The geometry must lie in one plane: a model in a plane other than z = const is rotated into
z = 0 and meshed there (:func:`_into_own_plane`, the frame in the notes and the domain's
``plane``, which takes the results back into the tilted plane), a ``.msh`` in one is read
in its own coordinates (the same); volumes and tetrahedra are rejected.
"""

import contextlib
import hashlib
import os
import re
import stat
import sys
from pathlib import Path

from ufl_frames.bootstrap import init_petsc

init_petsc()

import gmsh  # noqa: E402
import numpy as np  # noqa: E402
from mpi4py import MPI  # noqa: E402

from ufl_frames.mesh.arrays import plane_frame, record_plane, surfaces  # noqa: E402
from ufl_frames.mesh.distribute import create, verbose  # noqa: E402
from ufl_frames.mesh.domain import (  # noqa: E402
    Domain,
    GeometryError,
    check_mesh_size,
    check_positive,
    check_refinements,
    is_real,
    one_line,
)
from ufl_frames.mesh.meshing import MAX_TRIANGLES, Sizing, check_crossings, mesh_model  # noqa: E402

#: File extensions understood by :func:`load`, lower case.
GEO_EXTENSIONS = (".geo",)
MESH_EXTENSIONS = (".msh",)
CAD_EXTENSIONS = (".step", ".stp", ".brep")
#: Seconds :func:`load` lets Gmsh read and mesh a file with the default ``max_triangles``
#: (more in proportion for a larger one, :func:`mesh_time_limit`); then it is stopped.
MESH_TIME_LIMIT = 300.0

#: Largest ``.geo`` script read (and any file it includes), in bytes.
MAX_SCRIPT_BYTES = 64 * 2**20
#: Largest ``.step``/``.stp``/``.brep`` file read, in bytes.
MAX_CAD_BYTES = 1024 * 2**20
#: Bytes per triangle a ``.msh`` may hold: :func:`max_file_bytes` allows a mesh of
#: ``max_triangles`` triangles this large (ASCII MSH 4.1 with its nodes takes about 100).
MSH_BYTES_PER_TRIANGLE = 400

_GMSH_3D_NAMES = {4: "tetrahedra", 5: "hexahedra", 6: "prisms", 7: "pyramids"}


def mesh_time_limit(max_triangles: float = MAX_TRIANGLES) -> float:
    """The default time limit of :func:`load`: :data:`MESH_TIME_LIMIT` seconds, scaled up
    in proportion above the default ``max_triangles``."""
    return MESH_TIME_LIMIT * max(1.0, float(max_triangles) / MAX_TRIANGLES)


def load(
    comm: MPI.Comm,
    path,
    mesh_size: float | None = None,
    size_factor: float = 1.0,
    max_triangles: int = MAX_TRIANGLES,
    time_limit: float | None = None,
    refinements: int = 0,
    resolve_features: bool = False,
) -> Domain:
    """Domain from a ``.geo``, ``.msh``, ``.step``/``.stp`` or ``.brep`` file.

    The domain is all the file's surfaces, each a region; its physical groups, curves
    (boundary, interfaces, embedded) and points are kept on the domain. A ``.msh``
    is taken as it is: sizes do not apply. Boundaries whose curves cross (a curve loop
    through itself, a hole across the outline), on which Gmsh's meshing never ends, are
    refused before meshing.

    Args:
        comm: The communicator the mesh is distributed over (collective); only rank 0
            reads the file.
        path: The file.
        mesh_size: Absolute, in the file's units: caps the element size
            (``Mesh.MeshSizeMax``, set after a ``.geo`` has run, so it wins over the
            script's own value; finer point sizes are kept). None: relative to the
            shape, the file's own sizes (point sizes, size fields, ``Mesh.MeshSizeMax``)
            where it sets any, else the size that gives about
            :data:`~ufl_frames.mesh.meshing.AUTO_TRIANGLES` triangles.
        size_factor: Scales either size (< 1 refines).
        max_triangles: Sizes that would give more triangles (estimated from the area)
            are refused before meshing.
        time_limit: Reading and meshing run in a child process stopped after this many
            seconds, with :class:`~ufl_frames.mesh.domain.MeshTimeLimit` (default
            :func:`mesh_time_limit`; ``math.inf``: in this process, no limit).
        refinements: As for :func:`~ufl_frames.mesh.build` (not for a ``.msh``).
        resolve_features: With ``mesh_size``, still cap the size where the shape is thin
            or tightly curved (:mod:`~ufl_frames.mesh.feature_size`), as without it: for
            a size taken from the quads', not one the user asked for.

    Returns:
        The distributed domain.

    Raises:
        GeometryError: On every rank, with a one-line message.
    """
    path = Path(path)
    h = None if mesh_size is None else check_mesh_size(mesh_size)
    refinements = check_refinements(refinements)
    factor = check_positive("size_factor", size_factor)
    limit = check_positive("max_triangles", max_triangles)
    seconds = mesh_time_limit(limit) if time_limit is None else time_limit
    if not (is_real(seconds) and seconds > 0):  # inf allowed: no limit
        raise GeometryError(f"time_limit must be a positive number of seconds, got {seconds!r}")
    ext = path.suffix.lower()
    known = GEO_EXTENSIONS + MESH_EXTENSIONS + CAD_EXTENSIONS
    if ext not in known:
        raise GeometryError(
            f"unsupported geometry file extension {path.suffix!r} for {str(path)!r}: "
            f"use one of {', '.join(known)}"
        )
    source = str(path)

    def make(notes):  # on rank 0 only: the file need not be visible to the other ranks
        check_input_file(path, limit)
        if ext in MESH_EXTENSIONS:
            _check_msh_header(path)
        if ext in GEO_EXTENSIONS:
            _check_geo_script(path)
        _merge(path, quiet=ext in CAD_EXTENSIONS)
        if ext in MESH_EXTENSIONS:
            if refinements:
                raise GeometryError(f"{source!r} is a mesh: it cannot be made by refinement")
            _check_no_3d_mesh(source)
            if not surfaces():
                raise GeometryError(f"{source!r} holds no 2D surface mesh")
            return None
        if gmsh.model.getEntities(3):
            raise GeometryError(
                f"{source!r} defines volumes: only planar 2D geometries are supported"
            )
        if not surfaces():
            raise GeometryError(f"{source!r} defines no 2D surface")
        _into_own_plane(source, notes)
        check_crossings(source)
        return mesh_model(Sizing(h, factor, limit, refinements, resolve_features), notes)

    return create(comm, make, source, cad=ext not in MESH_EXTENSIONS, time_limit=seconds)


def max_file_bytes(path, max_triangles: float = MAX_TRIANGLES) -> int:
    """The largest geometry file :func:`check_input_file` lets through, by its kind: a
    ``.msh`` :data:`MSH_BYTES_PER_TRIANGLE` bytes per triangle allowed (at least
    :data:`MAX_SCRIPT_BYTES`), a CAD file :data:`MAX_CAD_BYTES`, anything else (a
    script) :data:`MAX_SCRIPT_BYTES`."""
    ext = Path(path).suffix.lower()
    if ext in MESH_EXTENSIONS:
        return int(max(MAX_SCRIPT_BYTES, MSH_BYTES_PER_TRIANGLE * float(max_triangles)))
    return MAX_CAD_BYTES if ext in CAD_EXTENSIONS else MAX_SCRIPT_BYTES


def _kind_of(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def check_input_file(path, max_triangles: float = MAX_TRIANGLES, what: str = "geometry file"):
    """Raise :class:`GeometryError` unless ``path`` is a regular file (or a link to one)
    no larger than :func:`max_file_bytes`; nothing is opened (a FIFO would block, a
    device be read without end).

    Args:
        path: the file.
        max_triangles: as for :func:`load` (bounds a ``.msh``).
        what: what the file is, for the message.

    Returns:
        The file's size in bytes.
    """
    path = Path(path)
    try:
        info = path.stat()
    except FileNotFoundError:
        raise GeometryError(f"{what} not found: {str(path)!r}") from None
    except OSError as e:
        raise GeometryError(f"cannot read {str(path)!r}: {one_line(e)}") from None
    if not stat.S_ISREG(info.st_mode):
        raise GeometryError(f"{what} {str(path)!r} is {_kind_of(info.st_mode)}: give a "
                            "regular file")
    bound = max_file_bytes(path, max_triangles)
    if info.st_size > bound:
        raise GeometryError(
            f"{what} {str(path)!r} has {info.st_size} bytes, more than a geometry of at most "
            f"{max_triangles:.3g} triangles can need ({bound} bytes): not read")
    return info.st_size


def _read_regular(path: Path, limit: int) -> bytes:
    """At most ``limit`` bytes of ``path``, opened only if it is a regular file (checked on
    the open descriptor, without blocking on a FIFO)."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    with os.fdopen(fd, "rb") as f:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise GeometryError(f"{str(path)!r} is {_kind_of(mode)}: give a regular file")
        return f.read(limit)


def file_digest(path, max_triangles: float = MAX_TRIANGLES) -> str | None:
    """``"sha256:<hex>"`` of a geometry file, or None where :func:`check_input_file`
    refuses it or it cannot be read (loading it reports why)."""
    try:
        size = check_input_file(path, max_triangles)
        digest = hashlib.sha256()
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
        with os.fdopen(fd, "rb") as f:
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                return None
            while size >= 0 and (chunk := f.read(min(2**20, size + 1))):
                digest.update(chunk)
                size -= len(chunk)
        return "sha256:" + digest.hexdigest()
    except (GeometryError, OSError):
        return None


def _into_own_plane(source: str, notes: list[str]) -> None:
    """Rotate a model that lies in a plane other than z = const into z = 0 (its points
    and points along its curves, :func:`~ufl_frames.mesh.arrays.plane_frame`): its mesh
    coordinates are then (u, v) along the plane's axes e1, e2 from its origin o, said in
    ``notes`` and kept (:func:`~ufl_frames.mesh.arrays.record_plane`, the domain's
    ``plane``). Raises :class:`GeometryError` where the model lies in no plane."""
    samples = [np.asarray(gmsh.model.getValue(0, tag, []), dtype=float)
               for _, tag in gmsh.model.getEntities(0)]
    for _, curve in gmsh.model.getEntities(1):
        lo, hi = (float(v[0]) for v in gmsh.model.getParametrizationBounds(1, curve))
        samples.append(np.asarray(gmsh.model.getValue(1, curve, np.linspace(lo, hi, 9)),
                                  dtype=float))
    xyz = np.concatenate([p.reshape(-1, 3) for p in samples]) if samples else np.zeros((0, 3))
    frame = plane_frame(xyz, source)
    if frame is None:
        return
    origin, e1, e2 = frame
    normal = np.cross(e1, e2)
    occ = gmsh.model.occ.getEntities(2)
    if occ:  # the surfaces (their curves and points follow) and what bounds none of them
        bounded = {(1, abs(t)) for _, t in gmsh.model.getBoundary(occ, combined=False,
                                                                   oriented=False)}
        free = [e for e in gmsh.model.occ.getEntities(1) if e not in bounded]
        bounded |= {(0, abs(t)) for _, t in gmsh.model.getBoundary(
            occ + free, combined=False, oriented=False, recursive=True)}
        free += [e for e in gmsh.model.occ.getEntities(0) if e not in bounded]
        rows = np.stack([e1, e2, normal])  # p -> R (p - o)
        matrix = np.concatenate([rows, -(rows @ origin)[:, None]], axis=1)
        gmsh.model.occ.affineTransform(occ + free, matrix.ravel().tolist())
        gmsh.model.occ.synchronize()
    if gmsh.model.getEntities(0) and not occ:
        points = gmsh.model.getEntities(0)  # the built-in kernel's curves follow its points
        geo = gmsh.model.geo
        geo.translate(points, *(-origin))
        # normal -> z about the horizontal axis e1, then e1 -> x about z
        angle = float(np.arccos(np.clip(normal[2], -1.0, 1.0)))
        if angle > 0:
            geo.rotate(points, 0, 0, 0, *e1, -angle)
        geo.rotate(points, 0, 0, 0, 0, 0, 1, -float(np.arctan2(e1[1], e1[0])))
        geo.synchronize()
    check = [np.asarray(gmsh.model.getValue(0, tag, []))[2] for _, tag in gmsh.model.getEntities(0)]
    scale = max(float(np.abs(xyz).max()), 1e-300)
    if check and float(np.ptp(check)) > 1e-8 * scale:
        raise GeometryError(f"{source!r} lies in a tilted plane that could not be rotated into "
                            "z = 0 (mixed CAD kernels?)")
    record_plane(frame)
    notes.append("the geometry lies in a tilted plane: meshed in its own coordinates "
                 f"(u, v) = ((p - o)·e1, (p - o)·e2), o = {_vector(origin)}, "
                 f"e1 = {_vector(e1)}, e2 = {_vector(e2)}")


def _vector(v) -> str:
    return "(" + ", ".join(f"{float(c):.6g}" for c in v) + ")"


def _check_msh_header(path: Path) -> None:
    try:
        head = _read_regular(path, 64).lstrip()
    except OSError as e:
        raise GeometryError(f"cannot read {str(path)!r}: {one_line(e)}") from None
    if not head.startswith((b"$MeshFormat", b"$NOD", b"$NOE")):
        raise GeometryError(f"cannot read {str(path)!r}: not a Gmsh mesh (no $MeshFormat header)")


#: Comments and strings of a Gmsh script (``//`` to the end of the line, ``/* */``, "...").
_GEO_NOISE = re.compile(r'//[^\n]*|/\*.*?(?:\*/|\Z)|"(?:[^"\\]|\\.)*"?', re.DOTALL)
#: Scripts a script runs: ``Include "file"``, and ``Merge "file.geo"``.
_GEO_INCLUDE = re.compile(r'\b(Include|Merge)\s*"((?:[^"\\]|\\.)*)"')
_GEO_COMPUTED_INCLUDE = re.compile(r'(?<![.\w])Include\s*(?!["\s])')
#: Script commands refused (Gmsh 4.15 runs each of them): what each would do.
_GEO_REFUSED = {
    "Exit": "would end the program inside Gmsh",
    "SystemCall": "runs a program",
    "NonBlockingSystemCall": "runs a program",
    "System": "runs a program",
    "OnelabRun": "runs a program",
    "Save": "writes a file",
    "Print": "writes a file",
    "CreateDir": "creates a folder",
}
_GEO_COMMAND = re.compile(r"(?<![.\w])(" + "|".join(_GEO_REFUSED) + r")\b")
_GEO_PRINTF = re.compile(r"(?<![.\w])Printf\s*\(")


def _printf_redirect(code: str, start: int) -> bool:
    """Whether the ``Printf(`` call whose ``(`` ends at ``start`` is followed by ``>``
    (``> "file"``, ``>> "file"``: written to a file)."""
    depth, i = 1, start
    while i < len(code) and depth:
        depth += {"(": 1, ")": -1}.get(code[i], 0)
        i += 1
    return code[i:].lstrip().startswith(">")


def _check_geo_script(path: Path, seen: set | None = None) -> None:
    """Refuse a ``.geo`` (or a script it ``Include``s or ``Merge``s) that would act
    outside the run: ``Exit`` (Gmsh would end the whole process, with status 0 and
    nothing done), programs (``SystemCall``, ``System``, ``OnelabRun``...) and files or
    folders written (``Save``, ``Print``, ``Printf(...) > "file"``, ``CreateDir``); also
    an ``Include`` of a computed name, which cannot be checked."""
    seen = set() if seen is None else seen
    key = path.resolve()
    if key in seen or len(seen) > 100:
        return
    seen.add(key)
    check_input_file(path, what="script")
    try:
        text = _read_regular(path, MAX_SCRIPT_BYTES).decode("utf-8", errors="replace")
    except OSError as e:
        raise GeometryError(f"cannot read {str(path)!r}: {one_line(e)}") from None

    def blank(m):  # keeps the line numbers
        kept = "\n" * m.group(0).count("\n")
        return f'""{kept}' if m.group(0).startswith('"') else f" {kept}"

    code = _GEO_NOISE.sub(blank, text)
    found = [(m.start(), m.group(1), _GEO_REFUSED[m.group(1)])
             for m in _GEO_COMMAND.finditer(code)]
    found += [(m.start(), 'Printf(...) > "file"', "writes a file")
              for m in _GEO_PRINTF.finditer(code) if _printf_redirect(code, m.end())]
    found += [(m.start(), "Include with a computed file name", "cannot be checked")
              for m in _GEO_COMPUTED_INCLUDE.finditer(code)]
    if found:
        start, name, what = min(found)
        line = code.count("\n", 0, start) + 1
        raise GeometryError(f"{str(path)!r} line {line} calls {name}, which {what}: remove it")
    no_comments = re.sub(r'//[^\n]*|/\*.*?(?:\*/|\Z)', " ", text, flags=re.DOTALL)
    for command, name in _GEO_INCLUDE.findall(no_comments):
        child = path.parent / name
        if not (child.exists() or child.is_symlink()):
            continue  # Gmsh reports it
        if command == "Include" or child.suffix.lower() in GEO_EXTENSIONS:
            _check_geo_script(child, seen)
        else:
            check_input_file(child, what=f"{command} file")


def _merge(path: Path, quiet: bool) -> None:
    """``gmsh.merge`` that reports the file's errors as :class:`GeometryError`.

    With ``General.AbortOnError`` at its API default (2) Gmsh throws at the first
    syntax error in a script and leaves the rest of the file in its lexer, which
    then breaks every later parse in the process. So errors are not thrown here but
    collected from the logger (a logger started by the caller is stopped).
    """
    abort = gmsh.option.getNumber("General.AbortOnError")
    gmsh.option.setNumber("General.AbortOnError", 0)
    gmsh.logger.start()
    try:
        with _silenced(quiet and not verbose()):
            gmsh.merge(str(path))
        errors = [m for m in gmsh.logger.get() if m.startswith("Error")]
    except Exception as e:
        errors = [one_line(e)]
    finally:
        gmsh.logger.stop()
        gmsh.option.setNumber("General.AbortOnError", abort)
    if errors:
        message = errors[0].removeprefix("Error:").strip()
        raise GeometryError(f"cannot read {str(path)!r}: {one_line(message)}")
    if not gmsh.model.getEntities():
        raise GeometryError(f"cannot read {str(path)!r}: no geometry found in the file")


@contextlib.contextmanager
def _silenced(active: bool):
    """Send the process's stdout and stderr to /dev/null (OpenCASCADE prints directly)."""
    if not active:
        yield
        return
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, devnull):
            os.close(fd)


def _check_no_3d_mesh(source: str) -> None:
    types = set()
    for _, tag in gmsh.model.getEntities(3):
        types.update(int(t) for t in gmsh.model.mesh.getElements(3, tag)[0])
    if types:
        names = ", ".join(sorted(_GMSH_3D_NAMES.get(t, f"type {t}") for t in types))
        raise GeometryError(
            f"{source!r} is a 3D mesh ({names}): only planar triangle meshes are supported"
        )
