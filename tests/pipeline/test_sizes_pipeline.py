"""Quads of the sizes asked for: ``solve --size`` and a file's own sizes, end to end.

Truth is the target itself: the quads' local edge length against h at their centroids
(``summary.json``'s ``sizes.quads``, recomputed here from ``quads.msh`` read back by Gmsh),
the file's SizeMin/SizeMax, the number of quads asked for. Serial and under MPI (the
command runs in-process, collectively).
"""

import json
from pathlib import Path

import numpy as np
import pytest

from ufl_frames.bootstrap import init_petsc

init_petsc([])

from mpi4py import MPI  # noqa: E402

from ufl_frames.app import cli  # noqa: E402
from ufl_frames.mesh.sizes import SizeTarget  # noqa: E402
from ufl_frames.pipeline.sizes import quad_size_record  # noqa: E402

COMM = MPI.COMM_WORLD
ERROR = "ufl-frames: error: "
#: A 2 × 1 rectangle refined towards its corner (0, 1) by Gmsh's Distance and Threshold
#: fields (sizes 0.01 to 0.1): a grading over one decade.
GRADED = """
Point(1) = {0, 0, 0, 0.1}; Point(2) = {2, 0, 0, 0.1};
Point(3) = {2, 1, 0, 0.1}; Point(4) = {0, 1, 0, 0.01};
Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 1};
Curve Loop(1) = {1, 2, 3, 4}; Plane Surface(1) = {1};
Field[1] = Distance; Field[1].PointsList = {4};
Field[2] = Threshold; Field[2].InField = 1; Field[2].SizeMin = 0.01; Field[2].SizeMax = 0.1;
Field[2].DistMin = 0.05; Field[2].DistMax = 1.0;
Background Field = 2;
"""


@pytest.fixture
def shared_tmp(tmp_path):
    return Path(COMM.bcast(str(tmp_path), root=0))


