r"""Results on disk: the run summary, the field for ParaView and the two figures of note §5.

* :func:`write_summary` — a JSON file (rank 0 writes it).
* :func:`write_field` — the final frame field, for ParaView, in one ADIOS2 ``.bp``
  folder (:class:`dolfinx.io.VTXWriter`), or an XDMF file where DOLFINx was built
  without ADIOS2.
* :func:`plot_frames` — crosses coloured by frame length, with the singularities
  (note Fig. 1).
* :func:`plot_convergence` — H(q) and E(q) against the iteration (note Fig. 2).

Every function is collective over the mesh communicator (call it on all ranks):
data are gathered to rank 0, which alone writes.
"""

import json
import math
from pathlib import Path

from ufl_frames.bootstrap import init_petsc

init_petsc()

import dolfinx  # noqa: E402
import dolfinx.fem as fem  # noqa: E402
import dolfinx.geometry  # noqa: E402
import dolfinx.io  # noqa: E402
import numpy as np  # noqa: E402
import ufl  # noqa: E402
from mpi4py import MPI  # noqa: E402

from ufl_frames import energy, odeco  # noqa: E402

__all__ = ["plot_convergence", "plot_frames", "write_field", "write_summary"]

#: Sampled crosses across the longer side of the bounding box in :func:`plot_frames`.
GLYPHS_ACROSS = 36
#: Half-length of the longer arm of a cross, as a fraction of the glyph spacing.
GLYPH_ARM = 0.42


# --- summary --------------------------------------------------------------------


