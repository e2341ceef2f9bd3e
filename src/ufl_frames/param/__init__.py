"""From an integrable frame field to a parametrisation (U, V) (the note's purpose).

* :mod:`~ufl_frames.param.cut`: face frames, matchings, singular vertices, the cut graph,
  the combing and the cut mesh (pure NumPy/SciPy);
* :mod:`~ufl_frames.param.seamless`: the seamless least-squares map on the cut mesh;
* :mod:`~ufl_frames.param.measures`: misfit, flipped triangles, distortion.
"""
