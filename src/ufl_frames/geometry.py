r"""Planar domains for frame-field computations, built or read with Gmsh.

Every builder returns a :class:`Domain`: the distributed P1 triangle mesh
(``gdim = 2``), its boundary facets tagged by the curve they lie on, the boundary
directions and corners of the CAD model where one exists, the Euler characteristic,
the mesh size actually used and notes on what the loader changed.

Built-in geometries (the research note's test cases, *A tensor formulation for
integrable frame fields*, §4, Fig. 1):

- :func:`annulus`: the ring :math:`r_i \le |x| \le r_o` (default 0.5 and 1, area
  :math:`3\pi/4`). A boundary-aligned cross field on it has no singularity.
- :func:`piano`: a grand-piano outline, 2 × 1.2, whose smooth boundary-aligned cross
  field has exactly one +1/4 singularity in its left part and one −1/4 in its right
  part (the note does not give its exact shape; this one is ours).

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
(read as is) or CAD ``.step``/``.stp``/``.brep`` (imported with OpenCASCADE, then
meshed in 2D). What real files contain is handled so that the frame field gets a
conforming P1 triangle mesh of the whole planar domain:

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
- mesh size (:func:`load`): the default is relative to the shape (the file's own
  sizes where it sets any, else about :data:`AUTO_TRIANGLES` triangles), curves are
  resolved with at least :data:`CURVE_POINTS_PER_TURN` points per full turn, and an
  estimate above ``max_triangles`` is refused before meshing;
- a ``.geo`` that would act outside the run (``Exit``, ``SystemCall``, ``Save``, ...:
  :func:`_check_geo_script`) is refused before Gmsh runs it, and a surface whose
  boundary curves cross (:func:`_check_crossings`) before it is meshed;
- reading and meshing run in a child process, stopped after a time limit
  (:func:`mesh_time_limit`, :class:`MeshTimeLimit`).

The geometry must lie in a plane z = const; volumes and tetrahedra are rejected.
Gmsh runs on rank 0 only; errors are raised on every rank as :class:`GeometryError`
with a one-line message. Gmsh is finalised afterwards unless the caller had
initialised it (its current model and the options touched here are then restored).
Gmsh prints nothing unless ``UFL_FRAMES_GMSH_VERBOSE`` is set (to anything but
``""``/``0``).
"""

import contextlib
import math
import numbers
import os
import pickle
import re
import select
import signal
import sys
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from ufl_frames.bootstrap import init_petsc

init_petsc()

import dolfinx  # noqa: E402
import dolfinx.io.gmsh  # noqa: E402
import gmsh  # noqa: E402
import numpy as np  # noqa: E402
from mpi4py import MPI  # noqa: E402

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
]

#: File extensions understood by :func:`load`, lower case.
GEO_EXTENSIONS = (".geo",)
MESH_EXTENSIONS = (".msh",)
CAD_EXTENSIONS = (".step", ".stp", ".brep")

#: Mesh size of the built-in geometries when none is given.
BUILTIN_MESH_SIZE = 0.05
#: Triangles aimed at by the default size of a file that sets no sizes of its own.
AUTO_TRIANGLES = 2000
#: Circles and ellipses get at least this many mesh points per full turn (Gmsh's
#: ``Mesh.MinimumCirclePoints``): a cross turns by 4× the boundary's turn between two
#: boundary vertices, and the discrete index of the field needs that below 180°.
CURVE_POINTS_PER_TURN = 12
#: Other curved curves (splines, B-splines) get at least this many points each.
CURVE_POINTS_PER_CURVE = 8
#: Largest estimated triangle count meshed without asking (``max_triangles``).
MAX_TRIANGLES = 4_000_000
#: Above this estimated triangle count a uniform size h is meshed at 2^k h and refined k
#: times by Gmsh (every triangle split into 4, new boundary points put on the curves):
#: 10⁶ piano triangles took 41 s meshed directly, 4 s as 6·10⁴ refined twice.
REFINE_ABOVE = 150_000
#: Facet tag of boundary edges that lie on no curve of the file (a bare ``.msh``).
NO_CURVE = 0
#: Seconds :func:`load` lets Gmsh read and mesh a file with the default ``max_triangles``
#: (more in proportion for a larger one, :func:`mesh_time_limit`); then it is stopped.
#: Loading the piano at 3.8e6 triangles (about the largest default) took 62 s on a 2-core
#: machine, DOLFINx's distribution included: the default leaves a factor 5.
MESH_TIME_LIMIT = 300.0
#: Points per curved boundary curve for the crossing check of :func:`_check_crossings`
#: (and, to confirm a crossing found, :data:`CROSSING_CONFIRM` times as many).
CROSSING_SAMPLES = 64
CROSSING_CONFIRM = 16

# Piano outline (see module docstring).
PIANO_WIDTH = 2.0
PIANO_HEIGHT = 1.2
PIANO_CONVEX_RADIUS = 0.8  # the rounded tail, top left
PIANO_CONCAVE_RADIUS = 0.6  # the bentside, top right

_GMSH_3D_NAMES = {4: "tetrahedra", 5: "hexahedra", 6: "prisms", 7: "pyramids"}
_EQUILATERAL = math.sqrt(3) / 4  # area of the equilateral triangle of unit edge
_UNSET_SIZE = 1e21  # Gmsh's "no size" is 1e22 (MAX_LC)


class GeometryError(ValueError):
    """A geometry could not be built, read or meshed (one-line message)."""


class MeshTimeLimit(GeometryError):
    """Reading and meshing a geometry file took longer than its time limit."""


def mesh_time_limit(max_triangles: float = MAX_TRIANGLES) -> float:
    """The default time limit of :func:`load`: :data:`MESH_TIME_LIMIT` seconds, scaled up
    in proportion above the default ``max_triangles``."""
    return MESH_TIME_LIMIT * max(1.0, float(max_triangles) / MAX_TRIANGLES)


@dataclass(frozen=True)
class Corner:
    """A corner of the boundary: position, interior angle (radians) and its quarter
    turns ``k = round(angle / (π/2))``; a boundary-aligned cross field gets the index
    (2 − k)/4 from it (a right-angled convex corner: 1/4, a reflex one: −1/4)."""

    x: float
    y: float
    angle: float

    @property
    def quarter_turns(self) -> int:
        return int(round(self.angle / (math.pi / 2)))


