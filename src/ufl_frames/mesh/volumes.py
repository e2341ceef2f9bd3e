"""3D geometries: Gmsh volumes to distributed P1 tetrahedra, with the boundary's normals.

A :class:`Volume` is what a 3D frame field needs of its geometry: the tetrahedral mesh,
its boundary facets tagged by CAD surface, and at every boundary vertex either the unit
normal one frame axis must follow (a vertex inside a surface, or on a curve where the
surfaces meet smoothly) or, on a sharp feature (a curve or point where surfaces meet at an
angle), the whole frame: the rotation whose axes are closest to the normals that meet
there. Normals come from the CAD surfaces (``gmsh.model.getNormal`` at each node's
parametric coordinates); a ``.msh`` without CAD gets them from its boundary facets.

Built-ins (:func:`box`, :func:`hollow_cylinder`, :func:`ball`) and files (:func:`load`:
``.geo``, ``.step``/``.stp``, ``.brep``, ``.msh``) are meshed on rank 0 and distributed.
"""

import math
from dataclasses import dataclass, field
from pathlib import Path

from ufl_frames.bootstrap import init_petsc

init_petsc()

import dolfinx  # noqa: E402
import dolfinx.io.gmsh  # noqa: E402
import gmsh  # noqa: E402
import numpy as np  # noqa: E402
from mpi4py import MPI  # noqa: E402

from ufl_frames.gmsh_scratch import scratch_model  # noqa: E402
from ufl_frames.mesh.domain import GeometryError, check_mesh_size, lookup, one_line  # noqa: E402

__all__ = ["Volume", "ball", "box", "hollow_cylinder", "load"]

#: Normals at a vertex that differ by more than this angle make it a sharp feature.
FEATURE_ANGLE = math.radians(30.0)
#: Gmsh element type of the 4-node tetrahedron and of the 3-node triangle.
_TET, _TRI = 4, 2


@dataclass(frozen=True)
class Volume:
    """A meshed 3D domain (see the module docstring).

    ``facet_tags`` marks boundary facets with their CAD surface tag (0 without CAD);
    ``mesh_size`` the mean edge length. The boundary data is keyed by input node index
    (sorted): ``_aligned_nodes`` with ``_normals`` (k, 3), ``_feature_nodes`` with
    ``_rotations`` (f, 3, 3); read it per P1 row with :meth:`boundary_frames`.
    """

    mesh: dolfinx.mesh.Mesh
    facet_tags: dolfinx.mesh.MeshTags
    mesh_size: float
    source: str
    notes: tuple[str, ...] = ()
    _aligned_nodes: np.ndarray = field(default=None, repr=False)
    _normals: np.ndarray = field(default=None, repr=False)
    _feature_nodes: np.ndarray = field(default=None, repr=False)
    _rotations: np.ndarray = field(default=None, repr=False)

    @property
    def comm(self) -> MPI.Comm:
        return self.mesh.comm

    @property
    def num_cells(self) -> int:
        return self.mesh.topology.index_map(3).size_global

    @property
    def num_boundary_vertices(self) -> tuple[int, int]:
        """(vertices with one normal: frames aligned with it, vertices on sharp features:
        frames held) on the whole boundary."""
        return int(self._aligned_nodes.size), int(self._feature_nodes.size)

    def boundary_frames(self, V):
        """The boundary rows of the P1 space ``V`` (local, owned and ghost): (aligned rows,
        their unit normals (k, 3)), (feature rows, their rotations (f, 3, 3))."""
        geometry = self.mesh.geometry
        ids = np.asarray(geometry.input_global_indices, dtype=np.int64)
        index_map = V.dofmap.index_map
        n_rows = index_map.size_local + index_map.num_ghosts
        node_of_row = np.full(n_rows, -1, dtype=np.int64)
        # P1: the dofs of a cell are its vertices in the order of its geometry nodes
        node_of_row[V.dofmap.list.ravel()] = ids[geometry.dofmaps[0].ravel()]
        out = []
        for keys, values in ((self._aligned_nodes, self._normals),
                             (self._feature_nodes, self._rotations)):
            flat = values.reshape(values.shape[0], int(np.prod(values.shape[1:])))
            found = np.stack([lookup(keys, flat[:, j], node_of_row) for j in range(flat.shape[1])],
                             axis=1) if keys.size else np.full((n_rows, flat.shape[1]), np.nan)
            rows = np.flatnonzero(np.isfinite(found[:, 0]))
            out.append((rows.astype(np.int32), found[rows].reshape((-1,) + values.shape[1:])))
        return out[0], out[1]


# --- built-ins ------------------------------------------------------------------------


def box(comm: MPI.Comm, size=(1.0, 1.0, 1.0), mesh_size: float = 0.2) -> Volume:
    """The box [0, a] × [0, b] × [0, c]."""
    a, b, c = (float(v) for v in size)
    return _create(comm, lambda: gmsh.model.occ.addBox(0, 0, 0, a, b, c), f"box {a}x{b}x{c}",
                   mesh_size)


