"""ASCII VTK files read back with the standard library (no ParaView, ADIOS2 or HDF5).

:func:`read_vtk` reads the ``.pvd`` / ``.pvtu`` / ``.vtu`` set that
:func:`ufl_frames.output.write_field` writes; :func:`vtk_references` lists the files a
``.pvd`` or ``.pvtu`` names.
"""

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

__all__ = ["read_vtk", "vtk_references", "write_vtu"]

#: VTK cell types by the number of vertices of a straight cell of each dimension.
VTK_CELL_TYPES = {("line", 2): 3, ("triangle", 3): 5, ("quad", 4): 9, ("tetra", 4): 10}

_VTK_DTYPES = {
    "Float32": np.float32, "Float64": np.float64, "Int8": np.int8, "UInt8": np.uint8,
    "Int16": np.int16, "UInt16": np.uint16, "Int32": np.int32, "UInt32": np.uint32,
    "Int64": np.int64, "UInt64": np.uint64,
}


def vtk_references(path: Path) -> list[Path]:
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
        out += [child, *vtk_references(child)]
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
        path = vtk_references(path)[0]
    pieces = [p for p in vtk_references(path) if p.suffix == ".vtu"] or [path]
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


def write_vtu(path, points, cells, cell_type: str, point_data: dict | None = None,
              cell_data: dict | None = None) -> Path:
    """Write one unstructured grid as an ASCII VTK XML file (``.vtu``) for ParaView.

    Args:
        path: the file to write.
        points: the points (n, 2 or 3) (2D ones written with z = 0).
        cells: point indices (m, k), all of one type.
        cell_type: ``"line"``, ``"triangle"``, ``"quad"`` or ``"tetra"``.
        point_data: arrays per point by name ((n,) or (n, c); None: none).
        cell_data: arrays per cell by name ((m,) or (m, c); None: none).

    Returns:
        ``path`` as a :class:`~pathlib.Path`.

    Raises:
        ValueError: a wrong cell type, an array of a wrong shape, or an index outside the
            points.
    """
    x = np.asarray(points, dtype=float)
    c = np.asarray(cells, dtype=np.int64)
    if c.ndim != 2 or (cell_type, c.shape[1]) not in VTK_CELL_TYPES:
        raise ValueError(f"cells of type {cell_type!r} with shape {c.shape} cannot be written")
    if c.size and (c.min() < 0 or c.max() >= x.shape[0]):
        raise ValueError(f"cells index points outside 0..{x.shape[0] - 1}")
    if x.ndim != 2 or x.shape[1] not in (2, 3):
        raise ValueError(f"points must have shape (n, 2) or (n, 3), got {x.shape}")
    points3 = x if x.shape[1] == 3 else np.c_[x, np.zeros(x.shape[0])]

    def text(a, fmt="%.17g"):
        return " ".join(fmt % v for v in np.asarray(a).ravel())

    def arrays(data, count, where):
        out = []
        for name, values in (data or {}).items():
            a = np.asarray(values, dtype=float)
            if a.shape[:1] != (count,) or a.ndim > 2:
                raise ValueError(f"{where} data {name!r} must have shape ({count},) or "
                                 f"({count}, c), got {a.shape}")
            components = 1 if a.ndim == 1 else a.shape[1]
            out.append(f'<DataArray type="Float64" Name="{name}" '
                       f'NumberOfComponents="{components}" format="ascii">{text(a)}</DataArray>')
        return "".join(out)

    m, k = c.shape
    offsets = text(k * np.arange(1, m + 1), "%d")
    types = text(np.full(m, VTK_CELL_TYPES[(cell_type, k)]), "%d")
    body = f"""<?xml version="1.0"?>
<VTKFile type="UnstructuredGrid" version="0.1" byte_order="LittleEndian">
<UnstructuredGrid><Piece NumberOfPoints="{x.shape[0]}" NumberOfCells="{m}">
<PointData>{arrays(point_data, x.shape[0], "point")}</PointData>
<CellData>{arrays(cell_data, m, "cell")}</CellData>
<Points><DataArray type="Float64" NumberOfComponents="3" format="ascii">{text(points3)}</DataArray>
</Points>
<Cells>
<DataArray type="Int64" Name="connectivity" format="ascii">{text(c, "%d")}</DataArray>
<DataArray type="Int64" Name="offsets" format="ascii">{offsets}</DataArray>
<DataArray type="UInt8" Name="types" format="ascii">{types}</DataArray>
</Cells>
</Piece></UnstructuredGrid>
</VTKFile>
"""
    path = Path(path)
    path.write_text(body)
    return path
