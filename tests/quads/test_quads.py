"""Quantisation and quad extraction (``ufl_frames.param.quantise``,
``ufl_frames.quads.extract``), pure NumPy/SciPy.

Truth: fields whose integer-grid map is known. A constant frame on a rectangle: the map is
affine, U = n x / width, V = m y / height with n, m the rounded quad counts, so the quads
are the exact n × m grid (also on a mesh whose vertices lie on the grid lines, where every
line passes through vertices and along edges). The isotropic annulus field (r e_r, r e_θ):
U = a ln r + b, V = n θ / 2π, a structured polar grid of n_θ × n_r quads, all interior
vertices of valence 4, the quads' corners on circles r₀ (r₁/r₀)^{k/n_r} to O(h²).
Validity is checked by :func:`ufl_frames.quads.measures.check_quad_mesh`, written apart
from the extraction: conformity, orientation, area.
"""

import numpy as np
import pytest
from planar_meshes import annulus, annulus_field, assert_polar_grid, grid

from ufl_frames.frames2d import odeco
from ufl_frames.param import cut, quantise, seamless
from ufl_frames.quads import extract
from ufl_frames.quads.measures import check_quad_mesh, quad_quality


def constant_field(x, lengths=(1.0, 1.0)):
    return odeco.frames_to_q(np.tile([lengths], (x.shape[0], 1)), np.zeros(x.shape[0]))


def wobble(x, amount, width=2.0, height=1.0):
    """Move the interior vertices of a rectangle mesh, keep the boundary."""
    bump = x[:, :1] * (width - x[:, :1]) * x[:, 1:] * (height - x[:, 1:])
    return x + amount * np.sin(7 * x[:, ::-1]) * bump


@pytest.mark.parametrize("scale, mesh_wobble", [(3.3, 0.05), (4.0, 0.0), (2.6, 0.02)],
                         ids=["generic", "lines-through-vertices", "coarse"])
def test_rectangle_gives_the_exact_grid(scale, mesh_wobble):
    x, cells = grid(8, 6, 0, 2, 0, 1)
    x = wobble(x, mesh_wobble)
    mesh = cut.cut_mesh(x, cells, constant_field(x))
    grid_map = quantise.quantise(mesh, scale)
    n, m = int(np.rint(2 * scale)), int(np.rint(scale))
    assert grid_map.rounded >= 1
    quads = extract.extract_quads(grid_map)
    assert quads.num_quads == n * m
    assert check_quad_mesh(quads.points, quads.quads, area=2.0, rtol=1e-9) == []
    # the corners are the grid points (i 2/n, j/m), each once
    expected = np.stack(np.meshgrid(np.arange(n + 1) * 2 / n, np.arange(m + 1) / m,
                                    indexing="ij"), axis=-1).reshape(-1, 2)
    assert quads.points.shape == expected.shape
    distance = np.linalg.norm(quads.points[:, None] - expected[None], axis=2)
    assert distance.min(axis=0).max() < 1e-4 / scale  # fixed point: 2⁻¹⁶ of a quad
    assert np.unique(distance.argmin(axis=0)).size == expected.shape[0]
    quality = quad_quality(quads.points, quads.quads)
    assert quality["irregular_vertices"] == 0 and quality["min_sj"] > 1 - 1e-6


def test_rectangle_anisotropic_frames_set_the_two_counts():
    """Frames (l1, l2) = (1, 0.25): U advances s per unit length, V 4 s: quads 4 x thinner."""
    x, cells = grid(10, 10, 0, 2, 0, 1)
    mesh = cut.cut_mesh(x, cells, constant_field(x, (1.0, 0.25)))
    quads = extract.extract_quads(quantise.quantise(mesh, 1.5))
    counts = sorted([3 * 1, 1 * 6])  # 2·1.5 along x, 4·1.5 along y, in either labelling
    assert quads.num_quads == counts[0] * counts[1]
    assert check_quad_mesh(quads.points, quads.quads, area=2.0) == []


