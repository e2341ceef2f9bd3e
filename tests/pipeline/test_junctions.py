"""Poincaré–Hopf with interior curves meeting the boundary (junctions), on the solver's
field: squares cut by interfaces from an edge's midpoint at 90° and 60°, from a corner at
60°, a fan of two at 60°/120° from a midpoint, and a square with a 300° V-notch whose tip
an interface leaves along the bisector (deal.II step-49's slit tip in small). Serial and
MPI.

Truth, by hand from the outlines: the triangles sum to χ − Σ_c (2 − k_c)/4 of the whole
domain (the boundary rows are held); a junction's index is (k − Σ k_i)/4 of its sectors;
the regions the curves cut out, each with its own corners, sum to that less the
junctions' indices. At the notch's tip the boundary's cross (45° off both edges' crosses,
which differ by 4 × 60°) is 45° off the interface's: the steps to the interface's nodes
are exactly π.
"""

import math

import pytest

from ufl_frames.bootstrap import init_petsc

init_petsc([])  # not pytest's command line

from mpi4py import MPI  # noqa: E402

from ufl_frames.mesh import load  # noqa: E402
from ufl_frames.pipeline import FrameField  # noqa: E402

COMM = MPI.COMM_WORLD
R3 = math.sqrt(3)
H = math.tan(math.radians(30))


def geo(points, lines, loops) -> str:
    """A built-in-kernel file of points, lines and one plane surface per curve loop."""
    text = [f"Point({k}) = {{{float(x)!r}, {float(y)!r}, 0}};" for k, (x, y) in points.items()]
    text += [f"Line({k}) = {{{a}, {b}}};" for k, (a, b) in lines.items()]
    text += [f"Curve Loop({k}) = {{{', '.join(map(str, loop))}}}; Plane Surface({k}) = {{{k}}};"
             for k, loop in loops.items()]
    return "\n".join(text) + "\n"


SQUARE = {1: (0, 0), 3: (1, 0), 5: (1, 1), 6: (0, 1)}
# name: (file, whole domain's sum, junction indices {(x, y): index}, regions' sum)
CASES = {
    # two 1 × 1/2 rectangles: 0 each; 90° + 90° at both ends
    "midpoint_90": (geo({**SQUARE, 2: (0.5, 0), 4: (0.5, 1)},
                        {1: (1, 2), 2: (2, 3), 3: (3, 5), 4: (5, 4), 5: (4, 6), 6: (6, 1),
                         7: (2, 4)}, {1: [1, 7, 5, 6], 2: [2, 3, 4, -7]}),
                    0.0, {(0.5, 0.0): 0.0, (0.5, 1.0): 0.0}, 0.0),
    # 60° + 120° at the midpoint (k 1 + 1 = 2), 150° + 30° on the right side (2 + 0 = 2)
    "midpoint_60": (geo({**SQUARE, 2: (0.5, 0), 4: (1, R3 / 2)},
                        {1: (1, 2), 2: (2, 3), 3: (3, 4), 4: (4, 5), 5: (5, 6), 6: (6, 1),
                         7: (2, 4)}, {1: [1, 7, 4, 5, 6], 2: [2, 3, -7]}),
                    0.0, {(0.5, 0.0): 0.0, (1.0, R3 / 2): 0.0}, 0.0),
    # the corner's 90° split 60° + 30° (1 + 0 = 1), the top side 60° + 120°
    "corner_60": (geo({**SQUARE, 4: (1 / R3, 1)},
                      {1: (1, 3), 2: (3, 5), 3: (5, 4), 4: (4, 6), 5: (6, 1), 6: (1, 4)},
                      {1: [1, 2, 3, -6], 2: [6, 4, 5]}),
                  0.0, {(0.0, 0.0): 0.0, (1 / R3, 1.0): 0.0}, 0.0),
    # 60° + 60° + 60° at the midpoint (3 against 2: −1/4); the middle region (corners
    # 60°, 150°, 90°, 90°, 150°) sums to 1 − 3/4 = 1/4, the two triangles (90°, 60°, 30°) 0
    "fan_60": (geo({**SQUARE, 2: (0.5, 0), 4: (1, R3 / 2), 7: (0, R3 / 2)},
                   {1: (1, 2), 2: (2, 3), 3: (3, 4), 4: (4, 5), 5: (5, 6), 6: (6, 7),
                    7: (7, 1), 8: (2, 4), 9: (2, 7)},
                   {1: [1, 9, 7], 2: [2, 3, -8], 3: [8, 4, 5, 6, -9]}),
               0.0, {(0.5, 0.0): -0.25, (1.0, R3 / 2): 0.0, (0.0, R3 / 2): 0.0}, 0.25),
    # [0, 2]² with a 60° notch from the left side to (1, 1): corners 4 × 90°, 2 × 120°
    # (k = 1), 300° (k = 3): 1 − (6 − 1)/4 = −1/4; the tip split 150° + 150° (2 + 2 = 4
    # against 3: −1/4); each half (150°, 90°, 90°, 90°, 120°) sums to 0
    "notch_300": (geo({1: (1, 1), 2: (2, 1), 3: (2, 2), 4: (0, 2), 5: (0, 1 + H),
                       6: (0, 1 - H), 7: (0, 0), 8: (2, 0)},
                      {1: (1, 2), 2: (2, 3), 3: (3, 4), 4: (4, 5), 5: (5, 1), 6: (1, 6),
                       7: (6, 7), 8: (7, 8), 9: (8, 2)},
                      {1: [1, 2, 3, 4, 5], 2: [6, 7, 8, 9, -1]}),
                  -0.25, {(1.0, 1.0): -0.25, (2.0, 1.0): 0.0}, 0.0),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_index_sum_with_interfaces_meeting_the_boundary(name, tmp_path_factory):
    text, whole, junctions, regions = CASES[name]
    folder = tmp_path_factory.mktemp(name) if COMM.rank == 0 else None
    path = COMM.bcast(folder, root=0) / f"{name}.geo"
    if COMM.rank == 0:
        path.write_text(text)
    COMM.Barrier()
    size = 0.1 if name == "notch_300" else 0.05
    domain = load(COMM, path, size)
    found = {(round(j.x, 9), round(j.y, 9)): j.index for j in domain.junctions}
    assert found == {(round(x, 9), round(y, 9)): i for (x, y), i in junctions.items()}
    field = FrameField.initial(domain, isotropic=False)
    field.solve(max_it=50)
    check = field.index_theorem()
    assert check["expected"] == whole and check["ambiguous_corners"] == 0
    assert check["index_sum"] == whole and check["agrees"]
    assert check["junction_index"] == sum(junctions.values())
    assert check["expected_away_from_junctions"] == regions
    # the junctions' indices sit in triangles touching them, the rest inside the regions
    near = 2.5 * domain.mesh_size
    at = [s["index"] for s in field.singularities
          if min(math.dist((s["x"], s["y"]), p) for p in junctions) < near]
    assert sum(at) == sum(junctions.values())
    assert check["index_sum"] - sum(at) == regions
