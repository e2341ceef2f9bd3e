"""Quad meshes on disk and on screen: Gmsh MSH 4.1, ParaView ``.vtu``, a picture.

A quad mesh is ``points`` (n, 2) and ``quads`` (m, 4), counter-clockwise rows of point
indices (:mod:`ufl_frames.quads.measures`).

* :func:`write_quad_msh` — MSH 4.1 through the Gmsh API. Without the model's entities:
  one discrete surface holding the 4-node quads (Gmsh type 3) and one discrete curve
  holding the boundary lines (type 1), physical groups ``domain`` (2D, tag 1) and
  ``boundary`` (1D, tag 2), so that ``dolfinx.io.gmsh.read_from_msh(path, comm, 0,
  gdim=2)`` reads a quadrilateral mesh with its boundary facets tagged 2. With them (a
  region per quad, the edges on model curves, the nodes at model points): the model's
  entities with the file's tags — a discrete surface per region with its quads, a
  discrete curve per curve with its lines, a point entity per model point with its node
  (a point element, type 15) — and the file's physical groups with their names and
  numbers; without groups every element is saved (Gmsh's ``Mesh.SaveAll``), as Gmsh
  writes a model that has none (DOLFINx reads only files with physical groups).
* :func:`gmsh_quality` — Gmsh's own per-element quality of the quads. ``minSIGE`` is an
  independent check of :func:`~ufl_frames.quads.measures.scaled_jacobians` (the same
  number on valid linear quads); ``minSJ``, the default, is Gmsh's Jacobian ratio (min
  corner Jacobian / Jacobian at the centre), not the corner-angle scaled Jacobian.
* :func:`write_quad_vtu` — ASCII VTK XML unstructured grid (VTK_QUAD = 9) with cell data,
  written with NumPy alone.
* :func:`plot_quads` — the quads coloured by scaled Jacobian, irregular vertices marked.

Gmsh is imported only by the functions that use it. It is finalised afterwards unless the
caller had initialised it; then the caller's current model and the options touched here
are restored.
"""

from pathlib import Path

import numpy as np

from ufl_frames.gmsh_scratch import scratch_model
from ufl_frames.quads.measures import _arrays, scaled_jacobians, vertex_valence

__all__ = ["entity_groups", "gmsh_quality", "mesh_boundary_edges", "plot_quads",
           "write_quad_msh", "write_quad_vtu"]

#: Physical group tags of :func:`write_quad_msh`.
DOMAIN_TAG = 1
BOUNDARY_TAG = 2
#: Gmsh element types.
GMSH_POINT, GMSH_LINE, GMSH_QUAD = 15, 1, 3
#: VTK cell type of a 4-node quadrilateral.
VTK_QUAD = 9

_TOUCHED_OPTIONS = ("General.Terminal", "Mesh.MshFileVersion", "Mesh.Binary",
                    "Mesh.SaveAll")


def _gmsh_model(name: str):
    """A fresh Gmsh model (:func:`ufl_frames.gmsh_scratch.scratch_model`) whose file
    options this module may set."""
    return scratch_model(name, _TOUCHED_OPTIONS)


def mesh_boundary_edges(quads) -> np.ndarray:
    """Edges (k, 2) in one quad only, directed as in their quad (domain on the left)."""
    q = np.asarray(quads, dtype=np.int64).reshape(-1, 4)
    directed = np.stack([q, np.roll(q, -1, axis=1)], axis=-1).reshape(-1, 2)
    ordered = np.sort(directed, axis=1)
    _, inverse, counts = np.unique(ordered, axis=0, return_inverse=True, return_counts=True)
    return directed[counts[inverse.ravel()] == 1]


