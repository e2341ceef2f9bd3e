r"""The figures of note §5, and the singularities in one line.

* :func:`plot_frames` — crosses coloured by frame length, with the singularities
  (note Fig. 1), sized for the domain's aspect ratio (:func:`frame_layout`).
* :func:`plot_convergence` — H(q) and E(q) against the iteration (note Fig. 2).
* :func:`describe_singularities` — a one-line console summary.

The figures are collective over the mesh communicator: data are gathered to rank 0,
which alone draws and writes (:func:`ufl_frames.output.report.on_root`).
"""

import math
import textwrap
from typing import NamedTuple

from ufl_frames.bootstrap import init_petsc

init_petsc()

import dolfinx.fem as fem  # noqa: E402
import numpy as np  # noqa: E402
from mpi4py import MPI  # noqa: E402

from ufl_frames.fem import scales  # noqa: E402
from ufl_frames.fem.energy import check_frame_function as check_frame_field  # noqa: E402
from ufl_frames.fem.gather import gather_rows  # noqa: E402
from ufl_frames.frames2d import odeco  # noqa: E402
from ufl_frames.output.fields import frame_vectors  # noqa: E402
from ufl_frames.output.glyphs import (  # noqa: E402
    GLYPH_ARM,
    GLYPH_MIN_ARM,
    GLYPH_MIN_SPACING_IN,
    GLYPHS,
    boundary_segments,
    distance_to_segments,
    glyph_samples,
    glyph_segments,
)
from ufl_frames.output.report import on_root  # noqa: E402

__all__ = ["FrameLayout", "describe_singularities", "frame_layout", "plot_convergence",
           "plot_frames"]

#: Resolution of the PNG figures.
DPI = 200
#: Area (square inches) of the data area of :func:`plot_frames` for a compact domain.
AXES_AREA_IN2 = 40.0
#: Longest side (inches) of the data area when the domain is wide / tall (screens are
#: wider than tall).
AXES_LONG_MAX_IN = (15.0, 11.0)
#: Shortest side (inches) of the data area: a thinner domain (more than about 25:1) is
#: drawn stretched across, without equal aspect (at equal aspect a 1000:1 strip would be
#: a sliver no renderer can lay out).
AXES_SHORT_MIN_IN = 0.6
#: Smallest figure (inches): room for a wrapped title, the axis labels and the colour bar.
FIGURE_MIN_IN = (3.0, 2.5)
#: Font size of the title of :func:`plot_frames` (points).
TITLE_FONTSIZE = 11.0
#: :func:`describe_singularities` lists up to this many; more are counted per index.
DESCRIBE_LIMIT = 6
#: Beyond this many singularities the markers are small dots without an outline.
MANY_SINGULARITIES = 200


def _check_history(history) -> None:
    if not isinstance(history, (list, tuple)) or not history:
        raise ValueError("history must be a non-empty list of {'it', 'H', 'E'} entries")
    for entry in history:
        if not isinstance(entry, dict) or not {"it", "H", "E"} <= set(entry):
            raise ValueError(f"history entries need the keys 'it', 'H' and 'E', got {entry!r}")


def _is_isotropic(q: fem.Function) -> bool:
    """Whether l1 = l2 (relative 1e-6) at every vertex, on all ranks (collective)."""
    comm = q.function_space.mesh.comm
    owned = q.function_space.dofmap.index_map.size_local
    lengths, _, _ = frame_vectors(q.x.array.reshape(-1, odeco.NUM_COEFFICIENTS)[:owned])
    scale = comm.allreduce(float(np.abs(lengths).max(initial=0.0)), op=MPI.MAX)
    spread = comm.allreduce(
        float(np.abs(lengths[:, 0] - lengths[:, 1]).max(initial=0.0)), op=MPI.MAX
    )
    return spread <= 1e-6 * max(scale, 1e-300)


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _wrap_title(title: str, fig_width: float) -> str:
    """``title`` broken into lines that fit a figure ``fig_width`` inches wide."""
    # About 0.6 em per character of DejaVu Sans; tests check that the result fits.
    chars = max(16, int((fig_width - 0.3) * 72 / (0.6 * TITLE_FONTSIZE)))
    return "\n".join(textwrap.wrap(title, chars, break_long_words=True))


