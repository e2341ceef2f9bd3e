"""Triangle indices of cross fields (ufl_frames.frames2d.singularities), NumPy and DOLFINx sides."""

import subprocess
import sys

import numpy as np
import pytest

from ufl_frames.frames2d.singularities import (
    corner_cross,
    corner_quarter_turns,
    find_singularities,
    index_theorem,
    locate_singularities,
    poincare_hopf_sum,
    triangle_indices,
)


def q_from_theta4(theta4, s=2.0):
    """Isotropic Odeco coefficients whose cross angle is theta4 / 4 (odeco module docstring)."""
    theta4 = np.asarray(theta4, dtype=float)
    q = np.zeros((theta4.size, 5))
    q[:, 0] = 3 * np.sqrt(2) * s / 8
    q[:, 3] = s / 8 * np.cos(theta4)
    q[:, 4] = s / 8 * np.sin(theta4)
    return q


def grid(n=12, jitter=0.0, seed=0):
    """Triangulated [0, 1]^2 (counter-clockwise cells), optionally with moved interior nodes."""
    x, y = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    coords = np.stack([x.ravel(), y.ravel()], axis=1)
    if jitter:
        interior = (coords > 0).all(axis=1) & (coords < 1).all(axis=1)
        rng = np.random.default_rng(seed)
        coords[interior] += jitter / n * rng.uniform(-1, 1, size=(interior.sum(), 2))
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    cells = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return cells, coords


def vortex(coords, centres):
    """theta4 = sum_k k * atan2(y - y0, x - x0): a k/4 singularity at each (x0, y0, k)."""
    theta4 = np.zeros(coords.shape[0])
    for x0, y0, k in centres:
        theta4 += k * np.arctan2(coords[:, 1] - y0, coords[:, 0] - x0)
    return theta4


# --- NumPy side -------------------------------------------------------------------


def test_single_triangle_winding_and_wrapping():
    cells = np.array([[0, 1, 2]])
    # theta4 going once around: steps of 2π/3 each, all inside (−π, π].
    q = q_from_theta4([0.0, 2 * np.pi / 3, 4 * np.pi / 3])
    assert triangle_indices(cells, q).tolist() == [0.25]
    assert triangle_indices(cells[:, ::-1], q).tolist() == [-0.25]
    # Same angles shifted by 2π multiples: arg() only sees them modulo 2π.
    q2 = q_from_theta4([10 * np.pi, 2 * np.pi / 3 - 4 * np.pi, 4 * np.pi / 3 + 2 * np.pi])
    assert triangle_indices(cells, q2).tolist() == [0.25]
    # Back and forth: no winding. The jump 3 -> -3 is read the short way (+2π - 6).
    assert triangle_indices(cells, q_from_theta4([0.0, 1.0, -1.0])).tolist() == [0.0]
    assert triangle_indices(cells, q_from_theta4([0.0, 3.0, -3.0])).tolist() == [0.25]


def test_orientation_from_coords():
    cells, coords = grid(6)
    theta4 = vortex(coords, [(0.43, 0.61, 1)])
    q = q_from_theta4(theta4)
    ccw = triangle_indices(cells, q, coords)
    flipped = cells[:, [0, 2, 1]]
    assert np.array_equal(triangle_indices(flipped, q, coords), ccw)
    assert np.array_equal(triangle_indices(flipped, q), -ccw)
    assert np.array_equal(triangle_indices(cells, q), ccw)


@pytest.mark.parametrize("k", [1, -1])
@pytest.mark.parametrize("jitter", [0.0, 0.3])
def test_one_vortex(k, jitter):
    cells, coords = grid(12, jitter=jitter)
    x0, y0 = 0.437, 0.582
    q = q_from_theta4(vortex(coords, [(x0, y0, k)]))
    found = find_singularities(cells, coords, q)
    assert len(found) == 1
    (s,) = found
    assert s["index"] == k / 4
    assert np.hypot(s["x"] - x0, s["y"] - y0) < 1.0 / 12
    assert set(s) == {"index", "x", "y"}
    assert all(type(v) is float for v in s.values())


