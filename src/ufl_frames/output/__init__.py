r"""Results on disk: the run summary, the field for ParaView, the figures, the output folder.

* :mod:`~ufl_frames.output.report`: :func:`write_summary` (a JSON file) and
  :func:`~ufl_frames.output.report.on_root`, how every write here runs on rank 0;
* :mod:`~ufl_frames.output.fields`: :func:`write_field`, the final frame field for
  ParaView (ADIOS2 ``.bp``, or XDMF, and always ASCII VTK);
* :mod:`~ufl_frames.output.vtk`: :func:`read_vtk`, that ASCII VTK read back with the
  standard library alone;
* :mod:`~ufl_frames.output.figures`: :func:`plot_frames` (note Fig. 1),
  :func:`plot_convergence` (note Fig. 2), :func:`describe_singularities` (one line), with
  the crosses placed by :mod:`~ufl_frames.output.glyphs`;
* :mod:`~ufl_frames.output.folder`: :class:`OutputFolder`, a run's output folder written
  whole or not at all (a hidden sibling folder renamed into place when complete).

Every function that takes a DOLFINx object is collective over the mesh communicator
(call it on all ranks): data are gathered to rank 0, which alone writes. An error while
rank 0 writes (a full disk, a folder that went away) is raised on every rank alike:
rank 0 raises its own exception, the others :class:`WriteError` with its message.
"""

import importlib

#: The public names and their modules, imported on first use (PEP 562): the ASCII VTK
#: reader and writer (:mod:`~ufl_frames.output.vtk`) need NumPy alone.
_EXPORTS = {
    "field_functions": "fields", "write_field": "fields",
    "FrameLayout": "figures", "describe_singularities": "figures", "frame_layout": "figures",
    "plot_convergence": "figures", "plot_frames": "figures",
    "OutputFolder": "folder", "OutputFolderBusy": "folder", "is_output_name": "folder",
    "glyph_samples": "glyphs", "WriteError": "report", "write_summary": "report",
    "read_vtk": "vtk", "write_vtu": "vtk",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in set(_EXPORTS.values()) | {"volume"}:  # a submodule, not yet imported
        return importlib.import_module(f"ufl_frames.output.{name}")
    if name not in _EXPORTS:
        raise AttributeError(f"module 'ufl_frames.output' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"ufl_frames.output.{_EXPORTS[name]}"), name)
    globals()[name] = value
    return value
