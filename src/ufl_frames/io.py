r"""Results on disk: the run summary, the field for ParaView and the two figures of note §5.

* :func:`write_summary` — a JSON file (rank 0 writes it).
* :func:`write_field` — the final frame field, for ParaView, in one ADIOS2 ``.bp``
  folder (:class:`dolfinx.io.VTXWriter`), or an XDMF file where DOLFINx was built
  without ADIOS2, and always also as ASCII VTK (``.pvd`` + ``.pvtu`` + one ``.vtu``
  per rank), which :func:`read_vtk` reads back with the standard library alone.
* :func:`plot_frames` — crosses coloured by frame length, with the singularities
  (note Fig. 1), sized for the domain's aspect ratio (:func:`frame_layout`).
* :func:`plot_convergence` — H(q) and E(q) against the iteration (note Fig. 2).
* :func:`describe_singularities` — a one-line console summary.
* :class:`OutputFolder` — a run's output folder, written whole or not at all: the files
  go to a hidden sibling folder, renamed into place when complete.

Every function that takes a DOLFINx object is collective over the mesh communicator
(call it on all ranks): data are gathered to rank 0, which alone writes. An error while
rank 0 writes (a full disk, a folder that went away) is raised on every rank alike:
rank 0 raises its own exception, the others :class:`WriteError` with its message.
"""

import contextlib
import errno
import fcntl
import json
import math
import os
import re
import secrets
import shutil
import textwrap
import time
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import NamedTuple

from ufl_frames.bootstrap import init_petsc

init_petsc()

import dolfinx  # noqa: E402
import dolfinx.fem as fem  # noqa: E402
import dolfinx.geometry  # noqa: E402
import dolfinx.io  # noqa: E402
import numpy as np  # noqa: E402
import ufl  # noqa: E402
from mpi4py import MPI  # noqa: E402

from ufl_frames.fem import energy, scales  # noqa: E402
from ufl_frames.fem.energy import check_frame_function as check_frame_field  # noqa: E402
from ufl_frames.frames2d import odeco  # noqa: E402

__all__ = [
    "OutputFolder",
    "WriteError",
    "describe_singularities",
    "frame_layout",
    "plot_convergence",
    "plot_frames",
    "read_vtk",
    "write_field",
    "write_summary",
]

#: Crosses aimed at over the domain (its area, not its bounding box) in :func:`plot_frames`.
GLYPHS = 1500
#: The older density rule, crosses across the longer side of the bounding box; used only
#: where ``glyphs_across`` is passed explicitly.
GLYPHS_ACROSS = 36
#: Half-length of the longer arm of a cross, as a fraction of the glyph spacing.
GLYPH_ARM = 0.36
#: Smallest distance between crosses on the figure (inches; 14 px at :data:`DPI`): on
#: very elongated domains the target count would give crosses too small to read.
GLYPH_MIN_SPACING_IN = 0.07
#: Near the boundary a cross shrinks to its distance from it, but not below this fraction
#: of the full arm (so that crosses on the boundary itself stay visible).
GLYPH_MIN_ARM = 0.35
#: Resolution of the PNG figures.
DPI = 200
#: Area (square inches) of the data area of :func:`plot_frames` for a compact domain.
AXES_AREA_IN2 = 40.0
#: Longest side (inches) of the data area when the domain is wide / tall (screens are
#: wider than tall).
AXES_LONG_MAX_IN = (15.0, 11.0)
#: Smallest figure (inches): room for a wrapped title, the axis labels and the colour bar.
FIGURE_MIN_IN = (3.0, 2.5)
#: Font size of the title of :func:`plot_frames` (points).
TITLE_FONTSIZE = 11.0
#: :func:`describe_singularities` lists up to this many; more are counted per index.
DESCRIBE_LIMIT = 6
#: Beyond this many singularities the markers are small dots without an outline.
MANY_SINGULARITIES = 200


# --- errors on rank 0, raised everywhere ----------------------------------------------


class WriteError(OSError):
    """Writing results failed (on this rank, or on rank 0 while this rank waited)."""


