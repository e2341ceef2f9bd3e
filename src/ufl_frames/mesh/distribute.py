"""Where Gmsh runs and how its mesh reaches every rank.

:func:`create` runs a mesh-making step on rank 0 in a fresh Gmsh model (Gmsh is
finalised afterwards unless the caller had initialised it; its current model and the
options touched here are then restored), optionally in a forked child process stopped
after a time limit (:class:`~ufl_frames.mesh.domain.MeshTimeLimit`), turns the mesh
into checked arrays and distributes them as a DOLFINx mesh over the communicator.
Errors are raised on every rank as one-line
:class:`~ufl_frames.mesh.domain.GeometryError`. Gmsh prints nothing unless
``UFL_FRAMES_GMSH_VERBOSE`` is set (to anything but ``""``/``0``).
"""

import contextlib
import math
import os
import pickle
import select
import signal
import sys
import time
import warnings

from ufl_frames.bootstrap import init_petsc

init_petsc()

import dolfinx  # noqa: E402
import dolfinx.io.gmsh  # noqa: E402
import gmsh  # noqa: E402
import numpy as np  # noqa: E402
from mpi4py import MPI  # noqa: E402

from ufl_frames.mesh.arrays import (  # noqa: E402
    MeshArrays,
    acute_corner_directions,
    cad_directions,
    euler_characteristic,
    interior_angles,
    mean_edge_length,
    mesh_arrays,
    mesh_corners,
    recorded_plane,
)
from ufl_frames.mesh.domain import Domain, GeometryError, MeshTimeLimit, one_line  # noqa: E402

_TOUCHED_OPTIONS = (
    "General.Terminal", "General.AbortOnError", "Mesh.MeshSizeMax", "Mesh.MeshSizeFactor",
    "Mesh.MinimumCirclePoints", "Mesh.MinimumCurvePoints", "Mesh.RecombineAll",
    "Mesh.SubdivisionAlgorithm", "Mesh.Algorithm", "Mesh.ElementOrder",
)


def verbose() -> bool:
    """Whether Gmsh may print (``UFL_FRAMES_GMSH_VERBOSE`` set, and not to ``0``/``no``)."""
    return os.environ.get("UFL_FRAMES_GMSH_VERBOSE", "").strip().lower() not in (
        "",
        "0",
        "false",
        "no",
    )


def create(comm: MPI.Comm, make, source: str, cad: bool,
           time_limit: float = math.inf) -> Domain:
    """Run ``make(notes)`` on rank 0 in a fresh Gmsh model (it meshes, returning the size
    asked for), turn the mesh into checked arrays, distribute it over ``comm``.

    Args:
        comm: The communicator the mesh is distributed over (collective).
        make: Called as ``make(notes)`` on rank 0 with the fresh model current: builds or
            reads and meshes it, appends what it changed to ``notes`` and returns the
            mesh size asked for (None: the file's own sizes, or a ``.msh``).
        source: The geometry's name or path, for the messages and :attr:`Domain.source`.
        cad: Whether the model has CAD curves (their tangents give the boundary
            directions and corners); else corners are taken from the mesh.
        time_limit: Seconds; finite: ``make`` runs in a child process, stopped
            (:class:`MeshTimeLimit`) when it takes longer (see :func:`_in_child`).

    Returns:
        The distributed domain, the same on every rank.

    Raises:
        GeometryError: On every rank, with the same one-line message.
    """
    root = 0
    error, arrays, info = None, None, None
    if comm.rank == root:
        try:
            if math.isfinite(time_limit) and hasattr(os, "fork"):
                arrays, info = _in_child(lambda: _gmsh_session(make, source, cad), source,
                                         time_limit)
            else:
                arrays, info = _gmsh_session(make, source, cad)
        except GeometryError as e:  # its class too (MeshTimeLimit, TooManyTriangles)
            error = type(e)(str(e))
    error = comm.bcast(error, root=root)
    if error is not None:
        raise error
    info = comm.bcast(info, root=root)
    return _distribute(comm, arrays, info, source)