def _json_default(value):
    """NumPy scalars and arrays, and paths, as plain JSON values."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def write_summary(path, data: dict, comm: MPI.Comm = MPI.COMM_WORLD) -> None:
    """Write ``data`` as indented JSON to ``path`` on rank 0 of ``comm`` (collective).

    Non-finite floats are written as ``NaN``/``Infinity`` (Python's JSON dialect).
    """
    if comm.rank == 0:
        text = json.dumps(data, indent=2, default=_json_default)
        Path(path).write_text(text + "\n")
    comm.Barrier()


# --- pointwise frame data ---------------------------------------------------------


def _frames(rows: np.ndarray):
    """Lengths (N, 2), branch vectors u, v (each (N, 2)) of the rows; zeros for zero rows.

    The branch labels follow :func:`ufl_frames.odeco.q_to_frames` (angle of u in
    (−π/4, π/4]): the frame is continuous, the labels u/v are not.
    """
    rows = np.asarray(rows, dtype=np.float64)
    lengths = np.zeros((rows.shape[0], 2))
    u = np.zeros((rows.shape[0], 2))
    v = np.zeros((rows.shape[0], 2))
    nonzero = np.any(rows != 0.0, axis=1)
    if np.any(nonzero):
        lengths[nonzero], angles = odeco.q_to_frames(rows[nonzero])
        c, s = np.cos(angles), np.sin(angles)
        u[nonzero] = lengths[nonzero, :1] * np.stack([c, s], axis=1)
        v[nonzero] = lengths[nonzero, 1:] * np.stack([-s, c], axis=1)
    return lengths, u, v


# --- field for ParaView -------------------------------------------------------------


def bracket_rms(q: fem.Function) -> fem.Function:
    r"""Cell-wise RMS of the Lie bracket, :math:`\sqrt{|K|^{-1}\int_K |[u,v]|^2\,dx}`, in DG0.

    The L² projection of :math:`|[u,v]|^2` onto piecewise constants, then the square
    root: :math:`\tfrac12\sum_K |K|\,b_K^2 = H(q)` exactly, so the picture shows where
    the integrability energy sits. (On each cell [u,v] is linear in x; a value at
    one point, e.g. ``fem.Expression`` at the centroid, would miss part of it.)
    """
    mesh = q.function_space.mesh
    D0 = fem.functionspace(mesh, ("DG", 0))
    w = ufl.TestFunction(D0)
    bracket = energy.lie_bracket(q)
    density = fem.assemble_vector(fem.form(ufl.inner(bracket, bracket) * w * ufl.dx))
    volume = fem.assemble_vector(fem.form(w * ufl.dx))
    owned = D0.dofmap.index_map.size_local
    out = fem.Function(D0, name="bracket_rms")
    out.x.array[:owned] = np.sqrt(
        np.maximum(density.array[:owned], 0.0) / volume.array[:owned]
    )
    out.x.scatter_forward()
    return out


def field_functions(q: fem.Function) -> list[fem.Function]:
    """The functions written by :func:`write_field`.

    ``q`` (P1, 5 components); ``lengths`` (P1, (l1, l2)); ``u`` and ``v`` (P1
    vectors, the two branches scaled by their lengths, see :func:`_frames`);
    ``bracket_rms`` (DG0, :func:`bracket_rms`).
    """
    mesh = q.function_space.mesh
    V2 = fem.functionspace(mesh, ("Lagrange", 1, (2,)))
    lengths, u, v = _frames(q.x.array.reshape(-1, 5))
    # P1 spaces on one mesh share the vertex numbering: the rows of q are those of V2.
    out = []
    for name, values in (("lengths", lengths), ("u", u), ("v", v)):
        f = fem.Function(V2, name=name)
        f.x.array[:] = values.ravel()
        out.append(f)
    q_out = fem.Function(q.function_space, name="q")
    q_out.x.array[:] = q.x.array
    return [q_out, *out, bracket_rms(q)]


def write_field(directory, q: fem.Function, stem: str = "frames") -> Path:
    """Write the frame field for ParaView into ``directory``; return the path written.

    ``<stem>.bp`` (ADIOS2, :class:`dolfinx.io.VTXWriter`: the P1 functions as point
    data and ``bracket_rms`` as cell data, in one file) when DOLFINx has ADIOS2,
    otherwise ``<stem>.xdmf`` (+ ``.h5``). The functions are listed in
    :func:`field_functions`. Collective.
    """
    directory = Path(directory)
    comm = q.function_space.mesh.comm
    functions = field_functions(q)
    if dolfinx.io.has_adios2:
        path = directory / f"{stem}.bp"
        with dolfinx.io.VTXWriter(comm, path, functions, engine="BP4") as writer:
            writer.write(0.0)
    else:
        path = directory / f"{stem}.xdmf"
        with dolfinx.io.XDMFFile(comm, path, "w") as xdmf:
            xdmf.write_mesh(q.function_space.mesh)
            for f in functions:
                xdmf.write_function(f, 0.0)
    comm.Barrier()
    return path


# --- gathering to rank 0 -------------------------------------------------------------


def _gather_rows(comm: MPI.Comm, array: np.ndarray) -> np.ndarray | None:
    """Concatenation on rank 0 of the per-rank arrays (same trailing shape); None elsewhere."""
    parts = comm.gather(np.ascontiguousarray(array), root=0)
    return np.concatenate(parts) if comm.rank == 0 else None


def _boundary_segments(mesh) -> np.ndarray:
    """Coordinates (nf, 2, 2) of the exterior facets owned by this rank."""
    tdim = mesh.topology.dim
    mesh.topology.create_connectivity(tdim - 1, tdim)
    facets = dolfinx.mesh.exterior_facet_indices(mesh.topology)
    nodes = dolfinx.mesh.entities_to_geometry(mesh, tdim - 1, facets)
    return mesh.geometry.x[nodes][:, :, :2].reshape(-1, 2, 2)


def _mean_edge_length(mesh) -> float:
    """h of equilateral triangles with the mesh's area and cell count (collective)."""
    comm = mesh.comm
    area = comm.allreduce(fem.assemble_scalar(fem.form(1.0 * ufl.dx(domain=mesh))), op=MPI.SUM)
    cells = mesh.topology.index_map(mesh.topology.dim).size_global
    return math.sqrt(4 * area / (math.sqrt(3) * cells))


def grid_points(lo, hi, spacing: float) -> np.ndarray:
    """Points (M, 3) of the square grid of step ``spacing`` centred on the box [lo, hi]."""
    axes = []
    for a, b in zip(lo, hi, strict=True):
        n = math.floor((b - a) / spacing) + 1
        axes.append((a + b) / 2 + spacing * (np.arange(n) - (n - 1) / 2))
    x, y = np.meshgrid(*axes, indexing="ij")
    return np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)


def _evaluate_owned(q: fem.Function, points: np.ndarray):
    """(indices of the points inside owned cells, q there (k, 5)) on this rank."""
    mesh = q.function_space.mesh
    owned_cells = np.arange(mesh.topology.index_map(mesh.topology.dim).size_local, dtype=np.int32)
    tree = dolfinx.geometry.bb_tree(mesh, mesh.topology.dim, entities=owned_cells)
    candidates = dolfinx.geometry.compute_collisions_points(tree, points)
    colliding = dolfinx.geometry.compute_colliding_cells(mesh, candidates, points)
    found, cells = [], []
    for i in range(points.shape[0]):
        links = colliding.links(i)
        if links.size:
            found.append(i)
            cells.append(links[0])
    found = np.asarray(found, dtype=np.int64)
    if found.size == 0:
        return found, np.zeros((0, 5))
    values = q.eval(points[found], np.asarray(cells, dtype=np.int32))
    return found, np.asarray(values).reshape(-1, 5)


