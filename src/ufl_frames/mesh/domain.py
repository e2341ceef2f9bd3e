"""The meshed domain record and what every stage of building one shares.

:class:`Domain` is what the frame-field pipeline receives: the distributed P1 triangle
mesh, its boundary facets tagged by curve, the corners and the CAD boundary directions.
:class:`GeometryError` (and :class:`MeshTimeLimit`) is the one-line error of every
builder; the argument checks here raise it.
"""

import math
import numbers
from dataclasses import dataclass, field

from ufl_frames.bootstrap import init_petsc

init_petsc()

import dolfinx  # noqa: E402
import numpy as np  # noqa: E402
from mpi4py import MPI  # noqa: E402

from ufl_frames.frames2d.singularities import corner_quarter_turns  # noqa: E402

#: Facet tag of boundary edges that lie on no curve of the file (a bare ``.msh``).
NO_CURVE = 0


class GeometryError(ValueError):
    """A geometry could not be built, read or meshed (one-line message)."""


class MeshTimeLimit(GeometryError):
    """Reading and meshing a geometry file took longer than its time limit."""


class TooManyTriangles(GeometryError):
    """The mesh size asked for would give more triangles than the limit."""


@dataclass(frozen=True)
class Corner:
    """A corner of the boundary: position, interior angle (radians) and its quarter
    turns ``k = round(angle / (π/2))``, at least 1 (a corner under 45° is a squeezed quad
    corner: :func:`~ufl_frames.frames2d.singularities.corner_quarter_turns`); a
    boundary-aligned cross field gets the index (2 − k)/4 from it (a right-angled convex
    corner: 1/4, a reflex one: −1/4)."""

    x: float
    y: float
    angle: float

    @property
    def quarter_turns(self) -> int:
        return corner_quarter_turns(self.angle)


@dataclass(frozen=True)
class Junction:
    """A point where curves inside the domain (interfaces, embedded curves) end, turn or
    meet each other or the boundary: position, the angles (radians) of the sectors
    between consecutive curves counter-clockwise (inside the domain: all around, summing
    to 2π; on the boundary: from one boundary curve to the other, summing to the
    interior angle) and whether it lies on the boundary.

    A cross field aligned to every curve turns by α − k π/2 across a sector of angle α
    (k = round(α/(π/2))), so it has the index :attr:`index` there: 0 at a T or a cross
    of curves, at an interface meeting a straight boundary at 90°, at the end of an
    embedded curve; +1/4 where three curves meet at 120°; −1/4 at deal.II step-49's
    300° slit tip, split 60° + 90° + 90° + 60° (3 quarter turns whole, 4 by sectors).

    The regions the curves cut out, each with its own Poincaré–Hopf sum (a junction's
    sectors its corners, k_i quarter turns each), sum to χ − Σ_c (2 − k_c)/4 − Σ_J
    index_J, the whole domain's sum less the junctions' indices (Euler's formula over
    the curves' arcs and junctions); the field's triangles, which also cover the
    junctions, still sum to the whole domain's χ − Σ_c (2 − k_c)/4, the boundary
    corners counted whole.
    """

    x: float
    y: float
    sectors: tuple[float, ...]
    on_boundary: bool

    @property
    def index(self) -> float:
        """(k − Σ_i k_i)/4: k_i the sectors' quarter turns, k that of the whole angle
        (4 inside the domain; on the boundary the corner's, at least 1 as for
        :class:`Corner`)."""
        k = [int(round(a / (math.pi / 2))) for a in self.sectors]
        whole = corner_quarter_turns(sum(self.sectors)) if self.on_boundary else 4
        return (whole - sum(k)) / 4


@dataclass(frozen=True)
class PhysicalGroup:
    """A named group of model entities of the file (Gmsh's ``Physical Curve`` /
    ``Physical Surface`` / ``Physical Point``): its dimension, number, name ('' where the
    file gives none) and the tags of its entities."""

    dim: int
    tag: int
    name: str
    entities: tuple[int, ...]