@dataclass
class Domain:
    """A meshed planar domain: what the frame-field pipeline needs of the geometry.

    ``facet_tags`` marks every boundary facet with the tag of the curve it lies on
    (the Gmsh curve tag; :data:`NO_CURVE` where the file has no curves).
    ``corners`` are the boundary's corners (interior angle ≠ 180°, from the CAD
    curves' tangents where they exist, else from the mesh), the same on every rank.
    ``mesh_size`` is the mean edge length of the mesh; ``requested_mesh_size`` the
    size Gmsh was asked for (None: the file's own sizes, or a ``.msh``).
    ``notes`` lists what the loader changed or dropped, one line each.
    """

    mesh: dolfinx.mesh.Mesh
    facet_tags: dolfinx.mesh.MeshTags
    corners: tuple[Corner, ...]
    euler_characteristic: int
    mesh_size: float
    requested_mesh_size: float | None
    source: str
    notes: tuple[str, ...] = ()
    #: Boundary directions from the CAD model: sorted input node indices and the cross
    #: angle ψ (a tangent's angle, mod π/2) at each of them.
    _direction_nodes: np.ndarray = field(default=None, repr=False)
    _direction_angles: np.ndarray = field(default=None, repr=False)

    @property
    def comm(self) -> MPI.Comm:
        return self.mesh.comm

    @property
    def num_cells(self) -> int:
        return self.mesh.topology.index_map(2).size_global

    @property
    def num_vertices(self) -> int:
        return self.mesh.topology.index_map(0).size_global

    @property
    def boundary_curves(self) -> list[int]:
        """Tags of the curves that carry boundary facets (collective: call on all ranks)."""
        local = np.unique(self.facet_tags.values).tolist()
        return sorted({int(t) for part in self.comm.allgather(local) for t in part})

    def boundary_angles(self, V) -> np.ndarray | None:
        """Cross angle ψ (mod π/2) from the CAD curves at every local row of the P1 space
        ``V`` (NaN where the model gives none); None without a CAD model."""
        if self._direction_nodes is None:
            return None
        geometry = self.mesh.geometry
        at_node = _lookup(self._direction_nodes, self._direction_angles,
                          np.asarray(geometry.input_global_indices, dtype=np.int64))
        index_map = V.dofmap.index_map
        angles = np.full(index_map.size_local + index_map.num_ghosts, np.nan)
        # P1: the dofs of a cell are its vertices in the order of its geometry nodes.
        angles[V.dofmap.list.ravel()] = at_node[geometry.dofmaps[0].ravel()]
        return angles


def _lookup(keys: np.ndarray, values: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """values[keys == w] for each w of ``wanted`` (``keys`` sorted); NaN where absent."""
    out = np.full(wanted.shape, np.nan)
    if keys.size:
        pos = np.minimum(np.searchsorted(keys, wanted), keys.size - 1)
        hit = keys[pos] == wanted
        out[hit] = values[pos[hit]]
    return out


# --- public builders ------------------------------------------------------------


def annulus(
    comm: MPI.Comm,
    mesh_size: float = BUILTIN_MESH_SIZE,
    r_inner: float = 0.5,
    r_outer: float = 1.0,
    refinements: int = 0,
) -> Domain:
    """Triangle mesh of the annulus r_inner ≤ |x| ≤ r_outer centred at the origin
    (``refinements``: see :func:`build`)."""
    h = _check_mesh_size(mesh_size)
    refinements = _check_refinements(refinements)
    for name, r in (("r_inner", r_inner), ("r_outer", r_outer)):
        if not _is_real(r) or not math.isfinite(r) or r <= 0:
            raise GeometryError(f"{name} must be a positive finite number, got {r!r}")
    if not r_inner < r_outer:
        raise GeometryError(f"r_inner must be smaller than r_outer, got {r_inner} >= {r_outer}")

    def make(notes):
        occ = gmsh.model.occ
        outer = occ.addDisk(0.0, 0.0, 0.0, r_outer, r_outer)
        inner = occ.addDisk(0.0, 0.0, 0.0, r_inner, r_inner)
        occ.cut([(2, outer)], [(2, inner)])
        occ.synchronize()
        return _mesh_model(_Sizing(h, refinements=refinements), notes)

    return _create(comm, make, "annulus", cad=True)


def piano(comm: MPI.Comm, mesh_size: float = BUILTIN_MESH_SIZE, refinements: int = 0) -> Domain:
    """Triangle mesh of the 'piano' outline (module docstring, ``meshes/piano.geo``;
    ``refinements``: see :func:`build`)."""
    h = _check_mesh_size(mesh_size)
    refinements = _check_refinements(refinements)

    def make(notes):
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
        occ.synchronize()
        return _mesh_model(_Sizing(h, refinements=refinements), notes)

    return _create(comm, make, "piano", cad=True)


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


def load(
    comm: MPI.Comm,
    path,
    mesh_size: float | None = None,
    size_factor: float = 1.0,
    max_triangles: int = MAX_TRIANGLES,
    time_limit: float | None = None,
    refinements: int = 0,
) -> Domain:
    """Domain from a ``.geo``, ``.msh``, ``.step``/``.stp`` or ``.brep`` file.

    ``mesh_size`` (absolute, in the file's units) caps the element size
    (``Mesh.MeshSizeMax``, set after a ``.geo`` has run, so it wins over the script's
    own value; finer point sizes are kept). Without it the size is relative to the
    shape: the file's own sizes (point sizes, size fields, ``Mesh.MeshSizeMax``)
    where it sets any, else the size that gives about :data:`AUTO_TRIANGLES`
    triangles. ``size_factor`` scales either (< 1 refines). Sizes that would give
    more than ``max_triangles`` (estimated from the area) are refused before
    meshing. A ``.msh`` is taken as it is: sizes do not apply.
    Physical groups in the file are ignored: the domain is all its surfaces.

    Reading and meshing run in a child process stopped after ``time_limit`` seconds
    (default :func:`mesh_time_limit`; ``math.inf``: in this process, no limit), with
    :class:`MeshTimeLimit`. Boundaries whose curves cross (a curve loop through itself,
    a hole across the outline), on which Gmsh's meshing never ends, are refused before.
    ``refinements`` as for :func:`build` (not for a ``.msh``).
    """
    path = Path(path)
    h = None if mesh_size is None else _check_mesh_size(mesh_size)
    refinements = _check_refinements(refinements)
    factor = _check_positive("size_factor", size_factor)
    limit = _check_positive("max_triangles", max_triangles)
    seconds = mesh_time_limit(limit) if time_limit is None else time_limit
    if not (_is_real(seconds) and seconds > 0):  # inf allowed: no limit
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
        if not path.is_file():
            raise GeometryError(f"geometry file not found: {source!r}")
        if ext in MESH_EXTENSIONS:
            _check_msh_header(path)
        if ext in GEO_EXTENSIONS:
            _check_geo_script(path)
        _merge(path, quiet=ext in CAD_EXTENSIONS)
        if ext in MESH_EXTENSIONS:
            if refinements:
                raise GeometryError(f"{source!r} is a mesh: it cannot be made by refinement")
            _check_no_3d_mesh(source)
            if not _surfaces():
                raise GeometryError(f"{source!r} holds no 2D surface mesh")
            return None
        if gmsh.model.getEntities(3):
            raise GeometryError(
                f"{source!r} defines volumes: only planar 2D geometries are supported"
            )
        if not _surfaces():
            raise GeometryError(f"{source!r} defines no 2D surface")
        _check_crossings(source)
        return _mesh_model(_Sizing(h, factor, limit, refinements), notes)

    return _create(comm, make, source, cad=ext not in MESH_EXTENSIONS, time_limit=seconds)


#: Built-in geometry names accepted by :func:`build`.
KNOWN_GEOMETRIES = {"annulus": annulus, "piano": piano}


def build(
    comm: MPI.Comm,
    name_or_path,
    mesh_size: float | None = None,
    size_factor: float = 1.0,
    max_triangles: int = MAX_TRIANGLES,
    time_limit: float | None = None,
    refinements: int = 0,
) -> Domain:
    """A built-in geometry by name (:data:`KNOWN_GEOMETRIES`) or a file for :func:`load`.

    Built-in shapes take ``mesh_size`` (default :data:`BUILTIN_MESH_SIZE`) times
    ``size_factor`` (meshed in this process: ``max_triangles`` and ``time_limit`` are
    for files). With ``refinements`` = k Gmsh meshes at 2^k times that size and splits
    every triangle into 4, k times (new boundary points on the curves): the mesh is
    then a refinement of the one ``size_factor`` · 2^k and ``refinements`` 0 give, as
    :func:`build_nested` needs.
    """
    key = str(name_or_path)
    if key in KNOWN_GEOMETRIES:
        h = BUILTIN_MESH_SIZE if mesh_size is None else _check_mesh_size(mesh_size)
        factor = _check_positive("size_factor", size_factor)
        return KNOWN_GEOMETRIES[key](comm, mesh_size=h * factor, refinements=refinements)
    path = Path(key)
    looks_like_file = path.suffix.lower() in GEO_EXTENSIONS + MESH_EXTENSIONS + CAD_EXTENSIONS
    # Decided on rank 0, which reads the file: every rank must take the same branch.
    is_file = (looks_like_file or path.exists()) if comm.rank == 0 else None
    if comm.bcast(is_file, root=0):
        return load(comm, path, mesh_size, size_factor, max_triangles, time_limit,
                    refinements)
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
) -> list[Domain]:
    """``levels`` nested meshes of one geometry, coarse to fine: Gmsh meshes the coarsest
    at 2^(levels−1) times the size :func:`build` would use, and level k is that mesh
    split k times (every triangle into 4, new boundary points on the curves); the finest
    has about the size asked for. The meshes of nested iteration
    (:meth:`~ufl_frames.pipeline.FrameField.nested`): on nested meshes a coarse P1 field
    is a fine one, while interpolation onto an independent Gmsh mesh mixes the jumps of
    its gradient across coarse edges into the fine triangles that straddle them, in
    bands along the coarse mesh's rows (the non-isotropic piano's start from 6.3·10³ on
    2.5·10⁴ triangles: 7.7x the coarse H, nested 2.9x; that level then took 116 Newton
    steps, nested 43). Split meshes are worse meshes for H, though: a one-mesh solve ends
    8-30 % higher than on a Gmsh mesh of the same size (``benchmarks/README.md``).
    """
    if isinstance(levels, bool) or not isinstance(levels, numbers.Integral) or levels < 1:
        raise GeometryError(f"levels must be a positive integer, got {levels!r}")
    return [build(comm, name_or_path, mesh_size, size_factor * 2.0 ** (levels - 1 - k),
                  max_triangles, time_limit, refinements=k) for k in range(levels)]