def read_quads(path: Path):
    """Points (n, 2) and quads (m, 4) of an MSH file, read back by Gmsh."""
    import gmsh

    owns = not gmsh.isInitialized()
    if owns:
        gmsh.initialize(argv=[], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.open(str(path))
        tags, coords, _ = gmsh.model.mesh.getNodes()
        index = {int(t): i for i, t in enumerate(tags)}
        _, nodes = gmsh.model.mesh.getElementsByType(3)
        quads = np.array([index[int(n)] for n in nodes]).reshape(-1, 4)
        gmsh.model.remove()
    finally:
        if owns:
            gmsh.finalize()
    return coords.reshape(-1, 3)[:, :2], quads


class _QuadMesh:
    def __init__(self, points, quads):
        self.points, self.quads = points, quads


def solve(out: Path, *args) -> dict:
    status = cli.main(["solve", *map(str, args), "--out", str(out), "-q"])
    assert status == 0
    return json.loads((out / "summary.json").read_text())


def test_quads_follow_the_file_s_own_sizes(shared_tmp):
    """The file's Distance/Threshold sizes (no --size): the target spans 0.01-0.1 as the
    file says; the log of the quads' edge length correlates ≥ 0.9 with the log of h, the
    count is within 10 % of --quad-count, and no vertex is irregular (the rectangle needs
    none)."""
    geo = shared_tmp / "graded.geo"
    if COMM.rank == 0:
        geo.write_text(GRADED)
    COMM.Barrier()
    summary = solve(shared_tmp / "out", geo, "--quads", "--quad-count", 400)
    sizes = summary["sizes"]
    assert sizes["target"].startswith("the file's sizes")
    assert sizes["h_min"] == pytest.approx(0.01, rel=1e-6)
    assert sizes["h_max"] == pytest.approx(0.1, rel=1e-6)
    found = sizes["quads"]
    assert found["log_correlation"] >= 0.9, found
    assert abs(found["count_error"]) <= 0.1, found
    assert summary["quads"]["irregular_vertices"] == 0
    # recomputed from the file written, read back by Gmsh, against the file's formula
    if COMM.rank == 0:
        points, quads = read_quads(shared_tmp / "out" / "quads.msh")
        assert len(quads) == found["quads"]

        def threshold(x, y):
            t = np.clip((np.hypot(x, y - 1.0) - 0.05) / 0.95, 0.0, 1.0)
            return 0.01 + 0.09 * t

        again = quad_size_record(_QuadMesh(points, quads), SizeTarget.of_function(threshold))
        assert again["log_correlation"] >= 0.9
        assert again["log_correlation"] == pytest.approx(found["log_correlation"], abs=0.01)


def test_log_polar_size_on_the_annulus(shared_tmp):
    """--size "hypot(x, y)" on the annulus: a target the integrable log-polar frames meet
    exactly, so the field's sizes follow it to within 1 % and the quads' edges to within
    a few per cent (their ratio to h, up to the global factor, in [0.95, 1.05]). Without
    the smoothing term (``-frames_size_smoothing 0``), whose minimum the log-polar field is
    not (the default's p90 of the field's |log(l/ch)| is 0.021 here, measured)."""
    summary = solve(shared_tmp / "out", "annulus", "--size", "hypot(x, y)", "--quads",
                    "--quad-count", 300, "-frames_size_smoothing", "0")
    sizes = summary["sizes"]
    assert sizes["h_ratio"] == pytest.approx(2.0, rel=1e-3)
    assert sizes["field"]["p90_abs_log"] < 0.01
    found = sizes["quads"]
    # 0.965 measured: since the circles' model points must be quad vertices the few quads
    # at them are off the log-polar grid (0.99993 before); the target is 0.9
    assert found["log_correlation"] > 0.95
    assert 0.95 < found["ratio_p10"] and found["ratio_p90"] < 1.05
    assert abs(found["count_error"]) <= 0.1


def test_uniform_default_and_none(shared_tmp):
    """A built-in shape gets the uniform target by default; --size none the unsized
    problem (no 'sizes' record)."""
    sized = solve(shared_tmp / "a", "piano", "--mesh-size", "0.1", "--levels", "1")
    assert sized["sizes"]["target"] == "uniform" and sized["sizes"]["h_ratio"] == 1.0
    plain = solve(shared_tmp / "b", "piano", "--mesh-size", "0.1", "--levels", "1",
                  "--size", "none")
    assert plain["sizes"] is None


@pytest.mark.parametrize("args", [
    ["--size", "__import__('os').system('true')"],
    ["--size", "x.__class__"],
    ["--size", "hypot(x, y"],
    ["--size", "x - 10"],  # negative everywhere on the annulus: refused when evaluated
    ["--size", "hypot(x, y)", "--isotropic"],
    ["--quad-count", "10"],  # without --quads
])
def test_bad_sizes_are_refused_in_one_line(shared_tmp, capsys, args):
    status = cli.main(["solve", "annulus", "--mesh-size", "0.2", "--max-it", "3", *args,
                       "--out", str(shared_tmp / "out"), "-q"])
    assert status in (1, 2)
    err = capsys.readouterr().err.strip().splitlines()
    errors = [line for line in err if line.startswith(ERROR)]
    assert len(errors) == (1 if COMM.rank == 0 else 0), err
    assert "Traceback" not in "\n".join(err)
    assert not any("internal error" in line for line in errors), errors
    assert not (shared_tmp / "out").exists()


def test_stage_size_record_measures_each_stage_apart():
    """stage_size_record on a known case: frames of exactly h (no spread), a map whose
    cells are twice h's on the right half (every quad log 2 / 2 from the median), quads
    of one size against h = 1 | e (every quad ½ from the median)."""
    from types import SimpleNamespace

    from ufl_frames.pipeline.sizes import stage_size_record

    nx, ny = 6, 5  # x = 0.5 is a grid line; no quad centroid on a triangle's edge
    gx, gy = np.meshgrid(np.linspace(0, 1, nx + 1), np.linspace(0, 1, ny + 1), indexing="ij")
    x = np.column_stack([gx.ravel(), gy.ravel()])
    v = np.arange((nx + 1) * (ny + 1)).reshape(nx + 1, ny + 1)
    a, b, c, d = v[:-1, :-1].ravel(), v[1:, :-1].ravel(), v[1:, 1:].ravel(), v[:-1, 1:].ravel()
    cells = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])

    def h(px, py):
        return np.where(px < 0.5, 1.0, np.e)

    right = x[cells].mean(axis=1)[:, 0] > 0.5
    h_cells = np.where(right, np.e, 1.0)
    scale = 3.0
    mesh = SimpleNamespace(x=x, cells=cells, l1=scale * h_cells, l2=scale * h_cells)
    cell = np.where(right, 2.0, 1.0) * h_cells  # the map's cells: 2h on the right
    zeros = np.zeros_like(cell)
    seamless_map = SimpleNamespace(scale=scale, grad_u=np.column_stack([1 / cell, zeros]),
                                   grad_v=np.column_stack([zeros, 1 / cell]))
    qx, qy = np.meshgrid(np.linspace(0, 1, 5), np.linspace(0, 1, 5), indexing="ij")
    w = np.arange(25).reshape(5, 5)
    quads = np.column_stack([w[:-1, :-1].ravel(), w[1:, :-1].ravel(), w[1:, 1:].ravel(),
                             w[:-1, 1:].ravel()])
    quad_mesh = SimpleNamespace(points=np.column_stack([qx.ravel(), qy.ravel()]), quads=quads)

    found = stage_size_record(mesh, seamless_map, quad_mesh, SizeTarget.of_function(h))
    assert found["located"] == found["count"] == 16
    assert found["field"]["p90_abs_log"] == pytest.approx(0.0, abs=1e-12)
    assert found["field"]["log_correlation"] == pytest.approx(1.0)
    for key in ("map", "map_over_field"):
        assert found[key]["median_abs_log"] == pytest.approx(0.5 * np.log(2.0))
        assert found[key]["p90_abs_log"] == pytest.approx(0.5 * np.log(2.0))
    assert found["quads"]["median_abs_log"] == pytest.approx(0.5)
    assert found["quads"]["log_correlation"] is None  # every quad of one size
    assert found["quads_over_map"]["p90_abs_log"] == pytest.approx(0.5 * (1 + np.log(2.0)))
    again = quad_size_record(quad_mesh, SizeTarget.of_function(h))
    assert again["p90_abs_log"] == pytest.approx(found["quads"]["p90_abs_log"])
