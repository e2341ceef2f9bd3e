"""The T-mesh of a seamless map, its patches, integer arc lengths and quads
(``ufl_frames.quads.charts``, ``.motorcycles``, ``.layout``), pure NumPy/SciPy.

Truth: a constant frame integrates to an affine map on any mesh (exactly), so on a
rectangle there is no trace, one patch, and the quads are the exact round(2 s) × round(s)
grid; on an L-shape the concave corner continues its two boundary curves inward (two
traces), three square patches, the quads again the exact grid (also where the traces run
along mesh edges through vertices). The annulus field (r e_r, r e_θ): no singularity and no
corner, so one trace across the inner loop makes it one patch, n_θ × n_r quads on circles.
Fields with singular vertices: 4 − turn separatrices each, the patches counted by Euler's
formula (nodes − arcs + patches = 1 on a disk), the singular vertex a quad vertex of
valence 4 − turn; a valence-5 one a fraction of a quad from a straight side goes onto it
(three quads), a valence-3 one stays inside. Validity is checked by
:func:`ufl_frames.quads.measures.check_quad_mesh`, written apart from the layout:
conformity, orientation, area.
"""

import time
from dataclasses import replace

import numpy as np
import pytest
from planar_meshes import annulus, annulus_field, assert_polar_grid, grid
from test_quads import constant_field, pair_field, wobble

from ufl_frames.frames2d import odeco
from ufl_frames.param import cut, seamless
from ufl_frames.quads import charts, layout, motorcycles, patches
from ufl_frames.quads.measures import check_quad_mesh, quad_quality


def l_shape(n, amount=0.0):
    """[0, 2]² without [1, 2]², structured (n per unit), interior vertices wobbled."""
    x, cells = grid(2 * n, 2 * n, 0, 2, 0, 2)
    cells = cells[~(x[cells].mean(axis=1) > 1).all(axis=1)]
    used = np.unique(cells)
    remap = np.full(x.shape[0], -1)
    remap[used] = np.arange(used.size)
    x, cells = x[used], remap[cells]
    if amount:
        inside = ((x > 0) & (x < 2)).all(axis=1) & ~((x >= 1).all(axis=1)
                                                    & ((x[:, 0] == 1) | (x[:, 1] == 1)))
        x = x + inside[:, None] * amount * np.sin(7 * x[:, ::-1]) * x * (2 - x) / 4
    return x, cells


def grid_points(points, spacing):
    """Largest distance of the points to the lattice of the given spacings."""
    k = points / spacing
    return float(np.abs(k - np.rint(k)).max())


@pytest.mark.parametrize("scale, mesh_wobble", [(3.3, 0.05), (4.0, 0.0), (2.6, 0.02)],
                         ids=["generic", "lines-through-vertices", "coarse"])
def test_rectangle_is_one_patch_and_the_exact_grid(scale, mesh_wobble):
    x, cells = grid(8, 6, 0, 2, 0, 1)
    x = wobble(x, mesh_wobble)
    mesh = cut.cut_mesh(x, cells, constant_field(x))
    quads, lay, n = patches.quads_of_map(seamless.integrate(mesh, scale))
    assert lay.traces == [] and len(lay.patches) == 1 and len(lay.arcs) == 4
    W, H = int(np.rint(2 * scale)), int(np.rint(scale))
    assert sorted(n.tolist()) == sorted([W, W, H, H])
    assert quads.num_quads == W * H
    assert check_quad_mesh(quads.points, quads.quads, area=2.0, rtol=1e-9) == []
    assert grid_points(quads.points, np.array([2 / W, 1 / H])) < 1e-5  # fixed point: 2⁻²⁰
    assert np.unique(np.rint(quads.points * [W / 2, H]), axis=0).shape[0] == (W + 1) * (H + 1)
    quality = quad_quality(quads.points, quads.quads)
    assert quality["irregular_vertices"] == 0 and quality["min_sj"] > 1 - 1e-5


