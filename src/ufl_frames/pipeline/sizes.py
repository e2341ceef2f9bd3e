"""How well a field, its map and its quads follow a size target: the ``sizes`` record of
``summary.json``.

Sizes are compared up to one global factor (the target asks for relative sizes; the map's
scale or ``--quad-count`` sets the factor): the frame's size is √(l1 l2) per vertex, the
quad's its mean edge length, each divided by h there and by the median of that ratio.
"""

import numpy as np
from mpi4py import MPI

__all__ = ["quad_size_record", "size_record", "stage_size_record"]


def _spread(log_ratio: np.ndarray) -> dict:
    """Median and 90th percentile of |log(l/h) − median|, for log ratios on rank 0."""
    deviation = np.abs(log_ratio - np.median(log_ratio))
    return {"median_abs_log": float(np.median(deviation)),
            "p90_abs_log": float(np.percentile(deviation, 90))}


def size_record(field, target, param=None, quads=None, quad_mesh=None,
                quad_count: int | None = None) -> dict:
    """The ``sizes`` record (collective; the same dict on every rank).

    Args:
        field: the solved :class:`~ufl_frames.pipeline.field.FrameField`.
        target: its :class:`~ufl_frames.mesh.sizes.SizeTarget`.
        param: the map's quality record (``Parametrised.quality``), if made.
        quads: the quads' quality record (``QuadMeshed.quality``), if made.
        quad_mesh: the :class:`~ufl_frames.quads.extract.QuadMesh` (rank 0), if made.
        quad_count: the number of quads asked for (``--quad-count``), if any.

    Returns:
        ``target`` (what it is), ``weight``, ``h_min``/``h_max``/``h_ratio`` (over the
        vertices), ``field`` (``median_abs_log``, ``p90_abs_log`` of √(l1 l2)/h, up to the
        global factor; ``misfit`` M of the solve), ``map_misfit``, and with quads
        ``quads`` (:func:`quad_size_record`).
    """
    from ufl_frames.frames2d.algebra import ALGEBRA

    comm = field.domain.comm
    q = field.q
    count = ALGEBRA.count
    owned = q.function_space.dofmap.index_map.size_local
    rows = q.x.array.reshape(-1, count)[:owned]
    x = q.function_space.tabulate_dof_coordinates()[:owned, :2]
    h = target(x)
    lengths, _ = ALGEBRA.q_to_frames(rows)
    log_ratio = 0.5 * np.log(lengths[:, 0] * lengths[:, 1]) - np.log(h)
    gathered = comm.gather(log_ratio, root=0)
    record = {
        "target": target.describe(),
        "weight": target.weight,
        "h_min": comm.allreduce(float(h.min()) if len(h) else np.inf, op=MPI.MIN),
        "h_max": comm.allreduce(float(h.max()) if len(h) else 0.0, op=MPI.MAX),
    }
    record["h_ratio"] = record["h_max"] / record["h_min"]
    spread = _spread(np.concatenate(gathered)) if comm.rank == 0 else None
    problem = field.problem
    record["field"] = {**comm.bcast(spread, root=0),
                       "misfit": problem.size_misfit() if problem is not None
                       and problem.size is not None else None}
    source = quads if quads is not None else param
    record["map_misfit"] = None if source is None else source.get(
        "misfit_seamless", source.get("misfit"))
    if quads is not None:
        found = quad_size_record(quad_mesh, target, quad_count) if comm.rank == 0 else None
        record["quads"] = comm.bcast(found, root=0)
    return record


def quad_size_record(quad_mesh, target, quad_count: int | None = None) -> dict:
    """The quads' local edge length (mean of a quad's four edges) against h at the quad's
    centroid: ``log_correlation`` (Pearson, of the logs), the ratio's spread up to the
    global factor (``median_abs_log``, ``p90_abs_log``, ``ratio_p10``, ``ratio_p90``),
    ``quads`` and, with ``quad_count``, ``requested`` and ``count_error`` (relative)."""
    points, cells = quad_mesh.points, quad_mesh.quads
    corners = points[cells]  # (m, 4, 2)
    edges = np.linalg.norm(np.roll(corners, -1, axis=1) - corners, axis=2).mean(axis=1)
    h = target(corners.mean(axis=1))
    log_edge, log_h = np.log(edges), np.log(h)
    varied = np.std(log_h) > 1e-12 and np.std(log_edge) > 1e-12
    ratio = log_edge - log_h
    centred = np.exp(ratio - np.median(ratio))
    record = {
        "quads": int(len(cells)),
        "log_correlation": float(np.corrcoef(log_edge, log_h)[0, 1]) if varied else None,
        **_spread(ratio),
        "ratio_p10": float(np.percentile(centred, 10)),
        "ratio_p90": float(np.percentile(centred, 90)),
    }
    if quad_count is not None:
        record["requested"] = int(quad_count)
        record["count_error"] = (len(cells) - quad_count) / quad_count
    return record


def stage_size_record(mesh, seamless_map, quad_mesh, target) -> dict:
    """Where the quads' sizes leave the target: the local edge length of each stage at the
    quads' centroids, against h there, each up to its own global factor (rank 0's arrays).

    * ``field``: the combed frame's (l1 + l2)/(2s) on the cut mesh's triangle holding the
      centroid (the map's input: the field, its close ± pairs removed);
    * ``map``: the seamless map's (1/|∇U| + 1/|∇V|)/2 there (a unit cell of (U, V));
    * ``quads``: the quad's mean edge length (as :func:`quad_size_record`).

    Each is a dict of ``log_correlation``, ``median_abs_log`` and ``p90_abs_log``
    (``count`` the quads, ``located`` those whose centroid lies in a triangle); the
    steps ``map_over_field`` and ``quads_over_map`` give the spread of one stage's log size
    against the one before (up to a factor), so the widening each adds is measured apart.

    Args:
        mesh: the :class:`~ufl_frames.param.cut.CutMesh` the map was made on.
        seamless_map: its :class:`~ufl_frames.param.seamless.Parametrisation`.
        quad_mesh: the quads (``points``, ``quads``).
        target: the :class:`~ufl_frames.mesh.sizes.SizeTarget`.
    """
    from ufl_frames.quads.features import locate

    corners = quad_mesh.points[quad_mesh.quads]
    centroids = corners.mean(axis=1)
    cells = locate(mesh.x[:, :2], mesh.cells, centroids)
    inside = cells >= 0
    cells, centroids, corners = cells[inside], centroids[inside], corners[inside]
    s = seamless_map.scale
    logs = {
        "field": np.log(0.5 * (mesh.l1[cells] + mesh.l2[cells]) / s),
        "map": np.log(0.5 * (1.0 / np.linalg.norm(seamless_map.grad_u[cells], axis=1)
                             + 1.0 / np.linalg.norm(seamless_map.grad_v[cells], axis=1))),
        "quads": np.log(np.linalg.norm(np.roll(corners, -1, axis=1) - corners,
                                       axis=2).mean(axis=1)),
    }
    log_h = np.log(target(centroids))
    record = {"located": int(inside.sum()), "count": int(len(inside))}
    for name, log_edge in logs.items():
        varied = np.std(log_h) > 1e-12 and np.std(log_edge) > 1e-12
        record[name] = {"log_correlation": float(np.corrcoef(log_edge, log_h)[0, 1])
                        if varied else None, **_spread(log_edge - log_h)}
    record["map_over_field"] = _spread(logs["map"] - logs["field"])
    record["quads_over_map"] = _spread(logs["quads"] - logs["map"])
    return record
