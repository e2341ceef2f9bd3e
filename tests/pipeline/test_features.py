"""The model entities gathered onto rank 0 (``param.gather.gather_features``,
``RootField.features``) on the numbering of the gathered field: regions' areas, curves'
lengths and which curve edges are interior, points at their coordinates. Serial and MPI.
"""

import math

import numpy as np
import pytest

from ufl_frames.bootstrap import init_petsc

init_petsc([])  # not pytest's command line

from mpi4py import MPI  # noqa: E402

from ufl_frames.mesh import load, piano  # noqa: E402
from ufl_frames.mesh.builtin import piano_area, piano_perimeter  # noqa: E402
from ufl_frames.param.features import Features  # noqa: E402
from ufl_frames.pipeline import FrameField  # noqa: E402
from ufl_frames.pipeline.stages import RootField  # noqa: E402

COMM = MPI.COMM_WORLD

# Two unit squares sharing the side x = 1, a segment embedded in the right one, a point in
# the left one.
FILE = """SetFactory("OpenCASCADE");
Rectangle(1) = {0, 0, 0, 1, 1};
Rectangle(2) = {1, 0, 0, 1, 1};
BooleanFragments{ Surface{1}; Delete; }{ Surface{2}; Delete; }
Point(20) = {0.4, 0.7, 0};
Point{20} In Surface{1};
Point(21) = {1.2, 0.2, 0}; Point(22) = {1.8, 0.6, 0};
Line(30) = {21, 22};
Curve{30} In Surface{2};
"""


def areas(x, cells):
    e1, e2 = x[cells[:, 1]] - x[cells[:, 0]], x[cells[:, 2]] - x[cells[:, 0]]
    return 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def test_features_of_two_regions_an_embedded_curve_and_point(tmp_path):
    path = tmp_path / "features.geo"
    if COMM.rank == 0:
        path.write_text(FILE)
    COMM.Barrier()
    domain = load(COMM, path, 0.1)
    root = RootField(FrameField.initial(domain, isotropic=True))
    if COMM.rank != 0:
        assert root.features is None
        return
    x, cells, _ = root._arrays
    f = root.features
    assert isinstance(f, Features)
    assert f.cell_region.shape == (cells.shape[0],)
    a = areas(x, cells)
    per_region = {int(r): float(a[f.cell_region == r].sum()) for r in np.unique(f.cell_region)}
    assert sorted(per_region) == [1, 2]
    assert per_region[1] == pytest.approx(1.0, rel=1e-10)
    assert per_region[2] == pytest.approx(1.0, rel=1e-10)
    # the left region's triangles lie left of x = 1
    assert x[cells[f.cell_region == 1]][..., 0].max() <= 1 + 1e-12
    length = np.linalg.norm(x[f.curve_edges[:, 1]] - x[f.curve_edges[:, 0]], axis=1)
    per_curve = {int(c): float(length[f.edge_curve == c].sum()) for c in np.unique(f.edge_curve)}
    assert per_curve[30] == pytest.approx(math.hypot(0.6, 0.4), rel=1e-10)
    assert sum(per_curve.values()) == pytest.approx(6 + 1 + math.hypot(0.6, 0.4), rel=1e-10)
    inside = f.interior_curve_edges(cells)
    interior_curves = set(np.unique(f.edge_curve[inside]).tolist())
    assert 30 in interior_curves and len(interior_curves) == 2  # the segment, x = 1
    assert float(length[inside].sum()) == pytest.approx(1 + math.hypot(0.6, 0.4), rel=1e-10)
    assert np.allclose(x[f.curve_edges[inside & (f.edge_curve != 30)]][..., 0], 1.0,
                       rtol=0, atol=1e-12)
    at = dict(zip(f.point_tag.tolist(), x[f.point_nodes].tolist(), strict=True))
    assert at[20] == pytest.approx([0.4, 0.7], abs=1e-12)
    assert at[21] == pytest.approx([1.2, 0.2], abs=1e-12)
    assert at[22] == pytest.approx([1.8, 0.6], abs=1e-12)
    assert len(at) == 6 + 3 and f.point_nodes.size == 9  # the six corners, three inside


def test_features_of_a_builtin_shape():
    root = RootField(FrameField.initial(piano(COMM, 0.1), isotropic=True))
    if COMM.rank != 0:
        return
    x, cells, _ = root._arrays
    f = root.features
    assert np.unique(f.cell_region).size == 1
    assert float(areas(x, cells).sum()) == pytest.approx(piano_area(), rel=2e-3)
    assert not f.interior_curve_edges(cells).any()
    length = np.linalg.norm(x[f.curve_edges[:, 1]] - x[f.curve_edges[:, 0]], axis=1)
    assert float(length.sum()) == pytest.approx(piano_perimeter(), rel=2e-3)
    assert np.unique(f.edge_curve).size == 6