@pytest.mark.parametrize("amount", [0.0, 0.1], ids=["along-edges", "generic"])
def test_l_shape_corner_gives_two_traces_and_three_patches(amount):
    x, cells = l_shape(6, amount)
    mesh = cut.cut_mesh(x, cells, constant_field(x))
    scale = 3.3
    quads, lay, n = patches.quads_of_map(seamless.integrate(mesh, scale))
    corner = int(np.flatnonzero(np.all(x == 1.0, axis=1))[0])
    assert [t.start for t in lay.traces] == [("v", corner)] * 2
    assert all(t.stop == "boundary" for t in lay.traces)
    assert len(lay.patches) == 3 and len(lay.arcs) == 10 and len(lay.nodes) == 8
    assert len(lay.nodes) - len(lay.arcs) + len(lay.patches) == 1
    assert n.tolist() == [3] * 10  # every arc 3.3 long
    assert quads.num_quads == 27
    assert check_quad_mesh(quads.points, quads.quads, area=3.0, rtol=1e-9) == []
    assert grid_points(quads.points, 1 / 3) < 1e-5
    quality = quad_quality(quads.points, quads.quads)
    assert quality["interior_valence"] == {"4": 16} and quality["min_sj"] > 1 - 1e-5


@pytest.mark.parametrize("scale", [2.0, 4.0, 6.0])
def test_annulus_is_one_patch_across_the_seam(scale):
    r0, r1 = 0.5, 1.0
    x, cells = annulus(12, 72, r0, r1)
    mesh = cut.cut_mesh(x, cells, annulus_field(x))
    param = seamless.integrate(mesh, scale)
    quads, lay, n = patches.quads_of_map(param)
    assert len(lay.traces) == 1 and len(lay.patches) == 1 and len(lay.arcs) == 3
    radial = lay.traces[0]
    assert radial.stop == "boundary"
    n_r = int(np.rint(scale * np.log(r1 / r0)))
    around = [a.length for a in lay.arcs if a.boundary]
    assert around == pytest.approx([2 * np.pi * scale] * 2, rel=0.02)
    # as many edges round as the map's length, but at least as many as keep each edge's
    # chord within CHORD_SAGITTA of the quad size (2π r / length) off its circle
    n_theta = int(np.rint(around[0]))
    size = 2 * np.pi * r0 / around[0]
    while r0 * (1 - np.cos(np.pi / n_theta)) > patches.CHORD_SAGITTA * size:
        n_theta += 1
    assert n_theta == {2.0: 16, 4.0: 25, 6.0: 38}[scale]  # the coarsest one has more edges
    assert sorted(n.tolist()) == [n_r, n_theta, n_theta]
    assert_polar_grid(quads, n_theta, n_r, r0, r1)
    # without the bound: the map's own length round
    assert sorted(patches.integer_lengths(lay, sagitta=0).tolist()) == [n_r] + [
        int(np.rint(around[0]))] * 2


def quarter_field(x, centre=(-0.07, -0.13)):
    theta = np.arctan2(x[:, 1] - centre[1], x[:, 0] - centre[0])
    return odeco.frames_to_q(np.ones((x.shape[0], 2)), theta / 4)


def check_singular_layout(mesh, lay, quads, area, rtol=0.01):
    """Separatrices, Euler's formula, the singular vertices as quad vertices of valence
    4 − turn, validity."""
    for v, turn in zip(mesh.singular, mesh.turns, strict=True):
        leaving = [t for t in lay.traces if t.start == ("v", int(v))]
        arriving = [t for t in lay.traces if t.end == ("v", int(v)) and t.stop == "singular"]
        assert len(leaving) + len(arriving) == 4 - turn
    assert len(lay.nodes) - len(lay.arcs) + len(lay.patches) == 1
    assert check_quad_mesh(quads.points, quads.quads, area=area, rtol=rtol) == []
    valence = np.zeros(quads.points.shape[0], dtype=int)
    edges = np.unique(np.sort(np.stack([quads.quads, np.roll(quads.quads, -1, axis=1)],
                                       axis=-1).reshape(-1, 2), axis=1), axis=0)
    np.add.at(valence, edges.ravel(), 1)
    for v, turn in zip(mesh.singular, mesh.turns, strict=True):
        at = np.flatnonzero(np.linalg.norm(quads.points - mesh.x[v], axis=1) < 1e-12)
        assert at.size == 1 and valence[at[0]] == 4 - turn


