"""Pictures and files of a parametrisation: iso-lines of U and V, and the map for ParaView.

Written on the rank that holds the :class:`~ufl_frames.param.seamless.Parametrisation`.
"""


import numpy as np

from ufl_frames.param.seamless import Parametrisation

__all__ = ["plot_param", "write_param_vtu"]


def _cut_triangulation(p: Parametrisation):
    """Coordinates (W, 2) of the cut mesh's vertices and its triangles (m, 3)."""
    mesh = p.mesh
    xy = np.zeros((mesh.num_wedges, 2))
    xy[mesh.corners.ravel()] = mesh.x[mesh.cells.ravel()]
    return xy, mesh.corners


def plot_param(path, p: Parametrisation, title: str = "") -> None:
    """The domain with the integer iso-lines of U (blue) and V (red), the cut (black) and
    flipped triangles (filled): a quad mesh appears where the map is good.

    Args:
        path: the image file to write (its suffix picks the format, e.g. ``.png``).
        p: the parametrisation to draw.
        title: the figure's title.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.tri import Triangulation

    xy, triangles = _cut_triangulation(p)
    tri = Triangulation(xy[:, 0], xy[:, 1], triangles)
    lo, hi = p.mesh.x.min(axis=0), p.mesh.x.max(axis=0)
    aspect = (hi[1] - lo[1]) / max(hi[0] - lo[0], 1e-300)
    fig, ax = plt.subplots(figsize=(7.0, max(2.5, min(9.0, 7.0 * aspect)) + 0.6))
    for c, colour in ((0, "tab:blue"), (1, "tab:red")):
        values = p.uv[:, c]
        levels = np.arange(np.floor(values.min()), np.ceil(values.max()) + 1)
        if levels.size > 400:  # too fine to draw: every k-th line
            levels = levels[:: int(np.ceil(levels.size / 400))]
        ax.tricontour(tri, values, levels=levels, colors=colour, linewidths=0.6,
                      linestyles="solid")
    mesh = p.mesh
    boundary = mesh.edges[mesh.faces[:, 1] < 0]
    for e, colour, width in ((boundary, "0.3", 0.8), (mesh.edges[mesh.cut], "k", 1.6)):
        if len(e):
            segments = mesh.x[e]
            ax.plot(segments[:, :, 0].T, segments[:, :, 1].T, color=colour, linewidth=width)
    det = p.grad_u[:, 0] * p.grad_v[:, 1] - p.grad_u[:, 1] * p.grad_v[:, 0]
    flipped = det <= 0
    if flipped.any():
        ax.tripcolor(Triangulation(mesh.x[:, 0], mesh.x[:, 1], mesh.cells[flipped]),
                     np.ones(int(flipped.sum())), cmap="Greys", vmin=0, vmax=1.5)
    ax.set_aspect("equal")
    ax.set_axis_off()
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=150)
    plt.close(fig)


def write_param_vtu(path, p: Parametrisation) -> None:
    """The cut mesh with point data U, V (and the cell data misfit) as an ASCII ``.vtu``."""
    xy, triangles = _cut_triangulation(p)
    residual = np.sqrt(np.sum((p.grad_u - p.target_u) ** 2 + (p.grad_v - p.target_v) ** 2,
                              axis=1))
    target = np.sqrt(np.sum(p.target_u**2 + p.target_v**2, axis=1))
    misfit = residual / np.maximum(target, 1e-300)

    from ufl_frames.output.vtk import write_vtu

    write_vtu(path, xy, triangles, "triangle",
              point_data={"U": p.uv[:, 0], "V": p.uv[:, 1]}, cell_data={"misfit": misfit})
