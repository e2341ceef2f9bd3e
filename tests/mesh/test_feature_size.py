"""The local feature size (:mod:`ufl_frames.mesh.feature_size`): widths and caps of
analytic shapes (a strip of known width, a disc, a wedge), the graded cap against its
formula, and the default mesh of files with a thin neck and a tight nose (serial and MPI).
"""

import math
from pathlib import Path

import numpy as np
import pytest

from ufl_frames.bootstrap import init_petsc

init_petsc([])  # not pytest's command line

from mpi4py import MPI  # noqa: E402

from ufl_frames.mesh import load  # noqa: E402
from ufl_frames.mesh.feature_size import (  # noqa: E402
    ELEMENTS_ACROSS,
    FLOOR_SHARE,
    GRADING,
    POINTS_PER_TURN,
    FeatureSize,
    Samples,
    extra_triangles,
    feature_caps,
    widths,
)

COMM = MPI.COMM_WORLD
AIRFOIL = Path(__file__).parents[2] / "benchmarks" / "shapes" / "airfoil_box.geo"


def polygon_samples(corners, spacing):
    """:class:`Samples` of a closed polygon, one line curve per side, model point k at
    corner k."""
    parts = []
    m = len(corners)
    ends = np.array([[k, (k + 1) % m] for k in range(m)])
    for k in range(m):
        a, b = np.asarray(corners[k], float), np.asarray(corners[(k + 1) % m], float)
        length = float(np.linalg.norm(b - a))
        n = max(int(math.ceil(length / spacing)) + 1, 3)
        s = np.linspace(0.0, length, n)
        parts.append((a + np.outer(s / length, b - a), np.full(n, k), s, np.full(n, length),
                      np.zeros(n), np.gradient(s)))
    f = [np.concatenate([p[i] for p in parts]) for i in range(6)]
    return Samples(f[0], f[1], f[2], f[3], f[4], ends, np.zeros(m, dtype=bool), f[5])


def in_polygon(corners):
    from matplotlib.path import Path as MplPath

    path = MplPath(np.asarray(corners, float))
    return lambda p: path.contains_points(np.asarray(p).reshape(-1, 2))


def test_strip_width_is_its_width_and_its_ends_are_not_thin():
    length, w = 4.0, 0.1
    corners = [(0, 0), (length, 0), (length, w), (0, w)]
    s = polygon_samples(corners, 0.01)
    t = widths(s, in_polygon(corners), reach=1.0)
    x, y = s.points.T
    sides = (np.abs(y) < 1e-12) | (np.abs(y - w) < 1e-12)
    middle = sides & (x > 2 * w) & (x < length - 2 * w)
    assert np.all(np.abs(t[middle] - w) <= 1e-9 + 0.5 * 0.01**2 / w)  # nearest sample across
    ends = (np.abs(x) < 1e-12) | (np.abs(x - length) < 1e-12)
    assert np.all(np.isinf(t[ends & ~sides]))  # across an end is the strip's length
    caps = feature_caps(s, in_polygon(corners), reference=0.2)
    assert np.allclose(caps[middle], w / ELEMENTS_ACROSS, rtol=1e-3)


def test_square_and_open_wedge_are_not_thin_but_a_sharp_wedge_is():
    square = [(0, 0), (1, 0), (1, 1), (0, 1)]
    s = polygon_samples(square, 0.02)
    assert np.all(np.isinf(widths(s, in_polygon(square), reach=0.9)))  # reach < the side
    t = widths(s, in_polygon(square), reach=2.0)  # across: the opposite side, 1 away
    assert np.all(np.abs(t - 1.0) <= 0.5 * 0.02**2 + 1e-12)
    for angle, thin in ((60.0, False), (30.0, True)):
        a = math.radians(angle)
        wedge = [(0, 0), (1, 0), (math.cos(a), math.sin(a))]
        s = polygon_samples(wedge, 0.01)
        t = widths(s, in_polygon(wedge), reach=0.5)
        x, y = s.points.T
        near_tip = (np.hypot(x, y) > 0.1) & (np.hypot(x, y) < 0.3) & (s.curve != 1)
        if thin:  # across the wedge: 2 r sin(α/2) from a point at r on the other side
            r = np.hypot(x, y)[near_tip]
            assert np.all(np.abs(t[near_tip] - 2 * r * math.sin(a / 2)) < 0.02)
        else:
            assert np.all(np.isinf(t[near_tip]))


def test_curvature_cap_and_floor():
    n = 200
    u = np.linspace(0, 2 * np.pi, n)
    radius = 0.05
    s = Samples(np.c_[radius * np.cos(u), radius * np.sin(u)], np.zeros(n, dtype=np.int64),
                radius * u, np.full(n, 2 * np.pi * radius), np.full(n, 1 / radius),
                np.array([[-1, -1]]), np.array([True]), np.full(n, 2 * np.pi * radius / n))
    disc = lambda p: np.hypot(*np.asarray(p).reshape(-1, 2).T) < radius  # noqa: E731
    caps = feature_caps(s, disc, reference=0.5)  # the disc itself is not thin
    assert np.allclose(caps, 2 * np.pi * radius / POINTS_PER_TURN)
    caps = feature_caps(s, disc, reference=100.0)
    assert np.allclose(caps, FLOOR_SHARE * 100.0)


