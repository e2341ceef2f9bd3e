r"""Planar triangle meshes for frame-field computations, built or read with Gmsh.

Built-in geometries (note §4, Fig. 1):

- :func:`annulus`: the ring :math:`r_i \le |x| \le r_o` (default 0.5 and 1, area
  :math:`3\pi/4`). A boundary-aligned cross field on it has no singularity.
- :func:`piano`: a grand-piano outline, 2 × 1.2, whose smooth boundary-aligned cross
  field has exactly one +1/4 singularity in its left part and one −1/4 in its right
  part (the note's second test case; its exact shape is not given, this one is ours).

  Counter-clockwise from the origin: the straight keyboard (0, 0)–(2, 0); the straight
  treble cheek (2, 0)–(2, 0.6); the concave bentside, a quarter circle of radius 0.6
  centred at (2, 1.2) from (2, 0.6) to (1.4, 1.2); the straight top (1.4, 1.2)–(0.8, 1.2);
  the convex tail, a quarter circle of radius 0.8 centred at (0.8, 0.4) from (0.8, 1.2)
  to (0, 0.4), tangent to the top and to the straight bass side (0, 0.4)–(0, 0).

  The four corners ((0, 0), (2, 0), (2, 0.6), (1.4, 1.2)) are right angles, so the
  interior indices sum to 1 − Σ_corners (2 − k_c)/4 = 0 (corner angles k_c·90°). The
  tail turns the boundary by +90° without a corner, which puts a +1/4 singularity
  under it, near (0.41, 0.79); the bentside turns it by −90°, which puts a −1/4 one
  beside it, near (1.43, 0.63) (harmonic 4θ field; ``meshes/README.md``).

Files (:func:`load`): a Gmsh script ``.geo`` (run, then meshed in 2D), a mesh ``.msh``
(read as is; ``mesh_size`` is ignored) or CAD ``.step``/``.stp``/``.brep`` (imported
with OpenCASCADE, then meshed in 2D). The geometry must lie in a plane z = const;
volumes, tetrahedra and quadrilaterals are rejected.

Every mesh returned is two-dimensional (``gdim = 2``), made of P1 triangles, and
distributed over ``comm``: Gmsh runs on rank 0 only. Errors are raised on every rank
as :class:`GeometryError` with a one-line message. Gmsh is finalised afterwards unless
the caller had initialised it (its current model and the options touched here are then
restored). Gmsh prints nothing unless the environment variable
``UFL_FRAMES_GMSH_VERBOSE`` is set (to anything but ``""``/``0``).
"""

import contextlib
import math
import numbers
import os
import sys
from pathlib import Path

from ufl_frames.bootstrap import init_petsc

init_petsc()

import dolfinx  # noqa: E402
import dolfinx.io.gmsh  # noqa: E402
import gmsh  # noqa: E402
from mpi4py import MPI  # noqa: E402

__all__ = ["GeometryError", "KNOWN_GEOMETRIES", "annulus", "build", "load", "piano"]

#: Physical-group tags put on every mesh handed to DOLFINx.
DOMAIN_TAG = 1
BOUNDARY_TAG = 2

#: File extensions understood by :func:`load`, lower case.
GEO_EXTENSIONS = (".geo",)
MESH_EXTENSIONS = (".msh",)
CAD_EXTENSIONS = (".step", ".stp", ".brep")

# Piano outline (see module docstring).
PIANO_WIDTH = 2.0
PIANO_HEIGHT = 1.2
PIANO_CONVEX_RADIUS = 0.8  # the rounded tail, top left
PIANO_CONCAVE_RADIUS = 0.6  # the bentside, top right

_TRIANGLE = 2  # Gmsh element types
_QUADRANGLE = 3
_GMSH_3D_NAMES = {4: "tetrahedra", 5: "hexahedra", 6: "prisms", 7: "pyramids"}


class GeometryError(ValueError):
    """A geometry could not be built, read or meshed (one-line message)."""


# --- public builders ------------------------------------------------------------