def _gmsh_session(make, source: str, cad: bool):
    """``make``'s mesh, in a fresh Gmsh model (this process, rank 0).

    Args:
        make: As for :func:`create`.
        source: As for :func:`create`.
        cad: As for :func:`create`.

    Returns:
        (arrays, info): the :class:`MeshArrays` and a dict of what :class:`Domain` holds
        besides the mesh (size asked for, corners, Euler characteristic, mean edge length,
        notes, CAD directions).

    Raises:
        GeometryError: For every failure, Gmsh's included.
    """
    owns, previous_model, saved = not gmsh.isInitialized(), None, {}
    try:
        if owns:
            gmsh.initialize(argv=[], readConfigFiles=False, interruptible=False)
        else:
            saved = {k: gmsh.option.getNumber(k) for k in _TOUCHED_OPTIONS}
            previous_model = gmsh.model.getCurrent()
        gmsh.option.setNumber("General.Terminal", 1 if verbose() else 0)
        gmsh.model.add(f"ufl_frames_{id(make):x}")
        notes: list[str] = []
        requested = make(notes)
        arrays = mesh_arrays(source, notes)
        mesh_angle = interior_angles(arrays.x, arrays.cells, arrays.x.shape[0])
        junctions = ()
        if cad:
            psi, corners, junctions = cad_directions(arrays, mesh_angle)
            nodes = np.flatnonzero(np.isfinite(psi)).astype(np.int64)
            directions = (nodes, psi[nodes])
        else:
            corners = mesh_corners(arrays, mesh_angle)
            directions = acute_corner_directions(arrays, mesh_angle)
        info = {
            "requested": requested,
            "corners": tuple(corners),
            "chi": euler_characteristic(arrays),
            "h": mean_edge_length(arrays),
            "notes": tuple(notes),
            "directions": directions,
            "junctions": tuple(junctions),
            "groups": arrays.physical_groups,
            "plane": recorded_plane(),
        }
        return arrays, info
    except GeometryError:
        raise
    except Exception as e:
        raise GeometryError(f"Gmsh failed: {one_line(e)}") from e
    finally:
        _release(owns, previous_model, saved)


def _in_child(work, source: str, limit: float):
    """``work()`` in a forked child process; its result, or :class:`GeometryError`.

    Gmsh has no way to stop a meshing step from outside (an invalid curve loop makes it
    retry its edge recovery forever), so the step runs in a copy of this process that is
    killed after ``limit`` seconds (:class:`MeshTimeLimit`); a crash of Gmsh there is an
    error here too, not the end of the run. The child inherits the blocked signals of
    :class:`ufl_frames.interrupts.SignalWatch`, gets SIGKILL if this process ends first
    (Linux), and returns its result pickled through a pipe.

    Args:
        work: Called without arguments in the child; its result must pickle.
        source: The geometry's name or path, for the messages.
        limit: Seconds the child may take.

    Returns:
        What ``work()`` returned.

    Raises:
        MeshTimeLimit: The child took longer than ``limit`` (it is killed).
        GeometryError: ``work`` raised, or the child crashed.
    """
    parent = os.getpid()
    read_end, write_end = os.pipe()
    sys.stdout.flush()
    sys.stderr.flush()
    with warnings.catch_warnings():  # "multi-threaded, fork() may deadlock": the child
        warnings.simplefilter("ignore", DeprecationWarning)  # runs Gmsh and NumPy alone
        pid = os.fork()
    if pid == 0:  # the child: never returns
        status = 1
        try:
            os.close(read_end)
            _die_with(parent)
            try:
                result = ("ok", work())
            except GeometryError as e:  # sent with its class
                result = ("error", type(e)(str(e)))
            except BaseException as e:
                result = ("error", GeometryError(f"Gmsh failed: {one_line(e)}"))
            with os.fdopen(write_end, "wb") as pipe:
                pickle.dump(result, pipe, protocol=pickle.HIGHEST_PROTOCOL)
            status = 0
        finally:
            with contextlib.suppress(Exception):
                sys.stdout.flush()
                sys.stderr.flush()
            os._exit(status)
    os.close(write_end)
    deadline = time.monotonic() + limit
    chunks, finished = [], False
    waiting = select.poll()  # not select.select: no limit on the descriptor's number
    waiting.register(read_end, select.POLLIN)
    try:
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or not waiting.poll(min(left, 1e6) * 1000):
                break
            chunk = os.read(read_end, 1 << 20)
            if not chunk:
                finished = True
                break
            chunks.append(chunk)
    finally:
        os.close(read_end)
        if not finished:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        status = os.waitpid(pid, 0)[1]
    if not finished:
        raise MeshTimeLimit(
            f"meshing {source!r} did not end within the time limit of {limit:g} s (an "
            "invalid geometry Gmsh cannot mesh, or a mesh too fine for the limit): stopped"
        )
    try:
        kind, value = pickle.loads(b"".join(chunks))
    except Exception:
        why = (f"killed by {signal.Signals(os.WTERMSIG(status)).name}"
               if os.WIFSIGNALED(status) else f"exit status {os.waitstatus_to_exitcode(status)}")
        raise GeometryError(f"Gmsh crashed on {source!r} ({why})") from None
    if kind == "error":
        raise value
    return value


