"""Where the crosses of a frame figure go, and their segments.

:func:`glyph_samples` evaluates a distributed P1 frame field at the points of a regular
grid in the domain (or takes its vertices, on a coarse mesh) and gathers them on rank 0;
:func:`glyph_segments` turns the frames there into the two segments of each cross;
:func:`boundary_segments` and :func:`distance_to_segments` keep crosses off the boundary.
"""

import math

from ufl_frames.bootstrap import init_petsc

init_petsc()

import dolfinx  # noqa: E402
import dolfinx.fem as fem  # noqa: E402
import dolfinx.geometry  # noqa: E402
import numpy as np  # noqa: E402

from ufl_frames.fem import scales  # noqa: E402
from ufl_frames.fem.gather import gather_rows  # noqa: E402
from ufl_frames.frames2d import odeco  # noqa: E402

__all__ = ["boundary_segments", "distance_to_segments", "glyph_samples", "glyph_segments",
           "grid_points"]

#: Crosses aimed at over the domain (its area, not its bounding box) in
#: :func:`~ufl_frames.output.figures.plot_frames`.
GLYPHS = 1500
#: The older density rule, crosses across the longer side of the bounding box; used only
#: where ``glyphs_across`` is passed explicitly.
GLYPHS_ACROSS = 36
#: Half-length of the longer arm of a cross, as a fraction of the glyph spacing.
GLYPH_ARM = 0.36
#: Smallest distance between crosses on the figure (inches; 14 px at 200 dpi,
#: :data:`~ufl_frames.output.figures.DPI`): on very elongated domains the target count
#: would give crosses too small to read.
GLYPH_MIN_SPACING_IN = 0.07
#: Near the boundary a cross shrinks to its distance from it, but not below this fraction
#: of the full arm (so that crosses on the boundary itself stay visible).
GLYPH_MIN_ARM = 0.35


def boundary_segments(mesh) -> np.ndarray:
    """Coordinates (nf, 2, 2) of the exterior facets owned by this rank."""
    tdim = mesh.topology.dim
    mesh.topology.create_connectivity(tdim - 1, tdim)
    facets = dolfinx.mesh.exterior_facet_indices(mesh.topology)
    nodes = dolfinx.mesh.entities_to_geometry(mesh, tdim - 1, facets)
    return mesh.geometry.x[nodes][:, :, :2].reshape(-1, 2, 2)


def grid_points(lo, hi, spacing: float) -> np.ndarray:
    """Points (M, 3) of the square grid of step ``spacing`` centred on the box [lo, hi].

    Args:
        lo: the box's lower corner (x, y).
        hi: the box's upper corner (x, y).
        spacing: the grid step (> 0).

    Returns:
        The grid points (M, 3), z = 0, x the slower index.
    """
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
    return found, np.asarray(values).reshape(-1, odeco.NUM_COEFFICIENTS)


def glyph_samples(
    q: fem.Function,
    glyphs_across: int | None = None,
    *,
    glyphs: int = GLYPHS,
    spacing: float | None = None,
):
    """Where to draw crosses, and the field there, on rank 0 (collective).

    On a mesh finer than the spacing, q is evaluated (P1 interpolation, exact for the
    discrete field) at the points of a regular grid that lie in the domain: a regular
    lattice of crosses. On coarser meshes every vertex gets a cross and the spacing is
    the mean edge length.

    Args:
        q: the frame field (P1, 5 components).
        glyphs_across: crosses across the longer side of the bounding box (used when
            ``spacing`` is None).
        glyphs: crosses aimed at over the domain: spacing √(area / ``glyphs``), whatever
            its shape (holes and concave parts do not count; used when ``spacing`` and
            ``glyphs_across`` are None).
        spacing: the grid's step.

    Returns:
        (points (M, 2), q there (M, 5), spacing) on rank 0; on the other ranks the
        points and rows are None.
    """
    V = q.function_space
    mesh = V.mesh
    comm = mesh.comm
    lo, hi = scales.bounding_box(mesh)
    if spacing is None:
        if glyphs_across is not None:
            spacing = float((hi - lo).max()) / glyphs_across
        else:
            spacing = math.sqrt(scales.area(mesh) / glyphs)
    spacing = float(spacing)
    h = scales.mean_cell_edge(mesh)
    if h >= 0.8 * spacing:
        owned = V.dofmap.index_map.size_local
        points = gather_rows(comm, V.tabulate_dof_coordinates()[:owned, :2])
        rows = gather_rows(comm, q.x.array.reshape(-1, odeco.NUM_COEFFICIENTS)[:owned])
        return points, rows, h
    grid = grid_points(lo, hi, spacing)
    found, values = _evaluate_owned(q, grid)
    found = gather_rows(comm, found)
    values = gather_rows(comm, values)
    if comm.rank != 0:
        return None, None, spacing
    # A point on an edge between ranks is found twice: keep it once.
    found, first = np.unique(found, return_index=True)
    return grid[found, :2], values[first], spacing


def distance_to_segments(points: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """Distance (M,) of each point (M, 2) to the nearest of the segments (nf, 2, 2)."""
    out = np.full(points.shape[0], np.inf)
    if segments.shape[0] == 0:
        return out
    a = segments[:, 0]
    d = segments[:, 1] - a
    dd = np.einsum("ij,ij->i", d, d)
    dd[dd == 0] = 1.0  # a degenerate facet: its distance is to its first point
    # Chunks of points keep the (points x segments) arrays near 8 MB each.
    step = max(1, 2**20 // segments.shape[0])
    for i in range(0, points.shape[0], step):
        rel = points[i : i + step, None, :] - a[None]
        t = np.clip(np.einsum("pij,ij->pi", rel, d) / dd, 0.0, 1.0)
        r = rel - t[..., None] * d
        out[i : i + step] = np.sqrt(np.einsum("pij,pij->pi", r, r).min(axis=1))
    return out


def glyph_segments(points, u, v, lengths, arm):
    """Two segments per point, ±u and ±v, the longer arm ``arm`` long.

    Args:
        points: the crosses' centres (M, 2).
        u: the first branch at each point (M, 2) (:func:`~ufl_frames.output.fields.frame_vectors`).
        v: the second branch (M, 2).
        lengths: the branch lengths (M, 2).
        arm: the half-length of the longer arm: a number or one per point (M,).

    Returns:
        (segments (2M, 2, 2): the u arms, then the v arms; colours (2M,): the arm's branch
        length).
    """
    longest = lengths.max(axis=1, keepdims=True)
    scale = np.reshape(arm, (-1, 1)) / np.where(longest > 0, longest, 1.0)
    segments, colours = [], []
    for k, branch in enumerate((u, v)):
        half = branch * scale
        segments.append(np.stack([points - half, points + half], axis=1))
        colours.append(lengths[:, k])
    return np.concatenate(segments), np.concatenate(colours)
