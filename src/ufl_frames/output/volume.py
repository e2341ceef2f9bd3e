"""A 3D frame field's results: the frames for ParaView, its singular graph, a picture.

:func:`write_volume_field` writes, on rank 0 from gathered arrays:

* ``frames3d.vtu`` — the tetrahedra with the frame at every vertex as three vector
  fields ``u1``, ``u2``, ``u3`` (the directions scaled by their lengths) and the lengths:
  ParaView's Glyph filter (arrows or lines, one per field) draws the crosses;
* ``singular.vtu`` — the singular edges as lines, with ``turn`` (quarter turns of the
  monodromy) and ``chain`` per edge;
* ``singular.png`` — the singular graph in 3D over the boundary's vertices (matplotlib).
"""

from pathlib import Path

import numpy as np

from ufl_frames.output.vtk import write_vtu

__all__ = ["plot_singular_graph", "write_volume_field"]


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
    """Picture of the singular edges (coloured by chain) inside the boundary's vertices
    (grey dots), in an axonometric view."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ufl_frames.frames3d.singular import boundary_vertices

    fig = plt.figure(figsize=(6, 6))
    ax = fig.add_subplot(projection="3d")
    b = x[boundary_vertices(cells)]
    ax.scatter(b[:, 0], b[:, 1], b[:, 2], s=1, c="0.75", depthshade=False)
    cmap = plt.get_cmap("tab10")
    for (i, j), chain in zip(graph.edges, graph.chains, strict=True):
        ax.plot(*zip(x[i], x[j], strict=True), color=cmap(int(chain) % 10), linewidth=2)
    lo, hi = x.min(axis=0), x.max(axis=0)
    centre, half = (lo + hi) / 2, (hi - lo).max() / 2
    for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre, strict=True):
        setter(c - half, c + half)
    ax.set_title(title or f"{len(graph.edges)} singular edges in {graph.num_chains} chains")
    path = Path(path)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path
