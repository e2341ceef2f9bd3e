"""``ufl-frames solve`` on volumes: the 3D built-ins and a file with a volume take the 3D
path (the MBO field and its singular graph); the files read back; 2D options and 2D
shapes with ``--dim 3`` are refused with one line. In-process (serial and under
``mpirun -n 2``)."""

import json
from pathlib import Path

import numpy as np
import pytest

from ufl_frames.bootstrap import init_petsc

init_petsc([])  # not pytest's command line

from mpi4py import MPI  # noqa: E402

from ufl_frames.app import cli  # noqa: E402
from ufl_frames.output.vtk import read_vtk  # noqa: E402

COMM = MPI.COMM_WORLD
FILES = {"frames3d.vtu", "singular.vtu", "singular.png", "summary.json"}
PLATE_GEO = 'SetFactory("OpenCASCADE");\nBox(1) = {0, 0, 0, 1, 0.6, 0.3};\n'


def folder(tmp_path_factory, name):
    return Path(COMM.bcast(str(tmp_path_factory.mktemp(name)), root=0))


def test_box_file_is_solved_in_3d(tmp_path_factory):
    root = folder(tmp_path_factory, "box3d")
    geo = root / "plate.geo"
    if COMM.rank == 0:
        geo.write_text(PLATE_GEO)
    COMM.Barrier()
    out = root / "out"
    assert cli.main(["solve", str(geo), "--mesh-size", "0.15", "--out", str(out), "-q"]) == 0
    assert {p.name for p in out.iterdir()} == FILES
    summary = json.loads((out / "summary.json").read_text())
    assert summary["dimension"] == 3 and summary["ranks"] == COMM.size
    assert summary["singular_graph"]["edges"] == 0  # a box's frames are its axes
    frames = read_vtk(out / "frames3d.vtu")
    assert frames["cells"].shape == (summary["tetrahedra"], 4)
    u = np.stack([frames["point_data"][f"u{i}"] for i in (1, 2, 3)], axis=1)
    assert np.abs(np.abs(u).max(axis=1) - 1).max() < 1e-9  # unit, along the axes


def test_ball_builtin_has_a_valid_singular_graph(tmp_path_factory):
    out = folder(tmp_path_factory, "ball3d") / "out"
    assert cli.main(["solve", "ball", "--mesh-size", "0.25", "--out", str(out), "-q"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    graph = summary["singular_graph"]
    assert graph["edges"] > 0 and graph["open_ends"] == 0
    lines = read_vtk(out / "singular.vtu")
    assert lines["cells"].shape == (graph["edges"], 2)


STEP_PART = Path(__file__).resolve().parents[2] / "benchmarks" / "shapes3d" / "gmsh_part.step"


def test_real_step_part_with_fillets(tmp_path_factory):
    """Gmsh's benchmark part (a public STEP bracket with filleted corners, see
    benchmarks/shapes3d/SOURCES.md), coarse: the 3D path, sharp edges held, a singular
    graph with no open end inside; the frames on the flat bottom face have an axis along z."""
    out = folder(tmp_path_factory, "step3d") / "out"
    assert cli.main(["solve", str(STEP_PART), "--mesh-size", "12", "--out", str(out),
                     "-q"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["dimension"] == 3 and summary["ranks"] == COMM.size
    assert summary["boundary_vertices"]["sharp"] > 0
    graph = summary["singular_graph"]
    assert graph["edges"] > 0 and graph["open_ends"] == 0
    frames = read_vtk(out / "frames3d.vtu")
    x = frames["points"]
    bottom = np.isclose(x[:, 2], x[:, 2].min(), rtol=0, atol=1e-6)
    assert np.count_nonzero(bottom) > 30
    u = np.stack([frames["point_data"][f"u{i}"] for i in (1, 2, 3)], axis=1)  # (n, 3, 3)
    assert (1 - np.abs(u[bottom, :, 2]).max(axis=1)).max() < 1e-9


@pytest.mark.parametrize("argv, message", [
    (["solve", "ball", "--quads"], "not available for 3D"),
    (["solve", "cylinder", "--isotropic"], "not available for 3D"),
    (["solve", "annulus", "--dim", "3"], "is a 2D shape"),
])
def test_2d_options_are_refused(tmp_path_factory, capsys, argv, message):
    out = folder(tmp_path_factory, "refused") / "out"
    assert cli.main([*argv, "--out", str(out)]) == 1
    if COMM.rank == 0:
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0]
    assert not out.exists()


def test_step_files_are_told_apart_by_their_solids(tmp_path_factory):
    """A STEP file with a solid takes the 3D path, one with a planar face alone the 2D
    one (the file is scanned for solid entities, not loaded)."""
    import gmsh

    from ufl_frames.app.volume import defines_volumes

    if COMM.rank:
        return
    root = Path(tmp_path_factory.mktemp("step"))
    owns = not gmsh.isInitialized()
    if owns:
        gmsh.initialize(argv=[], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        for name, make in (("solid", lambda: gmsh.model.occ.addBox(0, 0, 0, 1, 1, 1)),
                           ("face", lambda: gmsh.model.occ.addRectangle(0, 0, 0, 1, 1))):
            gmsh.model.add(name)
            make()
            gmsh.model.occ.synchronize()
            gmsh.write(str(root / f"{name}.step"))
            gmsh.model.remove()
    finally:
        if owns:
            gmsh.finalize()
    assert defines_volumes(root / "solid.step")
    assert not defines_volumes(root / "face.step")