def annulus(
    comm: MPI.Comm, mesh_size: float = 0.05, r_inner: float = 0.5, r_outer: float = 1.0
) -> dolfinx.mesh.Mesh:
    """Triangle mesh of the annulus r_inner ≤ |x| ≤ r_outer centred at the origin."""
    h = _check_mesh_size(mesh_size)
    for name, r in (("r_inner", r_inner), ("r_outer", r_outer)):
        if not _is_real(r) or not math.isfinite(r) or r <= 0:
            raise GeometryError(f"{name} must be a positive finite number, got {r!r}")
    if not r_inner < r_outer:
        raise GeometryError(f"r_inner must be smaller than r_outer, got {r_inner} >= {r_outer}")

    def make():
        occ = gmsh.model.occ
        outer = occ.addDisk(0.0, 0.0, 0.0, r_outer, r_outer)
        inner = occ.addDisk(0.0, 0.0, 0.0, r_inner, r_inner)
        occ.cut([(2, outer)], [(2, inner)])
        occ.synchronize()
        _mesh_2d(h)

    return _create(comm, make)


def piano(comm: MPI.Comm, mesh_size: float = 0.05) -> dolfinx.mesh.Mesh:
    """Triangle mesh of the 'piano' outline (module docstring, ``meshes/piano.geo``)."""
    h = _check_mesh_size(mesh_size)

    def make():
        occ = gmsh.model.occ
        pts = [occ.addPoint(x, y, 0.0) for x, y in piano_points()]
        p_bass, p_treble, p_cheek, p_top_right, p_top_left, p_tail, c_concave, c_convex = pts
        curves = [
            occ.addLine(p_bass, p_treble),  # keyboard
            occ.addLine(p_treble, p_cheek),  # treble cheek
            occ.addCircleArc(p_cheek, c_concave, p_top_right),  # concave bentside
            occ.addLine(p_top_right, p_top_left),  # top
            occ.addCircleArc(p_top_left, c_convex, p_tail),  # convex tail
            occ.addLine(p_tail, p_bass),  # bass side
        ]
        loop = occ.addCurveLoop(curves)
        occ.addPlaneSurface([loop])
        occ.remove([(0, c_concave), (0, c_convex)])
        occ.synchronize()
        _mesh_2d(h)

    return _create(comm, make)


def piano_points() -> list[tuple[float, float]]:
    """The points of the piano outline: its six boundary vertices in counter-clockwise
    order from the origin, then the centres of the concave and the convex arc."""
    w, top = PIANO_WIDTH, PIANO_HEIGHT
    r1, r2 = PIANO_CONCAVE_RADIUS, PIANO_CONVEX_RADIUS
    return [
        (0.0, 0.0),
        (w, 0.0),
        (w, top - r1),
        (w - r1, top),
        (r2, top),
        (0.0, top - r2),
        (w, top),
        (r2, top - r2),
    ]


def piano_area() -> float:
    """Exact area of the piano outline."""
    w, top = PIANO_WIDTH, PIANO_HEIGHT
    r1, r2 = PIANO_CONCAVE_RADIUS, PIANO_CONVEX_RADIUS
    # The rectangle less a quarter disc at the top right and the corner piece outside
    # the rounded tail at the top left.
    return w * top - r1 * r1 * math.pi / 4 - r2 * r2 * (1 - math.pi / 4)


def piano_perimeter() -> float:
    """Exact boundary length of the piano outline."""
    w, top = PIANO_WIDTH, PIANO_HEIGHT
    r1, r2 = PIANO_CONCAVE_RADIUS, PIANO_CONVEX_RADIUS
    return 2 * w + 2 * top - 2 * (r1 + r2) + math.pi / 2 * (r1 + r2)


