"""What the benchmark scripts share: the repository's geometry files, mesh sizes for a
triangle count, best-of timing, Gmsh's log and 2D elements as arrays, one-line messages
and Markdown table rules.

Imported as ``from _common import ...`` (a script's folder is the first entry of
``sys.path`` when it runs as ``python benchmarks/X.py``). Nothing here imports
DOLFINx, MPI or Gmsh at import time: the pure tests load some scripts.
"""

import math
import time
from pathlib import Path

import numpy as np

#: The repository's root folder.
ROOT = Path(__file__).resolve().parent.parent
#: The Gmsh scripts of the built-in shapes.
BUILTIN_GEO = {"annulus": ROOT / "meshes" / "annulus.geo", "piano": ROOT / "meshes" / "piano.geo"}
#: File endings of the geometries ``ufl-frames solve`` reads (lower case).
GEOMETRY_SUFFIXES = (".geo", ".msh", ".step", ".stp", ".brep")
#: Triangles of the Gmsh meshes of the built-in shapes at mesh size 0.05 (N ~ 1/h²).
TRIANGLES_AT_005 = {"piano": 1887, "annulus": 2305}


def mesh_size_for(shape: str, triangles: float) -> float:
    """The mesh size that gives about ``triangles`` triangles on the built-in ``shape``."""
    return 0.05 * math.sqrt(TRIANGLES_AT_005[shape] / triangles)


def best_time(func, repeat: int, comm=None) -> tuple[float, float]:
    """Best wall-clock and best CPU (process) time over ``repeat`` runs of ``func()``.

    CPU time is the fairer number on a shared machine; wall time is the one that counts.

    Args:
        func: Called without arguments.
        repeat: How many runs.
        comm: With an MPI communicator, every run starts at a barrier and its wall time
            is the largest over the ranks (the CPU time is this rank's).

    Returns:
        (wall seconds, CPU seconds), each the smallest over the runs.
    """
    walls, cpus = [], []
    for _ in range(repeat):
        if comm is not None:
            comm.Barrier()
        start, start_cpu = time.perf_counter(), time.process_time()
        func()
        cpus.append(time.process_time() - start_cpu)
        wall = time.perf_counter() - start
        if comm is not None:
            from mpi4py import MPI

            wall = comm.allreduce(wall, op=MPI.MAX)
        walls.append(wall)
    return min(walls), min(cpus)


def one_line(text) -> str:
    """``text`` with its white space folded: one line."""
    return " ".join(str(text).split())


def gmsh_errors(step, catch: bool = False) -> list[str]:
    """Run ``step()`` with Gmsh's logger on; the messages it logged as errors.

    With ``General.AbortOnError`` 0 Gmsh logs errors instead of raising them. ``catch``:
    an exception of ``step`` is returned as the one error instead of raised.
    """
    import gmsh

    gmsh.logger.start()
    try:
        step()
        return [m for m in gmsh.logger.get() if m.startswith("Error")]
    except Exception as e:
        if not catch:
            raise
        return [str(e)]
    finally:
        gmsh.logger.stop()


def surface_elements() -> tuple[np.ndarray, list[dict[int, np.ndarray]]]:
    """The current Gmsh mesh's nodes and 2D elements as arrays.

    Returns:
        (xyz, surfaces): the (n, 3) coordinates of all nodes, and for each surface a dict
        from Gmsh element type to its elements as (m, nodes per element) rows of ``xyz``.
    """
    import gmsh

    tags, coords, _ = gmsh.model.mesh.getNodes()
    xyz = coords.reshape(-1, 3)
    row = np.full(int(tags.max(initial=0)) + 1, -1, dtype=np.int64)
    row[tags.astype(np.int64)] = np.arange(tags.size)
    surfaces = []
    for _, surface in gmsh.model.getEntities(2):
        found = {}
        for kind, _, nodes in zip(*gmsh.model.mesh.getElements(2, surface), strict=True):
            count = gmsh.model.mesh.getElementProperties(kind)[3]
            found[int(kind)] = row[nodes.astype(np.int64)].reshape(-1, count)
        surfaces.append(found)
    return xyz, surfaces


def table_rule(header: str) -> str:
    """The Markdown rule under the table row ``header`` (``| a | b |``): ``|---|---|``."""
    return "|" + "---|" * (header.count("|") - 1)