def _on_root(comm: MPI.Comm, action) -> None:
    """Run ``action()`` on rank 0 of ``comm``; its exception, if any, on every rank (collective).

    Rank 0 re-raises its own exception; the other ranks raise :class:`WriteError` with
    its message (a ``KeyboardInterrupt`` stays one). Returns only when rank 0 is done,
    like a barrier.
    """
    failure = None
    if comm.rank == 0:
        try:
            action()
        except BaseException as e:  # noqa: BLE001  (re-raised below, on every rank)
            failure = e
    if comm.size > 1:
        message = None
        if failure is not None:
            message = (isinstance(failure, KeyboardInterrupt), _one_line(failure))
        message = comm.bcast(message, root=0)
        if comm.rank != 0 and message is not None:
            interrupted, text = message
            raise KeyboardInterrupt(text) if interrupted else WriteError(text)
    if failure is not None:
        raise failure


def _one_line(e: BaseException) -> str:
    text = " ".join(str(e).split())
    return text or type(e).__name__


# --- checks on the arguments --------------------------------------------------------------


def _check_history(history) -> None:
    if not isinstance(history, (list, tuple)) or not history:
        raise ValueError("history must be a non-empty list of {'it', 'H', 'E'} entries")
    for entry in history:
        if not isinstance(entry, dict) or not {"it", "H", "E"} <= set(entry):
            raise ValueError(f"history entries need the keys 'it', 'H' and 'E', got {entry!r}")


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

    Non-finite floats are written as ``NaN``/``Infinity`` (Python's JSON dialect). A
    failure (a value JSON cannot hold, a write error) is raised on every rank.
    """
    if not isinstance(data, dict):
        raise ValueError(f"data must be a dict, got {type(data).__name__}")

    def write():
        text = json.dumps(data, indent=2, default=_json_default)
        Path(path).write_text(text + "\n")

    _on_root(comm, write)


# --- pointwise frame data ---------------------------------------------------------


def _frames(rows: np.ndarray):
    """Lengths (N, 2), branch vectors u, v (each (N, 2)) of the rows; zeros for zero rows.

    The branch labels follow :func:`ufl_frames.frames2d.odeco.q_to_frames` (angle of u in
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
    check_frame_field(q)
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
    check_frame_field(q)
    mesh = q.function_space.mesh
    V2 = fem.functionspace(mesh, ("Lagrange", 1, (2,)))
    lengths, u, v = _frames(q.x.array.reshape(-1, odeco.NUM_COEFFICIENTS))
    # P1 spaces on one mesh share the vertex numbering: the rows of q are those of V2.
    out = []
    for name, values in (("lengths", lengths), ("u", u), ("v", v)):
        f = fem.Function(V2, name=name)
        f.x.array[:] = values.ravel()
        out.append(f)
    q_out = fem.Function(q.function_space, name="q")
    q_out.x.array[:] = q.x.array
    return [q_out, *out, bracket_rms(q)]


def write_field(directory, q: fem.Function, stem: str = "frames") -> list[Path]:
    """Write the frame field into ``directory``; return the paths written (same on all ranks).

    The functions of :func:`field_functions`, twice:

    * ``<stem>.bp`` (ADIOS2, :class:`dolfinx.io.VTXWriter`: the P1 functions as point
      data and ``bracket_rms`` as cell data, in one folder) when DOLFINx has ADIOS2,
      otherwise ``<stem>.xdmf`` + ``<stem>.h5``;
    * ``<stem>.pvd`` + ``<stem>000000.pvtu`` + one ``<stem>_p<rank>_000000.vtu`` per
      rank (:class:`dolfinx.io.VTKFile`, ASCII XML): ParaView opens it too, and unlike
      the others it can be read back here without ADIOS2 or HDF5 (:func:`read_vtk`).

    The list is in that order (the ``.bp`` folder is one entry). Collective.
    ``directory`` must exist.
    """
    check_frame_field(q)
    directory = Path(directory)
    comm = q.function_space.mesh.comm
    problem = None
    if comm.rank == 0 and not directory.is_dir():
        problem = f"output folder {str(directory)!r} does not exist"
    problem = comm.bcast(problem, root=0)
    if problem is not None:
        raise FileNotFoundError(errno.ENOENT, problem)
    functions = field_functions(q)
    if dolfinx.io.has_adios2:
        paths = [directory / f"{stem}.bp"]
        with dolfinx.io.VTXWriter(comm, paths[0], functions, engine="BP4") as writer:
            writer.write(0.0)
    else:
        paths = [directory / f"{stem}.xdmf", directory / f"{stem}.h5"]
        with dolfinx.io.XDMFFile(comm, paths[0], "w") as xdmf:
            xdmf.write_mesh(q.function_space.mesh)
            for f in functions:
                xdmf.write_function(f, 0.0)
    pvd = directory / f"{stem}.pvd"
    with dolfinx.io.VTKFile(comm, pvd, "w") as vtk:
        vtk.write_function(functions, 0.0)
    comm.Barrier()
    # The piece names are DOLFINx's: read them from the files rather than guess them. On
    # rank 0, and what it finds (or why it cannot, e.g. ranks given different folders)
    # reaches every rank: an error on rank 0 alone would leave the others in the bcast.
    written = None
    if comm.rank == 0:
        try:
            written = [pvd, *_vtk_references(pvd)]
        except (OSError, ET.ParseError) as e:
            written = e
    written = comm.bcast(written, root=0)
    if isinstance(written, Exception):
        raise OSError(f"the VTK files just written in {str(directory)!r} cannot be read "
                      f"back ({written}); all ranks must be given the same folder") from written
    return paths + written


# --- reading VTK back -------------------------------------------------------------------

_VTK_DTYPES = {
    "Float32": np.float32, "Float64": np.float64, "Int8": np.int8, "UInt8": np.uint8,
    "Int16": np.int16, "UInt16": np.uint16, "Int32": np.int32, "UInt32": np.uint32,
    "Int64": np.int64, "UInt64": np.uint64,
}


def _vtk_references(path: Path) -> list[Path]:
    """Files a ``.pvd`` (its data sets) or ``.pvtu`` (its pieces) names, recursively."""
    root = ET.parse(path).getroot()
    if path.suffix == ".pvd":
        names = [d.get("file") for d in root.iter("DataSet")]
    elif path.suffix == ".pvtu":
        names = [piece.get("Source") for piece in root.iter("Piece")]
    else:
        return []
    out = []
    for name in names:
        child = path.parent / name
        out += [child, *_vtk_references(child)]
    return out


def _vtk_array(element) -> tuple[str, np.ndarray]:
    """(Name, values) of an ASCII ``DataArray``: shape (n,) or (n, NumberOfComponents)."""
    if element.get("format") != "ascii":
        raise ValueError(f"only ASCII VTK data arrays can be read, got {element.get('format')!r}")
    values = np.array((element.text or "").split(), dtype=_VTK_DTYPES[element.get("type")])
    components = int(element.get("NumberOfComponents", "1"))
    return element.get("Name"), values.reshape(-1, components) if components > 1 else values


def _read_vtu(path: Path) -> dict:
    piece = ET.parse(path).getroot().find("UnstructuredGrid/Piece")
    points = _vtk_array(piece.find("Points/DataArray"))[1]
    cells = dict(_vtk_array(e) for e in piece.findall("Cells/DataArray"))
    point_data = dict(_vtk_array(e) for e in piece.findall("PointData/DataArray"))
    cell_data = dict(_vtk_array(e) for e in piece.findall("CellData/DataArray"))
    sizes = np.diff(cells["offsets"], prepend=0)
    if sizes.size and np.any(sizes != sizes[0]):
        raise ValueError(f"{path}: cells of mixed sizes are not supported")
    connectivity = cells["connectivity"].reshape(sizes.size, -1).astype(np.int64)
    # Cells owned by another rank are repeated in this piece, flagged in vtkGhostType.
    keep = cell_data.get("vtkGhostType", np.zeros(sizes.size, dtype=np.uint8)) == 0
    return {
        "points": points,
        "cells": connectivity[keep],
        "point_data": {k: v for k, v in point_data.items() if not k.startswith("vtk")},
        "cell_data": {k: v[keep] for k, v in cell_data.items() if not k.startswith("vtk")},
    }


def read_vtk(path) -> dict:
    """The mesh and data of an ASCII VTK file (``.pvd``, ``.pvtu`` or ``.vtu``).

    Returns ``{"points": (N, 3), "cells": (M, k) indices into points, "point_data":
    {name: (N,) or (N, c)}, "cell_data": {name: (M,) or (M, c)}}``. The pieces of a
    parallel file are concatenated: ghost cells are dropped, so every cell appears
    once, but a point shared by pieces appears once per piece. VTK's bookkeeping
    arrays (``vtk*``) are left out; 2-vectors come back with 3 components (z = 0). A
    ``.pvd`` gives its first data set. The standard library's XML parser is enough:
    this is how results are read back without ParaView, ADIOS2 or HDF5.
    """
    path = Path(path)
    if path.suffix == ".pvd":
        path = _vtk_references(path)[0]
    pieces = [p for p in _vtk_references(path) if p.suffix == ".vtu"] or [path]
    parts = [_read_vtu(p) for p in pieces]
    first = np.cumsum([0] + [len(part["points"]) for part in parts[:-1]])
    return {
        "points": np.concatenate([part["points"] for part in parts]),
        "cells": np.concatenate([part["cells"] + k for part, k in zip(parts, first, strict=True)]),
        "point_data": {name: np.concatenate([part["point_data"][name] for part in parts])
                       for name in parts[0]["point_data"]},
        "cell_data": {name: np.concatenate([part["cell_data"][name] for part in parts])
                      for name in parts[0]["cell_data"]},
    }


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
    return found, np.asarray(values).reshape(-1, odeco.NUM_COEFFICIENTS)


def glyph_samples(
    q: fem.Function,
    glyphs_across: int | None = None,
    *,
    glyphs: int = GLYPHS,
    spacing: float | None = None,
):
    """Where to draw crosses: (points (M, 2), q there (M, 5), spacing) on rank 0. Collective.

    The spacing is ``spacing`` if given, else the longer side of the bounding box /
    ``glyphs_across`` if given, else √(area / ``glyphs``): about ``glyphs`` crosses in
    the domain whatever its shape (holes and concave parts do not count). On a mesh
    finer than the spacing, q is evaluated (P1 interpolation, exact for the discrete
    field) at the points of a regular grid that lie in the domain: a regular lattice
    of crosses. On coarser meshes every vertex gets a cross and the spacing is the
    mean edge length. Other ranks get Nones.
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
        points = _gather_rows(comm, V.tabulate_dof_coordinates()[:owned, :2])
        rows = _gather_rows(comm, q.x.array.reshape(-1, odeco.NUM_COEFFICIENTS)[:owned])
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
    lengths, _, _ = _frames(q.x.array.reshape(-1, odeco.NUM_COEFFICIENTS)[:owned])
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


def _distance_to_segments(points: np.ndarray, segments: np.ndarray) -> np.ndarray:
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


def _glyph_segments(points, u, v, lengths, arm):
    """Two segments per point, ±u and ±v, the longer arm ``arm`` long; colours = lengths.

    ``arm`` is a number or one per point (M,).
    """
    longest = lengths.max(axis=1, keepdims=True)
    scale = np.reshape(arm, (-1, 1)) / np.where(longest > 0, longest, 1.0)
    segments, colours = [], []
    for k, branch in enumerate((u, v)):
        half = branch * scale
        segments.append(np.stack([points - half, points + half], axis=1))
        colours.append(lengths[:, k])
    return np.concatenate(segments), np.concatenate(colours)


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


def frame_layout(lo, hi, title: str | None = None, legend: bool = False) -> FrameLayout:
    """Figure geometry for a domain of bounding box [lo, hi] (:class:`FrameLayout`).

    The data area has the domain's aspect ratio and :data:`AXES_AREA_IN2` square
    inches, its longer side (horizontal or vertical, as the domain comes) capped by
    :data:`AXES_LONG_MAX_IN`: an elongated domain gets a long figure, not a sliver in
    a fixed-width one. The figure adds room for labels, the colour bar (below wide
    domains, right of the others), the legend and the title, wrapped to its width,
    and is at least :data:`FIGURE_MIN_IN`. Depends only on the shape: scaling the
    domain (mm instead of m) changes nothing but ``scale``.
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
        scale=axes_w / width,
        horizontal=horizontal,
        title=text,
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

    Crosses at the points of :func:`glyph_samples` — about ``glyphs`` in the domain,
    fewer where they would be closer than :data:`GLYPH_MIN_SPACING_IN` on paper
    (``glyphs_across`` per longer side instead, if given) — each drawn as the
    segments ±u and ±v: the longer arm has a fixed size (smaller near the boundary,
    so that crosses do not hide holes), the shorter one is in proportion (so
    anisotropy shows), and each arm is coloured by its branch length (the colour
    bar gives the lengths; an isotropic field, detected at the vertices unless
    ``isotropic`` is given, is drawn with l1 = l2 = (l1 + l2)/2). The boundary is
    every boundary facet. ``singularities`` (``{"index", "x", "y"}``, e.g. from
    :func:`ufl_frames.frames2d.singularities.locate_singularities`) are marked, smaller the
    more there are. Figure size: :func:`frame_layout`.
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
    boundary = _gather_rows(comm, _boundary_segments(mesh))

    def draw():
        fig = _frames_figure(layout, points, rows, spacing, boundary, area, singularities,
                             isotropic)
        _save(fig, path, dpi)

    _on_root(comm, draw)


def _save(fig, path, dpi) -> None:
    """Write and close a figure (tests replace it to inspect the figure)."""
    try:
        fig.savefig(path, dpi=dpi)
    finally:
        _pyplot().close(fig)


def _frames_figure(layout, points, rows, spacing, boundary, area, singularities, isotropic):
    plt = _pyplot()
    from matplotlib.collections import LineCollection

    lengths, u, v = _frames(rows)
    if isotropic:
        mean = lengths.mean(axis=1, keepdims=True)
        scale = mean / np.where(lengths > 0, lengths, 1.0)
        u, v, lengths = u * scale[:, :1], v * scale[:, 1:], np.repeat(mean, 2, axis=1)
    arm = GLYPH_ARM * spacing
    arms = np.clip(_distance_to_segments(points, boundary), GLYPH_MIN_ARM * arm, arm)
    segments, colours = _glyph_segments(points, u, v, lengths, arms)

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
        fig.draw_without_rendering()
        box = ax.get_position(original=True)
        old = fig.get_size_inches()
        needed = np.asarray(layout.axes_size) + (1 - np.array([box.width, box.height])) * old
        # Where the minimum size wins (a very narrow domain, beside its title), the data
        # area keeps its planned size and the figure has some white.
        new = np.maximum(FIGURE_MIN_IN, needed)
        if np.abs(new - old).sum() < 0.005:
            break
        fig.set_size_inches(*new)
        if title is not None:
            title.set_text(_wrap_title(layout.title, new[0]))
    ax.set_aspect("equal")
    return fig


def plot_convergence(
    path, history: list[dict], title: str | None = None, comm: MPI.Comm = MPI.COMM_WORLD,
    levels: list[tuple[str, list[dict]]] | None = None,
) -> None:
    """H(q) (log scale) and E(q) against the iteration (note Fig. 2), written by rank 0.

    ``history`` is :attr:`ufl_frames.solvers.SolveResult.history` (entries with
    ``"it"``, ``"H"``, ``"E"``). With ``levels`` (nested iteration: ``(label, history)``
    per mesh, coarse to fine, the last being ``history``) the meshes follow one another
    on one iteration axis, one colour each. Collective over ``comm``.
    """
    _check_history(history)
    for _, part in levels or ():
        _check_history(part)
    _on_root(comm, lambda: _draw_convergence(path, history, title, levels))


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


# --- the output folder, all or nothing ------------------------------------------------------

#: The names a run writes into its output folder (regular expressions, whole names):
#: with ``force``, :meth:`OutputFolder.commit` replaces exactly these, nothing else.
OUTPUT_NAMES = (
    r"summary\.json", r"frames\.bp", r"frames\.pvd", r"frames\d+\.pvtu", r"frames_p\d+_\d+\.vtu",
    r"frames\.xdmf", r"frames\.h5", r"frames\.png", r"convergence\.png",
    r"param\.png", r"param\.vtu",  # pipeline.files.write_param
    r"quads\.msh", r"quads\.vtu", r"quads\.png",  # pipeline.files.write_quads
    r"checkpoint",  # ufl_frames.checkpoint: an unfinished run's, removed when it completes
)
_OUTPUT_NAME = re.compile("|".join(f"(?:{name})" for name in OUTPUT_NAMES))
#: Seconds :meth:`OutputFolder.commit` waits for another run replacing files in the same
#: folder (``--force``) before it gives up.
LOCK_WAIT_S = 30.0


def is_output_name(name: str) -> bool:
    """Whether ``name`` is one the files a run writes (:data:`OUTPUT_NAMES`)."""
    return _OUTPUT_NAME.fullmatch(name) is not None


def output_target(path) -> Path:
    """The folder ``path`` names: absolute, normalised (``a/..``), a link to a folder
    resolved (the output goes to its target)."""
    path = Path(path)
    return path.resolve() if path.is_symlink() else Path(os.path.abspath(path))


def create_missing(folder: Path) -> list[Path]:
    """Create ``folder`` and whichever of its parents are missing; the folders created,
    outermost first (so that a caller can remove exactly those)."""
    missing = []
    while not folder.exists():
        missing.append(folder)
        folder = folder.parent
    for created in reversed(missing):
        created.mkdir()
    return missing[::-1]


class OutputFolderBusy(OSError):
    """The output folder changed under this run (another run wrote it meanwhile)."""


class OutputFolder:
    """A run's output folder, complete or untouched (collective over ``comm``).

    :meth:`open` creates a fresh hidden folder next to ``path`` (same parent, so that a
    rename moves it), where the run writes (:attr:`staging`); :meth:`commit` puts it in
    place, :meth:`discard` removes it (and the parent folders :meth:`open` created).

    * ``path`` does not exist: the staging folder is renamed to it in one step. If
      another run created it meanwhile, nothing is replaced: :class:`OutputFolderBusy`.
    * ``path`` is an empty folder: the files are renamed into it, ``summary.json`` last
      (the folder itself stays: it may be a mount point or a shell's working folder).
    * ``path`` has files and ``force``: the run's own names (:data:`OUTPUT_NAMES`) in it
      are replaced, all of them (those of an earlier run that this one did not write
      go too, so that two runs never mix), ``summary.json`` last; other files stay.
      Entries are renamed, never opened, so a symbolic link (``frames.png`` → elsewhere)
      is replaced itself and its target is not touched. Two runs replacing in the same
      folder take turns (an ``flock`` on the folder).
    * ``path`` has files without ``force``: :class:`OutputFolderBusy` (checked again
      at the end: another run may have written it meanwhile).

    A symbolic link to a folder as ``path`` stands for its target. ``ours``: names in
    ``path`` that this run wrote there itself (its ``checkpoint`` folder): they do not
    make the folder non-empty, and go when the results are put in place.
    """

    def __init__(self, path, force: bool = False, comm: MPI.Comm = MPI.COMM_WORLD,
                 ours: tuple[str, ...] = ()):
        self.path = Path(path)
        self.force = force
        self.comm = comm
        self.ours = tuple(ours)
        self.staging: Path | None = None
        self._created: list[Path] = []  # parent folders made by open(), innermost last

    def _target(self) -> Path:
        return output_target(self.path)

    def open(self) -> Path:
        """Create the staging folder; its path (on every rank). Collective."""
        result = None

        def make():
            nonlocal result
            target = self._target()
            self._created += create_missing(target.parent)
            token = f"{os.getpid():x}{secrets.token_hex(4)}"
            staging = target.parent / f".{target.name}.ufl-frames-{token}.partial"
            try:
                staging.mkdir()
            except OSError as e:
                raise WriteError(e.errno, f"cannot create a folder in {str(target.parent)!r} "
                                 f"({e.strerror})") from e
            result = str(staging)

        _on_root(self.comm, make)
        self.staging = Path(self.comm.bcast(result, root=0))
        return self.staging

    def discard(self, here: bool = False) -> None:
        """Remove the staging folder and the parents :meth:`open` created: on rank 0, or on
        this rank if ``here`` (a rank that fails alone, before it aborts the job). Safe to
        call more than once, from any thread, on one rank alone (not collective)."""
        if self.comm.rank != 0 and not here:
            return
        staging, self.staging = self.staging, None
        if staging is not None:
            for _ in range(3):  # another thread or rank may still be adding files
                shutil.rmtree(staging, ignore_errors=True)
                if not os.path.lexists(staging):
                    break
                time.sleep(0.05)
        while self._created:
            try:
                self._created.pop().rmdir()  # only if still empty
            except OSError:
                break

    def commit(self) -> None:
        """Put the staging folder's files in place (see the class); collective."""
        _on_root(self.comm, self._publish)
        self.staging = None
        self._created = []

    def _publish(self) -> None:
        staging, target = self.staging, self._target()
        if not os.path.lexists(target):
            try:
                os.rename(staging, target)
                return
            except OSError as e:
                if e.errno not in (errno.EEXIST, errno.ENOTEMPTY, errno.EISDIR, errno.ENOTDIR):
                    raise
                # Created meanwhile: decided below, with the lock.
        if not target.is_dir():
            raise OutputFolderBusy(errno.EEXIST, f"output path {str(self.path)!r} was created "
                                   "meanwhile and is not a folder; results discarded")
        with _locked(target, self.path):
            entries = os.listdir(target)
            if all(name in self.ours for name in entries):
                # Moved in, not renamed over it: it may be someone's cwd.
                old = target.parent / f"{staging.name[:-len('.partial')]}.old"
                old.mkdir()
                moved = []
                try:
                    for name in entries:
                        os.rename(target / name, old / name)
                        moved.append(name)
                    for name in sorted(os.listdir(staging), key=lambda n: n == "summary.json"):
                        os.rename(staging / name, target / name)
                    staging.rmdir()
                except BaseException:
                    for name in moved:  # this run's checkpoint stays, as it was
                        with contextlib.suppress(OSError):
                            os.rename(old / name, target / name)
                    raise
                finally:
                    shutil.rmtree(old, ignore_errors=True)
                return
            if not self.force:
                raise OutputFolderBusy(
                    errno.ENOTEMPTY, f"output folder {str(self.path)!r} was written by another "
                    "run meanwhile; not replaced (results discarded; use --force to replace)"
                )
            old = target.parent / f"{staging.name[:-len('.partial')]}.old"
            old.mkdir()
            try:
                for name in entries:
                    if is_output_name(name):
                        os.rename(target / name, old / name)
                names = sorted(os.listdir(staging), key=lambda n: n == "summary.json")
                for name in names:
                    os.rename(staging / name, target / name)
                staging.rmdir()
            finally:
                shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def _locked(folder: Path, shown: Path):
    """An exclusive ``flock`` on ``folder`` (waits up to :data:`LOCK_WAIT_S`)."""
    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    try:
        deadline = time.monotonic() + LOCK_WAIT_S
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    raise OutputFolderBusy(
                        errno.EBUSY, f"output folder {str(shown)!r} is being written by "
                        "another run; results discarded") from None
                time.sleep(0.1)
        yield
    finally:
        os.close(fd)