# --- checks ---------------------------------------------------------------------


def _is_real(x) -> bool:
    return isinstance(x, numbers.Real) and not isinstance(x, bool)


def _check_refinements(refinements) -> int:
    if (isinstance(refinements, bool) or not isinstance(refinements, numbers.Integral)
            or refinements < 0):
        raise GeometryError(f"refinements must be a non-negative integer, got {refinements!r}")
    return int(refinements)


def _check_positive(name: str, value) -> float:
    if not _is_real(value) or not math.isfinite(value) or value <= 0:
        raise GeometryError(f"{name} must be a positive finite number, got {value!r}")
    return float(value)


def _check_mesh_size(mesh_size) -> float:
    return _check_positive("mesh_size", mesh_size)


def _one_line(e: BaseException | str) -> str:
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
    try:
        text = path.read_bytes().decode("utf-8", errors="replace")
    except OSError as e:
        raise GeometryError(f"cannot read {str(path)!r}: {_one_line(e)}") from None

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
        if (command == "Include" or child.suffix.lower() in GEO_EXTENSIONS) and child.is_file():
            _check_geo_script(child, seen)


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


def _check_no_3d_mesh(source: str) -> None:
    types = set()
    for _, tag in gmsh.model.getEntities(3):
        types.update(int(t) for t in gmsh.model.mesh.getElements(3, tag)[0])
    if types:
        names = ", ".join(sorted(_GMSH_3D_NAMES.get(t, f"type {t}") for t in types))
        raise GeometryError(
            f"{source!r} is a 3D mesh ({names}): only planar triangle meshes are supported"
        )


# --- meshing a CAD model ----------------------------------------------------------


@dataclass
class _Sizing:
    """How to size the mesh: absolute ``h`` (None: relative to the shape), a factor, and
    how many times at least the mesh is made by splitting a 2^k times coarser one."""

    h: float | None
    factor: float = 1.0
    max_triangles: float = MAX_TRIANGLES
    refinements: int = 0


def _verbose() -> bool:
    return os.environ.get("UFL_FRAMES_GMSH_VERBOSE", "").strip().lower() not in (
        "",
        "0",
        "false",
        "no",
    )


def _unite_surfaces(notes: list[str]) -> None:
    """One conforming domain of several surfaces: fragment (OCC) or merge duplicates."""
    surfaces = gmsh.model.getEntities(2)
    if len(surfaces) < 2:
        return
    occ = gmsh.model.occ.getEntities(2)
    if sorted(occ) == sorted(surfaces):
        before = len(surfaces)
        gmsh.model.occ.fragment(surfaces[:1], surfaces[1:])
        gmsh.model.occ.removeAllDuplicates()
        gmsh.model.occ.synchronize()
        after = len(gmsh.model.getEntities(2))
        notes.append(
            f"{before} surfaces fragmented into one conforming domain of {after} surfaces "
            "(shared curves are interior)"
        )
    else:
        gmsh.model.geo.removeAllDuplicates()
        gmsh.model.geo.synchronize()
        notes.append(f"{len(surfaces)} surfaces meshed as one domain (shared curves are interior)")


