"""A frame field's record for ``summary.json``, in JSON types.

The record has two parts, so that the command can put its own settings between them
(:func:`ufl_frames.app.run.run`) without taking a record apart: :func:`frames_record`
(the kind of frames and the mesh size) and :func:`findings_record` (the mesh, the solve,
singularities, Poincaré–Hopf, the stages, the history). :func:`field_summary` is both.
"""

from ufl_frames.bootstrap import init_petsc

init_petsc()

from ufl_frames.fem import energy  # noqa: E402

__all__ = ["field_summary", "findings_record", "frames_record"]


def frames_record(frames) -> dict:
    """The kind of frames (isotropic, aspect bound, pinned singularities) and the mesh
    size of the :class:`~ufl_frames.pipeline.field.FrameField` ``frames``."""
    return {
        "isotropic": bool(frames.isotropic),
        "max_aspect": frames.max_aspect,
        "pinned_singularities": frames.pinned_singularities,
        "mesh_size": frames.domain.mesh_size,
        "requested_mesh_size": frames.domain.requested_mesh_size,
    }


def findings_record(frames, param=None, quads=None) -> dict:
    """What was found (collective): the pin radius, the mesh's counts, the solve (after
    one; the energy of the field as it is for the conformal scale), the levels of nested
    iteration, the singularities, Poincaré–Hopf, the measures of the stages and the
    solve's history.

    Args:
        frames: the :class:`~ufl_frames.pipeline.field.FrameField`.
        param: its :class:`~ufl_frames.pipeline.stages.Parametrised`, if made.
        quads: its :class:`~ufl_frames.pipeline.stages.QuadMeshed`, if made.

    Returns:
        The record, keys in ``summary.json``'s order.
    """
    domain, result = frames.domain, frames.result
    record = {
        "pin_radius": frames.pin_radius,
        "num_vertices": int(domain.num_vertices),
        "num_cells": int(domain.num_cells),
    }
    if frames.conformal_scale:  # no solve: the energy of the field as it is
        record.update(conformal_scale=True, H_final=energy.integrability_energy(frames.q))
    if result is not None:
        record.update({
            "converged_reason": result.converged_reason,
            "converged": result.converged_reason.startswith("CONVERGED"),
            "iterations": int(result.iterations),
            "H_initial": result.H_initial,
            "H_final": result.H_final,
            "E_initial": result.history[0]["E"],
            "E_final": result.E_final,
            "wall_time_s": result.wall_time_s,
        })
    if frames.levels is not None:
        record["levels"] = frames.levels
    record["singularities"] = frames.singularities
    record["poincare_hopf"] = frames.index_theorem()
    if param is not None:
        record["param"] = param.quality
    if quads is not None:
        record["quads"] = quads.quality
    if result is not None:
        record["history"] = result.history
    return record


def field_summary(frames, param=None, quads=None) -> dict:
    """:func:`frames_record` and :func:`findings_record` of ``frames`` in one record
    (collective): a field's summary outside the command.

    Args:
        frames: the :class:`~ufl_frames.pipeline.field.FrameField`.
        param: its :class:`~ufl_frames.pipeline.stages.Parametrised`, if made.
        quads: its :class:`~ufl_frames.pipeline.stages.QuadMeshed`, if made.

    Returns:
        The record, keys in ``summary.json``'s order.
    """
    return {**frames_record(frames), **findings_record(frames, param, quads)}