class FrameLayout(NamedTuple):
    """Geometry of a :func:`plot_frames` figure (lengths in inches)."""

    #: estimated; :func:`plot_frames` corrects it by the room labels really take
    figsize: tuple[float, float]
    #: the data area (domain + margin), drawn at equal aspect
    axes_size: tuple[float, float]
    #: data limits ((x0, x1), (y0, y1))
    limits: tuple[tuple[float, float], tuple[float, float]]
    #: inches per unit of length of the domain
    scale: float
    #: colour bar below the domain (wide domains) rather than on its right
    horizontal: bool
    #: the title, wrapped to the figure's width ("" for none)
    title: str
    #: drawn at equal aspect (False: a domain too thin for it, stretched across)
    equal: bool = True


def frame_layout(lo, hi, title: str | None = None, legend: bool = False) -> FrameLayout:
    """Figure geometry for a domain of bounding box [lo, hi].

    The data area has the domain's aspect ratio and :data:`AXES_AREA_IN2` square
    inches, its longer side (horizontal or vertical, as the domain comes) capped by
    :data:`AXES_LONG_MAX_IN`: an elongated domain gets a long figure, not a sliver in
    a fixed-width one; its shorter side is at least :data:`AXES_SHORT_MIN_IN` (a domain
    thinner than that at equal aspect is stretched across: ``equal`` False). The
    figure adds room for labels, the colour bar (below wide domains, right of the
    others), the legend and the title, wrapped to its width, and is at least
    :data:`FIGURE_MIN_IN`. Depends only on the shape: scaling the
    domain (mm instead of m) changes nothing but ``scale``.

    Args:
        lo: the bounding box's lower corner (x, y[, z]).
        hi: its upper corner.
        title: the figure's title (None: none).
        legend: whether there is a legend (of the singularities) above the domain.

    Returns:
        The :class:`FrameLayout`.
    """
    lo, hi = np.asarray(lo, dtype=float)[:2], np.asarray(hi, dtype=float)[:2]
    extent = np.maximum(hi - lo, 1e-12 * max(float((hi - lo).max()), 1e-300))
    # A margin from the geometric mean of the sides: a percentage of the longer side
    # would double the width of a thin strip.
    margin = 0.03 * math.sqrt(extent[0] * extent[1])
    width, height = extent + 2 * margin
    aspect = width / height
    wide = aspect >= 1.0
    long_side = min(math.sqrt(AXES_AREA_IN2 * max(aspect, 1 / aspect)),
                    AXES_LONG_MAX_IN[0 if wide else 1])
    axes_w, axes_h = (long_side, long_side / aspect) if wide else (long_side * aspect, long_side)
    equal = min(axes_w, axes_h) >= AXES_SHORT_MIN_IN
    axes_w, axes_h = max(axes_w, AXES_SHORT_MIN_IN), max(axes_h, AXES_SHORT_MIN_IN)
    horizontal = aspect >= 1.4
    # Room around the data area (inches): tick labels and axis labels, colour bar.
    fig_w = axes_w + 0.85 + 0.25 + (0.0 if horizontal else 1.25)
    fig_w = max(fig_w, FIGURE_MIN_IN[0])
    text = _wrap_title(title, fig_w) if title else ""
    lines = text.count("\n") + 1 if text else 0
    fig_h = (axes_h + 0.6 + 0.2 + (0.95 if horizontal else 0.0) + (0.4 if legend else 0.0)
             + lines * TITLE_FONTSIZE * 1.3 / 72)
    fig_h = max(fig_h, FIGURE_MIN_IN[1])
    return FrameLayout(
        figsize=(round(fig_w, 2), round(fig_h, 2)),
        axes_size=(axes_w, axes_h),
        limits=((lo[0] - margin, hi[0] + margin), (lo[1] - margin, hi[1] + margin)),
        scale=axes_w / width if wide else axes_h / height,
        horizontal=horizontal,
        title=text,
        equal=equal,
    )


_SINGULARITY_STYLE = {
    0.25: {"marker": "o", "color": "#d62728", "label": "+1/4"},
    -0.25: {"marker": "s", "color": "#1f77b4", "label": "−1/4"},
}


def _marker_size(count: int, domain_area_pt2: float) -> float:
    """Marker area (points²) for ``count`` singularities on a domain of that drawn area.

    80 for up to 20, then shrinking like count^(-3/4), and all markers together cover
    at most 5% of the domain: thousands of singularities stay dots, not a carpet.
    """
    if count <= 0:
        return 80.0
    size = 80.0 * min(1.0, 20.0 / count) ** 0.75
    return float(max(1.0, min(size, 0.05 * domain_area_pt2 / count)))