def test_pair_and_sorting():
    cells, coords = grid(16)
    q = q_from_theta4(vortex(coords, [(0.717, 0.463, -1), (0.291, 0.538, 1)]))
    found = find_singularities(cells, coords, q)
    assert [s["index"] for s in found] == [0.25, -0.25]
    assert found[0]["x"] < 0.5 < found[1]["x"]


def test_double_vortex_total_index():
    # A ±1/2 vortex spreads over neighbouring triangles (an edge may see a jump > π),
    # but the total is exact.
    cells, coords = grid(16)
    for k in (2, -2):
        q = q_from_theta4(vortex(coords, [(0.517, 0.493, k)]))
        index = triangle_indices(cells, q, coords)
        assert index.sum() == k / 4
        assert np.all(np.abs(index) <= 0.5)


def test_smooth_field_has_none():
    cells, coords = grid(10, jitter=0.3)
    theta4 = 2.0 * coords[:, 0] - 1.3 * coords[:, 1] + 0.4 * np.sin(3 * coords[:, 0])
    q = q_from_theta4(theta4)
    assert find_singularities(cells, coords, q) == []
    assert np.all(triangle_indices(cells, q, coords) == 0.0)
    # −0.0 is not returned
    assert not np.any(np.signbit(triangle_indices(cells, q, coords)))


def test_discrete_index_theorem():
    """Sum of triangle indices = winding of theta4 along the boundary / (8π)."""
    cells, coords = grid(10, jitter=0.3, seed=3)
    rng = np.random.default_rng(1)
    centres = [(*rng.uniform(0.1, 0.9, 2), k) for k in (1, 1, -1, 1)]
    q = q_from_theta4(vortex(coords, centres))
    theta4 = np.arctan2(q[:, 4], q[:, 3])
    n = 10
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    loop = np.concatenate([idx[:, 0], idx[-1, 1:], idx[-2::-1, -1], idx[0, -2:0:-1]])
    steps = np.diff(theta4[np.append(loop, loop[0])])
    winding = np.sum(np.pi - np.mod(np.pi - steps, 2 * np.pi)) / (8 * np.pi)
    assert triangle_indices(cells, q, coords).sum() == pytest.approx(winding)
    assert winding == pytest.approx(0.5)


def test_step_of_exactly_pi_counts_once():
    """Two triangles of the unit square whose shared diagonal carries a step of exactly π
    (θ4 = 0 at (0, 0), π at (1, 1)): the boundary turns θ4 by 4 × π/2 = 2π, index 1/4,
    and the two triangles together give 1/4 (not 1/2: +π on both sides of the diagonal),
    the same triangle getting it whatever the vertices' numbering."""
    coords = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    theta4 = np.array([0.0, np.pi / 2, np.pi, 3 * np.pi / 2])
    cells = np.array([[0, 1, 2], [0, 2, 3]])
    index = triangle_indices(cells, q_from_theta4(theta4), coords)
    assert index.sum() == 0.25
    for perm in ([3, 2, 1, 0], [2, 0, 3, 1], [1, 3, 0, 2]):
        new = np.empty(4, dtype=int)
        new[perm] = np.arange(4)  # vertex v is renumbered new[v]
        renumbered = triangle_indices(new[cells], q_from_theta4(theta4[perm]), coords[perm])
        assert renumbered.tolist() == index.tolist()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_index_theorem_with_many_steps_of_pi(seed):
    """θ4 a random multiple of π/2 inside, 0 on the boundary (whose winding is then 0):
    many edges carry steps of exactly ±π, and the triangles still sum to 0."""
    n = 8
    cells, coords = grid(n, jitter=0.2, seed=seed)
    boundary = (coords == 0).any(axis=1) | (coords == 1).any(axis=1)
    rng = np.random.default_rng(seed)
    theta4 = np.where(boundary, 0.0, np.pi / 2 * rng.integers(0, 4, size=coords.shape[0]))
    edges = np.concatenate([cells[:, [0, 1]], cells[:, [1, 2]], cells[:, [2, 0]]])
    assert np.sum(np.isclose(np.abs(np.diff(theta4[edges], axis=1)), np.pi)) > 20
    index = triangle_indices(cells, q_from_theta4(theta4), coords)
    assert index.sum() == 0.0
    assert np.count_nonzero(index) > 0  # the field is singular, its indices cancel