def _die_with(parent: int) -> None:
    """SIGKILL for this (child) process when ``parent`` ends (Linux ``prctl``; else none)."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() != parent:  # the parent ended before the prctl
        os._exit(1)


def _distribute(comm: MPI.Comm, arrays: MeshArrays | None, info: dict, source: str) -> Domain:
    """The DOLFINx mesh and facet tags from rank 0's arrays (collective).

    Args:
        comm: The communicator of the mesh.
        arrays: The mesh on rank 0 (ignored on the other ranks).
        info: :func:`_gmsh_session`'s info, the same on every rank.
        source: The geometry's name or path.

    Returns:
        The distributed domain.
    """
    element = dolfinx.io.gmsh.ufl_mesh(2, 2, dtype=np.float64)  # Gmsh type 2: 3-node triangle
    if comm.rank == 0:
        cells, x = arrays.cells, arrays.x
        facets, values = arrays.boundary, arrays.boundary_curve.astype(np.int32)
        entities = {1: (arrays.curve_edges, arrays.edge_curve),
                    0: (arrays.point_nodes[:, None], arrays.point_tag)}
        surface = arrays.cell_surface.astype(np.int32)
    else:
        cells, x = np.zeros((0, 3), dtype=np.int64), np.zeros((0, 2))
        facets, values = np.zeros((0, 2), dtype=np.int64), np.zeros(0, dtype=np.int32)
        entities = {d: (np.zeros((0, d + 1), dtype=np.int64), np.zeros(0, dtype=np.int32))
                    for d in (0, 1)}
        surface = None
    mesh = dolfinx.mesh.create_mesh(comm, cells, element, x)
    mesh.topology.create_connectivity(1, 2)
    tags = _meshtags(mesh, 1, facets, values, "boundary_curves")
    model = {d: _meshtags(mesh, d, *entities[d], name)
             for d, name in ((1, "curves"), (0, "points"))}
    # the cells' surfaces: every rank reads those of its cells at their input index
    surface = comm.bcast(surface, root=0)
    original = np.asarray(mesh.topology.original_cell_index, dtype=np.int64)
    model[2] = dolfinx.mesh.meshtags(mesh, 2, np.arange(original.size, dtype=np.int32),
                                     surface[original])
    model[2].name = "surfaces"
    nodes, angles = info["directions"] if info["directions"] is not None else (None, None)
    return Domain(
        mesh=mesh,
        facet_tags=tags,
        corners=info["corners"],
        euler_characteristic=info["chi"],
        mesh_size=info["h"],
        requested_mesh_size=info["requested"],
        source=source,
        notes=info["notes"],
        physical_groups=info["groups"],
        cell_tags=model[2],
        curve_tags=model[1],
        point_tags=model[0],
        junctions=info["junctions"],
        plane=info.get("plane"),
        _direction_nodes=nodes,
        _direction_angles=angles,
    )


def _meshtags(mesh, dim: int, entities: np.ndarray, values: np.ndarray, name: str):
    """MeshTags of dimension ``dim`` from rank 0's entities (rows of input node indices)
    and their values (collective)."""
    local, local_values = dolfinx.io.distribute_entity_data(
        mesh, dim, np.ascontiguousarray(entities, dtype=np.int64),
        np.ascontiguousarray(values, dtype=np.int32))
    if dim > 0:
        mesh.topology.create_connectivity(dim, 0)
    tags = dolfinx.mesh.meshtags_from_entities(
        mesh, dim, dolfinx.graph.adjacencylist(local.astype(np.int32)),
        local_values.astype(np.int32, copy=False))
    tags.name = name
    return tags


def _release(owns: bool, previous_model, saved: dict) -> None:
    """End this session's use of Gmsh: finalise it if it was started here (``owns``), else
    remove this session's model, make ``previous_model`` current again and restore the
    options in ``saved`` (name -> value)."""
    if not gmsh.isInitialized():
        return
    if owns:
        gmsh.finalize()
        return
    try:
        gmsh.model.remove()
        if previous_model is not None:
            gmsh.model.setCurrent(previous_model)
    finally:
        for key, value in saved.items():
            gmsh.option.setNumber(key, value)
