"""The frame field on disk, for ParaView.

:func:`write_field` writes the final frame field (the functions of
:func:`field_functions`) in one ADIOS2 ``.bp`` folder (:class:`dolfinx.io.VTXWriter`), or
an XDMF file where DOLFINx was built without ADIOS2, and always also as ASCII VTK
(``.pvd`` + ``.pvtu`` + one ``.vtu`` per rank), which
:func:`ufl_frames.output.vtk.read_vtk` reads back with the standard library alone.
:func:`frame_vectors` gives the branch vectors of frame rows, for these files and the
figures.
"""

import errno
import xml.etree.ElementTree as ET
from pathlib import Path

from ufl_frames.bootstrap import init_petsc

init_petsc()

import dolfinx  # noqa: E402
import dolfinx.fem as fem  # noqa: E402
import dolfinx.io  # noqa: E402
import numpy as np  # noqa: E402

from ufl_frames.fem.energy import bracket_rms  # noqa: E402
from ufl_frames.fem.energy import check_frame_function as check_frame_field  # noqa: E402
from ufl_frames.frames2d import odeco  # noqa: E402
from ufl_frames.output.vtk import vtk_references  # noqa: E402

__all__ = ["field_functions", "frame_vectors", "write_field"]


def frame_vectors(rows: np.ndarray):
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


def field_functions(q: fem.Function) -> list[fem.Function]:
    """The functions written by :func:`write_field`.

    ``q`` (P1, 5 components); ``lengths`` (P1, (l1, l2)); ``u`` and ``v`` (P1
    vectors, the two branches scaled by their lengths, see :func:`frame_vectors`);
    ``bracket_rms`` (DG0, :func:`ufl_frames.fem.energy.bracket_rms`).
    """
    check_frame_field(q)
    mesh = q.function_space.mesh
    V2 = fem.functionspace(mesh, ("Lagrange", 1, (2,)))
    lengths, u, v = frame_vectors(q.x.array.reshape(-1, odeco.NUM_COEFFICIENTS))
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
    """Write the frame field into ``directory`` (collective).

    The functions of :func:`field_functions`, twice:

    * ``<stem>.bp`` (ADIOS2, :class:`dolfinx.io.VTXWriter`: the P1 functions as point
      data and ``bracket_rms`` as cell data, in one folder) when DOLFINx has ADIOS2,
      otherwise ``<stem>.xdmf`` + ``<stem>.h5``;
    * ``<stem>.pvd`` + ``<stem>000000.pvtu`` + one ``<stem>_p<rank>_000000.vtu`` per
      rank (:class:`dolfinx.io.VTKFile`, ASCII XML): ParaView opens it too, and unlike
      the others it can be read back here without ADIOS2 or HDF5
      (:func:`~ufl_frames.output.vtk.read_vtk`).

    Args:
        directory: an existing folder, the same on every rank.
        q: the frame field (P1, 5 components).
        stem: the files' name without its suffix.

    Returns:
        The paths written, in the order above (the ``.bp`` folder is one entry), the
        same on every rank.
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
            written = [pvd, *vtk_references(pvd)]
        except (OSError, ET.ParseError) as e:
            written = e
    written = comm.bcast(written, root=0)
    if isinstance(written, Exception):
        raise OSError(f"the VTK files just written in {str(directory)!r} cannot be read "
                      f"back ({written}); all ranks must be given the same folder") from written
    return paths + written
