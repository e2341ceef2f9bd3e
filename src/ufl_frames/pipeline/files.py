"""The files of a frame field and of its stages, written into an existing folder.

Each function is collective over the field's communicator and returns the names it
wrote; figures and the stages' files are written by rank 0. A figure that cannot be
drawn (a renderer's failure, not a full disk) is left out and its name and the reason
added to ``skipped``: a picture never costs the results (:func:`figure`).
"""

from pathlib import Path

from ufl_frames.bootstrap import init_petsc

init_petsc()

from ufl_frames import output  # noqa: E402
from ufl_frames.output.report import on_root  # noqa: E402

__all__ = ["figure", "write_field", "write_param", "write_quads"]


def figure(comm, path, draw, skipped: list | None) -> list[str]:
    """``draw()`` (collective over ``comm``; rank 0 writes ``path``): ``[path.name]``, or
    ``[]`` where it failed.

    A failure to write (an ``OSError``: a full disk, a path that cannot be written) is
    raised on every rank; any other failure (matplotlib or FreeType on a figure it cannot
    lay out) skips the figure: the part written is removed and ``(name, reason)``
    appended to ``skipped`` on every rank (with ``skipped`` None it is raised too).

    Args:
        comm: the communicator ``draw`` is collective over.
        path: the figure's file.
        draw: writes it (raises on every rank alike, as
            :func:`ufl_frames.output.report.on_root` does).
        skipped: where skipped figures are recorded.

    Returns:
        The names written.
    """
    path = Path(path)
    failure = None
    try:
        draw()
    except Exception as e:  # noqa: BLE001  (decided below, alike on every rank)
        failure = e
    reason = None
    if comm.rank == 0 and failure is not None:
        text = " ".join(str(failure).split())
        reason = ("" if isinstance(failure, OSError) or skipped is None
                  else f"{type(failure).__name__}: {text}" if text else type(failure).__name__)
    reason = comm.bcast(reason, root=0) if comm.size > 1 else reason
    if reason is None and failure is None:
        return [path.name]
    if not reason:  # a write error, or no list to skip into: the run's failure
        raise failure if failure is not None else output.WriteError(f"cannot write {path}")
    if comm.rank == 0:
        path.unlink(missing_ok=True)
    skipped.append((path.name, reason))
    return []


def write_field(out, frames, label: str, tao_type: str | None = None,
                skipped: list | None = None) -> list[str]:
    """The field for ParaView (:func:`ufl_frames.output.write_field`), ``frames.png`` and,
    after a solve, ``convergence.png`` (every level's history after nested iteration).

    Args:
        out: the folder (it exists).
        frames: the :class:`~ufl_frames.pipeline.field.FrameField`.
        label: the geometry's name, for the titles.
        tao_type: the TAO method, for the convergence plot's title (None: not said).
        skipped: where a figure that cannot be drawn is recorded (:func:`figure`;
            None: its failure is raised).

    Returns:
        The names written.
    """
    out = Path(out)
    result = frames.result
    kind = "isotropic" if frames.isotropic else "non-isotropic"
    names = [p.name for p in output.write_field(out, frames.q)]
    H = f" (H = {result.H_final:.3g})" if result is not None else ""
    comm = frames.domain.comm
    names += figure(comm, out / "frames.png",
                    lambda: output.plot_frames(out / "frames.png", frames.q,
                                               title=f"Frame field: {label}, {kind}{H}",
                                               singularities=frames.singularities), skipped)
    if result is not None:
        method = f", TAO {tao_type}" if tao_type else ""
        levels, iterations = None, f"{result.iterations} iterations"
        if frames.level_histories and len(frames.level_histories) > 1:
            levels = [(f"{entry['triangles']} triangles", part) for entry, part
                      in zip(frames.levels, frames.level_histories, strict=True)]
            iterations = (f"{' + '.join(str(e['iterations']) for e in frames.levels)} "
                          f"iterations on {len(frames.levels)} meshes")
        names += figure(comm, out / "convergence.png", lambda: output.plot_convergence(
            out / "convergence.png", result.history,
            title=f"{label}, {kind}: {iterations}{method}", comm=comm, levels=levels,
        ), skipped)
    return names