def load(comm: MPI.Comm, path, mesh_size: float = 0.05) -> dolfinx.mesh.Mesh:
    """Triangle mesh from a ``.geo``, ``.msh``, ``.step``/``.stp`` or ``.brep`` file.

    ``mesh_size`` caps the element size (``Mesh.MeshSizeMax``, set after a ``.geo``
    has run, so it wins over the script's own value; finer point sizes are kept). It
    is ignored for ``.msh`` files, which are taken as they are (higher-order
    triangles are reduced to P1). Physical groups in the file are replaced by one
    for all surfaces and one for their boundary curves.
    """
    path = Path(path)
    h = _check_mesh_size(mesh_size)
    ext = path.suffix.lower()
    known = GEO_EXTENSIONS + MESH_EXTENSIONS + CAD_EXTENSIONS
    if ext not in known:
        raise GeometryError(
            f"unsupported geometry file extension {path.suffix!r} for {str(path)!r}: "
            f"use one of {', '.join(known)}"
        )

    def make():  # on rank 0 only: the file need not be visible to the other ranks
        if not path.is_file():
            raise GeometryError(f"geometry file not found: {str(path)!r}")
        if ext in MESH_EXTENSIONS:
            _check_msh_header(path)
        _merge(path, quiet=ext in CAD_EXTENSIONS)
        if ext in MESH_EXTENSIONS:
            _check_no_3d_mesh(path)
            if not _surfaces():
                raise GeometryError(f"{str(path)!r} holds no 2D surface mesh")
        else:
            if gmsh.model.getEntities(3):
                raise GeometryError(
                    f"{str(path)!r} defines volumes: only planar 2D geometries are supported"
                )
            if not _surfaces():
                raise GeometryError(f"{str(path)!r} defines no 2D surface")
            _mesh_2d(h)
        _check_mesh(str(path))

    return _create(comm, make)


#: Built-in geometry names accepted by :func:`build`.
KNOWN_GEOMETRIES = {"annulus": annulus, "piano": piano}


def build(comm: MPI.Comm, name_or_path, mesh_size: float = 0.05) -> dolfinx.mesh.Mesh:
    """A built-in geometry by name (:data:`KNOWN_GEOMETRIES`) or a file for :func:`load`."""
    key = str(name_or_path)
    if key in KNOWN_GEOMETRIES:
        return KNOWN_GEOMETRIES[key](comm, mesh_size=mesh_size)
    path = Path(key)
    looks_like_file = path.suffix.lower() in GEO_EXTENSIONS + MESH_EXTENSIONS + CAD_EXTENSIONS
    # Decided on rank 0, which reads the file: every rank must take the same branch.
    is_file = (looks_like_file or path.exists()) if comm.rank == 0 else None
    if comm.bcast(is_file, root=0):
        return load(comm, path, mesh_size=mesh_size)
    raise GeometryError(
        f"unknown geometry {key!r}: not a file; known names are "
        f"{', '.join(sorted(KNOWN_GEOMETRIES))}"
    )


# --- checks ---------------------------------------------------------------------


def _is_real(x) -> bool:
    return isinstance(x, numbers.Real) and not isinstance(x, bool)


def _check_mesh_size(mesh_size) -> float:
    if not _is_real(mesh_size) or not math.isfinite(mesh_size) or mesh_size <= 0:
        raise GeometryError(f"mesh_size must be a positive finite number, got {mesh_size!r}")
    return float(mesh_size)


def _one_line(e: BaseException) -> str:
    text = " ".join(str(e).split())
    return text or type(e).__name__


def _surfaces() -> list[int]:
    return [tag for _, tag in gmsh.model.getEntities(2)]


def _check_msh_header(path: Path) -> None:
    try:
        with open(path, "rb") as f:
            head = f.read(64).lstrip()
    except OSError as e:
        raise GeometryError(f"cannot read {str(path)!r}: {_one_line(e)}") from None
    if not head.startswith((b"$MeshFormat", b"$NOD", b"$NOE")):
        raise GeometryError(f"cannot read {str(path)!r}: not a Gmsh mesh (no $MeshFormat header)")


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
        with _silenced(quiet and not _verbose()):
            gmsh.merge(str(path))
        errors = [m for m in gmsh.logger.get() if m.startswith("Error")]
    except Exception as e:
        errors = [_one_line(e)]
    finally:
        gmsh.logger.stop()
        gmsh.option.setNumber("General.AbortOnError", abort)
    if errors:
        message = errors[0].removeprefix("Error:").strip()
        raise GeometryError(f"cannot read {str(path)!r}: {_one_line(message)}")
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


def _check_no_3d_mesh(path: Path) -> None:
    types = set()
    for _, tag in gmsh.model.getEntities(3):
        types.update(int(t) for t in gmsh.model.mesh.getElements(3, tag)[0])
    if types:
        names = ", ".join(sorted(_GMSH_3D_NAMES.get(t, f"type {t}") for t in types))
        raise GeometryError(
            f"{str(path)!r} is a 3D mesh ({names}): only planar triangle meshes are supported"
        )