@pytest.mark.parametrize("scale", [2.0, 4.0, 6.0])
def test_annulus_gives_a_structured_polar_grid(scale):
    r0, r1 = 0.5, 1.0
    x, cells = annulus(12, 72, r0, r1)
    mesh = cut.cut_mesh(x, cells, annulus_field(x))
    grid_map = quantise.quantise(mesh, scale)
    n_theta, n_r = int(np.rint(2 * np.pi * scale)), int(np.rint(scale * np.log(r1 / r0)))
    seam = grid_map.values[grid_map.kinds == "seam"]
    assert set(np.abs(seam).astype(int)) <= {0, n_theta}  # the period across the cut
    quads = extract.extract_quads(grid_map)
    assert_polar_grid(quads, n_theta, n_r, r0, r1)


def test_too_coarse_grids_are_refused_or_repaired():
    """At s = 0.4 the annulus is 0.28 quads wide: rounding both circles to one line would
    collapse it, so the repair rounds one the other way (one layer of quads); with two
    quads around (s = 0.3) the straight quads cannot cover the annulus, which the
    independent check says. A field with no room at all is refused."""
    x, cells = annulus(8, 48)
    mesh = cut.cut_mesh(x, cells, annulus_field(x))
    grid_map = quantise.quantise(mesh, 0.4)
    assert grid_map.repaired >= 1
    radial = np.ptp(grid_map.param.uv, axis=0).min()
    assert radial == pytest.approx(1.0, abs=1e-6)
    quads = extract.extract_quads(grid_map)
    assert check_quad_mesh(quads.points, quads.quads) != []
    # the repair never produces a fold: it only keeps a trial with fewer folded triangles
    assert not seamless.folded(grid_map.param).any()


def test_a_close_pair_is_repaired_into_two_grid_vertices():
    """Two opposite singularities a quarter of a quad apart round onto one grid point
    (the map collapses); the repair rounds one the other way: a valid mesh with a
    valence-3 and a valence-5 vertex one quad apart (cut_mesh's cancellation off)."""
    x, cells = grid(20, 20, -1, 1, -1, 1)
    q = pair_field(x, (-0.11, 0.013), (0.12, 0.007))
    mesh = cut.cut_mesh(x, cells, q)
    assert sorted(mesh.turns.tolist()) == [-1, 1]
    grid_map = quantise.quantise(mesh, 1.0)
    assert grid_map.repaired >= 1
    quads = extract.extract_quads(grid_map)
    assert check_quad_mesh(quads.points, quads.quads, area=4.0) == []
    valence = quad_quality(quads.points, quads.quads)["interior_valence"]
    assert valence.get("3") == 1 and valence.get("5") == 1


def test_a_fold_free_map_winding_twice_around_a_vertex_is_invalid():
    """(U, V) = z² on a square around the origin has no folded triangle, yet its corner
    angles add up to 4π at the origin: only that vertex is miswound, and its triangles
    are invalid; the identity map is valid everywhere."""
    x, cells = grid(20, 20, -1, 1, -1, 1)
    mesh = cut.cut_mesh(x, cells, constant_field(x))
    vertex = np.zeros(mesh.num_wedges, dtype=np.int64)
    vertex[mesh.corners] = mesh.cells
    z = x[vertex, 0] + 1j * x[vertex, 1]
    identity = seamless.parametrisation(mesh, np.stack([z.real, z.imag], axis=1), 1.0)
    assert not seamless.invalid(identity).any()
    square = seamless.parametrisation(mesh, np.stack([(z**2).real, (z**2).imag], axis=1), 1.0)
    assert not seamless.folded(square).any()
    origin = int(np.flatnonzero(np.all(np.isclose(x, 0.0), axis=1))[0])
    assert np.flatnonzero(seamless.miswound(square)).tolist() == [origin]
    around = np.any(mesh.cells == origin, axis=1)
    assert np.array_equal(seamless.invalid(square), around)


def pair_field(x, plus, minus):
    """Frames turning by +1/4 around ``plus`` and −1/4 around ``minus`` (unit lengths)."""
    theta = (np.arctan2(x[:, 1] - plus[1], x[:, 0] - plus[0])
             - np.arctan2(x[:, 1] - minus[1], x[:, 0] - minus[0])) / 4
    return odeco.frames_to_q(np.ones((x.shape[0], 2)), theta)