def _mark_singularities(ax, singularities, domain_area_pt2, legend_columns) -> None:
    by_index = {}
    for s in singularities:
        by_index.setdefault(round(float(s["index"]) * 4) / 4, []).append((s["x"], s["y"]))
    count = len(singularities)
    size = _marker_size(count, domain_area_pt2)
    many = count > MANY_SINGULARITIES
    for index, xy in sorted(by_index.items(), reverse=True):
        style = _SINGULARITY_STYLE.get(
            index, {"marker": "X", "color": "black", "label": f"{index:+g}"}
        )
        xy = np.asarray(xy)
        ax.scatter(
            xy[:, 0], xy[:, 1], s=size, marker="o" if many else style["marker"],
            facecolor=style["color"], edgecolor="none" if many else "white",
            linewidth=0.0 if many else 1.2 * math.sqrt(size / 80.0), zorder=4,
            label=f"{style['label']} singularity ({len(xy)})",
        )
    if by_index:
        # Above the domain, outside it: inside, it would hide part of a thin strip.
        legend = ax.legend(loc="lower center", bbox_to_anchor=(0.5, 1.0), fontsize=8,
                           frameon=False, ncols=min(len(by_index), legend_columns),
                           borderaxespad=0.2)
        for handle in legend.legend_handles:
            handle.set_sizes([40.0])


def plot_frames(
    path,
    q: fem.Function,
    title: str | None = None,
    singularities: list[dict] | None = None,
    glyphs_across: int | None = None,
    isotropic: bool | None = None,
    *,
    glyphs: int = GLYPHS,
    dpi: int = DPI,
) -> None:
    """Figure of the frame field ``q`` (note Fig. 1) written to ``path`` by rank 0. Collective.

    Crosses at the points of :func:`~ufl_frames.output.glyphs.glyph_samples`, each drawn
    as the segments ±u and ±v: the longer arm has a fixed size (smaller near the
    boundary, so that crosses do not hide holes), the shorter one is in proportion (so
    anisotropy shows), and each arm is coloured by its branch length (the colour bar
    gives the lengths; an isotropic field is drawn with l1 = l2 = (l1 + l2)/2). The
    boundary is every boundary facet. Singularities are marked, smaller the more there
    are. Figure size: :func:`frame_layout`.

    Args:
        path: the PNG file (rank 0's).
        q: the frame field (P1, 5 components).
        title: the figure's title, wrapped to its width (None: none).
        singularities: ``{"index", "x", "y"}`` each, e.g. from
            :func:`ufl_frames.frames2d.singularities.locate_singularities`.
        glyphs_across: crosses per longer side of the bounding box (None: ``glyphs``).
        isotropic: draw the field as isotropic (None: detected at the vertices).
        glyphs: crosses aimed at over the domain's area, fewer where they would be
            closer than :data:`~ufl_frames.output.glyphs.GLYPH_MIN_SPACING_IN` on paper.
        dpi: the PNG's resolution.
    """
    check_frame_field(q)
    mesh = q.function_space.mesh
    comm = mesh.comm
    singularities = singularities or []
    if isotropic is None:
        isotropic = _is_isotropic(q)
    lo, hi = scales.bounding_box(mesh)
    area = scales.area(mesh)
    layout = frame_layout(lo, hi, title, legend=bool(singularities))
    if glyphs_across is None:
        spacing = max(math.sqrt(area / glyphs), GLYPH_MIN_SPACING_IN / layout.scale)
        points, rows, spacing = glyph_samples(q, spacing=spacing)
    else:
        points, rows, spacing = glyph_samples(q, glyphs_across)
    boundary = gather_rows(comm, boundary_segments(mesh))

    def draw():
        fig = _frames_figure(layout, points, rows, spacing, boundary, area, singularities,
                             isotropic)
        _save(fig, path, dpi)

    on_root(comm, draw)


def _save(fig, path, dpi) -> None:
    """Write and close a figure (tests replace it to inspect the figure)."""
    try:
        # a PNG at zlib level 1, not 6: a third less time to encode, the file ~10 % larger
        png = str(path).lower().endswith(".png")
        fig.savefig(path, dpi=dpi, **({"pil_kwargs": {"compress_level": 1}} if png else {}))
    finally:
        _pyplot().close(fig)


