"""``ufl-frames mesh demos/two_materials.geo``: a 2 × 1 plate with a round inclusion of
radius 0.3 (two surfaces sharing a circle of four arcs). The circle's four model points lie
inside the domain on the interface, and singular vertices of the field lie a fraction of a
quad from it; the T-mesh layout (not the greedy fallback) must make the quads: the model
points nodes of the T-mesh and integer grid points, the traces glued onto the circle where
a thin patch between them collapses (the circle's points staying where they are).

Truth: the geometry, read back from ``quads.msh`` with Gmsh: the four model points quad
nodes at their places (1e-12), the interface's line nodes on the exact circle (1e-9), the
two surfaces' areas (2 − π r² and π r², 0.5 %; the quads' edges on the circle are its
chords); the summary and the log say which path made the quads.

In-process (``cli.main``): runs serially and under ``mpirun -n 2 python -m pytest -m
"not serial"``; the read-back on rank 0.
"""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from ufl_frames.bootstrap import init_petsc

init_petsc([])  # not pytest's command line

from mpi4py import MPI  # noqa: E402

from ufl_frames.app import cli  # noqa: E402

COMM = MPI.COMM_WORLD
GEO = Path(__file__).resolve().parents[2] / "demos" / "two_materials.geo"
CENTRE, R = np.array([1.0, 0.5]), 0.3
MODEL_POINTS = {6: (1.3, 0.5), 7: (1.0, 0.8), 8: (0.7, 0.5), 9: (1.0, 0.2)}


def test_layout_meshes_the_interface_circle(tmp_path_factory, capsys):
    meshed = Path(COMM.bcast(str(tmp_path_factory.mktemp("two_materials")), root=0)) / "out"
    assert cli.main(["mesh", str(GEO), "--out", str(meshed)]) == 0
    said = capsys.readouterr().out
    summary = json.loads((meshed / "summary.json").read_text())["quads"]
    assert summary["valid"] and summary["min_sj"] >= 0.3
    assert summary["quantisation"] == "layout" and summary["fallback_reason"] is None
    assert summary["features"]["regions"] == 2 and summary["features"]["point_nodes"] == 8
    if COMM.rank == 0:
        assert "made by the T-mesh layout" in said
        import gmsh

        gmsh.initialize(argv=[], readConfigFiles=False)
        try:
            gmsh.option.setNumber("General.Terminal", 0)
            gmsh.open(str(meshed / "quads.msh"))
            tags, coords, _ = gmsh.model.mesh.getNodes()
            x = np.full((int(tags.max()) + 1, 2), np.nan)
            x[tags.astype(int)] = coords.reshape(-1, 3)[:, :2]
            groups = {gmsh.model.getPhysicalName(d, n): (d, n)
                      for d, n in gmsh.model.getPhysicalGroups()}
            quad_nodes = set()
            area = {}
            for name in ("steel", "rubber"):
                total = 0.0
                for s in gmsh.model.getEntitiesForPhysicalGroup(*groups[name]):
                    kinds, _, nodes = gmsh.model.mesh.getElements(2, int(s))
                    assert [int(k) for k in kinds] == [3]  # quads only
                    q = np.asarray(nodes[0], dtype=int).reshape(-1, 4)
                    quad_nodes.update(q.ravel().tolist())
                    p = x[q]
                    total += 0.5 * np.sum(p[..., 0] * np.roll(p[..., 1], -1, axis=1)
                                          - np.roll(p[..., 0], -1, axis=1) * p[..., 1])
                area[name] = abs(total)
            for tag, where in MODEL_POINTS.items():
                node_tags, _, _ = gmsh.model.mesh.getNodes(0, tag)
                assert len(node_tags) == 1 and int(node_tags[0]) in quad_nodes
                assert np.linalg.norm(x[int(node_tags[0])] - where) < 1e-12
            line_nodes = []
            for c in gmsh.model.getEntitiesForPhysicalGroup(*groups["interface"]):
                _, _, nodes = gmsh.model.mesh.getElements(1, int(c))
                line_nodes += np.asarray(nodes[0], dtype=int).tolist()
        finally:
            gmsh.finalize()
        radius = np.linalg.norm(x[np.unique(line_nodes)] - CENTRE, axis=1)
        assert len(line_nodes) > 0 and np.abs(radius - R).max() < 1e-9
        assert area["rubber"] == pytest.approx(math.pi * R**2, rel=5e-3)
        assert area["steel"] == pytest.approx(2.0 - math.pi * R**2, rel=5e-3)
