"""Size targets (:mod:`ufl_frames.mesh.sizes`): the safe expression reader, the target's
values against the formulas they come from, the quad-count factor against areas, and the
file's own sizes as Gmsh evaluates them (its size callback) against the sizes the file
sets (Distance/Threshold: the formula of Gmsh's documented Threshold field)."""

import math

import numpy as np
import pytest

from ufl_frames.mesh.sizes import (
    SizeExpressionError,
    SizeTarget,
    parse_size_expression,
    quad_count_factor,
    resolving_factor,
)


def test_expression_values():
    h = parse_size_expression("0.02 + 0.1*hypot(x, y)")
    x, y = np.array([0.0, 3.0, -1.0]), np.array([0.0, 4.0, 0.0])
    assert np.allclose(h(x, y), 0.02 + 0.1 * np.hypot(x, y))
    g = parse_size_expression("max(0.1, exp(-x**2) * sin(pi*y/2)) % 1 + e - e")
    assert np.allclose(g(x, y), np.maximum(0.1, np.exp(-x**2) * np.sin(np.pi * y / 2)) % 1)
    assert np.allclose(parse_size_expression("-(-2)")(x, y), 2.0)  # broadcast to the points


@pytest.mark.parametrize("text", [
    "__import__('os').system('true')",
    "os.system('true')",
    "x.__class__",
    "np.sys",
    "(lambda: 1)()",
    "[x for x in ()]",
    "x[0]",
    "'a' * 3",
    "open('/etc/passwd')",
    "eval('1')",
    "sqrt(x=1)",
    "sqrt(*x)",
    "x if y else 1",
    "x < y",
    "x and y",
    "z + 1",
    "True",
    "x; y",
    "import os",
    "",
    "1 +",
    "sqrt(" * 120 + "x" + ")" * 120,
    "-" * 500 + "x",
    "x" + " + x" * 600,
])
def test_unsafe_or_invalid_expressions_are_refused_in_one_line(text):
    with pytest.raises(SizeExpressionError) as info:
        parse_size_expression(text)
    message = str(info.value)
    assert message and "\n" not in message


def test_target_refuses_non_positive_sizes_in_one_line():
    target = SizeTarget.expression("x - 0.5")
    with pytest.raises(ValueError) as info:
        target(np.array([[1.0, 0.0], [0.25, 0.0]]))
    assert "\n" not in str(info.value) and "0.25" in str(info.value)


def test_uniform_callable_and_samples():
    points = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    assert np.all(SizeTarget.uniform()(points) == 1.0)
    function = SizeTarget.of_function(lambda x, y: 1 + x + 2 * y)
    assert np.allclose(function(points), [1, 2, 3, 4])
    # samples of h = exp(x + y): log h linear, so the interpolation is exact inside the
    # hull; outside it, the nearest sample
    grid = np.array([(a, b) for a in np.linspace(0, 1, 5) for b in np.linspace(0, 1, 5)])
    samples = np.column_stack([grid, np.exp(grid.sum(axis=1))])
    target = SizeTarget.of_samples(samples)
    inside = np.array([[0.3, 0.41], [0.9, 0.05]])
    assert np.allclose(target(inside), np.exp(inside.sum(axis=1)))
    assert target(np.array([[2.0, 2.0], [0.0, 0.0]]))[0] == pytest.approx(math.exp(2.0))


def test_samples_along_curves_interpolate_exactly():
    """Samples as a file's sizes come: many collinear points along a square's sides and
    cocircular ones on a circle (Qhull's degenerate case, triangulated joggled); a linear
    log h = x + 2y is reproduced inside, whichever triangulation is chosen, and the same
    on a second call (the triangulation kept)."""
    t = np.linspace(0, 1, 400, endpoint=False)
    square = np.concatenate([np.column_stack([t, 0 * t]), np.column_stack([1 + 0 * t, t]),
                             np.column_stack([1 - t, 1 + 0 * t]), np.column_stack([0 * t, 1 - t])])
    angle = 2 * np.pi * t
    circle = 0.5 + 0.3 * np.column_stack([np.cos(angle), np.sin(angle)])
    points = np.vstack([square, circle])
    target = SizeTarget.of_samples(np.column_stack([points, np.exp(points @ [1.0, 2.0])]))
    query = np.random.default_rng(3).uniform(0.01, 0.99, (500, 2))
    assert np.allclose(target(query), np.exp(query @ [1.0, 2.0]), rtol=1e-9)
    assert np.array_equal(target(query), target(query))