def glyph_samples(q: fem.Function, glyphs_across: int = GLYPHS_ACROSS):
    """Where to draw crosses: (points (M, 2), q there (M, 5), spacing) on rank 0. Collective.

    On a mesh finer than the spacing (longer side / ``glyphs_across``), q is evaluated
    (P1 interpolation, exact for the discrete field) at the points of a regular grid
    that lie in the domain: a regular lattice of crosses. On coarser meshes every
    vertex gets a cross and the spacing is the mean edge length. Other ranks get Nones.
    """
    V = q.function_space
    mesh = V.mesh
    comm = mesh.comm
    x = mesh.geometry.x[:, :2]
    lo, hi = np.empty(2), np.empty(2)
    comm.Allreduce(x.min(axis=0, initial=np.inf), lo, op=MPI.MIN)
    comm.Allreduce(x.max(axis=0, initial=-np.inf), hi, op=MPI.MAX)
    spacing = float((hi - lo).max()) / glyphs_across
    h = _mean_edge_length(mesh)
    if h >= 0.8 * spacing:
        owned = V.dofmap.index_map.size_local
        points = _gather_rows(comm, V.tabulate_dof_coordinates()[:owned, :2])
        rows = _gather_rows(comm, q.x.array.reshape(-1, 5)[:owned])
        return points, rows, h
    grid = grid_points(lo, hi, spacing)
    found, values = _evaluate_owned(q, grid)
    found = _gather_rows(comm, found)
    values = _gather_rows(comm, values)
    if comm.rank != 0:
        return None, None, spacing
    # A point on an edge between ranks is found twice: keep it once.
    found, first = np.unique(found, return_index=True)
    return grid[found, :2], values[first], spacing


def _is_isotropic(q: fem.Function) -> bool:
    """Whether l1 = l2 (relative 1e-6) at every vertex, on all ranks (collective)."""
    comm = q.function_space.mesh.comm
    owned = q.function_space.dofmap.index_map.size_local
    lengths, _, _ = _frames(q.x.array.reshape(-1, 5)[:owned])
    scale = comm.allreduce(float(np.abs(lengths).max(initial=0.0)), op=MPI.MAX)
    spread = comm.allreduce(
        float(np.abs(lengths[:, 0] - lengths[:, 1]).max(initial=0.0)), op=MPI.MAX
    )
    return spread <= 1e-6 * max(scale, 1e-300)


# --- figures -----------------------------------------------------------------------


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _glyph_segments(points, u, v, lengths, arm):
    """Two segments per point, ±u and ±v, the longer arm ``arm`` long; colours = lengths."""
    longest = lengths.max(axis=1, keepdims=True)
    scale = arm / np.where(longest > 0, longest, 1.0)
    segments, colours = [], []
    for k, branch in enumerate((u, v)):
        half = branch * scale
        segments.append(np.stack([points - half, points + half], axis=1))
        colours.append(lengths[:, k])
    return np.concatenate(segments), np.concatenate(colours)


_SINGULARITY_STYLE = {
    0.25: {"marker": "o", "color": "#d62728", "label": "+1/4"},
    -0.25: {"marker": "s", "color": "#1f77b4", "label": "−1/4"},
}


def _mark_singularities(ax, singularities) -> None:
    by_index = {}
    for s in singularities:
        by_index.setdefault(round(float(s["index"]) * 4) / 4, []).append((s["x"], s["y"]))
    for index, xy in sorted(by_index.items(), reverse=True):
        style = _SINGULARITY_STYLE.get(
            index, {"marker": "X", "color": "black", "label": f"{index:+g}"}
        )
        xy = np.asarray(xy)
        ax.scatter(
            xy[:, 0], xy[:, 1], s=80, marker=style["marker"], facecolor=style["color"],
            edgecolor="white", linewidth=1.2, zorder=4,
            label=f"{style['label']} singularity ({len(xy)})",
        )
    if by_index:
        ax.legend(loc="upper right", fontsize=8, framealpha=0.9)


def plot_frames(
    path,
    q: fem.Function,
    title: str | None = None,
    singularities: list[dict] | None = None,
    glyphs_across: int = GLYPHS_ACROSS,
    isotropic: bool | None = None,
) -> None:
    """Figure of the frame field ``q`` (note Fig. 1) written to ``path`` by rank 0. Collective.

    Crosses at the points of :func:`glyph_samples` (about ``glyphs_across`` across
    the longer side), each drawn as the segments ±u and ±v: the longer arm has a fixed
    size, the shorter one is in proportion (so anisotropy shows), and each arm is
    coloured by its branch length (the colour bar gives the lengths; an isotropic
    field, detected at the vertices unless ``isotropic`` is given, is drawn with
    l1 = l2 = (l1 + l2)/2). ``singularities`` (``{"index", "x", "y"}``, e.g. from
    :func:`ufl_frames.singularities.locate_singularities`) are marked.
    """
    mesh = q.function_space.mesh
    comm = mesh.comm
    if isotropic is None:
        isotropic = _is_isotropic(q)
    points, rows, spacing = glyph_samples(q, glyphs_across)
    boundary = _gather_rows(comm, _boundary_segments(mesh))
    if comm.rank == 0:
        _draw_frames(path, points, rows, spacing, boundary, title, singularities or [],
                     isotropic)
    comm.Barrier()


