"""A 3D frame field from a volume: MBO on tetrahedra, its singular graph, its files.

::

    volume = mesh.volumes.ball(comm, mesh_size=0.1)    # or volumes.load(comm, "part.step")
    result = solve_volume(volume)                       # VolumeField: q, graph on rank 0
    write_volume(result, folder)                        # frames3d.vtu, singular.vtu/.png

:func:`solve_volume` is collective and returns a frozen :class:`VolumeField` whose
``summary`` is the same dict on every rank; the gathered arrays and the singular graph
live on rank 0.
"""

import time
from dataclasses import dataclass, field

from ufl_frames.bootstrap import init_petsc

init_petsc()

import numpy as np  # noqa: E402

__all__ = ["VolumeField", "solve_volume", "write_volume"]


@dataclass(frozen=True)
class VolumeField:
    """A 3D frame field and what was measured of it.

    ``q`` is the distributed P1 field (15 coefficients); ``summary`` the same dict on
    every rank (mesh counts, boundary vertices aligned with one normal or held on sharp
    features, MBO seconds and levels, the singular graph's counts);
    ``arrays`` (x, cells, rows) and ``graph`` (a
    :class:`~ufl_frames.frames3d.singular.SingularGraph`) on rank 0, None elsewhere.
    """

    q: object = field(repr=False)
    summary: dict
    arrays: tuple | None = field(default=None, repr=False)
    graph: object | None = field(default=None, repr=False)


def solve_volume(volume, sweeps: int = 2, levels: int | None = None, say=None) -> VolumeField:
    """The boundary-aligned smooth 3D frame field of ``volume`` by MBO and its singular
    graph (collective).

    Args:
        volume: a :class:`~ufl_frames.mesh.volumes.Volume`.
        sweeps: MBO's diffuse–project iterations per diffusion time.
        levels: MBO's diffusion times (None: down to the mean edge length).
        say: called with a progress line per MBO level (None: silent).

    Returns:
        The :class:`VolumeField`.
    """
    from ufl_frames.fem.gather import gather_p1_field
    from ufl_frames.frames3d import singular
    from ufl_frames.solvers.mbo3d import mbo_frame_field_3d

    comm = volume.comm
    start = time.perf_counter()
    changes = []

    def monitor(level, tau, change):
        changes.append(change)
        if say is not None:
            say(f"  MBO level {level}: sqrt(tau) = {tau ** 0.5:.3g}, change {change:.2e}")

    q = mbo_frame_field_3d(volume, sweeps=sweeps, levels=levels, monitor=monitor)
    solved = time.perf_counter()
    x, cells, rows = gather_p1_field(q)
    graph, summary = None, None
    if comm.rank == 0:
        graph = singular.singular_graph(cells, rows, x)
        degree = np.bincount(graph.edges.ravel(), minlength=x.shape[0])
        summary = {
            "dimension": 3, "source": volume.source, "tetrahedra": int(cells.shape[0]),
            "vertices": int(x.shape[0]), "mesh_size": volume.mesh_size,
            "ranks": comm.size, "notes": list(volume.notes),
            "boundary_vertices": dict(zip(("aligned", "sharp"), volume.num_boundary_vertices,
                                          strict=True)),
            "mbo": {"levels": len(changes), "sweeps": sweeps, "last_change": changes[-1]
                    if changes else None, "seconds": solved - start},
            "singular_graph": {
                "edges": int(len(graph.edges)), "chains": graph.num_chains,
                "quarter_turns": int(np.count_nonzero(graph.turn == 1)),
                "half_turns": int(np.count_nonzero(graph.turn == 2)),
                "open_ends": int(graph.open_ends.size),
                "nodes": int(np.count_nonzero(degree >= 3)),
                "seconds": time.perf_counter() - solved,
            },
        }
    summary = comm.bcast(summary, root=0)
    arrays = (x, cells, rows) if comm.rank == 0 else None
    return VolumeField(q=q, summary=summary, arrays=arrays, graph=graph)


def write_volume(result: VolumeField, folder, comm) -> None:
    """Write the field's files into ``folder`` on rank 0 (collective: an error there is
    raised on every rank): ``frames3d.vtu``, ``singular.vtu``, ``singular.png``."""
    from ufl_frames.output.report import on_root
    from ufl_frames.output.volume import write_volume_field

    def action():
        x, cells, rows = result.arrays
        write_volume_field(folder, x, cells, rows, result.graph,
                           title=f"{result.summary['source']}: "
                                 f"{result.summary['singular_graph']['edges']} singular edges")

    on_root(comm, action)