def _override_meshing_requests(notes: list[str]) -> None:
    """Triangles for the frame field, whatever meshing the file asks for."""
    asked = []
    if gmsh.option.getNumber("Mesh.RecombineAll"):
        gmsh.option.setNumber("Mesh.RecombineAll", 0)
        asked.append("RecombineAll")
    if gmsh.option.getNumber("Mesh.SubdivisionAlgorithm"):
        gmsh.option.setNumber("Mesh.SubdivisionAlgorithm", 0)
        asked.append("subdivision into quadrilaterals")
    if gmsh.option.getNumber("Mesh.Algorithm") == 11:
        gmsh.option.setNumber("Mesh.Algorithm", 6)
        asked.append("the quasi-structured quad algorithm")
    if gmsh.option.getNumber("Mesh.ElementOrder") > 1:
        gmsh.option.setNumber("Mesh.ElementOrder", 1)
        asked.append("second-order elements")
    if asked:
        notes.append(f"the file asks for {', '.join(asked)}: meshed with linear triangles")
    if gmsh.option.getNumber("Mesh.Algorithm") == 3:
        # Measured on deal.II's step-49 input: MeshAdapt gave edges of 0.58 under a cap of
        # 0.1 (Frontal-Delaunay: 0.06), so the sizes asked for would not be the sizes had.
        gmsh.option.setNumber("Mesh.Algorithm", 6)
        notes.append("the file's 2D algorithm MeshAdapt (3) ignores the size limits: "
                     "Frontal-Delaunay (6) used instead")


def _file_sets_sizes() -> bool:
    points = gmsh.model.getEntities(0)
    sizes = np.asarray(gmsh.model.mesh.getSizes(points)) if points else np.zeros(0)
    return bool(
        np.any((sizes > 0) & (sizes < _UNSET_SIZE))
        or len(gmsh.model.mesh.field.list()) > 0
        or gmsh.option.getNumber("Mesh.MeshSizeMax") < _UNSET_SIZE
        or gmsh.option.getNumber("Mesh.MeshSizeFactor") != 1.0
    )


def _bounding_box_diagonal() -> float:
    x0, y0, _, x1, y1, _ = gmsh.model.getBoundingBox(-1, -1)
    return math.hypot(x1 - x0, y1 - y0)


def _model_area() -> float:
    """Area of all surfaces: exact for OpenCASCADE, else from a coarse trial mesh."""
    surfaces = gmsh.model.getEntities(2)
    if sorted(gmsh.model.occ.getEntities(2)) == sorted(surfaces):
        return float(sum(gmsh.model.occ.getMass(2, tag) for _, tag in surfaces))
    diagonal = _bounding_box_diagonal()
    names = ("Mesh.MeshSizeMin", "Mesh.MeshSizeMax", "Mesh.MeshSizeFromPoints",
             "Mesh.MeshSizeExtendFromBoundary")
    saved = {k: gmsh.option.getNumber(k) for k in names}
    try:
        gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
        gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
        gmsh.option.setNumber("Mesh.MeshSizeMin", diagonal / 500)
        gmsh.option.setNumber("Mesh.MeshSizeMax", diagonal / 30)
        gmsh.model.mesh.generate(2)
        x, cells = _triangles_of_model()[:2]
        area = float(np.abs(_signed_areas(x, cells)).sum())
    except Exception:
        area = 0.0
    finally:
        gmsh.model.mesh.clear()
        for k, v in saved.items():
            gmsh.option.setNumber(k, v)
    if not area > 0:  # the trial failed: an upper bound is enough for a size estimate
        x0, y0, _, x1, y1, _ = gmsh.model.getBoundingBox(-1, -1)
        area = (x1 - x0) * (y1 - y0)
    return area


def _curve_points(curve: int, samples: int) -> np.ndarray:
    """(n, 2) points along a curve, equally spaced in its parameter (2 for a line)."""
    n = 2 if gmsh.model.getType(1, curve) == "Line" else samples
    lo, hi = (float(v[0]) for v in gmsh.model.getParametrizationBounds(1, curve))
    xyz = np.asarray(gmsh.model.getValue(1, curve, np.linspace(lo, hi, n)))
    return xyz.reshape(-1, 3)[:, :2]


def _crossing_pairs(polylines: dict, tol: float) -> list[tuple[int, int, np.ndarray]]:
    """(curve, curve, point) of the polylines' segments that cross properly (each end of
    either strictly on its own side of the other, by more than ``tol``); one per pair."""
    curve_of = np.concatenate([np.full(len(p) - 1, c) for c, p in polylines.items()])
    a = np.concatenate([p[:-1] for p in polylines.values()])
    b = np.concatenate([p[1:] for p in polylines.values()])
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    order = np.argsort(lo[:, 0], kind="stable")
    xs = lo[order, 0]
    # Sweep in x: segment i against the later ones whose x-range starts within its own.
    ends = np.searchsorted(xs, hi[order, 0], side="right")
    found = {}
    start = 0
    while start < order.size:
        counts = np.maximum(ends[start:] - np.arange(start, order.size) - 1, 0)
        stop = start + max(1, int(np.searchsorted(np.cumsum(counts), 2_000_000)))
        stop = min(stop, order.size)
        first = np.repeat(np.arange(start, stop), counts[: stop - start])
        offsets = np.arange(first.size) - np.repeat(np.cumsum(counts[: stop - start])
                                                    - counts[: stop - start],
                                                    counts[: stop - start])
        i, j = order[first], order[first + 1 + offsets]
        start = stop
        keep = (lo[i, 1] <= hi[j, 1]) & (lo[j, 1] <= hi[i, 1])
        i, j = i[keep], j[keep]

        def side(p, q, r):
            return ((q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1])
                    - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0]))

        s1, s2 = side(a[i], b[i], a[j]), side(a[i], b[i], b[j])
        s3, s4 = side(a[j], b[j], a[i]), side(a[j], b[j], b[i])
        cross = ((np.minimum(s1, s2) < -tol) & (np.maximum(s1, s2) > tol)
                 & (np.minimum(s3, s4) < -tol) & (np.maximum(s3, s4) > tol))
        for k in np.flatnonzero(cross):
            pair = tuple(sorted((int(curve_of[i[k]]), int(curve_of[j[k]]))))
            t = s3[k] / (s3[k] - s4[k])  # where along segment i
            found.setdefault(pair, a[i[k]] + t * (b[i[k]] - a[i[k]]))
    return [(*pair, point) for pair, point in found.items()]


