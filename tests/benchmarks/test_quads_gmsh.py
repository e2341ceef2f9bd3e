"""The Gmsh side of ``benchmarks/quads.py`` on a ``.geo`` that Gmsh parses only once per
process: two rectangles drawn by one ``Function`` called twice (as the gallery's two
I-beams are), with point sizes far below the quad size asked for.

Truth: the rectangles' area in closed form (2 × 1 + 0.5 × 1); the count asked for.
"""

import argparse
import importlib.util
from pathlib import Path

import pytest

pytestmark = pytest.mark.serial  # subprocesses of Gmsh: nothing here is parallel
pytest.importorskip("gmsh")  # the pure suite (no Gmsh) collects this folder too

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "quads.py"

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
lc = 0.04;
x0 = 0; w = 2; Call Slab;
x0 = 3; w = 0.5; Call Slab;
"""


@pytest.fixture(scope="module")
def quads_script():
    import sys

    sys.path.insert(0, str(SCRIPT.parent))  # the script imports _common, _processes
    spec = importlib.util.spec_from_file_location("quads_benchmark", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_geo_with_a_function_is_meshed_at_the_count_asked(quads_script, tmp_path):
    """Every size tried parses the file again: in one process the second parse was a
    redefinition of ``Slab`` (and a crash), and the file's point sizes (0.04: 1 664
    quads) did not follow the size cap: the count stayed where the file put it."""
    geo = tmp_path / "two_slabs.geo"
    geo.write_text(TWO_SLABS)
    args = argparse.Namespace(quads=300.0, quad_size=None, out=tmp_path / "out",
                              area_rtol=0.005, gmsh_timeout=120.0)
    row = quads_script.run_gmsh(geo, "fullquad", args, "two_slabs")
    assert row["status"] == "ok", row.get("error")
    assert row["area_exact"] == pytest.approx(2.5, rel=1e-9)
    assert row["valid"], row["problems"]
    # Gmsh's count moves in steps here (336 at two sizes 6 % apart): near, not within 10 %
    assert abs(row["quality"]["quads"] / 300.0 - 1) <= 0.25
    assert (tmp_path / "out" / "two_slabs.msh").exists()