def test_quad_count_factor():
    """h = 1 on the unit square: N quads of side 1/√N, so the factor is 1/√N; with
    h = 1 + x (∫ 1/h² over the square = 1/2) the factor is √(1/(2N))."""
    n = 200
    x = (np.arange(n) + 0.5) / n
    areas = np.full(n, 1.0 / n)  # strips of the unit square
    assert quad_count_factor(np.ones(n), areas, 400) == pytest.approx(1 / 20)
    assert quad_count_factor(1 + x, areas, 400) == pytest.approx(math.sqrt(0.5 / 400),
                                                                  rel=1e-4)
    with pytest.raises(ValueError):
        quad_count_factor(np.ones(n), areas, 0)


def test_resolving_factor():
    """Triangles of edge e = 0.01 (4·10⁴ of area 2.5·10⁻⁵: the unit square) under a
    uniform h: N quads have edge 1/√N. 400 quads (edge 0.05) span 5 triangle edges: no
    refinement; 10⁴ quads (edge 0.01) span one: the triangles must shrink by 1/3 to span
    three. A target graded like the triangles (h ∝ e) gives the same factor everywhere;
    a few cells (under 5 %) coarser than the rest do not decide it."""
    m = 40_000
    edges, areas = np.full(m, 0.01), np.full(m, 1.0 / m)
    assert resolving_factor(np.ones(m), edges, areas, 400, per_edge=3) == 1.0
    assert resolving_factor(np.ones(m), edges, areas, 10_000, per_edge=3) == \
        pytest.approx(1 / 3)
    rng = np.random.default_rng(1)
    h = np.exp(rng.uniform(-3, 0, m))  # a decade and more of sizes, triangles graded alike
    graded = 0.01 * h / h.mean()
    c = quad_count_factor(h, areas, 10_000)
    assert resolving_factor(h, graded, areas, 10_000, per_edge=2) == \
        pytest.approx(min(1.0, c * h.mean() / 0.01 / 2))
    coarse = edges.copy()
    coarse[: m // 50] = 0.1  # 2 % of the cells ten times coarser
    assert resolving_factor(np.ones(m), coarse, areas, 10_000, per_edge=3) == \
        pytest.approx(1 / 3)
    with pytest.raises(ValueError):
        resolving_factor(np.ones(m), edges, areas, 400, per_edge=0)


GRADED = """
Point(1) = {0, 0, 0, 0.1}; Point(2) = {2, 0, 0, 0.1};
Point(3) = {2, 1, 0, 0.1}; Point(4) = {0, 1, 0, 0.1};
Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 1};
Curve Loop(1) = {1, 2, 3, 4}; Plane Surface(1) = {1};
Field[1] = Distance; Field[1].PointsList = {4};
Field[2] = Threshold; Field[2].InField = 1; Field[2].SizeMin = 0.01; Field[2].SizeMax = 0.1;
Field[2].DistMin = 0.05; Field[2].DistMax = 1.0;
Background Field = 2;
Mesh.MeshSizeExtendFromBoundary = 0; Mesh.MeshSizeFromPoints = 0;
"""


def threshold(d):
    """Gmsh's Threshold field (linear between DistMin and DistMax)."""
    t = np.clip((d - 0.05) / (1.0 - 0.05), 0.0, 1.0)
    return 0.01 + t * (0.1 - 0.01)


@pytest.mark.serial
def test_file_sizes_are_gmsh_s_threshold_field(tmp_path):
    gmsh = pytest.importorskip("gmsh")
    from ufl_frames.mesh.sizes import file_size_samples

    path = tmp_path / "graded.geo"
    path.write_text(GRADED)
    owns = not gmsh.isInitialized()
    if owns:
        gmsh.initialize(argv=[], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.open(str(path))
        samples = file_size_samples()
        gmsh.model.remove()
    finally:
        if owns:
            gmsh.finalize()
    assert samples is not None and len(samples) > 1000
    distance = np.hypot(samples[:, 0], samples[:, 1] - 1.0)
    assert np.allclose(samples[:, 2], threshold(distance), rtol=1e-6)
    target = SizeTarget.of_samples(samples)
    points = np.array([[0.3, 0.8], [1.5, 0.2], [0.02, 0.97]])
    expected = threshold(np.hypot(points[:, 0], points[:, 1] - 1.0))
    assert np.allclose(target(points), expected, rtol=0.05)