def _add_quads(gmsh, xyz: np.ndarray, q: np.ndarray, lines: np.ndarray) -> tuple[int, int | None]:
    """Nodes (tags 1..n) at ``xyz`` (n, 3), quads (tags 1..m) and lines (m+1..) in the
    current model, on a discrete surface and, if there are lines, a discrete curve
    bounding it."""
    n, m = xyz.shape[0], q.shape[0]
    tags = np.arange(1, n + 1)
    curve = gmsh.model.addDiscreteEntity(1) if lines.size else None
    surface = gmsh.model.addDiscreteEntity(2, -1, [curve] if curve else [])
    on_curve = np.zeros(n, dtype=bool)
    if curve is not None:
        on_curve[lines.ravel()] = True
        gmsh.model.mesh.addNodes(1, curve, tags[on_curve], xyz[on_curve].ravel())
    gmsh.model.mesh.addNodes(2, surface, tags[~on_curve], xyz[~on_curve].ravel())
    gmsh.model.mesh.addElementsByType(surface, GMSH_QUAD, np.arange(1, m + 1),
                                      (q + 1).ravel())
    if curve is not None:
        gmsh.model.mesh.addElementsByType(curve, GMSH_LINE,
                                          np.arange(m + 1, m + 1 + lines.shape[0]),
                                          (lines + 1).ravel())
    return surface, curve


def write_quad_msh(path, points, quads, boundary_edges=None, *, quad_region=None,
                   curve_edges=None, edge_curve=None, point_nodes=None, point_tag=None,
                   groups=(), coordinates=None) -> Path:
    """Write the quad mesh as Gmsh MSH 4.1 (ASCII) to ``path`` (a ``.msh`` file).

    Without ``quad_region``, ``curve_edges`` and ``point_nodes``: one surface (physical
    group ``domain``) and the ``boundary_edges`` (k, 2) as lines of one curve (physical
    group ``boundary``); None: the mesh's boundary edges (:func:`mesh_boundary_edges`); an
    empty array: no lines and no boundary group.

    With any of them: the model's entities (module text). ``quad_region`` None puts every
    quad in surface 1; ``boundary_edges`` is then unused (the lines are ``curve_edges``).
    ``groups``: records with ``dim``, ``tag``, ``name`` and ``entities`` (such as
    :class:`ufl_frames.mesh.domain.PhysicalGroup`), written as physical groups of the
    entities written (a group none of whose entities has elements is left out); empty:
    no groups, every element saved. Node i is Gmsh node i + 1, quad j element j + 1, then
    the lines in the order given, then the point elements.

    Args:
        path: the file to write; its suffix must be ``.msh``.
        points: the points (n, 2).
        quads: point indices (m, 4).
        boundary_edges: the boundary lines (k, 2), as above.
        quad_region: (m,) the surface tag of every quad (tags > 0).
        curve_edges: (k, 2) point pairs of the quad edges on model curves.
        edge_curve: (k,) the curve tag of each (> 0).
        point_nodes: (p,) points at model points.
        point_tag: (p,) the model point's tag of each (> 0).
        groups: the physical groups, as above.
        coordinates: (n, 3) the nodes' coordinates written (a surface in a tilted plane
            written in it); None: (x, y, 0) of ``points``.

    Returns:
        ``path`` as a :class:`~pathlib.Path`.

    Raises:
        ValueError: ``path`` is not a ``.msh``, the arrays have a wrong shape, an index
            lies outside the points, or a tag is not positive.
    """
    path = Path(path)
    if path.suffix.lower() != ".msh":
        raise ValueError(f"write_quad_msh writes .msh files, got {str(path)!r}")
    x, q = _arrays(points, quads)
    xyz = np.c_[x, np.zeros(x.shape[0])] if coordinates is None else np.asarray(
        coordinates, dtype=float)
    if xyz.shape != (x.shape[0], 3) or not np.all(np.isfinite(xyz)):
        raise ValueError(f"coordinates must be finite with shape ({x.shape[0]}, 3), "
                         f"got {xyz.shape}")
    model = quad_region is not None or curve_edges is not None or point_nodes is not None
    if model:
        entities = _model_entities(x.shape[0], q, quad_region, curve_edges, edge_curve,
                                   point_nodes, point_tag)
    else:
        lines = (mesh_boundary_edges(q) if boundary_edges is None
                 else np.asarray(boundary_edges, dtype=np.int64))
        lines = _indices(lines.reshape(-1, 2), x.shape[0], "boundary edges")
    with _gmsh_model(f"quads_{path.stem}") as gmsh:
        if model:
            written = _add_model(gmsh, xyz, q, entities)
            for group in groups:
                dim, tag = int(group.dim), int(group.tag)
                kept = [int(e) for e in group.entities if (dim, int(e)) in written]
                if kept:
                    gmsh.model.addPhysicalGroup(dim, kept, tag, name=str(group.name))
            save_all = 0 if gmsh.model.getPhysicalGroups() else 1
        else:
            surface, curve = _add_quads(gmsh, xyz, q, lines)
            gmsh.model.addPhysicalGroup(2, [surface], DOMAIN_TAG, name="domain")
            if curve is not None:
                gmsh.model.addPhysicalGroup(1, [curve], BOUNDARY_TAG, name="boundary")
            save_all = 0
        gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
        gmsh.option.setNumber("Mesh.Binary", 0)
        gmsh.option.setNumber("Mesh.SaveAll", save_all)
        gmsh.write(str(path))
    return path


