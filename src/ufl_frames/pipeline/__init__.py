"""A frame field and what is made of it.

* :mod:`ufl_frames.pipeline.field`: :class:`FrameField`, a meshed domain's field and its
  solves (MBO, TAO, nested iteration, the conformal scale);
* :mod:`ufl_frames.pipeline.stages`: the rank-0 stages, the seamless map and the quad
  mesh, from one gathered and cut field;
* :mod:`ufl_frames.pipeline.files`: the field's and the stages' files;
* :mod:`ufl_frames.pipeline.report`: the record for ``summary.json``.
"""

from ufl_frames.pipeline.field import FrameField

__all__ = ["FrameField"]