def test_input_checks():
    cells, coords = grid(2)
    q = q_from_theta4(np.zeros(coords.shape[0]))
    with pytest.raises(ValueError, match="cells"):
        triangle_indices(cells[:, :2], q)
    with pytest.raises(ValueError, match="q must have shape"):
        triangle_indices(cells, q[:, :4])
    with pytest.raises(ValueError, match="outside"):
        triangle_indices(cells + 100, q)
    with pytest.raises(ValueError, match="integer"):
        triangle_indices(cells.astype(float), q)
    bad = q.copy()
    bad[0, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        triangle_indices(cells, bad)
    with pytest.raises(ValueError, match="coords"):
        find_singularities(cells, coords[:-1], q)
    assert triangle_indices(np.zeros((0, 3), dtype=int), q).shape == (0,)


@pytest.mark.serial
def test_module_imports_without_dolfinx():
    code = (
        "import sys, ufl_frames.frames2d.singularities; "
        "assert 'dolfinx' not in sys.modules, 'dolfinx imported'; "
        "assert 'petsc4py' not in sys.modules, 'petsc4py imported'"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


# --- DOLFINx side -----------------------------------------------------------------


def _dolfinx():
    pytest.importorskip("petsc4py")  # the pure NumPy venv (make test-pure) has none
    from ufl_frames.bootstrap import init_petsc

    init_petsc([])  # not pytest's command line
    import dolfinx
    from mpi4py import MPI

    return MPI, dolfinx


def _p1_frames(mesh, theta4_of_x):
    _, dolfinx = _dolfinx()
    V = dolfinx.fem.functionspace(mesh, ("Lagrange", 1, (5,)))
    q = dolfinx.fem.Function(V)
    q.interpolate(lambda x: q_from_theta4(theta4_of_x(x)).T)
    return q


def _same_on_all_ranks(comm, found):
    everyone = comm.allgather(found)
    assert all(other == everyone[0] for other in everyone)


def test_locate_synthetic_pair():
    MPI, dolfinx = _dolfinx()
    comm = MPI.COMM_WORLD
    mesh = dolfinx.mesh.create_rectangle(
        comm, [[0.0, 0.0], [2.0, 1.0]], [24, 12], dolfinx.mesh.CellType.triangle
    )
    plus, minus = (0.537, 0.412), (1.461, 0.583)

    def theta4(x):
        return np.arctan2(x[1] - plus[1], x[0] - plus[0]) - np.arctan2(
            x[1] - minus[1], x[0] - minus[0]
        )

    found = locate_singularities(_p1_frames(mesh, theta4))
    _same_on_all_ranks(comm, found)
    assert [s["index"] for s in found] == [0.25, -0.25]
    for s, (x0, y0) in zip(found, (plus, minus), strict=True):
        assert np.hypot(s["x"] - x0, s["y"] - y0) < 2.0 / 12


def test_locate_smooth_field_none():
    MPI, dolfinx = _dolfinx()
    comm = MPI.COMM_WORLD
    mesh = dolfinx.mesh.create_unit_square(comm, 10, 10)
    found = locate_singularities(_p1_frames(mesh, lambda x: 1.5 * x[0] - 2.0 * x[1]))
    assert found == []


def test_locate_rejects_scalar_space():
    MPI, dolfinx = _dolfinx()
    mesh = dolfinx.mesh.create_unit_square(MPI.COMM_WORLD, 2, 2)
    f = dolfinx.fem.Function(dolfinx.fem.functionspace(mesh, ("Lagrange", 1)))
    with pytest.raises(ValueError, match="value shape"):
        locate_singularities(f)


# --- Poincaré–Hopf ----------------------------------------------------------------


@pytest.mark.parametrize(
    "chi, corners_deg, expected",
    [
        (1, [], 1.0),  # disc: one +1 worth of quarter singularities inside
        (0, [], 0.0),  # annulus
        (-2, [], -2.0),  # disc with three holes
        (1, [90] * 4, 0.0),  # rectangle: integrable, no singularity
        (1, [90] * 5 + [270], 0.0),  # L-shape
        (1, [60] * 3, 0.25),  # equilateral triangle: 60° rounds to one quarter turn
        (1, [120] * 6, -0.5),  # regular hexagon: 120° rounds to one quarter turn too
        (0, [240] * 6, 1.5),  # a hexagonal hole in a disc: reflex 240° → three
        (1, [179, 181, 90, 90, 90, 90], 0.0),  # near-straight points count as straight
        (1, [30, 60, 90], 0.25),  # 30° is a squeezed quad corner, one quarter turn
        (0, [90] * 4 + [27, 27], -1.5),  # a box around two disks meeting at 27° cusps
    ],
)
def test_poincare_hopf_sum(chi, corners_deg, expected):
    angles = np.radians(corners_deg)
    assert poincare_hopf_sum(chi, angles) == expected
    check = index_theorem([{"index": expected, "x": 0, "y": 0}], chi, angles)
    assert check["agrees"] and check["index_sum"] == expected
    assert check["corners"] == sum(1 for a in corners_deg if round(a / 90) != 2)
    wrong = index_theorem([{"index": expected + 0.25, "x": 0, "y": 0}], chi, angles)
    assert not wrong["agrees"]


@pytest.mark.parametrize("bad", [[0.0], [-1.0], [2 * np.pi], [np.nan]])
def test_poincare_hopf_rejects_bad_angles(bad):
    with pytest.raises(ValueError, match="corner angles"):
        poincare_hopf_sum(1, bad)


def test_index_theorem_with_ambiguous_corners():
    """A 135° corner: the cross may turn by +45° or −45° there; both sums are right."""
    angles = np.radians([135, 135, 90])
    check = index_theorem([], 1, angles)
    assert check["ambiguous_corners"] == 2 and check["corners"] == 1
    # Rounded down, 135° is one quarter turn: 1 − 3/4; rounded up, two: 1 − 1/4.
    assert check["expected"] == 0.25
    agrees = [index_theorem([{"index": 0.25 + d, "x": 0, "y": 0}], 1, angles)["agrees"]
              for d in (-0.25, 0, 0.25, 0.5, 0.75)]
    assert agrees == [False, True, True, True, False]


@pytest.mark.parametrize("degrees, k", [(5, 1), (23.6, 1), (44, 1), (46, 1), (60, 1),
                                        (134, 1), (136, 2), (180, 2), (270, 3), (350, 4)])
def test_corner_quarter_turns(degrees, k):
    """round(α/90°), but a corner under 45° is one quarter turn (a quad corner squeezed
    to α), never none."""
    assert corner_quarter_turns(np.radians(degrees)) == k
    assert corner_quarter_turns(np.radians([degrees, 90]))[0] == k


@pytest.mark.parametrize("degrees", [10, 23.6, 27, 44, 60, 80, 150, 270])
def test_corner_cross_turns_the_corners_quarter_turns(degrees):
    """Rays along 0 and α from the corner, the domain between: the crosses of the two
    curves are 0 and α (mod 90°). Going from the first curve's cross to the corner's and
    on to the second's by the shortest steps, the cross turns by α − k·90° (k the corner's
    quarter turns), each step under 45°: the corner's cross is half-way along that turn."""
    alpha = np.radians(degrees)
    psi = corner_cross(alpha / 2, alpha)  # the interior bisector: counter-clockwise from 0

    def step(a, b):  # the shortest turn of a cross from angle a to angle b
        return (b - a + np.pi / 4) % (np.pi / 2) - np.pi / 4

    first, second = step(0.0, psi), step(psi, alpha)
    assert max(abs(first), abs(second)) < np.pi / 4
    assert first + second == pytest.approx(alpha - corner_quarter_turns(alpha) * np.pi / 2)
    assert first == pytest.approx(second)


def test_a_45_degree_corner_is_not_ambiguous():
    """45° is one quarter turn rounded either way; 135° stays ambiguous (1 or 2)."""
    check = index_theorem([], 1, np.radians([45, 135, 90]))
    assert check["ambiguous_corners"] == 1
    assert check["expected"] == 1 - (1 + 1 + 1) / 4