def _check_crossings(source: str) -> None:
    """Refuse a surface whose boundary curves cross: a curve loop through itself, or two
    of its loops across each other. Gmsh's 2D meshing never ends on those (it splits the
    crossing edges and tries again, forever). Checked on points along the curves
    (:data:`CROSSING_SAMPLES` per curved one), each crossing confirmed on
    :data:`CROSSING_CONFIRM` times as many (a chord of a curve may cross a curve close
    to it that the curve itself does not); curves that only touch are let through."""
    x0, y0, _, x1, y1, _ = gmsh.model.getBoundingBox(-1, -1)
    tol = 1e-9 * max((x1 - x0) ** 2 + (y1 - y0) ** 2, 1e-300)
    cache: dict[tuple[int, int], np.ndarray] = {}

    def points(curve, samples):
        if (curve, samples) not in cache:
            cache[curve, samples] = _curve_points(curve, samples)
        return cache[curve, samples]

    for _, surface in gmsh.model.getEntities(2):
        boundary = gmsh.model.getBoundary([(2, surface)], combined=False, oriented=False)
        curves = sorted({abs(int(tag)) for dim, tag in boundary if dim == 1})
        if not curves:
            continue
        coarse = {c: points(c, CROSSING_SAMPLES) for c in curves}
        for first, second, _ in _crossing_pairs(coarse, tol):
            fine = {c: points(c, CROSSING_SAMPLES * CROSSING_CONFIRM) for c in {first, second}}
            confirmed = [p for p in _crossing_pairs(fine, tol) if p[:2] == (first, second)]
            if confirmed:
                x, y = confirmed[0][2]
                which = (f"curve {first} crosses itself" if first == second
                         else f"curves {first} and {second} cross")
                raise GeometryError(
                    f"{source!r}: the boundary of surface {surface} crosses itself ({which} "
                    f"near ({x:.4g}, {y:.4g})): Gmsh cannot mesh it; make each curve loop a "
                    "simple closed curve, with holes inside the outline"
                )


def _mesh_model(sizing: _Sizing, notes: list[str]) -> float | None:
    """Mesh the CAD model of the current Gmsh model in 2D; return the size asked for."""
    _unite_surfaces(notes)
    _override_meshing_requests(notes)
    # Resolve curved boundaries whatever the size (Mesh.MeshSizeFromCurvature would do it
    # too, but hangs Gmsh 4.15 on built-in circles between points of different sizes).
    for name, least in (("Mesh.MinimumCirclePoints", CURVE_POINTS_PER_TURN),
                        ("Mesh.MinimumCurvePoints", CURVE_POINTS_PER_CURVE)):
        gmsh.option.setNumber(name, max(gmsh.option.getNumber(name), least))
    own_sizes = sizing.h is None and _file_sets_sizes()
    area = _model_area()
    if not (area > 0 and math.isfinite(area)):
        raise GeometryError(f"the surfaces have no area to mesh (area {area:.3g})")
    refinements, automatic = sizing.refinements, 0
    if own_sizes:
        h = None
        gmsh.option.setNumber("Mesh.MeshSizeFactor", gmsh.option.getNumber("Mesh.MeshSizeFactor")
                              * sizing.factor * 2**refinements)
    else:
        if sizing.h is None:
            h = sizing.factor * math.sqrt(area / (_EQUILATERAL * AUTO_TRIANGLES))
        else:
            h = sizing.h * sizing.factor
        estimate = area / (_EQUILATERAL * h * h)
        if estimate > sizing.max_triangles:
            raise GeometryError(
                f"mesh size {h:.3g} on a domain of area {area:.3g} gives about "
                f"{estimate:.2g} triangles, more than the limit {sizing.max_triangles:.3g}: "
                "choose a larger mesh size (or raise the limit)"
            )
        while estimate / 4**(refinements + automatic) > REFINE_ABOVE:
            automatic += 1
        gmsh.option.setNumber("Mesh.MeshSizeMax", h * 2**(refinements + automatic))
    gmsh.model.mesh.generate(2)
    for _ in range(refinements + automatic):
        gmsh.model.mesh.refine()
    if automatic:
        notes.append(f"meshed at size {h * 2**(refinements + automatic):.3g} and refined "
                     f"{refinements + automatic} time(s) (each triangle split into 4): faster "
                     f"than meshing at {h * 2**refinements:.3g}")
    return h


# --- from the Gmsh mesh to arrays -------------------------------------------------