def _check_mesh(source: str) -> None:
    """The 2D elements are P1 triangles in a plane z = const, and there are some."""
    types = set()
    for tag in _surfaces():
        types.update(int(t) for t in gmsh.model.mesh.getElements(2, tag)[0])
    if types - {_TRIANGLE} and _QUADRANGLE not in types:
        # Higher-order triangles: keep their corner nodes only.
        gmsh.model.mesh.setOrder(1)
        types = set()
        for tag in _surfaces():
            types.update(int(t) for t in gmsh.model.mesh.getElements(2, tag)[0])
    if _QUADRANGLE in types:
        raise GeometryError(f"{source!r} has quadrilateral cells: only triangles are supported")
    if types != {_TRIANGLE}:
        raise GeometryError(f"{source!r} produced no triangle cells")
    _, coords, _ = gmsh.model.mesh.getNodes()
    z = coords.reshape(-1, 3)[:, 2]
    xy = coords.reshape(-1, 3)[:, :2]
    scale = max(float(abs(xy).max()), 1.0)
    if float(z.max() - z.min()) > 1e-8 * scale:
        raise GeometryError(f"{source!r} is not planar in the xy-plane (z varies)")


# --- Gmsh session handling ------------------------------------------------------


def _verbose() -> bool:
    return os.environ.get("UFL_FRAMES_GMSH_VERBOSE", "").strip().lower() not in (
        "",
        "0",
        "false",
        "no",
    )


def _mesh_2d(mesh_size: float) -> None:
    gmsh.option.setNumber("Mesh.MeshSizeMax", mesh_size)
    gmsh.model.mesh.generate(2)


def _tag_physical_groups() -> None:
    """Replace any physical groups by one for all surfaces and one for their boundary."""
    gmsh.model.removePhysicalGroups()
    surfaces = _surfaces()
    gmsh.model.addPhysicalGroup(2, surfaces, tag=DOMAIN_TAG, name="domain")
    boundary = gmsh.model.getBoundary([(2, s) for s in surfaces], combined=True, oriented=False)
    curves = sorted(
        {
            abs(tag)
            for dim, tag in boundary
            if dim == 1 and len(gmsh.model.mesh.getElements(1, abs(tag))[0])
        }
    )
    if curves:
        gmsh.model.addPhysicalGroup(1, curves, tag=BOUNDARY_TAG, name="boundary")


_TOUCHED_OPTIONS = ("General.Terminal", "General.AbortOnError", "Mesh.MeshSizeMax")


def _create(comm: MPI.Comm, make) -> dolfinx.mesh.Mesh:
    """Run ``make`` on rank 0 in a fresh Gmsh model, then distribute the mesh on ``comm``."""
    root = 0
    owns = False
    previous_model = None
    saved = {}
    error = None
    if comm.rank == root:
        owns = not gmsh.isInitialized()
        try:
            if owns:
                gmsh.initialize(argv=[], readConfigFiles=False, interruptible=False)
            else:
                saved = {k: gmsh.option.getNumber(k) for k in _TOUCHED_OPTIONS}
                previous_model = gmsh.model.getCurrent()
            gmsh.option.setNumber("General.Terminal", 1 if _verbose() else 0)
            gmsh.model.add(f"ufl_frames_{id(make):x}")
            make()
            _tag_physical_groups()
        except GeometryError as e:
            error = str(e)
        except Exception as e:
            error = f"Gmsh failed: {_one_line(e)}"
    error = comm.bcast(error, root=root)
    try:
        if error is not None:
            raise GeometryError(error)
        model = gmsh.model if comm.rank == root else None
        data = dolfinx.io.gmsh.model_to_mesh(model, comm, root, gdim=2)
    finally:
        if comm.rank == root:
            _release(owns, previous_model, saved)
    return data.mesh


def _release(owns: bool, previous_model, saved: dict) -> None:
    if not gmsh.isInitialized():
        return
    if owns:
        gmsh.finalize()
        return
    try:
        gmsh.model.remove()
        if previous_model is not None:
            gmsh.model.setCurrent(previous_model)
    finally:
        for key, value in saved.items():
            gmsh.option.setNumber(key, value)
