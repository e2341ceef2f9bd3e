"""cut.glue_to_boundary (through cut_mesh(glue_within=…)): a singular vertex a sliver off
the boundary moves onto it; one further away, or with only kept boundary vertices near
it, stays. Truth: the singular vertices of the cut mesh's matchings
(cut.singular_vertices), counted independently of the gluing."""

import numpy as np
from planar_meshes import grid

from ufl_frames.frames2d import odeco
from ufl_frames.param import cut


def minus_field(x, at):
    """Unit frames turning by −1/4 around ``at`` only."""
    theta = -np.arctan2(x[:, 1] - at[1], x[:, 0] - at[0]) / 4
    return odeco.frames_to_q(np.ones((x.shape[0], 2)), theta)


def test_a_singular_vertex_a_sliver_off_the_boundary_is_glued_onto_it():
    x, cells = grid(20, 20, -1, 1, -1, 1)  # edges 0.1
    q = minus_field(x, (0.87, 0.03))  # its singular vertex at (0.9, 0): 0.1 from x = 1
    left = cut.cut_mesh(x, cells, q)
    assert left.turns.tolist() == [-1] and left.cancelled == 0
    glued = cut.cut_mesh(x, cells, q, glue_within=0.15)
    assert glued.singular.size == 0 and glued.cancelled == 1
    per_vertex = cut.cut_mesh(x, cells, q, glue_within=np.full(x.shape[0], 0.15))
    assert per_vertex.singular.size == 0
    assert cut.cut_mesh(x, cells, q, glue_within=0.05).singular.size == 1


def test_kept_boundary_vertices_take_no_singular_vertex():
    from ufl_frames.param.features import Features

    x, cells = grid(20, 20, -1, 1, -1, 1)
    q = minus_field(x, (0.87, 0.03))
    right = np.flatnonzero(np.isclose(x[:, 0], 1.0))  # all of the near side held
    features = Features(cell_region=np.zeros(cells.shape[0], dtype=np.int64),
                        curve_edges=np.zeros((0, 2), dtype=np.int64),
                        edge_curve=np.zeros(0, dtype=np.int64),
                        point_nodes=right, point_tag=np.arange(right.size))
    assert cut.cut_mesh(x, cells, q, glue_within=0.15,
                        features=features).singular.size == 1
