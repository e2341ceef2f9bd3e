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

from ufl_frames.output.fields import field_functions, write_field
from ufl_frames.output.figures import (
    FrameLayout,
    describe_singularities,
    frame_layout,
    plot_convergence,
    plot_frames,
)
from ufl_frames.output.folder import OutputFolder, OutputFolderBusy, is_output_name
from ufl_frames.output.glyphs import glyph_samples
from ufl_frames.output.report import WriteError, write_summary
from ufl_frames.output.vtk import read_vtk

__all__ = [
    "FrameLayout",
    "OutputFolder",
    "OutputFolderBusy",
    "WriteError",
    "describe_singularities",
    "field_functions",
    "frame_layout",
    "glyph_samples",
    "is_output_name",
    "plot_convergence",
    "plot_frames",
    "read_vtk",
    "write_field",
    "write_summary",
]
