"""The files of a frame field and of its stages, written into an existing folder.

Each function is collective over the field's communicator and returns the names it
wrote; figures and the stages' files are written by rank 0.
"""

from pathlib import Path

from ufl_frames.bootstrap import init_petsc

init_petsc()

from ufl_frames import output  # noqa: E402

__all__ = ["write_field", "write_param", "write_quads"]


def write_field(out, frames, label: str, tao_type: str | None = None) -> list[str]:
    """The field for ParaView (:func:`ufl_frames.output.write_field`), ``frames.png`` and,
    after a solve, ``convergence.png`` (every level's history after nested iteration).

    Args:
        out: the folder (it exists).
        frames: the :class:`~ufl_frames.pipeline.field.FrameField`.
        label: the geometry's name, for the titles.
        tao_type: the TAO method, for the convergence plot's title (None: not said).

    Returns:
        The names written.
    """
    out = Path(out)
    result = frames.result
    kind = "isotropic" if frames.isotropic else "non-isotropic"
    names = [p.name for p in output.write_field(out, frames.q)]
    H = f" (H = {result.H_final:.3g})" if result is not None else ""
    output.plot_frames(out / "frames.png", frames.q, title=f"Frame field: {label}, {kind}{H}",
                   singularities=frames.singularities)
    names.append("frames.png")
    if result is not None:
        method = f", TAO {tao_type}" if tao_type else ""
        levels, iterations = None, f"{result.iterations} iterations"
        if frames.level_histories and len(frames.level_histories) > 1:
            levels = [(f"{entry['triangles']} triangles", part) for entry, part
                      in zip(frames.levels, frames.level_histories, strict=True)]
            iterations = (f"{' + '.join(str(e['iterations']) for e in frames.levels)} "
                          f"iterations on {len(frames.levels)} meshes")
        output.plot_convergence(
            out / "convergence.png", result.history,
            title=f"{label}, {kind}: {iterations}{method}",
            comm=frames.domain.comm, levels=levels,
        )
        names.append("convergence.png")
    return names


def write_param(out, param, label: str, comm, stem: str = "param") -> list[str]:
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

    Returns:
        The names written, on every rank.
    """
    from ufl_frames.param.figures import plot_param, write_param_vtu

    names = [f"{stem}.png", f"{stem}.vtu"]
    if comm.rank == 0:
        quality = param.quality
        title = (f"{label}: iso-lines of U, V (misfit {quality['misfit']:.3g}, "
                 f"{quality['flipped_triangles']} flipped, {quality['cuts']} cuts)")
        plot_param(Path(out) / names[0], param.parametrisation, title=title)
        write_param_vtu(Path(out) / names[1], param.parametrisation)
    comm.Barrier()
    return names


def write_quads(out, quads, label: str, comm, stem: str = "quads",
                groups=()) -> list[str]:
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
            (:func:`~ufl_frames.quads.msh.write_quad_msh`).

    Returns:
        The names written, on every rank.
    """
    from ufl_frames.quads.measures import scaled_jacobians
    from ufl_frames.quads.msh import plot_quads, write_quad_msh, write_quad_vtu

    names = [f"{stem}.msh", f"{stem}.vtu", f"{stem}.png"]
    if comm.rank == 0:
        mesh, quality = quads.mesh, quads.quality
        out = Path(out)
        model = {name: getattr(mesh, name, None) for name in (
            "quad_region", "curve_edges", "edge_curve", "point_nodes", "point_tag")}
        write_quad_msh(out / names[0], mesh.points, mesh.quads, groups=groups, **model)
        write_quad_vtu(out / names[1], mesh.points, mesh.quads,
                       {"scaled_jacobian": scaled_jacobians(mesh.points, mesh.quads)})
        title = (f"{label}: {quality['quads']} quads, {quality['irregular_vertices']} "
                 f"irregular vertices, min SJ {quality['min_sj']:.2f}")
        plot_quads(out / names[2], mesh.points, mesh.quads, title=title)
    comm.Barrier()
    return names