def test_close_pairs_cancel():
    """cut_mesh(cancel_within=d): a ± pair closer than d is cancelled (no singular vertex
    left, no cut), its quarter turn carried along the path between them."""
    x, cells = grid(20, 20, -1, 1, -1, 1)
    q = pair_field(x, (-0.11, 0.013), (0.12, 0.007))
    kept = cut.cut_mesh(x, cells, q)
    assert sorted(kept.turns.tolist()) == [-1, 1] and kept.cancelled == 0
    cancelled = cut.cut_mesh(x, cells, q, cancel_within=0.5)
    assert cancelled.singular.size == 0 and cancelled.cancelled == 1
    assert cut.cut_mesh(x, cells, q, cancel_within=0.1).singular.size == 2


def test_quantised_functionals_are_integers_and_rounding_is_cheap():
    x, cells = annulus(12, 72)
    mesh = cut.cut_mesh(x, cells, annulus_field(x))
    grid_map = quantise.quantise(mesh, 6.0)
    F = grid_map.functionals
    values = F @ grid_map.param.uv.ravel()
    assert np.abs(values - np.rint(values)).max() < 1e-6
    # the rounding moves the radial count 6 ln 2 = 4.16 to 4: a small energy increase
    assert 0 < grid_map.energy_increase < 0.01


def test_scale_for_quad_size_gives_that_mean_edge():
    x, cells = grid(12, 12, 0, 2, 0, 1)
    mesh = cut.cut_mesh(x, cells, constant_field(x, (1.0, 0.5)))
    scale = seamless.scale_for_quad_size(mesh, 0.1)
    quads = extract.extract_quads(quantise.quantise(mesh, scale))
    mean = quad_quality(quads.points, quads.quads)["mean_edge_length"]
    assert mean == pytest.approx(0.1, rel=0.05)


def test_improving_the_worst_quads_restores_a_skewed_grid_and_never_worsens():
    """A structured grid with an interior vertex pushed until a quad inverts: the
    optimisation brings every quad back above SJ 0.8, keeps the boundary where it was,
    and on random perturbations never lowers the worst SJ (check_quad_mesh agrees)."""
    from ufl_frames.quads.improve import WORST_SJ, improve_worst_quads
    from ufl_frames.quads.measures import scaled_jacobians

    n = 8
    X, Y = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    x = np.stack([X.ravel(), Y.ravel()], axis=1)
    i = np.arange(x.shape[0]).reshape(n + 1, n + 1)
    q = np.stack([i[:-1, :-1], i[1:, :-1], i[1:, 1:], i[:-1, 1:]], axis=-1).reshape(-1, 4)
    interior = ((x > 0) & (x < 1)).all(axis=1)
    skewed = x.copy()
    skewed[i[3, 4]] += [0.1, 0.05]  # one of its quads inverted: SJ −0.45
    assert scaled_jacobians(skewed, q).min() < 0
    improved = improve_worst_quads(skewed, q)
    assert scaled_jacobians(improved, q).min() > WORST_SJ
    assert np.array_equal(improved[~interior], skewed[~interior])
    rng = np.random.default_rng(3)
    for _ in range(5):
        noisy = x.copy()
        noisy[interior] += rng.uniform(-0.04, 0.04, size=(interior.sum(), 2))
        before = scaled_jacobians(noisy, q).min()
        after = improve_worst_quads(noisy, q)
        assert scaled_jacobians(after, q).min() >= before - 1e-12
        assert check_quad_mesh(after, q, area=1.0) == []


def _disk_fan(n=64):
    """The unit disk as n triangles around its centre (node 0): its boundary a regular
    n-gon with a vertex at angle 0."""
    t = 2 * np.pi * np.arange(n) / n
    x = np.concatenate([[[0.0, 0.0]], np.stack([np.cos(t), np.sin(t)], axis=1)])
    k = np.arange(n)
    return x, np.stack([np.zeros(n, dtype=int), 1 + k, 1 + (k + 1) % n], axis=1)