@pytest.mark.parametrize("scale", [3.0, 6.0])
def test_a_quarter_singularity_has_three_separatrices(scale):
    x, cells = grid(16, 16, -1, 1, -1, 1)
    mesh = cut.cut_mesh(x, cells, quarter_field(x))
    assert mesh.turns.tolist() == [1]
    quads, lay, n = patches.quads_of_map(seamless.integrate(mesh, scale))
    assert sum(t.start == ("v", int(mesh.singular[0])) for t in lay.traces) == 3
    check_singular_layout(mesh, lay, quads, 4.0)
    interior = quad_quality(quads.points, quads.quads)["interior_valence"]
    assert interior.get("3") == 1 and set(interior) <= {"3", "4"}
    # per patch, opposite sides have equal integer lengths, every arc at least 1
    assert n.min() >= 1
    for sides in lay.patches:
        total = [sum(n[h // 2] for h in side) for side in sides]
        assert total[0] == total[2] and total[1] == total[3]


@pytest.mark.parametrize("scale", [1.0, 2.0, 4.0])
def test_a_close_pair_gives_valid_quads_without_repair(scale):
    """The ± pair a quarter of a quad apart that greedy rounding folds at s = 1
    (test_quads repairs it): on the T-mesh the quads are valid by construction."""
    x, cells = grid(20, 20, -1, 1, -1, 1)
    mesh = cut.cut_mesh(x, cells, pair_field(x, (-0.11, 0.013), (0.12, 0.007)))
    quads, lay, _ = patches.quads_of_map(seamless.integrate(mesh, scale))
    check_singular_layout(mesh, lay, quads, 4.0)
    interior = quad_quality(quads.points, quads.quads)["interior_valence"]
    assert interior.get("3") == 1 and interior.get("5") == 1


def test_fixed_point_charts_are_exact():
    """Every seam's transition is the same at both ends of each cut edge, in integers,
    and the values are the map's to 2⁻²⁰."""
    x, cells = grid(16, 16, -1, 1, -1, 1)
    mesh = cut.cut_mesh(x, cells, quarter_field(x))
    param = seamless.integrate(mesh, 3.0)
    P = charts.fixed_point(param)
    assert np.abs(P / charts.UNIT - (param.uv - param.uv[0])).max() < 2.0**-18
    for e in mesh.cut:
        f, g = mesh.faces[e]
        rot = seamless.quarter_turn(mesh.jump[e]).astype(np.int64)
        shifts = [P[seamless.wedge_of(mesh, g, v)] - rot @ P[seamless.wedge_of(mesh, f, v)]
                  for v in mesh.edges[e]]
        assert np.array_equal(shifts[0], shifts[1])


def test_a_map_running_backwards_along_the_boundary_is_untangled_by_sliding():
    """A boundary vertex moved along its iso-line past its neighbour folds the boundary's
    triangles (the map runs backwards there, as next to the sized airfoil's trailing
    edge): untangling slides it back along the boundary, keeping the boundary's constant
    coordinate, and the quads are the grid again."""
    x, cells = l_shape(6)
    mesh = cut.cut_mesh(x, cells, constant_field(x))
    param = seamless.integrate(mesh, 3.3)
    uv = param.uv.copy()
    v = int(np.flatnonzero(np.all(np.isclose(x, [0.5, 0.0]), axis=1))[0])  # bottom edge
    wedges = np.unique(mesh.corners[mesh.cells == v])
    assert wedges.size == 1
    right = int(np.flatnonzero(np.all(np.isclose(x, [0.5 + 1 / 6, 0.0]), axis=1))[0])
    step = param.uv[np.unique(mesh.corners[mesh.cells == right])[0]] - param.uv[wedges[0]]
    constant = int(np.argmin(np.abs(step)))  # the coordinate kept along y = 0
    assert abs(step[constant]) < 1e-9 and abs(step[1 - constant]) > 0.2
    before = param.uv[wedges[0]].copy()
    uv[wedges[0], 1 - constant] += 0.8  # past its neighbour, 3.3 / 6 along
    folded = seamless.parametrisation(mesh, uv, 3.3)
    assert np.count_nonzero(seamless.folded(folded)) > 0
    untangled, left = layout.untangle(folded)
    assert left == 0
    after = untangled.uv[wedges[0]]
    assert after[constant] == before[constant]  # still on the boundary's iso-line
    assert abs(after[1 - constant] - before[1 - constant]) < 0.05
    quads, lay, _ = patches.quads_of_map(folded)
    assert lay.folded.size == 0
    assert check_quad_mesh(quads.points, quads.quads, area=3.0, rtol=1e-9) == []
    assert quads.num_quads == 27


def test_a_folded_map_is_reported_or_untangled():
    """A trace that enters a folded triangle stops, and the layout says so; untangled (the
    folded region relaxed towards its neighbours' mean, here towards the affine map until
    nothing folds) the quads are the grid to within 2 % of a quad. A fold off the traces
    does not stop them: the layout lists it."""
    x, cells = l_shape(6)
    mesh = cut.cut_mesh(x, cells, constant_field(x))
    param = seamless.integrate(mesh, 3.3)
    uv = param.uv.copy()
    v = int(np.flatnonzero(np.all(np.isclose(x, [0.5, 1.0]), axis=1))[0])  # on a trace
    uv[mesh.corners[mesh.cells == v]] += [1.0, 0.0]  # past its neighbour at U = 2.2
    folded = seamless.parametrisation(mesh, uv, 3.3)
    count = int(np.count_nonzero(seamless.folded(folded)))
    assert count > 0
    with pytest.raises(charts.LayoutError, match="fold"):
        layout.layout(folded)
    quads, lay, _ = patches.quads_of_map(folded)
    assert lay.untangled == count and lay.folded.size == 0
    assert check_quad_mesh(quads.points, quads.quads, area=3.0, rtol=1e-9) == []
    assert quads.num_quads == 27 and grid_points(quads.points, 1 / 3) < 0.02
    uv = param.uv.copy()
    v = int(np.flatnonzero(np.all(np.isclose(x, [0.5, 1.0 + 1 / 6]), axis=1))[0])
    uv[mesh.corners[mesh.cells == v]] += [0.0, -1.2]
    folded = seamless.parametrisation(mesh, uv, 3.3)
    lay = layout.layout(folded)
    assert np.array_equal(lay.folded, np.flatnonzero(seamless.folded(folded)))
    quads, unlocated = patches.patch_quads(lay, patches.integer_lengths(lay))
    assert unlocated == 0  # the patch's points walked around the fold
    assert check_quad_mesh(quads.points, quads.quads, area=3.0, rtol=1e-3) == []


def test_a_trace_that_does_not_end_is_reported():
    x, cells = annulus(8, 48)
    mesh = cut.cut_mesh(x, cells, annulus_field(x))
    param = seamless.integrate(mesh, 3.0)
    tracer = motorcycles.Motorcycles(param, max_steps=3)
    with pytest.raises(charts.LayoutError, match="does not end"):
        layout.layout(param, tracer)


def test_larger_map_is_fast():
    """A 60 × 60 mesh (7200 triangles) with a ± pair at s = 8: under a few seconds."""
    x, cells = grid(60, 60, -1, 1, -1, 1)
    mesh = cut.cut_mesh(x, cells, pair_field(x, (-0.31, 0.013), (0.32, 0.107)))
    param = seamless.integrate(mesh, 8.0)
    start = time.perf_counter()
    quads, lay, _ = patches.quads_of_map(param)
    assert time.perf_counter() - start < 10.0
    check_singular_layout(mesh, lay, quads, 4.0)


def slit(nx=8, ny=4):
    """[0, 2] × [0, 1] with a slit along y = 1/2 from x = 0 to 1 (its points doubled)."""
    x, cells = grid(nx, ny, 0, 2, 0, 1)
    below = x[cells].mean(axis=1)[:, 1] < 0.5
    on = np.flatnonzero(np.isclose(x[:, 1], 0.5) & (x[:, 0] < 1 - 1e-9))
    copy = np.full(x.shape[0], -1)
    copy[on] = x.shape[0] + np.arange(on.size)
    lower = cells[below]
    cells = cells.copy()
    cells[below] = np.where(copy[lower] >= 0, copy[lower], lower)
    return np.concatenate([x, x[on]]), cells


def test_a_slit_tip_continues_three_ways():
    """The slit's tip is a boundary vertex whose fan turns by 360°: three traces (on
    along the slit's line, and both ways across it), four patches of 3 × 2 quads; the
    slit's two sides are boundary with their own points (the only coinciding ones)."""
    x, cells = slit()
    mesh = cut.cut_mesh(x, cells, constant_field(x))
    quads, lay, n = patches.quads_of_map(seamless.integrate(mesh, 3.3))
    tip = int(np.flatnonzero(np.all(np.isclose(x, [1.0, 0.5]), axis=1))[0])
    assert [t.start for t in lay.traces] == [("v", tip)] * 3
    assert len(lay.patches) == 4 and quads.num_quads == 24
    problems = check_quad_mesh(quads.points, quads.quads, area=2.0, rtol=1e-6)
    assert len(problems) == 1 and problems[0].startswith("3 pairs of points coincide")
    distance = np.linalg.norm(quads.points[:, None] - quads.points[None], axis=2)
    i, j = np.nonzero(np.triu(distance < 1e-9, k=1))
    assert i.size == 3
    assert np.allclose(quads.points[i, 1], 0.5) and quads.points[i, 0].max() < 1.0
    assert grid_points(quads.points, np.array([1 / 3, 1 / 4])) < 1e-5


def disk(n):
    """The unit disk: rings of points (about 2π k on ring k), Delaunay triangles."""
    from scipy.spatial import Delaunay

    rings = [np.zeros((1, 2))]
    for k in range(1, n + 1):
        t = np.arange(max(6, round(2 * np.pi * k))) * 2 * np.pi / max(6, round(2 * np.pi * k))
        rings.append(k / n * np.stack([np.cos(t + 0.3 * k), np.sin(t + 0.3 * k)], axis=1))
    x = np.concatenate(rings)
    return x, Delaunay(x).simplices


def disk_field(x, r0=0.5, turn=0.1):
    """Frames turning by 4θ along the circle (aligned with it to within 2°), with four
    +1/4 singularities at radius r0: 4 × angle = arg of a degree-4 Blaschke product."""
    z = x[:, 0] + 1j * x[:, 1]
    a = r0 * np.exp(1j * (np.pi / 2 * np.arange(4) + turn))
    B = np.prod([(z - ak) / (1 - np.conj(ak) * z) for ak in a], axis=0)
    return odeco.frames_to_q(np.ones((x.shape[0], 2)), np.angle(B) / 4)


def test_four_singularities_in_a_disk_line_up_by_collapsing_thin_patches():
    """Four valence-3 singular vertices whose separatrices pass each other a fraction of
    a quad apart: with every arc at least 1 the thin patches between them get a layer of
    quads each; collapsed (arcs shorter than half a quad may be 0) the separatrices join.
    The singular vertices are the only irregular interior vertices, the quads valid, and
    better still with the worst quads improved (quads.improve)."""
    from ufl_frames.quads.improve import improve_worst_quads

    x, cells = disk(24)
    mesh = cut.cut_mesh(x, cells, disk_field(x))
    assert mesh.turns.tolist() == [1, 1, 1, 1]
    param = seamless.integrate(mesh, 6.0)
    lay = layout.layout(param)
    assert len(lay.nodes) - len(lay.arcs) + len(lay.patches) == 1
    thin = lay.lengths() < 0.5
    assert thin.any()
    assert patches.integer_lengths(lay, collapse_below=0).min() >= 1
    n = patches.integer_lengths(lay)
    assert np.all(n[thin] == 0) and np.all(n[~thin] >= 1)
    quads, _ = patches.patch_quads(lay, n)
    interior = quad_quality(quads.points, quads.quads)["interior_valence"]
    assert interior.get("3") == 4 and set(interior) == {"3", "4"}
    check_singular_layout(mesh, lay, quads, np.pi, rtol=0.02)
    improved = replace(quads, points=improve_worst_quads(quads.points, quads.quads))
    # the boundary polygon of some 38 chords (not uniform in length) loses 1.2 % of π
    assert check_quad_mesh(improved.points, quads.quads, area=np.pi, rtol=0.02) == []
    assert quad_quality(improved.points, quads.quads)["min_sj"] > 0.5


def test_a_strip_thinner_than_half_a_quad_keeps_one_layer():
    """A 2 × 0.1 strip at 3.3 quads per unit is 0.33 quads high: collapsing it would
    glue its two boundary sides (the domain lost), so it keeps one layer of 7 quads."""
    x, cells = grid(20, 2, 0, 2, 0, 0.1)
    mesh = cut.cut_mesh(x, cells, constant_field(x))
    quads, lay, n = patches.quads_of_map(seamless.integrate(mesh, 3.3))
    assert sorted(n.tolist()) == [1, 1, 7, 7]
    assert check_quad_mesh(quads.points, quads.quads, area=0.2, rtol=1e-9) == []


@pytest.mark.parametrize("amount", [0.0, 0.05], ids=["along-edges", "generic"])
def test_a_square_hole_gives_eight_patches(amount):
    """[0, 3]² without [1, 2]²: each corner of the hole is concave (270° in the domain)
    and continues both its sides to the outer boundary: 8 traces, 8 patches (Euler's
    formula on an annulus: nodes − arcs + patches = 0), the exact grid across the cut."""
    x, cells = grid(12, 12, 0, 3, 0, 3)
    middle = x[cells].mean(axis=1)
    cells = cells[~((middle > 1) & (middle < 2)).all(axis=1)]
    used = np.unique(cells)
    remap = np.full(x.shape[0], -1)
    remap[used] = np.arange(used.size)
    x, cells = x[used], remap[cells]
    on_hole = np.isclose(np.abs(x - 1.5).max(axis=1), 0.5)
    x = x + amount * (~on_hole)[:, None] * np.sin(5 * x[:, ::-1] + 1) * \
        (x * (3 - x)).prod(axis=1, keepdims=True) / 4
    mesh = cut.cut_mesh(x, cells, constant_field(x))
    assert mesh.paths == 1
    quads, lay, n = patches.quads_of_map(seamless.integrate(mesh, 2.2))
    assert len(lay.traces) == 8 and all(t.stop == "boundary" for t in lay.traces)
    assert len(lay.patches) == 8 and len(lay.nodes) - len(lay.arcs) + len(lay.patches) == 0
    assert n.tolist() == [2] * 24 and quads.num_quads == 32
    assert check_quad_mesh(quads.points, quads.quads, area=8.0, rtol=1e-9) == []
    assert grid_points(quads.points, 0.5) < 1e-5


@pytest.mark.parametrize("seed", [101, 110, 128])
def test_random_pairs_of_singularities_give_valid_quads(seed):
    """1 to 3 ± pairs at random on a wobbled square mesh, a random scale: the seamless
    map is fold-free, so the layout exists, every singular vertex is a quad vertex of
    valence 4 − turn, and with the worst quads improved (quads.improve) the mesh is
    valid."""
    from ufl_frames.quads.improve import improve_worst_quads

    rng = np.random.default_rng(seed)
    k = rng.integers(1, 4)
    centres, signs = rng.uniform(-0.8, 0.8, (2 * k, 2)), np.array([1, -1] * k)
    x, cells = grid(40, 40, -1, 1, -1, 1)
    x = wobble(x + 1, 0.05, 2, 2) - 1
    theta = sum(s * np.arctan2(x[:, 1] - c[1], x[:, 0] - c[0])
                for s, c in zip(signs, centres, strict=True)) / 4
    mesh = cut.cut_mesh(x, cells, odeco.frames_to_q(np.ones((x.shape[0], 2)), theta))
    param = seamless.integrate(mesh, rng.uniform(2, 10))
    assert not seamless.folded(param).any()
    quads, lay, n = patches.quads_of_map(param)
    assert len(lay.nodes) - len(lay.arcs) + len(lay.patches) == 1
    for v, turn in zip(mesh.singular, mesh.turns, strict=True):
        at = np.flatnonzero(np.linalg.norm(quads.points - mesh.x[v], axis=1) < 1e-12)
        assert at.size == 1
        assert np.count_nonzero(quads.quads == at[0]) == 4 - turn
    points = improve_worst_quads(quads.points, quads.quads)
    assert check_quad_mesh(points, quads.quads, area=4.0, rtol=0.01) == []


@pytest.mark.parametrize("case", ["pair-1", "pair-2", "quarter", "pair-wide", "annulus"])
def test_an_integer_grid_map_gives_the_extracted_quads(case):
    """On the integer-grid map of the greedy quantisation (param.quantise) every trace runs
    on an integer line: into other singular vertices, along other traces, through mesh
    vertices, the exact coincidences a seamless map avoids. Its layout's arcs have integer
    lengths, and its quads are those that quads.extract traces out of the same map: the
    same points (to fixed point) and the same quads."""
    from ufl_frames.param import quantise
    from ufl_frames.quads import extract

    if case == "annulus":
        x, cells = annulus(12, 72)
        q, scale = annulus_field(x), 4.0
    elif case == "quarter":
        x, cells = grid(16, 16, -1, 1, -1, 1)
        q, scale = quarter_field(x), 3.0
    else:
        wide = case == "pair-wide"
        x, cells = grid(30 if wide else 20, 30 if wide else 20, -1, 1, -1, 1)
        plus, minus = ((-0.31, 0.013), (0.32, 0.107)) if wide else ((-0.11, 0.013),
                                                                     (0.12, 0.007))
        q, scale = pair_field(x, plus, minus), {"pair-1": 1.0, "pair-2": 2.0}.get(case, 4.0)
    grid_map = quantise.quantise(cut.cut_mesh(x, cells, q), scale)
    expected = extract.extract_quads(grid_map)
    quads, lay, n = patches.quads_of_map(grid_map.param)
    assert np.allclose(lay.lengths(), n, atol=1e-5)
    if case in ("pair-1", "pair-2"):  # the pair on one integer line: a trace between them
        assert [t.stop for t in lay.traces].count("singular") == 1
    assert quads.points.shape == expected.points.shape
    distance = np.linalg.norm(quads.points[:, None] - expected.points[None], axis=2)
    match = distance.argmin(axis=1)
    assert distance.min(axis=1).max() < 1e-4 / scale
    assert np.unique(match).size == match.size
    ours = {tuple(sorted(quad)) for quad in match[quads.quads].tolist()}
    assert ours == {tuple(sorted(quad)) for quad in expected.quads.tolist()}


def test_two_components_each_get_their_grid():
    """Two rectangles apart, [0, 2] × [0, 1] and [3, 4] × [0, 1], in one mesh: one cut mesh
    with a map anchored on each component, a patch each, 7 × 3 and 3 × 3 quads."""
    a, cells_a = grid(8, 4, 0, 2, 0, 1)
    b, cells_b = grid(4, 4, 3, 4, 0, 1)
    x, cells = np.concatenate([a, b]), np.concatenate([cells_a, cells_b + a.shape[0]])
    mesh = cut.cut_mesh(x, cells, constant_field(x))
    quads, lay, _ = patches.quads_of_map(seamless.integrate(mesh, 3.3))
    assert len(lay.patches) == 2
    assert quads.num_quads == 21 + 9
    assert check_quad_mesh(quads.points, quads.quads, area=3.0, rtol=1e-9) == []
    left = quads.points[:, 0] < 2.5
    assert grid_points(quads.points[left], np.array([2 / 7, 1 / 3])) < 1e-5
    assert grid_points(quads.points[~left] - [3, 0], 1 / 3) < 1e-5


def test_anisotropic_frames_set_the_two_counts():
    """Frames (l1, l2) = (1, 0.25) on [0, 2] × [0, 1] at s = 1.5: U advances 1.5 per unit
    length, V 6: one patch of 3 × 6 quads (in either labelling), each 2/3 × 1/6."""
    x, cells = grid(10, 10, 0, 2, 0, 1)
    mesh = cut.cut_mesh(x, cells, constant_field(x, (1.0, 0.25)))
    quads, lay, n = patches.quads_of_map(seamless.integrate(mesh, 1.5))
    assert len(lay.patches) == 1 and sorted(n.tolist()) == [3, 3, 6, 6]
    assert quads.num_quads == 18
    assert check_quad_mesh(quads.points, quads.quads, area=2.0, rtol=1e-9) == []
    assert grid_points(quads.points, np.array([2 / 3, 1 / 6])) < 1e-5


def wall_pair_field(x, near, far, sign):
    """Frames turning by ``sign``/4 around ``near`` and −``sign``/4 around ``far``, each
    with its mirror image in the wall y = −1 (so the frames are aligned with it)."""
    z = x[:, 0] + 1j * x[:, 1]
    theta = 0.0
    for c, s in ((near, sign), (far, -sign)):
        theta = theta + s * (np.angle(z - complex(c[0], c[1]))
                             + np.angle(z - complex(c[0], -2 - c[1])))
    return odeco.frames_to_q(np.ones((x.shape[0], 2)), theta / 4)


@pytest.mark.parametrize("sign, s", [(-1, 4.0), (1, 2.0)], ids=["valence-5", "valence-3"])
def test_a_singular_vertex_near_the_boundary(sign, s, monkeypatch):
    """A singular vertex 0.05 from the straight side y = −1 (its partner far inside), at s
    quads per unit: its separatrix to the side is shorter than half a quad, so the thin
    patches beside it may collapse and glue it to the side. Turn −1 (valence 5, s = 4):
    two separatrices run along the side 0.2 quads away; the thin patches collapse, the
    singular vertex goes onto the side as a boundary vertex in three quads (about 60°
    each), and no quad edge is shorter than 0.35 of a quad (the sliver layer is gone).
    Turn +1 (valence 3, s = 2): on the side it would be one quad with a 180° corner (as
    it is with the fan rule off), so the collapse is refused: the vertex stays a
    valence-3 vertex inside, the quads valid."""
    d = 0.05
    x, cells = grid(40, 40, -1, 1, -1, 1)
    mesh = cut.cut_mesh(x, cells, wall_pair_field(x, (0.013, -1 + d), (0.02, 0.4), sign))
    near = int(mesh.singular[np.argmin(mesh.x[mesh.singular, 1])])
    assert mesh.turns[list(mesh.singular).index(near)] == sign
    assert np.isclose(mesh.x[near, 1], -1 + d)
    param = seamless.integrate(mesh, s)
    quads, lay, n = patches.quads_of_map(param)
    to_side = [a for a, arc in enumerate(lay.arcs) if lay.nodes[arc.start] == ("v", near)
               and lay.nodes[arc.end][0] == "e" and arc.length < patches.COLLAPSE_BELOW]
    assert len(to_side) == 1  # a collapse onto the side is possible
    assert check_quad_mesh(quads.points, quads.quads, area=4.0, rtol=0.01) == []
    P, Q = quads.points, quads.quads
    at = np.flatnonzero(np.linalg.norm(P - mesh.x[near], axis=1) < 1e-12)
    assert quad_quality(P, Q)["min_sj"] >= 0.5
    if sign == -1:
        assert at.size == 0 and n[to_side[0]] == 0 and np.count_nonzero(n == 0) == 3
        on_side = np.flatnonzero((np.abs(P[:, 1] + 1) < 1e-9)
                                 & (np.abs(P[:, 0] - mesh.x[near, 0]) < 0.5 / s))
        assert on_side.size == 1 and np.count_nonzero(Q == on_side[0]) == 3
        edges = np.linalg.norm(P[Q] - P[np.roll(Q, -1, axis=1)], axis=-1)
        assert edges.min() * s > 0.35
    else:
        assert at.size == 1 and np.count_nonzero(Q == at[0]) == 3 and n[to_side[0]] == 1
        monkeypatch.setattr(patches, "FAN_ANGLES", (0.0, 360.0))  # any fan
        n = patches.integer_lengths(lay)
        assert n[to_side[0]] == 0
        glued, _ = patches.patch_quads(lay, n)
        assert quad_quality(glued.points, glued.quads)["min_sj"] < 0.05


@pytest.mark.parametrize("side", ["up", "right"])
def test_a_concave_corner_the_map_folds_shut_is_named(side):
    """The map can fold at a concave corner with none of the corner's own triangles
    inverted: its boundary runs backwards next to the corner, so the map turns 1 quarter
    there where the domain turns 3 (gmsh_full_quad at 400 quads, issue 37: a 60° rotated
    hole's corner). The tracer then takes the corner as convex and starts no trace from
    it: a face with a corner of 3 quarter turns, or one turning past the outside. The
    refusal names the corner and both counts (the old one gave only the face)."""
    x, cells = l_shape(6)
    mesh = cut.cut_mesh(x, cells, constant_field(x))
    param = seamless.integrate(mesh, 3.3)
    corner = int(np.flatnonzero(np.all(np.isclose(x, [1.0, 1.0]), axis=1))[0])
    (at_corner,) = np.unique(mesh.corners[mesh.cells == corner])
    beside = [1.0, 1 + 1 / 6] if side == "up" else [1 + 1 / 6, 1.0]
    v = int(np.flatnonzero(np.all(np.isclose(x, beside), axis=1))[0])
    (w,) = np.unique(mesh.corners[mesh.cells == v])
    step = param.uv[w] - param.uv[at_corner]
    c = int(np.argmax(np.abs(step)))  # the coordinate that runs along this side
    uv = param.uv.copy()
    uv[w, c] = param.uv[at_corner, c] - 0.3 * np.sign(step[c])  # behind the corner
    folded = seamless.parametrisation(mesh, uv, 3.3)
    assert seamless.wrong_corners(param) == []
    assert (corner, 1, 3) in seamless.wrong_corners(folded)
    with pytest.raises(charts.LayoutError,
                       match=r"the map turns 1 quarter turn where the domain turns 3 at the "
                             r"boundary vertex \(1, 1\)"):
        layout.layout(folded)
