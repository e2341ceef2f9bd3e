"""``ufl-frames solve`` on a ``.geo`` whose two surfaces one ``Function`` draws (as the
gallery's two I-beams): the general field reads the file's sizes, then meshes it again
finer for the quads asked for; each parse now happens in its own child process (Gmsh's
parser keeps a function for the life of a process: the second parse crashed Gmsh, issue
37). Both components get valid quads, each its own map. In-process: serial and under
``mpirun -n 2 python -m pytest -m "not serial"``.

Truth: the two rectangles' areas (2 × 1 and 0.5 × 1), exact for quads with straight
boundaries.
"""

import json
from pathlib import Path

import numpy as np
import pytest

from ufl_frames.bootstrap import init_petsc

init_petsc([])  # not pytest's command line

from mpi4py import MPI  # noqa: E402
from msh_readback import read_msh

from ufl_frames.app import cli  # noqa: E402

COMM = MPI.COMM_WORLD
TWO_SLABS = """Function Slab
  p1 = newp; Point(p1) = {x0, 0, 0, lc};
  p2 = newp; Point(p2) = {x0 + w, 0, 0, lc};
  p3 = newp; Point(p3) = {x0 + w, 1, 0, lc};
  p4 = newp; Point(p4) = {x0, 1, 0, lc};
  l1 = newl; Line(l1) = {p1, p2};
  l2 = newl; Line(l2) = {p2, p3};
  l3 = newl; Line(l3) = {p3, p4};
  l4 = newl; Line(l4) = {p4, p1};
  loop = newll; Curve Loop(loop) = {l1, l2, l3, l4};
  face = news; Plane Surface(face) = {loop};
Return
lc = 0.1;
x0 = 0; w = 2; Call Slab;
x0 = 3; w = 0.5; Call Slab;
"""


def test_solve_quads_of_two_components_drawn_by_a_function(tmp_path_factory):
    root = Path(COMM.bcast(str(tmp_path_factory.mktemp("slabs")), root=0))
    geo = root / "two_slabs.geo"
    if COMM.rank == 0:
        geo.write_text(TWO_SLABS)
    COMM.Barrier()
    out = root / "out"
    assert cli.main(["solve", str(geo), "--quads", "--quad-count", "100", "--out", str(out),
                     "--force", "-q"]) == 0
    quads = json.loads((out / "summary.json").read_text())["quads"]
    assert quads["valid"], quads["problems"]
    assert quads["min_sj"] >= 0.3
    if COMM.rank == 0:
        x, q, _ = read_msh(out / "quads.msh", dim=2)
        p = x[q]
        area = 0.5 * np.abs(np.sum(p[:, :, 0] * np.roll(p[:, :, 1], -1, axis=1)
                                   - np.roll(p[:, :, 0], -1, axis=1) * p[:, :, 1], axis=1))
        left = p[:, :, 0].mean(axis=1) < 2.5
        assert area[left].sum() == pytest.approx(2.0, rel=1e-9)
        assert area[~left].sum() == pytest.approx(0.5, rel=1e-9)