def _signed_areas(x: np.ndarray, cells: np.ndarray) -> np.ndarray:
    e1 = x[cells[:, 1]] - x[cells[:, 0]]
    e2 = x[cells[:, 2]] - x[cells[:, 0]]
    return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def _split_quads(quads: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Two triangles per quadrilateral (corners in cyclic order), cut along the shorter
    diagonal."""
    d02 = np.linalg.norm(x[quads[:, 2]] - x[quads[:, 0]], axis=1)
    d13 = np.linalg.norm(x[quads[:, 3]] - x[quads[:, 1]], axis=1)
    along02 = (d02 <= d13)[:, None]
    first = np.where(along02, quads[:, [0, 1, 2]], quads[:, [0, 1, 3]])
    second = np.where(along02, quads[:, [0, 2, 3]], quads[:, [1, 2, 3]])
    return np.concatenate([first, second])


# Gmsh's 6-node triangle: corners 0, 1, 2, then the midpoints of 01, 12, 20.
_P2_SPLIT = np.array([[0, 3, 5], [3, 1, 4], [5, 4, 2], [3, 4, 5]])


def _triangles_of_model(notes: list[str] | None = None):
    """(xyz of all nodes, triangles as node rows, edges of the 1D elements with their
    curve tags) of the current Gmsh mesh; higher orders and quadrilaterals converted."""
    tags, coords, _ = gmsh.model.mesh.getNodes()
    xyz = coords.reshape(-1, 3)
    row = np.full(int(tags.max(initial=0)) + 1, -1, dtype=np.int64)
    row[tags.astype(np.int64)] = np.arange(tags.size)
    pieces, converted = [], {}
    for _, surface in gmsh.model.getEntities(2):
        types, _, nodes = gmsh.model.mesh.getElements(2, surface)
        for kind, element_nodes in zip(types, nodes, strict=True):
            name, _, order, count, _, corners = gmsh.model.mesh.getElementProperties(kind)
            e = row[element_nodes.astype(np.int64)].reshape(-1, count)
            if corners == 3 and count == 6:
                pieces.append(e[:, _P2_SPLIT].reshape(-1, 3))
                what = "second-order triangles split into 4 linear triangles each (all nodes kept)"
            elif corners == 3:
                pieces.append(e[:, :3])
                what = None if order == 1 else f"{name} reduced to their corner nodes"
            elif corners == 4:
                pieces.append(_split_quads(e[:, :4], xyz))
                what = "quadrilaterals split into 2 triangles each"
                if order > 1:
                    what += " (higher-order nodes dropped)"
            else:
                raise GeometryError(f"unsupported 2D element type {name!r}")
            if what:
                converted[what] = converted.get(what, 0) + e.shape[0]
    if notes is not None:
        notes.extend(f"{n} {what}" for what, n in converted.items())
    cells = np.concatenate(pieces) if pieces else np.zeros((0, 3), dtype=np.int64)
    edges, edge_curve = [], []
    for _, curve in gmsh.model.getEntities(1):
        types, _, nodes = gmsh.model.mesh.getElements(1, curve)
        for kind, element_nodes in zip(types, nodes, strict=True):
            count = gmsh.model.mesh.getElementProperties(kind)[3]
            e = row[element_nodes.astype(np.int64)].reshape(-1, count)
            # A 3-node line is two edges through its midpoint (node 2), as the P2 split.
            pairs = e if count == 2 else np.concatenate([e[:, [0, 2]], e[:, [2, 1]]])
            edges.append(pairs[:, :2])
            edge_curve.append(np.full(pairs.shape[0], curve, dtype=np.int64))
    edges = np.concatenate(edges) if edges else np.zeros((0, 2), dtype=np.int64)
    curves = np.concatenate(edge_curve) if edge_curve else np.zeros(0, dtype=np.int64)
    return xyz, cells, edges, curves, tags


def _edge_keys(pairs: np.ndarray, n: int) -> np.ndarray:
    lo, hi = np.minimum(pairs[:, 0], pairs[:, 1]), np.maximum(pairs[:, 0], pairs[:, 1])
    return lo * n + hi


@dataclass
class _Arrays:
    """The mesh on rank 0 as arrays (compressed to the nodes the triangles use)."""

    x: np.ndarray  # (n, 2)
    cells: np.ndarray  # (m, 3), counter-clockwise
    boundary: np.ndarray  # (k, 2) boundary edges, domain on their left
    boundary_curve: np.ndarray  # (k,) curve tag of each
    gmsh_node: np.ndarray  # (n,) Gmsh node tag of each row
    edges: np.ndarray  # (e, 2) every edge once, (lo, hi)


def _mesh_arrays(source: str, notes: list[str]) -> _Arrays:
    """The current Gmsh mesh as checked arrays: used nodes only, planar, valid cells."""
    if len(_surfaces()) > 1:  # touching surfaces of a .msh or of a built-in model
        gmsh.model.mesh.removeDuplicateNodes()  # (2 s for 10⁶ triangles: not for one surface)
    xyz, cells, curve_edges, curves, tags = _triangles_of_model(notes)
    if cells.size == 0:
        raise GeometryError(f"{source!r} produced no triangle cells")
    used, cells = np.unique(cells, return_inverse=True)
    cells = cells.reshape(-1, 3)
    unused = tags.size - used.size
    if unused:
        notes.append(f"{unused} nodes that no triangle uses were dropped (centre points, ...)")
    xyz = xyz[used]
    if not np.all(np.isfinite(xyz)):
        raise GeometryError(f"{source!r} has nodes with NaN or infinite coordinates")
    scale = max(float(np.abs(xyz[:, :2]).max()), 1e-300)
    z = xyz[:, 2]
    if float(z.max() - z.min()) > 1e-8 * scale:
        raise GeometryError(f"{source!r} is not planar in the xy-plane (z varies)")
    x = np.ascontiguousarray(xyz[:, :2])
    if np.any((cells[:, 0] == cells[:, 1]) | (cells[:, 1] == cells[:, 2])
              | (cells[:, 0] == cells[:, 2])):
        raise GeometryError(f"{source!r} has triangles with a repeated node")
    area = _signed_areas(x, cells)
    # Degenerate by shape, not by size: graded meshes have tiny good triangles.
    longest = np.max([np.sum((x[cells[:, i]] - x[cells[:, (i + 1) % 3]]) ** 2, axis=1)
                      for i in range(3)], axis=0)
    degenerate = np.abs(area) <= 1e-10 * longest
    if degenerate.any():
        raise GeometryError(f"{source!r} has {int(degenerate.sum())} zero-area triangles")
    cells = np.where((area < 0)[:, None], cells[:, [0, 2, 1]], cells)

    n = x.shape[0]
    directed = np.concatenate([cells[:, [0, 1]], cells[:, [1, 2]], cells[:, [2, 0]]])
    keys = _edge_keys(directed, n)
    unique, first, counts = np.unique(keys, return_index=True, return_counts=True)
    mesh_edges = np.stack([unique // n, unique % n], axis=1)
    if np.any(counts > 2):
        raise GeometryError(
            f"{source!r}: {int((counts > 2).sum())} edges are shared by more than two "
            "triangles (overlapping surfaces)"
        )
    boundary = directed[first[counts == 1]]
    # Curve of each boundary edge, from the 1D elements (map their nodes to rows first).
    new_row = np.full(int(tags.size), -1, dtype=np.int64)
    new_row[used] = np.arange(used.size)
    boundary_curve = np.full(boundary.shape[0], NO_CURVE, dtype=np.int64)
    if curve_edges.size:
        mapped = new_row[curve_edges]
        ok = np.all(mapped >= 0, axis=1)
        curve_keys = _edge_keys(mapped[ok], n)
        order = np.argsort(curve_keys)
        curve_keys, curve_of = curve_keys[order], curves[ok][order]
        found = _lookup(curve_keys, curve_of.astype(float), _edge_keys(boundary, n))
        boundary_curve = np.where(np.isnan(found), NO_CURVE, found).astype(np.int64)
    _check_conforming(source, x, cells, boundary)
    return _Arrays(x=x, cells=cells, boundary=boundary, boundary_curve=boundary_curve,
                   gmsh_node=tags[used], edges=mesh_edges)


def _check_conforming(source: str, x, cells, boundary) -> None:
    """Refuse boundary edges that lie inside the domain: surfaces that touch or overlap
    without sharing their nodes (the frame field would see a slit there)."""
    from scipy.spatial import cKDTree

    a, b = x[boundary[:, 0]], x[boundary[:, 1]]
    edge = b - a
    outward = np.stack([edge[:, 1], -edge[:, 0]], axis=1)  # the domain is on the left
    probe = 0.5 * (a + b) + 1e-3 * outward
    centres = x[cells].mean(axis=1)
    k = min(12, cells.shape[0])
    _, near = cKDTree(centres).query(probe, k=k)
    near = near.reshape(probe.shape[0], -1)
    inside = np.zeros(probe.shape[0], dtype=bool)
    for j in range(near.shape[1]):
        tri = x[cells[near[:, j]]]  # (k, 3, 2)
        d = [
            (tri[:, (i + 1) % 3, 0] - tri[:, i, 0]) * (probe[:, 1] - tri[:, i, 1])
            - (tri[:, (i + 1) % 3, 1] - tri[:, i, 1]) * (probe[:, 0] - tri[:, i, 0])
            for i in range(3)
        ]
        inside |= (d[0] > 0) & (d[1] > 0) & (d[2] > 0)
    if inside.any():
        raise GeometryError(
            f"{source!r}: {int(inside.sum())} boundary edges lie inside the domain: surfaces "
            "touch or overlap without sharing nodes (use BooleanFragments or Coherence)"
        )


def _interior_angles(x, cells, n) -> np.ndarray:
    """Sum of the triangle angles at every node (2π inside, the interior angle on ∂Ω)."""
    total = np.zeros(n)
    for i in range(3):
        p, q, r = cells[:, i], cells[:, (i + 1) % 3], cells[:, (i + 2) % 3]
        u, v = x[q] - x[p], x[r] - x[p]
        angle = np.arctan2(np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]),
                           np.einsum("ij,ij->i", u, v))
        np.add.at(total, p, angle)
    return total


def _cad_directions(arrays: _Arrays, mesh_angle: np.ndarray):
    """Cross angles ψ at the boundary nodes from the curves' tangents, and the corners.

    At a node inside a curve ψ is the tangent's angle there; at a geometric point the
    crosses of the curves meeting there are averaged in the 4-fold representation
    e^{4iψ} and the interior angle is the angle between the curves' outgoing tangents
    (on the side the mesh says, for reflex corners)."""
    boundary_nodes = np.unique(arrays.boundary)
    row_of_tag = {int(arrays.gmsh_node[row]): int(row) for row in boundary_nodes}
    psi = np.full(arrays.x.shape[0], np.nan)
    curves = sorted({int(c) for c in arrays.boundary_curve if c != NO_CURVE})
    for curve in curves:
        tags, _, param = gmsh.model.mesh.getNodes(1, curve, includeBoundary=False,
                                                  returnParametricCoord=True)
        rows = np.array([row_of_tag.get(int(t), -1) for t in tags], dtype=np.int64)
        if not tags.size or param.size != tags.size:
            continue
        d = np.asarray(gmsh.model.getDerivative(1, curve, param)).reshape(-1, 3)
        ok = (rows >= 0) & (np.hypot(d[:, 0], d[:, 1]) > 0)
        psi[rows[ok]] = np.arctan2(d[ok, 1], d[ok, 0])
    corners = []
    curve_set = set(curves)
    for _, point in gmsh.model.getEntities(0):
        tags = gmsh.model.mesh.getNodes(0, point)[0]
        if tags.size != 1 or int(tags[0]) not in row_of_tag:
            continue
        node = row_of_tag[int(tags[0])]
        xyz = gmsh.model.getValue(0, point, [])
        outgoing = []
        for curve in gmsh.model.getAdjacencies(0, point)[0]:
            if int(curve) not in curve_set:
                continue
            lo, hi = (float(v[0]) for v in gmsh.model.getParametrizationBounds(1, int(curve)))
            for end, sign in ((lo, 1.0), (hi, -1.0)):
                at = gmsh.model.getValue(1, int(curve), [end])
                if math.dist(at[:2], xyz[:2]) > 1e-9 * max(1.0, math.hypot(*xyz[:2])):
                    continue
                t = gmsh.model.getDerivative(1, int(curve), [end])
                if math.hypot(t[0], t[1]) > 0:
                    outgoing.append((sign * t[0], sign * t[1]))
        if not outgoing:
            continue
        z = sum(np.exp(4j * math.atan2(ty, tx)) for tx, ty in outgoing)
        if abs(z) > 1e-9 * len(outgoing):
            psi[node] = np.angle(z) / 4
        if len(outgoing) == 2:
            (ax, ay), (bx, by) = outgoing
            theta = math.atan2(abs(ax * by - ay * bx), ax * bx + ay * by)
            angle = min((theta, 2 * math.pi - theta), key=lambda a: abs(a - mesh_angle[node]))
            if abs(angle - math.pi) > 1e-6:
                corners.append(Corner(float(arrays.x[node, 0]), float(arrays.x[node, 1]), angle))
    return psi, corners


def _mesh_corners(arrays: _Arrays, mesh_angle: np.ndarray) -> list[Corner]:
    """Corners of a bare mesh: boundary nodes whose interior angle is not ~180° (the
    ones a boundary-aligned cross must turn a quarter at)."""
    nodes = np.unique(arrays.boundary)
    turns = np.rint(mesh_angle[nodes] / (math.pi / 2))
    return [
        Corner(float(arrays.x[v, 0]), float(arrays.x[v, 1]), float(mesh_angle[v]))
        for v in nodes[turns != 2]
    ]


def _euler_characteristic(arrays: _Arrays) -> int:
    """χ = V − E + F of the triangulation (1 for a disc, 1 − holes in general)."""
    return int(arrays.x.shape[0] - arrays.edges.shape[0] + arrays.cells.shape[0])


def _mean_edge_length(arrays: _Arrays) -> float:
    e = arrays.edges
    return float(np.linalg.norm(arrays.x[e[:, 1]] - arrays.x[e[:, 0]], axis=1).mean())


# --- Gmsh session handling and distribution ---------------------------------------------


_TOUCHED_OPTIONS = (
    "General.Terminal", "General.AbortOnError", "Mesh.MeshSizeMax", "Mesh.MeshSizeFactor",
    "Mesh.MinimumCirclePoints", "Mesh.MinimumCurvePoints", "Mesh.RecombineAll",
    "Mesh.SubdivisionAlgorithm", "Mesh.Algorithm", "Mesh.ElementOrder",
)


def _create(comm: MPI.Comm, make, source: str, cad: bool,
            time_limit: float = math.inf) -> Domain:
    """Run ``make(notes)`` on rank 0 in a fresh Gmsh model (it meshes, returning the size
    asked for), turn the mesh into checked arrays, distribute it over ``comm``.

    With a finite ``time_limit`` (seconds) that runs in a child process, stopped
    (:class:`MeshTimeLimit`) when it takes longer (see :func:`_in_child`)."""
    root = 0
    error, arrays, info = None, None, None
    if comm.rank == root:
        try:
            if math.isfinite(time_limit) and hasattr(os, "fork"):
                arrays, info = _in_child(lambda: _gmsh_session(make, source, cad), source,
                                         time_limit)
            else:
                arrays, info = _gmsh_session(make, source, cad)
        except GeometryError as e:
            error = (isinstance(e, MeshTimeLimit), str(e))
    error = comm.bcast(error, root=root)
    if error is not None:
        raise (MeshTimeLimit if error[0] else GeometryError)(error[1])
    info = comm.bcast(info, root=root)
    return _distribute(comm, arrays, info, source)


def _gmsh_session(make, source: str, cad: bool):
    """(arrays, info) of ``make``'s mesh, in a fresh Gmsh model (this process, rank 0);
    every failure as :class:`GeometryError`."""
    owns, previous_model, saved = not gmsh.isInitialized(), None, {}
    try:
        if owns:
            gmsh.initialize(argv=[], readConfigFiles=False, interruptible=False)
        else:
            saved = {k: gmsh.option.getNumber(k) for k in _TOUCHED_OPTIONS}
            previous_model = gmsh.model.getCurrent()
        gmsh.option.setNumber("General.Terminal", 1 if _verbose() else 0)
        gmsh.model.add(f"ufl_frames_{id(make):x}")
        notes: list[str] = []
        requested = make(notes)
        arrays = _mesh_arrays(source, notes)
        mesh_angle = _interior_angles(arrays.x, arrays.cells, arrays.x.shape[0])
        if cad:
            psi, corners = _cad_directions(arrays, mesh_angle)
            nodes = np.flatnonzero(np.isfinite(psi)).astype(np.int64)
            directions = (nodes, psi[nodes])
        else:
            corners, directions = _mesh_corners(arrays, mesh_angle), None
        info = {
            "requested": requested,
            "corners": tuple(corners),
            "chi": _euler_characteristic(arrays),
            "h": _mean_edge_length(arrays),
            "notes": tuple(notes),
            "directions": directions,
        }
        return arrays, info
    except GeometryError:
        raise
    except Exception as e:
        raise GeometryError(f"Gmsh failed: {_one_line(e)}") from e
    finally:
        _release(owns, previous_model, saved)


def _in_child(work, source: str, limit: float):
    """``work()`` in a forked child process; its result, or :class:`GeometryError`.

    Gmsh has no way to stop a meshing step from outside (an invalid curve loop makes it
    retry its edge recovery forever), so the step runs in a copy of this process that is
    killed after ``limit`` seconds (:class:`MeshTimeLimit`); a crash of Gmsh there is an
    error here too, not the end of the run. The child inherits the blocked signals of
    :class:`ufl_frames.interrupts.SignalWatch`, gets SIGKILL if this process ends first
    (Linux), and returns its result pickled through a pipe."""
    parent = os.getpid()
    read_end, write_end = os.pipe()
    sys.stdout.flush()
    sys.stderr.flush()
    with warnings.catch_warnings():  # "multi-threaded, fork() may deadlock": the child
        warnings.simplefilter("ignore", DeprecationWarning)  # runs Gmsh and NumPy alone
        pid = os.fork()
    if pid == 0:  # the child: never returns
        status = 1
        try:
            os.close(read_end)
            _die_with(parent)
            try:
                result = ("ok", work())
            except GeometryError as e:
                result = ("error", str(e))
            except BaseException as e:
                result = ("error", f"Gmsh failed: {_one_line(e)}")
            with os.fdopen(write_end, "wb") as pipe:
                pickle.dump(result, pipe, protocol=pickle.HIGHEST_PROTOCOL)
            status = 0
        finally:
            with contextlib.suppress(Exception):
                sys.stdout.flush()
                sys.stderr.flush()
            os._exit(status)
    os.close(write_end)
    deadline = time.monotonic() + limit
    chunks, finished = [], False
    waiting = select.poll()  # not select.select: no limit on the descriptor's number
    waiting.register(read_end, select.POLLIN)
    try:
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or not waiting.poll(min(left, 1e6) * 1000):
                break
            chunk = os.read(read_end, 1 << 20)
            if not chunk:
                finished = True
                break
            chunks.append(chunk)
    finally:
        os.close(read_end)
        if not finished:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        status = os.waitpid(pid, 0)[1]
    if not finished:
        raise MeshTimeLimit(
            f"meshing {source!r} did not end within the time limit of {limit:g} s (an "
            "invalid geometry Gmsh cannot mesh, or a mesh too fine for the limit): stopped"
        )
    try:
        kind, value = pickle.loads(b"".join(chunks))
    except Exception:
        why = (f"killed by {signal.Signals(os.WTERMSIG(status)).name}"
               if os.WIFSIGNALED(status) else f"exit status {os.waitstatus_to_exitcode(status)}")
        raise GeometryError(f"Gmsh crashed on {source!r} ({why})") from None
    if kind == "error":
        raise GeometryError(value)
    return value


def _die_with(parent: int) -> None:
    """SIGKILL for this (child) process when ``parent`` ends (Linux ``prctl``; else none)."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() != parent:  # the parent ended before the prctl
        os._exit(1)


def _distribute(comm: MPI.Comm, arrays: _Arrays | None, info: dict, source: str) -> Domain:
    """The DOLFINx mesh and facet tags from rank 0's arrays (collective)."""
    element = dolfinx.io.gmsh.ufl_mesh(2, 2, dtype=np.float64)  # Gmsh type 2: 3-node triangle
    if comm.rank == 0:
        cells, x = arrays.cells, arrays.x
        facets, values = arrays.boundary, arrays.boundary_curve.astype(np.int32)
    else:
        cells, x = np.zeros((0, 3), dtype=np.int64), np.zeros((0, 2))
        facets, values = np.zeros((0, 2), dtype=np.int64), np.zeros(0, dtype=np.int32)
    mesh = dolfinx.mesh.create_mesh(comm, cells, element, x)
    local, local_values = dolfinx.io.distribute_entity_data(mesh, 1, facets, values)
    mesh.topology.create_connectivity(1, 2)
    tags = dolfinx.mesh.meshtags_from_entities(
        mesh, 1, dolfinx.graph.adjacencylist(local), local_values.astype(np.int32, copy=False)
    )
    tags.name = "boundary_curves"
    nodes, angles = info["directions"] if info["directions"] is not None else (None, None)
    return Domain(
        mesh=mesh,
        facet_tags=tags,
        corners=info["corners"],
        euler_characteristic=info["chi"],
        mesh_size=info["h"],
        requested_mesh_size=info["requested"],
        source=source,
        notes=info["notes"],
        _direction_nodes=nodes,
        _direction_angles=angles,
    )


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
