"""ASCII VTK files read back with the standard library (no ParaView, ADIOS2 or HDF5).

:func:`read_vtk` reads the ``.pvd`` / ``.pvtu`` / ``.vtu`` set that
:func:`ufl_frames.output.write_field` writes; :func:`vtk_references` lists the files a
``.pvd`` or ``.pvtu`` names.
"""

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

__all__ = ["read_vtk", "vtk_references"]

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