def hollow_cylinder(comm: MPI.Comm, inner: float = 0.5, outer: float = 1.0,
                    height: float = 1.0, mesh_size: float = 0.15) -> Volume:
    """The tube inner ≤ r ≤ outer, 0 ≤ z ≤ height."""
    def make():
        o = gmsh.model.occ.addCylinder(0, 0, 0, 0, 0, height, outer)
        i = gmsh.model.occ.addCylinder(0, 0, 0, 0, 0, height, inner)
        gmsh.model.occ.cut([(3, o)], [(3, i)])
    return _create(comm, make, f"hollow cylinder {inner}-{outer}x{height}", mesh_size)


def ball(comm: MPI.Comm, radius: float = 1.0, mesh_size: float = 0.2) -> Volume:
    """The ball |x| ≤ radius."""
    return _create(comm, lambda: gmsh.model.occ.addSphere(0, 0, 0, radius), f"ball {radius}",
                   mesh_size)


def load(comm: MPI.Comm, path, mesh_size: float | None = None) -> Volume:
    """A :class:`Volume` from a ``.geo``, ``.step``/``.stp``, ``.brep`` or ``.msh`` file
    (``mesh_size`` caps the element size; None: the file's own sizes, else a tenth of the
    diameter)."""
    path = Path(path)
    source = str(path)

    def make():
        if not path.is_file():
            raise GeometryError(f"geometry file not found: {source!r}")
        gmsh.merge(source)
        if path.suffix.lower() == ".msh":
            return
        if not gmsh.model.getEntities(3):
            raise GeometryError(f"{source!r} defines no volume")

    return _create(comm, make, source, mesh_size, cad=path.suffix.lower() != ".msh")


# --- the Gmsh session on rank 0 ----------------------------------------------------------


def _create(comm: MPI.Comm, make, source: str, mesh_size: float | None,
            cad: bool = True) -> Volume:
    """``make()``'s volume meshed on rank 0 (fresh Gmsh model), distributed (collective)."""
    if mesh_size is not None:
        mesh_size = check_mesh_size(mesh_size)
    payload, error = None, None
    if comm.rank == 0:
        try:
            payload = _mesh_on_root(make, source, mesh_size, cad)
        except GeometryError as e:
            error = str(e)
        except Exception as e:  # Gmsh's own errors
            error = f"Gmsh failed on {source!r}: {one_line(e)}"
    error = comm.bcast(error, root=0)
    if error is not None:
        raise GeometryError(error)
    return _distribute(comm, payload, source)


def _mesh_on_root(make, source, mesh_size, cad):
    """``make()``'s model (a fresh one, :func:`~ufl_frames.gmsh_scratch.scratch_model`)
    meshed with tetrahedra unless it holds some, as :func:`_arrays`."""
    with scratch_model(f"ufl_frames_volume_{id(make):x}", ("Mesh.MeshSizeMax",)):
        make()
        gmsh.model.occ.synchronize()
        if not gmsh.model.mesh.getElementsByType(_TET)[0].size:
            if mesh_size is None:
                lo, hi = np.array(gmsh.model.getBoundingBox(-1, -1)).reshape(2, 3)
                mesh_size = float(np.linalg.norm(hi - lo)) / 10
            gmsh.option.setNumber("Mesh.MeshSizeMax", mesh_size)
            gmsh.model.mesh.generate(3)
        return _arrays(source, cad)