def test_graded_cap_is_its_formula_and_pruning_keeps_it():
    rng = np.random.default_rng(3)
    points = rng.uniform(-1, 1, (300, 2))
    caps = rng.uniform(0.01, 0.5, 300)
    field = FeatureSize.of(points, caps)
    x, y = rng.uniform(-2, 2, (2, 500))
    exact = np.min(caps + GRADING * np.hypot(x[:, None] - points[:, 0],
                                             y[:, None] - points[:, 1]), axis=1)
    got = field(x, y)
    assert len(field.caps) < len(caps)
    assert np.all(got >= exact - 1e-12) and np.all(got <= 1.1 * exact + 1e-12)
    assert np.isinf(FeatureSize.of(points, caps, below=0.005)(0.0, 0.0))  # none kept


def test_extra_triangles_of_a_strip_against_the_integral():
    # One side of a straight boundary of length 10, cap c graded to size h: the added
    # area per length is ∫_0^ρ (1/(c + g r)² − 1/h²) dr, ρ = (h − c)/g.
    c, h, g = 0.01, 0.1, GRADING
    r = np.linspace(0, (h - c) / g, 200_001)
    integrand = 1 / (c + g * r) ** 2 - 1 / h**2
    per_length = float(np.sum(0.5 * (integrand[1:] + integrand[:-1]) * np.diff(r)))
    got = extra_triangles(np.full(1001, c), np.full(1001, 0.01), h)
    assert got == pytest.approx(10.01 * per_length / (math.sqrt(3) / 4), rel=1e-6)


NECK = """SetFactory("OpenCASCADE");
Rectangle(1) = {0, 0, 0, 1, 1};
Rectangle(2) = {2, 0, 0, 1, 1};
Rectangle(3) = {0.9, 0.475, 0, 1.2, 0.05};
BooleanUnion{ Surface{1}; Delete; }{ Surface{2, 3}; Delete; }
"""


def neck_edges(domain, x_lo, x_hi, y_lo, y_hi):
    """The edge lengths of the triangles (all ranks' owned ones) whose centroid lies in
    the box."""
    mesh = domain.mesh
    owned = mesh.topology.index_map(2).size_local
    cells = mesh.geometry.dofmaps[0][:owned]
    p = mesh.geometry.x[cells][:, :, :2]
    c = p.mean(axis=1)
    inside = (c[:, 0] > x_lo) & (c[:, 0] < x_hi) & (c[:, 1] > y_lo) & (c[:, 1] < y_hi)
    p = p[inside]
    local = np.linalg.norm(p - np.roll(p, 1, axis=1), axis=2).ravel()
    return np.concatenate(COMM.allgather(local))


def test_a_thin_neck_gets_three_elements_across_at_the_default_size(tmp_path):
    path = tmp_path / "neck.geo"
    if COMM.rank == 0:
        path.write_text(NECK)
    COMM.Barrier()
    w = 0.05
    default = load(COMM, path)
    edges = neck_edges(default, 1.3, 1.7, 0.475, 0.525)
    assert np.median(edges) <= 1.25 * w / ELEMENTS_ACROSS
    assert any("local feature size" in note for note in default.notes)
    # An explicit size is the user's: not capped (the automatic size here is ~0.048).
    explicit = load(COMM, path, mesh_size=0.048)
    assert np.median(neck_edges(explicit, 1.3, 1.7, 0.475, 0.525)) > w / 2
    assert not any("local feature size" in note for note in explicit.notes)
    # A size taken from the quads' (``resolve_features``) is capped as the default is.
    resolved = load(COMM, path, mesh_size=0.048, resolve_features=True)
    assert np.median(neck_edges(resolved, 1.3, 1.7, 0.475, 0.525)) <= 1.25 * w / ELEMENTS_ACROSS
    assert any("local feature size" in note for note in resolved.notes)
    # Away from the neck the default size is the automatic one (about 2000 triangles).
    far = neck_edges(default, 0.2, 0.6, 0.2, 0.8)
    assert np.median(far) > 0.5 * 0.048


def boundary_turns(domain):
    """The turn (radians) of the boundary between consecutive boundary edges at every
    boundary vertex of the mesh (all ranks' triangles gathered: an edge of one triangle
    only is a boundary edge)."""
    mesh = domain.mesh
    owned = mesh.topology.index_map(2).size_local
    p = mesh.geometry.x[mesh.geometry.dofmaps[0][:owned]][:, :, :2]
    p = np.concatenate(COMM.allgather(p))
    key = lambda q: tuple(np.round(q, 12))  # noqa: E731  (ranks number vertices apart)
    count = {}
    for tri in p:
        for a, b in ((tri[0], tri[1]), (tri[1], tri[2]), (tri[2], tri[0])):
            edge = tuple(sorted((key(a), key(b))))
            count[edge] = count.get(edge, 0) + 1
    at = {}
    for (a, b), n in count.items():
        if n == 1:
            a, b = np.array(a), np.array(b)
            at.setdefault(key(a), []).append(b - a)
            at.setdefault(key(b), []).append(a - b)
    turns = []
    for pair in at.values():
        assert len(pair) == 2  # the boundary is closed curves
        u, v = pair
        cos = -np.dot(u, v) / (np.linalg.norm(u) * np.linalg.norm(v))
        turns.append(math.acos(max(-1.0, min(1.0, cos))))
    return np.array(turns)


def test_the_airfoils_nose_is_resolved_at_the_default_size():
    # NACA 0012: nose radius about 0.0158 in a chord of 1; the default size alone (~0.044)
    # turned the boundary by ~150° between two boundary vertices there.
    domain = load(COMM, AIRFOIL)
    turns = np.degrees(boundary_turns(domain))
    sharp = turns > 60  # the box's corners and the trailing edge
    assert np.count_nonzero(sharp) == 5
    assert turns[~sharp].max() <= 360 / POINTS_PER_TURN * 1.5