def write_param(out, param, label: str, comm, stem: str = "param",
                skipped: list | None = None) -> list[str]:
    """``<stem>.png`` (the integer iso-lines of U and V) and ``<stem>.vtu`` of a
    :class:`~ufl_frames.pipeline.stages.Parametrised` ``param``, written by rank 0 of
    ``comm`` into the folder ``out`` (collective).

    Args:
        out: the folder (it exists).
        param: the :class:`~ufl_frames.pipeline.stages.Parametrised` (read on rank 0
            only).
        label: the geometry's name, for the figure's title.
        comm: the field's communicator.
        stem: the files' name without suffix.
        skipped: as for :func:`write_field`.

    Returns:
        The names written, on every rank.
    """
    from ufl_frames.param.figures import plot_param, write_param_vtu

    out = Path(out)

    def draw():
        quality = param.quality
        title = (f"{label}: iso-lines of U, V (misfit {quality['misfit']:.3g}, "
                 f"{quality['flipped_triangles']} flipped, {quality['cuts']} cuts)")
        plot_param(out / f"{stem}.png", param.parametrisation, title=title)

    names = figure(comm, out / f"{stem}.png", lambda: on_root(comm, draw), skipped)
    if comm.rank == 0:
        write_param_vtu(out / f"{stem}.vtu", param.parametrisation)
    comm.Barrier()
    return [*names, f"{stem}.vtu"]


def write_quads(out, quads, label: str, comm, stem: str = "quads",
                groups=(), skipped: list | None = None, plane=None) -> list[str]:
    """``<stem>.msh`` (Gmsh MSH 4.1), ``<stem>.vtu`` (scaled Jacobian per quad) and
    ``<stem>.png`` of a :class:`~ufl_frames.pipeline.stages.QuadMeshed` ``quads``, written
    by rank 0 of ``comm`` into the folder ``out`` (collective).

    Args:
        out: the folder (it exists).
        quads: the :class:`~ufl_frames.pipeline.stages.QuadMeshed` (read on rank 0 only).
        label: the geometry's name, for the figure's title.
        comm: the field's communicator.
        stem: the files' name without suffix.
        groups: the geometry's physical groups
            (:attr:`ufl_frames.mesh.domain.Domain.physical_groups`), written to the
            ``.msh`` with the model's entities where the quad mesh has them
            (:func:`~ufl_frames.quads.msh.write_quad_msh`); none: one unnamed group per
            entity (:func:`~ufl_frames.quads.msh.entity_groups`).
        skipped: as for :func:`write_field`.
        plane: the geometry's :class:`~ufl_frames.mesh.domain.Plane` where it lies in a
            tilted plane (:attr:`ufl_frames.mesh.domain.Domain.plane`): the ``.msh`` and
            ``.vtu`` are written in its original 3D coordinates; None: (x, y, 0).

    Returns:
        The names written, on every rank.
    """
    from ufl_frames.quads.measures import scaled_jacobians
    from ufl_frames.quads.msh import entity_groups, plot_quads, write_quad_msh, write_quad_vtu

    names = [f"{stem}.msh", f"{stem}.vtu"]
    out = Path(out)
    if comm.rank == 0:
        mesh = quads.mesh
        model = {name: getattr(mesh, name, None) for name in (
            "quad_region", "curve_edges", "edge_curve", "point_nodes", "point_tag")}
        if not groups and model["quad_region"] is not None:
            # no groups in the geometry: one per model entity (tag = the entity's), so
            # that DOLFINx, which reads tags from groups alone, reads the entities back
            groups = entity_groups(model["quad_region"], model["edge_curve"],
                                   model["point_tag"])
        xyz = None if plane is None else plane.to_3d(mesh.points)
        write_quad_msh(out / names[0], mesh.points, mesh.quads, groups=groups,
                       coordinates=xyz, **model)
        write_quad_vtu(out / names[1], mesh.points if xyz is None else xyz, mesh.quads,
                       {"scaled_jacobian": scaled_jacobians(mesh.points, mesh.quads)})
    comm.Barrier()

    def draw():
        mesh, quality = quads.mesh, quads.quality
        title = (f"{label}: {quality['quads']} quads, {quality['irregular_vertices']} "
                 f"irregular vertices, min SJ {quality['min_sj']:.2f}")
        plot_quads(out / f"{stem}.png", mesh.points, mesh.quads, title=title)

    return names + figure(comm, out / f"{stem}.png", lambda: on_root(comm, draw),
                          skipped)
