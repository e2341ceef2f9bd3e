"""± pairs closer than a quad removed before the map, in the pipeline's stages
(pipeline.stages.parametrise and quadrangulate), serial and MPI.

Truth: the 2 × 1 rectangle with the constant frame field and a planted ± pair 0.2 apart
(angle ¼(arg(z − a) − arg(z − b))). At quad size 0.5 the pair is under half a quad apart:
it is removed, the map has no cut and the quads are a grid with no irregular vertex; at
quad size 0.15 it is more than a quad apart and kept (two cut paths). The field itself (what its
files hold) does not change; the gathered problem is the same on any number of ranks.
"""

from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from ufl_frames.fem import energy
from ufl_frames.mesh import build
from ufl_frames.pipeline import FrameField
from ufl_frames.pipeline.stages import RootField, parametrise, quadrangulate

RECTANGLE = Path(__file__).resolve().parents[2] / "benchmarks" / "shapes" / "rectangle.geo"
A, B = (0.901, 0.507), (1.099, 0.511)


def planted_field(comm):
    domain = build(comm, RECTANGLE, mesh_size=0.05)
    V = energy.frame_space(domain.mesh)
    q = energy.interpolate_frames(V, lambda x: (
        1.0, 1.0, (np.arctan2(x[1] - A[1], x[0] - A[0])
                   - np.arctan2(x[1] - B[1], x[0] - B[0])) / 4))
    return FrameField(domain=domain, q=q, isotropic=True)


@pytest.fixture(scope="module")
def fields():
    return {name: planted_field(comm) for name, comm in
            (("self", MPI.COMM_SELF), ("world", MPI.COMM_WORLD))}


def test_a_pair_under_half_a_quad_apart_is_removed(fields):
    found = {}
    for name, field in fields.items():
        before = field.q.x.array.copy()
        root = RootField(field)
        param = parametrise(root, quad_size=0.5).quality
        quads = quadrangulate(root, quad_size=0.5).quality
        assert np.array_equal(field.q.x.array, before)  # the field's files are unchanged
        found[name] = (param, quads)
    for param, quads in found.values():
        assert param["removed_pairs"]["removed"] == 1
        assert param["cuts"] == 0 and param["flipped_triangles"] == 0
        assert quads["removed_pairs"] == param["removed_pairs"]
        pair = quads["removed_pairs"]["pairs"][0]
        assert pair["quads"] < 0.5 and pair["distance"] < 0.25
        assert quads["valid"] and quads["problems"] == []
        assert quads["irregular_vertices"] == 0 and quads["min_sj"] > 0.9
    for key in ("quads", "irregular_vertices"):
        assert found["self"][1][key] == found["world"][1][key]


def test_a_pair_a_quad_apart_is_kept(fields):
    param = parametrise(fields["world"], quad_size=0.15).quality
    assert param["removed_pairs"]["removed"] == 0 and param["removed_pairs"]["pairs"] == []
    assert param["cuts"] == 2  # one path from each singularity