@dataclass(frozen=True)
class Plane:
    """The plane of a surface that lies in no plane z = const: a point ``origin`` and two
    orthonormal axes ``e1``, ``e2`` (e1 × e2 its normal). The mesh's coordinates are then
    (u, v) = ((p − o)·e1, (p − o)·e2), and p = o + u e1 + v e2 the original point."""

    origin: tuple[float, float, float]
    e1: tuple[float, float, float]
    e2: tuple[float, float, float]

    def to_3d(self, uv) -> np.ndarray:
        """The original (n, 3) points of plane coordinates ``uv`` (n, 2)."""
        uv = np.asarray(uv, dtype=float).reshape(-1, 2)
        return (np.asarray(self.origin) + uv[:, :1] * np.asarray(self.e1)
                + uv[:, 1:] * np.asarray(self.e2))

    def to_plane(self, xyz) -> np.ndarray:
        """The plane coordinates (n, 2) of points ``xyz`` (n, 3)."""
        d = np.asarray(xyz, dtype=float).reshape(-1, 3) - np.asarray(self.origin)
        return np.stack([d @ np.asarray(self.e1), d @ np.asarray(self.e2)], axis=1)

    def record(self) -> dict:
        """The plane as JSON-ready lists: origin, e1, e2 and the normal."""
        normal = np.cross(self.e1, self.e2)
        return {"origin": list(self.origin), "e1": list(self.e1), "e2": list(self.e2),
                "normal": [float(c) for c in normal]}


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
    ``plane`` is the :class:`Plane` of a surface in a tilted plane (the mesh is in its
    (u, v) coordinates), None for one in z = const (the mesh's x, y).

    The model entities: ``cell_tags`` the surface (region) of every cell;
    ``curve_tags`` every facet on a model curve, on the boundary and inside (interfaces
    between surfaces, curves embedded in a surface), with the curve's tag; ``point_tags``
    the vertices at model points (corners, ends of curves, embedded points) with the
    point's tag; ``junctions`` the points where interior curves end, turn or meet (the
    same on every rank); ``physical_groups`` the file's named groups. A mesh without a
    model (built without them) has None tags.
    """

    mesh: dolfinx.mesh.Mesh
    facet_tags: dolfinx.mesh.MeshTags
    corners: tuple[Corner, ...]
    euler_characteristic: int
    mesh_size: float
    requested_mesh_size: float | None
    source: str
    notes: tuple[str, ...] = ()
    #: The file's physical groups (empty: the file has none, or a built-in shape).
    physical_groups: tuple[PhysicalGroup, ...] = ()
    cell_tags: dolfinx.mesh.MeshTags | None = None
    curve_tags: dolfinx.mesh.MeshTags | None = None
    point_tags: dolfinx.mesh.MeshTags | None = None
    junctions: tuple[Junction, ...] = ()
    plane: Plane | None = None
    #: Curve directions from the CAD model (boundary and interior curves): sorted input
    #: node indices and the cross angle ψ (a tangent's angle, mod π/2) at each of them.
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

    def interior_curve_facets(self) -> np.ndarray:
        """The local facets on a model curve that are not on the boundary (interfaces,
        embedded curves), owned ones only (each facet on one rank)."""
        if self.curve_tags is None:
            return np.zeros(0, dtype=np.int32)
        topology = self.mesh.topology
        topology.create_connectivity(1, 2)
        exterior = dolfinx.mesh.exterior_facet_indices(topology)
        facets = self.curve_tags.indices[self.curve_tags.values != NO_CURVE]
        owned = topology.index_map(1).size_local
        return np.setdiff1d(facets[facets < owned], exterior).astype(np.int32)

    def boundary_angles(self, V) -> np.ndarray | None:
        """Cross angle ψ (mod π/2) from the CAD curves at every local row of the P1 space
        ``V`` on a model curve, boundary or interior (NaN where the model gives none);
        None without a CAD model."""
        if self._direction_nodes is None:
            return None
        geometry = self.mesh.geometry
        at_node = lookup(self._direction_nodes, self._direction_angles,
                          np.asarray(geometry.input_global_indices, dtype=np.int64))
        index_map = V.dofmap.index_map
        angles = np.full(index_map.size_local + index_map.num_ghosts, np.nan)
        # P1: the dofs of a cell are its vertices in the order of its geometry nodes.
        angles[V.dofmap.list.ravel()] = at_node[geometry.dofmaps[0].ravel()]
        return angles


def lookup(keys: np.ndarray, values: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """values[keys == w] for each w of ``wanted``; NaN where absent.

    Args:
        keys: Sorted keys.
        values: The value of each key.
        wanted: The keys looked up.

    Returns:
        A float array of ``wanted``'s shape.
    """
    out = np.full(wanted.shape, np.nan)
    if keys.size:
        pos = np.minimum(np.searchsorted(keys, wanted), keys.size - 1)
        hit = keys[pos] == wanted
        out[hit] = values[pos[hit]]
    return out


# --- argument checks ---------------------------------------------------------------


def is_real(x) -> bool:
    """Whether ``x`` is a real number (not a bool)."""
    return isinstance(x, numbers.Real) and not isinstance(x, bool)


def check_refinements(refinements) -> int:
    """``refinements`` as an int, or :class:`GeometryError` if it is not one ≥ 0."""
    if (isinstance(refinements, bool) or not isinstance(refinements, numbers.Integral)
            or refinements < 0):
        raise GeometryError(f"refinements must be a non-negative integer, got {refinements!r}")
    return int(refinements)


def check_positive(name: str, value) -> float:
    """``value`` as a float, or :class:`GeometryError` naming ``name`` if it is not a
    positive finite number."""
    if not is_real(value) or not math.isfinite(value) or value <= 0:
        raise GeometryError(f"{name} must be a positive finite number, got {value!r}")
    return float(value)


def check_mesh_size(mesh_size) -> float:
    """``mesh_size`` as a float, or :class:`GeometryError` if it is not positive and finite."""
    return check_positive("mesh_size", mesh_size)


def one_line(e: BaseException | str) -> str:
    """An error's message on one line (its type's name where it has none)."""
    text = " ".join(str(e).split())
    return text or type(e).__name__