def _arrays(source: str, cad: bool) -> dict:
    """The tetrahedra, nodes, boundary triangles and boundary frames of the current mesh."""
    tags, coords, _ = gmsh.model.mesh.getNodes()
    row = np.full(int(tags.max(initial=0)) + 1, -1, dtype=np.int64)
    row[tags.astype(np.int64)] = np.arange(tags.size)
    _, tet_nodes = gmsh.model.mesh.getElementsByType(_TET)
    if tet_nodes.size == 0:
        raise GeometryError(f"{source!r} produced no tetrahedra")
    cells = row[tet_nodes.astype(np.int64)].reshape(-1, 4)
    used, cells = np.unique(cells, return_inverse=True)
    cells = cells.reshape(-1, 4)
    x = coords.reshape(-1, 3)[used]
    new_row = np.full(tags.size, -1, dtype=np.int64)
    new_row[used] = np.arange(used.size)
    # boundary faces: those of one tetrahedron
    faces = np.sort(np.concatenate([cells[:, [1, 2, 3]], cells[:, [0, 2, 3]],
                                    cells[:, [0, 1, 3]], cells[:, [0, 1, 2]]]), axis=1)
    unique, counts = np.unique(faces, axis=0, return_counts=True)
    boundary = unique[counts == 1]
    surface_of = np.zeros(boundary.shape[0], dtype=np.int32)
    normals_at: dict[int, list] = {}
    if cad:
        keys = boundary @ np.array([x.shape[0] ** 2, x.shape[0], 1])
        order = np.argsort(keys)
        for _, surface in gmsh.model.getEntities(2):
            _, tri = gmsh.model.mesh.getElementsByType(_TRI, surface)
            tri = np.sort(new_row[row[tri.astype(np.int64)]].reshape(-1, 3), axis=1)
            k = tri @ np.array([x.shape[0] ** 2, x.shape[0], 1])
            pos = np.searchsorted(keys[order], k)
            hit = (pos < keys.size) & (keys[order][np.minimum(pos, keys.size - 1)] == k)
            surface_of[order[pos[hit]]] = surface
            nodes = np.unique(tri[hit])
            if nodes.size == 0:
                continue
            uv = gmsh.model.getParametrization(2, surface, x[nodes].ravel().tolist())
            n = np.asarray(gmsh.model.getNormal(surface, uv)).reshape(-1, 3)
            for node, normal in zip(nodes, n, strict=True):
                normals_at.setdefault(int(node), []).append(normal)
    else:
        a, b, c = (x[boundary[:, i]] for i in range(3))
        n = np.cross(b - a, c - a)
        n /= np.linalg.norm(n, axis=1)[:, None]
        for face, normal in zip(boundary, n, strict=True):
            for node in face:
                normals_at.setdefault(int(node), []).append(normal)
    aligned, normals, features, rotations = [], [], [], []
    for node, ns in sorted(normals_at.items()):
        ns = np.asarray(ns)
        ns = ns / np.linalg.norm(ns, axis=1)[:, None]
        distinct = _distinct_directions(ns)
        if len(distinct) == 1:
            aligned.append(node)
            normals.append(distinct[0])
        else:
            features.append(node)
            rotations.append(_frame_of_normals(distinct))
    h = float(np.mean(np.linalg.norm(x[cells[:, 1]] - x[cells[:, 0]], axis=1)))
    return dict(x=x, cells=cells, boundary=boundary, surface=surface_of, h=h,
                aligned=np.array(aligned, dtype=np.int64),
                normals=np.array(normals).reshape(-1, 3),
                features=np.array(features, dtype=np.int64),
                rotations=np.array(rotations).reshape(-1, 3, 3))


def _distinct_directions(ns: np.ndarray) -> list[np.ndarray]:
    """The normals at a vertex grouped by direction (up to sign, within
    :data:`FEATURE_ANGLE`): one averaged unit vector per group."""
    groups: list[list[np.ndarray]] = []
    for n in ns:
        for g in groups:
            if abs(float(g[0] @ n)) > math.cos(FEATURE_ANGLE):
                g.append(n if g[0] @ n > 0 else -n)
                break
        else:
            groups.append([n])
    out = []
    for g in groups:
        m = np.sum(g, axis=0)
        out.append(m / np.linalg.norm(m))
    return out


def _frame_of_normals(directions: list[np.ndarray]) -> np.ndarray:
    """The rotation whose first axes are closest to the given normals (two or more, taken
    in order; the third axis their cross product): the orthogonal polar factor."""
    a = directions[0]
    b = directions[1]
    c = np.cross(a, b)
    M = np.stack([a, b, c / max(np.linalg.norm(c), 1e-300)], axis=1)
    U, _, Vt = np.linalg.svd(M)
    R = U @ Vt
    if np.linalg.det(R) < 0:
        R[:, 2] *= -1
    return R


def _distribute(comm: MPI.Comm, data: dict | None, source: str) -> Volume:
    element = dolfinx.io.gmsh.ufl_mesh(_TET, 3, dtype=np.float64)
    if comm.rank == 0:
        cells, x = data["cells"], data["x"]
        facets, values = data["boundary"], data["surface"]
    else:
        cells, x = np.zeros((0, 4), dtype=np.int64), np.zeros((0, 3))
        facets, values = np.zeros((0, 3), dtype=np.int64), np.zeros(0, dtype=np.int32)
    mesh = dolfinx.mesh.create_mesh(comm, cells, element, x)
    local, local_values = dolfinx.io.distribute_entity_data(mesh, 2, facets, values)
    mesh.topology.create_connectivity(2, 3)
    tags = dolfinx.mesh.meshtags_from_entities(
        mesh, 2, dolfinx.graph.adjacencylist(local), local_values.astype(np.int32, copy=False))
    tags.name = "boundary_surfaces"
    shared = comm.bcast(None if comm.rank else {k: data[k] for k in
                                                ("h", "aligned", "normals", "features",
                                                 "rotations")}, root=0)
    return Volume(mesh=mesh, facet_tags=tags, mesh_size=shared["h"], source=source,
                  _aligned_nodes=shared["aligned"], _normals=shared["normals"],
                  _feature_nodes=shared["features"], _rotations=shared["rotations"])
