"""Quads of one tooth of Gmsh's rotor sector (``meshes/gallery/gmsh_rotor_sector.geo``
with 40 poles in the whole cross-section: a 9° sector, eight surfaces): issue 37's rotor
in small. Serial and MPI.

Its regions are far thinner than a quad: an air-gap layer 0.22 mm thick between the
outer boundary and the iron, bar halves 0.7 mm wide at their neck, against quads of
2.5–4.7 mm. Every region keeps at least one layer of quads, so the T-mesh's patches there
are thin; two things made them fold or shear:

* two traces from the bar's corners on both sides of its axis (an interface) land on it a
  hair (under 1 % of a quad) from the model point there: the interface's arcs between
  them had to keep a length of one quad, which folded the quads of the bar's half
  (a non-positive area);
* a thin patch whose one side is a single arc (the outer boundary over the air gap, a
  trace beside the bar) and whose other side is split unevenly by the interface's model
  points had its quads sheared by most of a quad across their thickness (scaled Jacobian
  0.075).

Truth: the sector's area from the file's radii (0.5 %), the checks of the quad stage
(conforming, none inverted, every quad in one region, model points quad vertices) and a
scaled Jacobian of at least 0.3, by the T-mesh layout.
"""

import math
from pathlib import Path

import numpy as np
import pytest

from ufl_frames.bootstrap import init_petsc

init_petsc([])  # not pytest's command line

from mpi4py import MPI  # noqa: E402

from ufl_frames.mesh import load  # noqa: E402
from ufl_frames.pipeline import FrameField  # noqa: E402
from ufl_frames.pipeline.stages import RootField, quadrangulate  # noqa: E402
from ufl_frames.quads.measures import scaled_jacobians  # noqa: E402

COMM = MPI.COMM_WORLD
ROTOR = Path(__file__).resolve().parents[2] / "meshes" / "gallery" / "gmsh_rotor_sector.geo"
# the sector between the shaft (r = 53/2 mm) and the outer boundary (80 − 0.65 × 2/3 mm)
AREA = 0.5 * (2 * math.pi / 40) * ((0.080 - 0.00065 * 2 / 3) ** 2 - (0.053 / 2) ** 2)


@pytest.fixture(scope="module")
def tooth(tmp_path_factory):
    """The tooth's field (the conformal scale of the MBO directions, as ``ufl-frames
    mesh``), on triangles of size 3.32 mm capped by the shape's thin parts."""
    folder = Path(COMM.bcast(str(tmp_path_factory.mktemp("tooth")), root=0))
    path = folder / "tooth.geo"
    if COMM.rank == 0:
        text = ROTOR.read_text()
        assert "NbrPolesT = 4;" in text
        path.write_text(text.replace("NbrPolesT = 4;", "NbrPolesT = 40;", 1))
    COMM.Barrier()
    domain = load(COMM, path, mesh_size=0.00332, resolve_features=True)
    return RootField(FrameField.initial(domain, isotropic=True).conformal())


@pytest.mark.parametrize("size", [0.0047, 0.00332, 0.0025])
def test_a_rotor_tooth_gives_valid_quads_in_its_thin_regions(tooth, size):
    quads = quadrangulate(tooth, quad_size=size)
    quality = quads.quality
    assert quality["valid"] and quality["quantisation"] == "layout"
    assert quality["features"]["regions"] == 8
    assert quality["min_sj"] >= 0.3
    if COMM.rank != 0:
        return
    mesh = quads.mesh
    assert scaled_jacobians(mesh.points, mesh.quads).min() >= 0.3
    corners = mesh.points[mesh.quads]
    x, y = corners[..., 0], corners[..., 1]
    area = 0.5 * np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, axis=1)
    assert area.min() > 0
    assert area.sum() == pytest.approx(AREA, rel=5e-3)