def _frames_figure(layout, points, rows, spacing, boundary, area, singularities, isotropic):
    plt = _pyplot()
    from matplotlib.collections import LineCollection

    lengths, u, v = frame_vectors(rows)
    if isotropic:
        mean = lengths.mean(axis=1, keepdims=True)
        scale = mean / np.where(lengths > 0, lengths, 1.0)
        u, v, lengths = u * scale[:, :1], v * scale[:, 1:], np.repeat(mean, 2, axis=1)
    arm = GLYPH_ARM * spacing
    arms = np.clip(distance_to_segments(points, boundary), GLYPH_MIN_ARM * arm, arm)
    segments, colours = glyph_segments(points, u, v, lengths, arms)

    fig, ax = plt.subplots(figsize=layout.figsize, layout="constrained")
    # Line widths in points follow the glyph spacing on paper: thick strokes would
    # merge dense crosses into blobs.
    spacing_pt = spacing * layout.scale * 72
    # The boundary above the markers: a small hole stays visible under its singularities.
    ax.add_collection(LineCollection(boundary, colors="0.15", zorder=5,
                                     linewidths=float(np.clip(0.08 * spacing_pt, 0.5, 1.0))))
    glyphs = LineCollection(segments, cmap="viridis", capstyle="round", zorder=2,
                            linewidths=float(np.clip(0.11 * spacing_pt, 0.4, 1.3)))
    glyphs.set_array(colours)
    # A uniform field (an MBO field has unit lengths) gets a readable colour range.
    low, high = float(colours.min()), float(colours.max())
    middle, half = (low + high) / 2, max((high - low) / 2, 0.05 * abs(high + low) / 2, 1e-12)
    glyphs.set_clim(middle - half, middle + half)
    ax.add_collection(glyphs)
    area_pt2 = area * (layout.scale * 72) ** 2
    _mark_singularities(ax, singularities, area_pt2,
                        legend_columns=max(1, int(layout.figsize[0] / 1.9)))
    long_bar = layout.axes_size[0] if layout.horizontal else layout.axes_size[1]
    bar = fig.colorbar(glyphs, ax=ax, location="bottom" if layout.horizontal else "right",
                       shrink=min(0.85, 5.0 / long_bar), aspect=25, pad=0.02,
                       # its room in inches, not in a fraction of the data area, so that
                       # resizing the figure below does not resize the bar
                       fraction=0.35 / (layout.axes_size[1] if layout.horizontal
                                        else layout.axes_size[0]))
    bar.set_label("frame length $l_1 = l_2$" if isotropic else "branch length $l_1$, $l_2$")
    ax.set_xlim(*layout.limits[0])
    ax.set_ylim(*layout.limits[1])
    ax.set_xlabel("$x$")
    ax.set_ylabel("$y$")
    title = fig.suptitle(layout.title, fontsize=TITLE_FONTSIZE) if layout.title else None
    # The room taken by labels, ticks, colour bar and title is only estimated by
    # frame_layout: measure it on the laid-out figure and resize the figure to hold the
    # planned data area exactly. Measured with a free aspect ratio: with an equal one the
    # data area would not fill its box, and labels in the gap would count as no room.
    ax.set_aspect("auto")
    for _ in range(4):
        # the layout alone (what a draw does first), not the drawing of every artist
        fig.get_layout_engine().execute(fig)
        box = ax.get_position(original=True)
        old = fig.get_size_inches()
        needed = np.asarray(layout.axes_size) + (1 - np.array([box.width, box.height])) * old
        # Where the minimum size wins (a very narrow domain, beside its title), the data
        # area keeps its planned size and the figure has some white.
        new = np.maximum(FIGURE_MIN_IN, needed)
        if np.abs(new - old).sum() < 0.005:
            # laid out at this size: saving need not lay it out once more
            fig.set_layout_engine("none")
            break
        fig.set_size_inches(*new)
        if title is not None:
            title.set_text(_wrap_title(layout.title, new[0]))
    if layout.equal:
        ax.set_aspect("equal")
    return fig


