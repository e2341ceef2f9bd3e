"""A 3D frame field's results: the frames for ParaView, its singular graph, a picture.

:func:`write_volume_field` writes, on rank 0 from gathered arrays:

* ``frames3d.vtu`` — the tetrahedra with the frame at every vertex as three vector
  fields ``u1``, ``u2``, ``u3`` (the directions scaled by their lengths) and the lengths:
  ParaView's Glyph filter (arrows or lines, one per field) draws the crosses;
* ``singular.vtu`` — the singular edges as lines, with ``turn`` (quarter turns of the
  monodromy) and ``chain`` per edge;
* ``singular.png`` — the singular graph in 3D inside the boundary's sharp edges
  (matplotlib).
"""

from pathlib import Path

import numpy as np

from ufl_frames.output.vtk import write_vtu

__all__ = ["outline", "plot_singular_graph", "write_volume_field"]


def write_volume_field(folder, x, cells, q, graph, title: str = "") -> list[Path]:
    """Write ``frames3d.vtu``, ``singular.vtu`` and ``singular.png`` into ``folder``.

    Args:
        folder: an existing folder.
        x: vertex coordinates (n, 3).
        cells: tetrahedra (m, 4).
        q: the frame coefficients at the vertices (n, 15).
        graph: the field's :class:`~ufl_frames.frames3d.singular.SingularGraph`.
        title: the picture's title.

    Returns:
        The paths written.
    """
    from ufl_frames.frames3d import odeco

    folder = Path(folder)
    lengths, R = odeco.q_to_frames(q)
    point_data = {f"u{i + 1}": R[:, :, i] * lengths[:, i, None] for i in range(3)}
    point_data["lengths"] = lengths
    written = [write_vtu(folder / "frames3d.vtu", x, cells, "tetra", point_data=point_data)]
    edges = graph.edges if graph.edges.size else np.zeros((0, 2), dtype=np.int64)
    written.append(write_vtu(folder / "singular.vtu", x, edges, "line",
                             cell_data={"turn": graph.turn, "chain": graph.chains}))
    written.append(plot_singular_graph(folder / "singular.png", x, cells, graph, title))
    return written


def plot_singular_graph(path, x, cells, graph, title: str = "") -> Path:
    """Picture of the singular edges (coloured by chain) in an axonometric view, inside
    the boundary: its sharp edges (:func:`outline`) as thin lines and, faintly, its
    vertices."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    from ufl_frames.frames3d.singular import boundary_vertices

    fig = plt.figure(figsize=(6, 6))
    ax = fig.add_subplot(projection="3d")
    b = x[boundary_vertices(cells)]
    ax.scatter(b[:, 0], b[:, 1], b[:, 2], s=1, c="0.85", alpha=0.5, depthshade=False)
    sharp = outline(x, cells)
    if len(sharp):
        ax.add_collection3d(Line3DCollection(x[sharp], colors="0.35", linewidths=0.6))
    cmap = plt.get_cmap("tab10")
    if len(graph.edges):
        colours = [cmap(int(chain) % 10) for chain in graph.chains]
        ax.add_collection3d(Line3DCollection(x[graph.edges], colors=colours, linewidths=2.5))
    lo, hi = x.min(axis=0), x.max(axis=0)
    centre, half = (lo + hi) / 2, (hi - lo).max() / 2
    for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre, strict=True):
        setter(c - half, c + half)
    ax.set_title(title or f"{len(graph.edges)} singular edges in {graph.num_chains} chains",
                 fontsize=9)
    path = Path(path)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


def outline(x: np.ndarray, cells: np.ndarray, angle: float = 30.0) -> np.ndarray:
    """The sharp edges of the tetrahedra's boundary: the edges (k, 2) between two boundary
    triangles whose normals differ by more than ``angle`` degrees.

    Args:
        x: vertex coordinates (n, 3).
        cells: tetrahedra (m, 4).
        angle: the smallest angle between the normals of a sharp edge's triangles.

    Returns:
        Vertex pairs (k, 2), each sorted.
    """
    cells = np.asarray(cells, dtype=np.int64)
    local = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])
    faces = np.sort(cells[:, local].reshape(-1, 3), axis=1)
    opposite = cells.ravel()  # face k of a tetrahedron leaves out its vertex k
    _, first, counts = np.unique(faces, axis=0, return_index=True, return_counts=True)
    boundary = first[counts == 1]
    tri, inside = faces[boundary], opposite[boundary]
    if tri.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    normal = np.cross(x[tri[:, 1]] - x[tri[:, 0]], x[tri[:, 2]] - x[tri[:, 0]])
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    # outward: away from the tetrahedron's fourth vertex
    flip = np.einsum("ni,ni->n", normal, x[inside] - x[tri[:, 0]]) > 0
    normal[flip] *= -1
    # each triangle's three (sorted) edges; a closed boundary has each edge twice
    edges = np.concatenate([tri[:, [0, 1]], tri[:, [0, 2]], tri[:, [1, 2]]])
    owner = np.tile(np.arange(tri.shape[0]), 3)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    edges, owner = edges[order], owner[order]
    pair = np.flatnonzero(np.all(edges[1:] == edges[:-1], axis=1))
    cosine = np.einsum("ni,ni->n", normal[owner[pair]], normal[owner[pair + 1]])
    return edges[pair[cosine < np.cos(np.radians(angle))]]