def entity_groups(quad_region=None, edge_curve=None, point_tag=None) -> tuple:
    """One unnamed physical group per model entity (surfaces, curves, points; group tag =
    entity tag): for :func:`write_quad_msh` where the geometry has no groups but the file
    must be read by a program that needs them (DOLFINx)."""
    from types import SimpleNamespace

    out = []
    for dim, tags in ((2, quad_region), (1, edge_curve), (0, point_tag)):
        if tags is not None:
            out += [SimpleNamespace(dim=dim, tag=int(t), name="", entities=(int(t),))
                    for t in np.unique(np.asarray(tags, dtype=np.int64))]
    return tuple(out)


def _indices(a: np.ndarray, n: int, what: str) -> np.ndarray:
    """``a`` as int64 point indices, or ValueError if one lies outside 0..n-1."""
    a = np.asarray(a, dtype=np.int64)
    if a.size and (a.min() < 0 or a.max() >= n):
        raise ValueError(f"{what} index points outside 0..{n - 1}")
    return a


def _tags(a, count: int, what: str) -> np.ndarray:
    """``a`` as (count,) positive int64 entity tags, or ValueError."""
    a = np.asarray(a, dtype=np.int64).ravel()
    if a.shape != (count,):
        raise ValueError(f"{what} must have shape ({count},), got {a.shape}")
    if a.size and a.min() <= 0:
        raise ValueError(f"{what} must be positive entity tags, got {int(a.min())}")
    return a