def plot_convergence(
    path, history: list[dict], title: str | None = None, comm: MPI.Comm = MPI.COMM_WORLD,
    levels: list[tuple[str, list[dict]]] | None = None,
) -> None:
    """H(q) (log scale) and E(q) against the iteration (note Fig. 2), written by rank 0.

    Collective over ``comm``.

    Args:
        path: the PNG file (rank 0's).
        history: :attr:`ufl_frames.solvers.SolveResult.history` (entries with ``"it"``,
            ``"H"``, ``"E"``).
        title: the figure's title (None: none).
        comm: the communicator whose rank 0 writes.
        levels: nested iteration, ``(label, history)`` per mesh, coarse to fine, the last
            being ``history``: the meshes follow one another on one iteration axis, one
            colour each (None: one mesh).
    """
    _check_history(history)
    for _, part in levels or ():
        _check_history(part)
    on_root(comm, lambda: _draw_convergence(path, history, title, levels))


_LEVEL_COLOURS = ("#1f77b4", "#2ca02c", "#9467bd", "#d62728", "#8c564b", "#17becf",
                  "#7f7f7f", "#bcbd22")


def _draw_convergence(path, history, title, levels=None):
    plt = _pyplot()
    parts = levels if levels and len(levels) > 1 else [(None, history)]
    it = np.concatenate([np.array([h["it"] for h in part], dtype=float)
                         + sum(len(p) - 1 for _, p in parts[:k]) for k, (_, part)
                         in enumerate(parts)])
    H = np.array([h["H"] for _, part in parts for h in part], dtype=float)
    E = np.array([h["E"] for _, part in parts for h in part], dtype=float)
    style = {"marker": "o", "markersize": 3} if len(it) <= 60 else {}

    fig, (ax_h, ax_e) = plt.subplots(1, 2, figsize=(9.0, 3.6), layout="constrained")
    if len(parts) == 1:
        ax_h.plot(it, H, color="#1f77b4", lw=1.5, **style)
    else:  # one colour per mesh, and where each starts
        start = 0
        for k, (label, part) in enumerate(parts):
            colour = _LEVEL_COLOURS[k % len(_LEVEL_COLOURS)]
            span = slice(start, start + len(part))
            for ax, values in ((ax_h, H), (ax_e, E)):
                ax.plot(it[span], values[span], color=colour, lw=1.5, label=label, **style)
                ax.axvline(it[start], color="0.7", lw=0.8, ls="--")
            start += len(part)
        ax_h.legend(fontsize="small", title="mesh", title_fontsize="small")
    if np.all(H > 0):
        ax_h.set_yscale("log")
    ax_h.set_ylabel(r"$H(q) = \frac{1}{2}\int_\Omega |[u,v]|^2\,dx$")
    ax_h.set_title("integrability energy")
    if len(parts) == 1:
        ax_e.plot(it, E, color="#ff7f0e", lw=1.5, **style)
    ax_e.set_ylabel(r"$E(q) = \frac{1}{2}\int_\Omega |\nabla q|^2\,dx$")
    ax_e.set_title("Dirichlet energy")
    for ax in (ax_h, ax_e):
        ax.set_xlabel("iteration")
        ax.grid(True, which="both", alpha=0.3)
        if it.size and it[-1] <= 10:
            ax.set_xticks(np.arange(0, int(it[-1]) + 1))
    if title:
        fig.suptitle(title)
    try:
        fig.savefig(path, dpi=200)
    finally:
        plt.close(fig)


def describe_singularities(singularities: list[dict], limit: int = DESCRIBE_LIMIT) -> str:
    """One line: ``+1/4 at (0.35, 0.8), -1/4 at (1.57, 0.726)``, or ``none``.

    More than ``limit`` singularities are counted per index instead, with the sum of
    the indices (the Poincaré–Hopf check): ``+1/4: 1379, -1/4: 721, index sum 164.5``.
    """
    if not singularities:
        return "none"
    quarters = [round(float(s["index"]) * 4) for s in singularities]
    if len(singularities) <= limit:
        return ", ".join(f"{k:+d}/4 at ({s['x']:.3g}, {s['y']:.3g})"
                         for k, s in zip(quarters, singularities, strict=True))
    counts = {k: quarters.count(k) for k in sorted(set(quarters), reverse=True)}
    parts = [f"{k:+d}/4: {n}" for k, n in counts.items()]
    return ", ".join(parts) + f", index sum {sum(quarters) / 4:g}"