def _draw_frames(path, points, rows, spacing, boundary, title, singularities, isotropic):
    plt = _pyplot()
    from matplotlib.collections import LineCollection

    lengths, u, v = _frames(rows)
    if isotropic:
        mean = lengths.mean(axis=1, keepdims=True)
        scale = mean / np.where(lengths > 0, lengths, 1.0)
        u, v, lengths = u * scale[:, :1], v * scale[:, 1:], np.repeat(mean, 2, axis=1)
    segments, colours = _glyph_segments(points, u, v, lengths, GLYPH_ARM * spacing)

    ends = boundary.reshape(-1, 2)
    lo, hi = ends.min(axis=0), ends.max(axis=0)
    extent = hi - lo
    width = 7.0
    height = max(3.0, min(9.0, (width - 1.8) * extent[1] / max(extent[0], 1e-300) + 0.9))
    fig, ax = plt.subplots(figsize=(width, height), layout="constrained")
    ax.add_collection(LineCollection(boundary, colors="0.15", linewidths=1.0, zorder=1))
    glyphs = LineCollection(segments, cmap="viridis", linewidths=1.3, capstyle="round", zorder=2)
    glyphs.set_array(colours)
    # A uniform field (an MBO field has unit lengths) gets a readable colour range.
    low, high = float(colours.min()), float(colours.max())
    middle, half = (low + high) / 2, max((high - low) / 2, 0.05 * abs(high + low) / 2, 1e-12)
    glyphs.set_clim(middle - half, middle + half)
    ax.add_collection(glyphs)
    _mark_singularities(ax, singularities)
    bar = fig.colorbar(glyphs, ax=ax, shrink=0.85, pad=0.02)
    bar.set_label("frame length $l_1 = l_2$" if isotropic else "branch length $l_1$, $l_2$")
    margin = 0.04 * float(extent.max())
    ax.set_xlim(lo[0] - margin, hi[0] + margin)
    ax.set_ylim(lo[1] - margin, hi[1] + margin)
    ax.set_aspect("equal")
    ax.set_xlabel("$x$")
    ax.set_ylabel("$y$")
    if title:
        ax.set_title(title)
    fig.savefig(path, dpi=200)
    plt.close(fig)


def plot_convergence(
    path, history: list[dict], title: str | None = None, comm: MPI.Comm = MPI.COMM_WORLD
) -> None:
    """H(q) (log scale) and E(q) against the iteration (note Fig. 2), written by rank 0.

    ``history`` is :attr:`ufl_frames.solver.SolveResult.history` (entries with
    ``"it"``, ``"H"``, ``"E"``). Collective over ``comm``.
    """
    if comm.rank == 0:
        _draw_convergence(path, history, title)
    comm.Barrier()


def _draw_convergence(path, history, title):
    plt = _pyplot()
    it = np.array([h["it"] for h in history], dtype=float)
    H = np.array([h["H"] for h in history], dtype=float)
    E = np.array([h["E"] for h in history], dtype=float)
    style = {"marker": "o", "markersize": 3} if len(history) <= 60 else {}

    fig, (ax_h, ax_e) = plt.subplots(1, 2, figsize=(9.0, 3.6), layout="constrained")
    ax_h.plot(it, H, color="#1f77b4", lw=1.5, **style)
    if np.all(H > 0):
        ax_h.set_yscale("log")
    ax_h.set_ylabel(r"$H(q) = \frac{1}{2}\int_\Omega |[u,v]|^2\,dx$")
    ax_h.set_title("integrability energy")
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
    fig.savefig(path, dpi=200)
    plt.close(fig)


def describe_singularities(singularities: list[dict]) -> str:
    """One-line text such as ``+1/4 at (0.35, 0.8), -1/4 at (1.57, 0.726)`` (or ``none``)."""
    if not singularities:
        return "none"
    parts = []
    for s in singularities:
        parts.append(f"{round(float(s['index']) * 4):+d}/4 at ({s['x']:.3g}, {s['y']:.3g})")
    return ", ".join(parts)