def test_a_free_boundary_vertex_goes_where_its_edges_follow_the_boundary_best():
    """``onto_boundary``: a quad mesh of the unit disk (a square in the middle, eight quads
    around it, their outer vertices on the circle every 45°). The outer vertex at angle 0
    moved inside the disk, or along the circle to 22.5°, goes back to (1, 0): the middle
    of the arc between its neighbours at ±45°, where its two chords are longest together.
    On a straight boundary (a 2 × 1 box) a boundary vertex stays where it is along it, and
    one moved inside is put back onto it straight below. The mesh stays valid."""
    from ufl_frames.quads.improve import onto_boundary

    tri_x, tri_cells = _disk_fan()
    a = np.pi / 4 * np.arange(8)
    inner = 0.4 * np.stack([np.cos(a), np.sin(a)], axis=1) / np.maximum(
        np.abs(np.cos(a)), np.abs(np.sin(a)))[:, None]
    points = np.concatenate([[[0.0, 0.0]], inner, np.stack([np.cos(a), np.sin(a)], axis=1)])
    k = np.arange(8)
    quads = np.concatenate([
        np.stack([np.zeros(4, dtype=int), 1 + 2 * k[:4], 1 + (2 * k[:4] + 1) % 8,
                  1 + (2 * k[:4] + 2) % 8], axis=1),
        np.stack([1 + k, 9 + k, 9 + (k + 1) % 8, 1 + (k + 1) % 8], axis=1)])
    assert check_quad_mesh(points, quads) == []
    for moved in ([0.75, 0.05], [np.cos(np.pi / 8), np.sin(np.pi / 8)]):
        start = points.copy()
        start[9] = moved
        placed = onto_boundary(start, quads, [9], tri_x, tri_cells)
        assert placed[9] == pytest.approx([1.0, 0.0], abs=1e-12)
        assert np.array_equal(np.delete(placed, 9, axis=0), np.delete(start, 9, axis=0))
        assert check_quad_mesh(placed, quads) == []
    # a 2 × 1 box, triangles of a 4 × 2 grid; quads: two unit squares
    X, Y = np.meshgrid(np.linspace(0, 2, 5), np.linspace(0, 1, 3), indexing="ij")
    box = np.stack([X.ravel(), Y.ravel()], axis=1)
    i = np.arange(15).reshape(5, 3)
    box_cells = np.concatenate([np.stack([i[:-1, :-1], i[1:, :-1], i[1:, 1:]], -1).reshape(-1, 3),
                                np.stack([i[:-1, :-1], i[1:, 1:], i[:-1, 1:]], -1).reshape(-1, 3)])
    squares = np.array([[0.0, 0.0], [0.7, 0.0], [2.0, 0.0], [2.0, 1.0], [1.0, 1.0], [0.0, 1.0]])
    two = np.array([[0, 1, 4, 5], [1, 2, 3, 4]])
    assert onto_boundary(squares, two, [1], box, box_cells)[1] == pytest.approx([0.7, 0.0])
    inside = squares.copy()
    inside[1] = [0.7, 0.1]
    assert onto_boundary(inside, two, [1], box, box_cells)[1] == pytest.approx([0.7, 0.0])