def _model_entities(n: int, q: np.ndarray, quad_region, curve_edges, edge_curve,
                    point_nodes, point_tag) -> dict:
    """The checked arrays of the model's entities and which entity owns every node (the
    lowest-dimensional one it lies on: a point, else a curve, else a surface)."""
    m = q.shape[0]
    region = (np.ones(m, dtype=np.int64) if quad_region is None
              else _tags(quad_region, m, "quad_region"))
    edges = _indices(np.zeros((0, 2)) if curve_edges is None else curve_edges, n,
                     "curve edges").reshape(-1, 2)
    curve = _tags(np.zeros(0) if edge_curve is None else edge_curve, edges.shape[0],
                  "edge_curve")
    nodes = _indices(np.zeros(0) if point_nodes is None else point_nodes, n,
                     "point nodes").ravel()
    point = _tags(np.zeros(0) if point_tag is None else point_tag, nodes.shape[0], "point_tag")
    owner = np.zeros((n, 2), dtype=np.int64)  # (dim, tag); dim 3: unowned yet
    owner[:, 0] = 3
    owner[nodes] = np.c_[np.zeros_like(point), point]
    free = owner[edges.ravel(), 0] == 3
    owner[edges.ravel()[free]] = np.c_[np.ones(free.sum(), dtype=np.int64),
                                       np.repeat(curve, 2)[free]]
    corners = q.ravel()
    free = owner[corners, 0] == 3
    owner[corners[free]] = np.c_[np.full(free.sum(), 2), np.repeat(region, 4)[free]]
    # the curves bounding each surface: those with an edge of one of its quads
    directed = np.stack([q, np.roll(q, -1, axis=1)], axis=-1).reshape(-1, 2)
    key = np.sort(directed, axis=1) @ np.array([n, 1], dtype=np.int64)
    order = np.argsort(key)
    wanted = np.sort(edges, axis=1) @ np.array([n, 1], dtype=np.int64)
    pos = np.minimum(np.searchsorted(key[order], wanted), max(key.size - 1, 0))
    bounding = {}
    for c, i, hit in zip(curve, pos, key[order][pos] == wanted, strict=True):
        if hit:
            bounding.setdefault(int(region[order[i] // 4]), set()).add(int(c))
    return dict(region=region, edges=edges, curve=curve, nodes=nodes, point=point,
                owner=owner, bounding=bounding)


def _add_model(gmsh, xyz: np.ndarray, q: np.ndarray, e: dict) -> set:
    """The entities of :func:`_model_entities` with their nodes and elements in the current
    model, nodes at ``xyz`` (n, 3); the (dim, tag) pairs written."""
    n, m = xyz.shape[0], q.shape[0]
    node_tags = np.arange(1, n + 1)
    written = set()
    for p in np.unique(e["point"]):
        gmsh.model.addDiscreteEntity(0, int(p))
        written.add((0, int(p)))
    for c in np.unique(e["curve"]):
        ends = np.unique(e["edges"][e["curve"] == c])
        ends = [int(t) for t in np.unique(e["point"][np.isin(e["nodes"], ends)])]
        gmsh.model.addDiscreteEntity(1, int(c), ends)
        written.add((1, int(c)))
    for r in np.unique(e["region"]):
        gmsh.model.addDiscreteEntity(2, int(r), sorted(e["bounding"].get(int(r), ())))
        written.add((2, int(r)))
    owner = e["owner"]
    for dim, tag in sorted(written):
        mine = (owner[:, 0] == dim) & (owner[:, 1] == tag)
        if mine.any():
            gmsh.model.mesh.addNodes(dim, tag, node_tags[mine], xyz[mine].ravel())
    for r in np.unique(e["region"]):
        which = np.flatnonzero(e["region"] == r)
        gmsh.model.mesh.addElementsByType(int(r), GMSH_QUAD, which + 1, (q[which] + 1).ravel())
    for c in np.unique(e["curve"]):
        which = np.flatnonzero(e["curve"] == c)
        gmsh.model.mesh.addElementsByType(int(c), GMSH_LINE, m + 1 + which,
                                          (e["edges"][which] + 1).ravel())
    first = m + 1 + e["edges"].shape[0]
    for i, (node, p) in enumerate(zip(e["nodes"], e["point"], strict=True)):
        gmsh.model.mesh.addElementsByType(int(p), GMSH_POINT, [first + i], [int(node) + 1])
    return written


def gmsh_quality(points, quads, measure: str = "minSJ") -> np.ndarray:
    """Gmsh's ``getElementQualities`` of every quad (m,), ``measure`` one of Gmsh's names
    (``minSJ``, ``minSICN``, ``minSIGE``, ``gamma``, ...; module docstring). Gmsh ignores
    the orientation: a clockwise square gets 1.

    Args:
        points: the points (n, 2).
        quads: point indices (m, 4).
        measure: the quality's Gmsh name.

    Returns:
        The quality of every quad (m,).
    """
    x, q = _arrays(points, quads)
    with _gmsh_model("quads_quality") as gmsh:
        _add_quads(gmsh, np.c_[x, np.zeros(x.shape[0])], q, np.zeros((0, 2), dtype=np.int64))
        return np.asarray(
            gmsh.model.mesh.getElementQualities(np.arange(1, q.shape[0] + 1), measure),
            dtype=float)


def write_quad_vtu(path, points, quads, cell_data: dict | None = None) -> Path:
    """Write the quad mesh with ``cell_data`` (name → (m,) or (m, c) array) as an ASCII
    VTK XML unstructured grid (``.vtu``) for ParaView.

    Args:
        path: the file to write.
        points: the points (n, 2) (written with z = 0) or (n, 3).
        quads: point indices (m, 4).
        cell_data: arrays per quad by name (None: none).

    Returns:
        ``path`` as a :class:`~pathlib.Path`.

    Raises:
        ValueError: the arrays have a wrong shape, or an index lies outside the points.
    """
    from ufl_frames.output.vtk import write_vtu

    x = np.asarray(points, dtype=float)
    if x.ndim == 2 and x.shape[1] == 3:
        _, q = _arrays(x[:, :2], quads)
    else:
        x, q = _arrays(points, quads)
    return write_vtu(path, x, q, "quad", cell_data=cell_data)


def plot_quads(path, points, quads, title: str = "", highlight: bool = True) -> Path:
    """Picture of the quads coloured by scaled Jacobian (colour bar), with the irregular
    vertices marked: fewer edges than regular (valence 3 inside) as blue dots, more
    (valence 5 inside) as red squares.

    Args:
        path: the image file to write (its suffix picks the format, e.g. ``.png``).
        points: the points (n, 2).
        quads: point indices (m, 4).
        title: the figure's title.
        highlight: mark the irregular vertices.

    Returns:
        ``path`` as a :class:`~pathlib.Path`.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    x, q = _arrays(points, quads)
    sj = scaled_jacobians(x, q)
    lo, hi = x.min(axis=0), x.max(axis=0)
    aspect = (hi[1] - lo[1]) / max(hi[0] - lo[0], 1e-300)
    fig, ax = plt.subplots(figsize=(7.5, max(2.5, min(9.0, 6.5 * aspect)) + 0.8))
    cells = PolyCollection(x[q], array=sj, cmap="viridis", edgecolors="k",
                           linewidths=0.3 if q.shape[0] < 5000 else 0.0)
    cells.set_clim(min(0.0, float(sj.min())), 1.0)
    ax.add_collection(cells, autolim=False)  # the limits are set below: no path extents
    fig.colorbar(cells, ax=ax, label="scaled Jacobian", shrink=0.8)
    if highlight:
        v = vertex_valence(x, q)
        used = v["expected"] > 0
        size = max(6.0, min(40.0, 4000.0 / max(q.shape[0], 1)))
        for mask, style, label in (
            (used & (v["valence"] < v["expected"]), dict(c="tab:blue", marker="o"),
             "fewer edges (valence 3)"),
            (used & (v["valence"] > v["expected"]), dict(c="tab:red", marker="s"),
             "more edges (valence 5)"),
        ):
            if mask.any():
                ax.scatter(x[mask, 0], x[mask, 1], s=size, zorder=3, edgecolors="w",
                           linewidths=0.5, label=f"{label}: {int(mask.sum())}", **style)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="upper center", bbox_to_anchor=(0.5, 0.0), ncol=2, fontsize=8,
                      frameon=False)
    pad = 0.02 * max(hi - lo)
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal")
    ax.set_axis_off()
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    path = Path(path)
    # a PNG at zlib level 1, not 6: a third less time to encode, the file ~10 % larger
    png = path.suffix.lower() == ".png"
    fig.savefig(path, dpi=150, **({"pil_kwargs": {"compress_level": 1}} if png else {}))
    plt.close(fig)
    return path