def test_every_integer_point_of_the_map_is_one_quad_corner():
    """An independent count: the integer points of the fixed-point map found by brute force
    (every lattice point of each triangle's box, exact orientation tests), named by where
    they lie (a vertex; an edge and the parameter along it; inside a triangle), are the
    quads' corners, each once, at the place the triangle's affine map puts them."""
    from fractions import Fraction

    x, cells = grid(20, 20, -1, 1, -1, 1)
    mesh = cut.cut_mesh(x, cells, pair_field(x, (-0.11, 0.013), (0.12, 0.007)))
    grid_map = quantise.quantise(mesh, 2.0)
    assert mesh.cut.size > 0
    P, unit = extract.fixed_point(grid_map), extract.UNIT
    found = {}
    for f in range(cells.shape[0]):
        X = [tuple(int(c) for c in P[w]) for w in mesh.corners[f]]
        box = [range(-(-min(p[k] for p in X) // unit), max(p[k] for p in X) // unit + 1)
               for k in (0, 1)]
        for i in box[0]:
            for j in box[1]:
                # barycentric coordinates as exact fractions
                area = [(X[(k + 2) % 3][0] - X[(k + 1) % 3][0]) * (j * unit - X[(k + 1) % 3][1])
                        - (X[(k + 2) % 3][1] - X[(k + 1) % 3][1]) * (i * unit - X[(k + 1) % 3][0])
                        for k in range(3)]
                if min(area) < 0:
                    continue
                weights = [Fraction(a, sum(area)) for a in area]
                zero = [k for k in range(3) if area[k] == 0]
                if len(zero) == 2:
                    key = ("vertex", int(cells[f, 3 - sum(zero)]))
                elif len(zero) == 1:
                    a, b = sorted(int(cells[f, k]) for k in range(3) if k != zero[0])
                    key = ("edge", a, b, weights[list(cells[f]).index(b)])
                else:
                    key = ("inside", f, i, j)
                found[key] = sum(float(w) * x[v] for w, v in zip(weights, cells[f], strict=True))
    quads = extract.extract_quads(grid_map)
    assert quads.points.shape[0] == len(found)
    expected = np.array(list(found.values()))
    distance = np.linalg.norm(quads.points[:, None] - expected[None], axis=2)
    assert distance.min(axis=1).max() < 1e-12
    assert np.unique(distance.argmin(axis=1)).size == len(found)


def test_two_components_give_two_exact_grids():
    """Two rectangles apart, [0, 2] × [0, 1] and [3, 4] × [0, 1.5], with the constant
    frame: each its own map and anchor, each the exact grid of its size (8 × 4 and 4 × 6
    quads at scale 4), the quads conforming within each and covering the area."""
    x1, c1 = grid(8, 6, 0, 2, 0, 1)
    x2, c2 = grid(5, 7, 3, 4, 0, 1.5)
    x, cells = np.vstack([x1, x2]), np.vstack([c1, c2 + x1.shape[0]])
    mesh = cut.cut_mesh(x, cells, constant_field(x))
    assert mesh.cut.size == 0  # no singularity, no hole: each component a disk already
    grid_map = quantise.quantise(mesh, 4.0)
    quads = extract.extract_quads(grid_map)
    assert quads.num_quads == 8 * 4 + 4 * 6
    assert check_quad_mesh(quads.points, quads.quads, area=2.0 + 1.5, rtol=1e-9) == []
    left = quads.points[:, 0] < 2.5
    assert np.unique(np.round(quads.points[left, 0] * 4, 6)).size == 9
    assert np.unique(np.round(quads.points[~left, 1] * 4, 6)).size == 7


def test_one_factorisation_solves_every_weighted_constrained_map():
    """The quantisation's maps (rounded integers fixed, folded triangles weighted up) come
    from one factorisation and the Woodbury identity; the same minimiser, factorised
    anew with the weights (``seamless.weighted_solve``), agrees to round-off."""
    x, cells = grid(12, 12, -1, 1, -1, 1)
    mesh = cut.cut_mesh(x, cells, pair_field(x, (-0.4, 0.1), (0.45, -0.2)))
    system = seamless.SeamlessSystem(mesh, 2.0, quantise.anchor_wedges(mesh))
    F, kinds = quantise.integer_functionals(mesh)
    Fy = (F @ system.T).tocsr()
    distinct = quantise._distinct_rows(Fy)
    F_all, kinds = Fy[distinct], kinds[distinct]
    G_all = quantise._covariance(system.lu, F_all)
    phase = np.array([quantise._PHASE[k] for k in kinds])
    fixed, target = quantise._greedy(F_all @ system.y0, G_all, phase)  # independent rows
    Fk, G = F_all[fixed], G_all[np.ix_(fixed, fixed)]
    d = target[fixed] + np.arange(fixed.size) % 2
    assert fixed.size >= 4
    rng = np.random.default_rng(3)
    weight = np.ones(cells.shape[0])
    weight[rng.choice(cells.shape[0], 20, replace=False)] = 10.0 ** rng.integers(1, 4, 20)
    assert 4 * 20 <= seamless.WOODBURY_ROWS  # the update, not a new factorisation
    for w in (None, weight):
        direct = seamless.weighted_solve(system.AT, system.b,
                                         np.ones(cells.shape[0]) if w is None else w, Fk, d)
        y = system.solve(Fk, G, d, w)
        assert np.allclose(Fk @ y, d, atol=1e-9)
        assert np.abs(y - direct).max() < 1e-8 * np.abs(direct).max()
    assert np.allclose(system.solve(weight=weight),
                       seamless.weighted_solve(system.AT, system.b, weight), atol=1e-10)
