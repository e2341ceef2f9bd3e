"""Quad-mesh measures and checks (``ufl_frames.quads.measures``), files (``quads.msh``).

Truth: hand-made meshes with known answers (a structured grid: no irregular vertex, SJ 1,
exact area and edge lengths; one vertex moved sideways by d: SJ 1/√(1+d²) in its four
quads; a triangle of 3 quads and a pentagon of 5 quads: one valence-3 and one valence-5
centre; an L-shaped grid, whose concave corner has the regular valence 4; inverted,
T-junction, fin, pinched and duplicated meshes that must be refused), random quads
against an independent formula (sin of the difference of the edges' polar angles), and
Gmsh's own qualities: ``minSIGE`` is the corner SJ on valid linear quads, ``minSJ`` is
Gmsh's Jacobian ratio min J / J(centre). The files are read back with Gmsh and DOLFINx
(serially and under MPI: the area sums across ranks).

The pure tests run in the NumPy-only venv (``.venv-pure``); Gmsh, matplotlib and DOLFINx
are imported inside the tests that need them (skipped where absent).
"""

import json
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from ufl_frames.quads import measures
from ufl_frames.quads.measures import (
    boundary_length,
    check_quad_mesh,
    euler_characteristic,
    quad_quality,
    scaled_jacobians,
)


def grid(nx, ny, width=2.0, height=1.0):
    """Structured nx × ny quads on [0, width] × [0, height], counter-clockwise."""
    X, Y = np.meshgrid(np.linspace(0, width, nx + 1), np.linspace(0, height, ny + 1),
                       indexing="ij")
    x = np.stack([X.ravel(), Y.ravel()], axis=1)
    i = np.arange(x.shape[0]).reshape(nx + 1, ny + 1)
    q = np.stack([i[:-1, :-1], i[1:, :-1], i[1:, 1:], i[:-1, 1:]], axis=-1).reshape(-1, 4)
    return x, q


def polygon_fan(corners):
    """A convex polygon of k corners as k quads around its centroid (corner, midpoint,
    centre, midpoint): valence k at the centre."""
    c = np.asarray(corners, dtype=float)
    k = len(c)
    mids = 0.5 * (c + np.roll(c, -1, axis=0))  # mids[i] between corner i and i + 1
    x = np.concatenate([c, mids, c.mean(axis=0, keepdims=True)])
    centre = 2 * k
    q = np.array([[i, k + i, centre, k + (i - 1) % k] for i in range(k)])
    return x, q


def regular_polygon(k, r=1.0):
    t = 2 * np.pi * np.arange(k) / k + np.pi / 2
    return np.stack([r * np.cos(t), r * np.sin(t)], axis=1)


def l_shape(n=4):
    """The n × n grid on [0, 2]² less its top-right (n/2)² block."""
    x, q = grid(n, n, 2.0, 2.0)
    centres = x[q].mean(axis=1)
    q = q[~((centres[:, 0] > 1) & (centres[:, 1] > 1))]
    used, q = np.unique(q, return_inverse=True)
    return x[used], q.reshape(-1, 4)


def merge(parts):
    """Glue meshes (points, quads) by merging points with equal coordinates."""
    x = np.concatenate([p for p, _ in parts])
    offsets = np.cumsum([0] + [len(p) for p, _ in parts[:-1]])
    q = np.concatenate([quads + o for (_, quads), o in zip(parts, offsets, strict=True)])
    _, first, inverse = np.unique(x, axis=0, return_index=True, return_inverse=True)
    return x[np.sort(first)], np.argsort(np.argsort(first))[inverse.ravel()][q]


def cross(a, b):
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def sj_by_angles(x, q):
    """Independent SJ: sin(polar angle of e_prev − polar angle of e_next), min over corners."""
    p = x[q]
    nxt, prv = np.roll(p, -1, axis=1) - p, np.roll(p, 1, axis=1) - p
    return np.sin(np.arctan2(prv[..., 1], prv[..., 0])
                  - np.arctan2(nxt[..., 1], nxt[..., 0])).min(axis=1)


# --- quad_quality on hand-made meshes ---------------------------------------------------


def test_structured_grid():
    nx, ny = 4, 3
    x, q = grid(nx, ny)
    m = quad_quality(x, q)
    assert tuple(m) == measures.QUALITY_KEYS
    json.dumps(m)  # JSON-ready
    assert m["quads"] == nx * ny and m["vertices"] == (nx + 1) * (ny + 1)
    assert m["irregular_vertices"] == m["irregular_interior"] == m["irregular_boundary"] == 0
    assert m["interior_valence"] == {"4": (nx - 1) * (ny - 1)}
    assert m["min_sj"] == pytest.approx(1.0, abs=1e-15)
    assert m["mean_sj"] == pytest.approx(1.0, abs=1e-15)
    assert m["sj_at_least_0_8"] == 1.0
    assert m["edge_length_ratio"] == pytest.approx({"mean": 1.5, "max": 1.5})  # 0.5 / (1/3)
    horizontal, vertical = nx * (ny + 1), (nx + 1) * ny
    mean = (horizontal * 2 / nx + vertical * 1 / ny) / (horizontal + vertical)
    assert m["mean_edge_length"] == pytest.approx(mean, rel=1e-14)
    assert m["area"] == pytest.approx(2.0, rel=1e-14)
    assert check_quad_mesh(x, q, area=2.0) == []


def test_moved_vertex_known_sj():
    """The centre of a 2 × 2 grid of unit squares moved by d along x: each of its four
    quads has SJ 1/√(1+d²); edges 1, 1, 1±d, √(1+d²)."""
    d = 0.5
    x, q = grid(2, 2, 2.0, 2.0)
    centre = int(np.flatnonzero(np.all(x == 1.0, axis=1))[0])
    x[centre, 0] += d
    m = quad_quality(x, q)
    assert scaled_jacobians(x, q) == pytest.approx(np.full(4, 1 / math.sqrt(1 + d * d)))
    assert m["min_sj"] == pytest.approx(1 / math.sqrt(1 + d * d))
    assert m["sj_at_least_0_8"] == 1.0  # 0.894
    ratios = [1 + d, 1 + d, math.sqrt(1 + d * d) / (1 - d), math.sqrt(1 + d * d) / (1 - d)]
    assert m["edge_length_ratio"]["max"] == pytest.approx(max(ratios))
    assert m["edge_length_ratio"]["mean"] == pytest.approx(np.mean(ratios))
    assert m["area"] == pytest.approx(4.0) and m["irregular_vertices"] == 0
    assert check_quad_mesh(x, q, area=4.0) == []
    x[centre, 0] = 1.8  # SJ 1/√1.64 = 0.78 in all four
    assert quad_quality(x, q)["sj_at_least_0_8"] == 0.0


def test_triangle_of_three_quads_has_a_valence_3_centre():
    x, q = polygon_fan(regular_polygon(3))
    m = quad_quality(x, q)
    # 60° corners: valence 2 (rounded up to one quad); midpoints: 3; centre: 3.
    assert m["interior_valence"] == {"3": 1}
    assert (m["irregular_vertices"], m["irregular_interior"], m["irregular_boundary"]) == (1, 1, 0)
    assert m["area"] == pytest.approx(3 * math.sqrt(3) / 4)
    assert check_quad_mesh(x, q, area=3 * math.sqrt(3) / 4) == []


def test_pentagon_of_five_quads_has_a_valence_5_centre():
    x, q = polygon_fan(regular_polygon(5))
    m = quad_quality(x, q)
    assert m["interior_valence"] == {"5": 1}
    assert (m["irregular_vertices"], m["irregular_interior"], m["irregular_boundary"]) == (1, 1, 0)
    assert m["area"] == pytest.approx(5 / 2 * math.sin(2 * math.pi / 5))
    assert check_quad_mesh(x, q) == []


def test_valence_3_and_5_in_one_mesh():
    """A triangle glued to a pentagon's side: the glued corners (108° + 60°) want valence
    3 and have it, the glued midpoint becomes a regular interior vertex."""
    pentagon = regular_polygon(5)
    a, b = pentagon[0], pentagon[1]  # a side; the triangle's apex lies outside it
    outward = np.array([b[1] - a[1], a[0] - b[0]])  # right of a → b (CCW pentagon)
    apex = 0.5 * (a + b) + math.sqrt(3) / 2 * outward
    x, q = merge([polygon_fan(pentagon), polygon_fan([b, a, apex])])
    m = quad_quality(x, q)
    assert m["quads"] == 8
    assert m["interior_valence"] == {"3": 1, "4": 1, "5": 1}
    assert (m["irregular_interior"], m["irregular_boundary"]) == (2, 0)
    assert check_quad_mesh(x, q) == []


def test_l_shape_concave_corner_is_regular():
    x, q = l_shape(4)
    v = measures.vertex_valence(x, q)
    corner = int(np.flatnonzero(np.all(np.isclose(x, 1.0), axis=1))[0])
    assert v["boundary"][corner] and v["angle"][corner] == pytest.approx(1.5 * np.pi)
    assert v["valence"][corner] == v["expected"][corner] == 4
    m = quad_quality(x, q)
    assert m["irregular_vertices"] == 0 and m["quads"] == 12
    assert check_quad_mesh(x, q, area=3.0) == []


def test_boundary_valence_mismatch_counts():
    """Valence 3 on a straight side and 2 at a 90° corner are regular; a 90° corner
    between two quads (valence 3) is not."""
    x, q = grid(2, 1, 2.0, 1.0)  # the bottom and top midpoints: valence 3 on a straight side
    assert quad_quality(x, q)["irregular_vertices"] == 0
    x, q = polygon_fan([[0, 0], [1, 0], [1, 1], [0, 1]])  # 2 × 2 split of a square
    m = quad_quality(x, q)
    assert m["irregular_vertices"] == 0 and m["interior_valence"] == {"4": 1}
    # A square split into 3 quads meeting at its centre 6, two of them at corner 3:
    x = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0], [1, 0.5], [0.5, 0.5]], float)
    q = np.array([[0, 4, 6, 3], [4, 1, 5, 6], [6, 5, 2, 3]])
    m = quad_quality(x, q)
    # Corner 3 (90°) has valence 3 where 2 is regular; the centre has valence 3.
    assert check_quad_mesh(x, q, area=1.0) == []
    assert (m["irregular_interior"], m["irregular_boundary"]) == (1, 1)
    assert m["interior_valence"] == {"3": 1}


def test_sharp_corner_wants_valence_2():
    """A 30° corner (sharper than 45°) is regular with one quad (valence 2)."""
    t = np.radians(15)
    x, q = polygon_fan([[0, 0], [math.cos(t), -math.sin(t)], [math.cos(t), math.sin(t)]])
    v = measures.vertex_valence(x, q)
    assert v["angle"][0] == pytest.approx(np.radians(30)) and v["expected"][0] == 2
    m = quad_quality(x, q)
    assert (m["irregular_interior"], m["irregular_boundary"]) == (1, 0)  # the centre only


def test_sj_threshold_is_inclusive():
    """Parallelograms with sides (5, 0) and (3, 4): SJ exactly 4/5."""
    x = np.array([[0, 0], [5, 0], [8, 4], [3, 4], [10, 0], [13, 4]], float)
    q = np.array([[0, 1, 2, 3], [1, 4, 5, 2]])
    assert scaled_jacobians(x, q).tolist() == [0.8, 0.8]
    assert quad_quality(x, q)["sj_at_least_0_8"] == 1.0


# --- random quads against independent formulas ----------------------------------------


def test_random_perturbations_against_independent_formulas():
    rng = np.random.default_rng(7)
    nx, ny = 9, 6
    x, q = grid(nx, ny, 3.0, 2.0)
    h = 2.0 / ny
    inner = (x[:, 0] > 0) & (x[:, 0] < 3) & (x[:, 1] > 0) & (x[:, 1] < 2)
    x[inner] += rng.uniform(-0.3 * h, 0.3 * h, (int(inner.sum()), 2))
    sj = scaled_jacobians(x, q)
    assert sj == pytest.approx(sj_by_angles(x, q), abs=1e-12)
    p = x[q]

    def tri(a, b, c):
        return 0.5 * cross(b - a, c - a)

    area = tri(p[:, 0], p[:, 1], p[:, 2]) + tri(p[:, 0], p[:, 2], p[:, 3])
    m = quad_quality(x, q)
    assert m["area"] == pytest.approx(6.0, rel=1e-13) == area.sum()
    assert m["min_sj"] == pytest.approx(sj.min()) and m["mean_sj"] == pytest.approx(sj.mean())
    assert m["sj_at_least_0_8"] == pytest.approx(np.mean(sj >= 0.8))
    assert m["irregular_vertices"] == 0  # moving points keeps the connectivity
    assert check_quad_mesh(x, q, area=6.0) == []


def test_scaled_jacobian_sign_and_degenerate():
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    assert scaled_jacobians(square, [[0, 1, 2, 3]]) == pytest.approx([1.0])
    assert scaled_jacobians(square, [[0, 3, 2, 1]]) == pytest.approx([-1.0])  # clockwise
    dart = np.array([[0, 0], [2, 0], [0.5, 0.5], [0, 2]], float)  # reflex corner at 2
    assert scaled_jacobians(dart, [[0, 1, 2, 3]])[0] < 0
    collapsed = np.array([[0, 0], [1, 0], [1, 0], [0, 1]], float)
    assert scaled_jacobians(collapsed, [[0, 1, 2, 3]]) == pytest.approx([0.0])


# --- check_quad_mesh refuses what is wrong ----------------------------------------------


def _one_problem(problems, word):
    assert len(problems) >= 1 and any(word in p for p in problems), problems
    return problems


def test_inverted_quad_is_refused():
    x, q = grid(3, 2)
    q[4] = q[4][::-1]
    problems = check_quad_mesh(x, q)
    _one_problem(problems, "non-positive area")
    _one_problem(problems, "same way")


def test_reflex_and_bow_tie_quads_are_refused():
    dart = np.array([[0, 0], [2, 0], [0.5, 0.5], [0, 2]], float)
    _one_problem(check_quad_mesh(dart, [[0, 1, 2, 3]]), "SJ <= 0")
    bow = np.array([[0, 0], [1, 1], [1, 0], [0, 1]], float)  # self-intersecting
    _one_problem(check_quad_mesh(bow, [[0, 1, 2, 3]]), "non-positive area")


def test_t_junction_is_refused():
    x = np.array([[0, 0], [1, 0], [1, 2], [0, 2], [2, 0], [2, 1], [1, 1], [2, 2]], float)
    q = np.array([[0, 1, 2, 3], [1, 4, 5, 6], [6, 5, 7, 2]])
    assert quad_quality(x, q)["area"] == pytest.approx(4.0)
    problems = check_quad_mesh(x, q, area=4.0)
    junction = _one_problem(problems, "T-junction")
    assert any("point 6 on edge [1, 2]" in p for p in junction)


def test_edge_in_three_quads_is_refused():
    x = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [2, 0], [2, 1], [1.5, 2], [1, 2]], float)
    q = np.array([[0, 1, 2, 3], [1, 4, 5, 2], [1, 5, 6, 2]])  # edge (1, 2) in all three
    _one_problem(check_quad_mesh(x, q), "more than two quads")


def test_pinched_vertex_is_not_manifold():
    x = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [2, 1], [2, 2], [1, 2]], float)
    q = np.array([[0, 1, 2, 3], [2, 4, 5, 6]])  # two squares touching at point 2
    problems = check_quad_mesh(x, q)
    assert len(problems) == 1
    _one_problem(problems, "not manifold")
    assert "point 2" in problems[0]


def test_duplicate_quad_unused_and_duplicate_points_wrong_area():
    x, q = grid(2, 2)
    _one_problem(check_quad_mesh(x, np.concatenate([q, q[:1]])), "same way")
    _one_problem(check_quad_mesh(np.concatenate([x, [[5.0, 5.0]]]), q), "in no quad")
    # quad 0 uses a copy of its corner 2 (shared with its neighbours): the copy coincides
    x2 = np.concatenate([x, x[q[0, 2]][None]])
    q2 = q.copy()
    q2[0, 2] = len(x)
    _one_problem(check_quad_mesh(x2, q2), "coincide")
    _one_problem(check_quad_mesh(x, q, area=2.1, rtol=1e-3), "area")
    assert check_quad_mesh(x, q, area=2.0 + 1e-12) == []
    assert check_quad_mesh(x, q, area=2.001, rtol=1e-2) == []


def test_malformed_input():
    x, q = grid(1, 1)
    assert check_quad_mesh(x, q[:, :3]) == ["quads must have shape (m, 4), got (1, 3)"]
    _one_problem(check_quad_mesh(x, q + 10), "outside")
    _one_problem(check_quad_mesh(x, [[0, 1, 1, 2]]), "repeat a corner")
    _one_problem(check_quad_mesh(np.where(x == 0, np.nan, x), q), "NaN")
    assert check_quad_mesh(x, np.zeros((0, 4), int)) == ["no quads"]
    with pytest.raises(ValueError, match="no quads"):
        quad_quality(x, np.zeros((0, 4), int))
    with pytest.raises(ValueError, match="integer"):
        quad_quality(x, q.astype(float))


# --- files: .vtu (pure), picture (matplotlib) -------------------------------------------


def test_write_quad_vtu(tmp_path):
    from ufl_frames.quads.msh import VTK_QUAD, write_quad_vtu

    x, q = grid(3, 2)
    sj = scaled_jacobians(x, q)
    path = write_quad_vtu(tmp_path / "q.vtu", x, q, {"sj": sj, "vec": np.c_[sj, 2 * sj]})
    piece = ET.parse(path).getroot().find("UnstructuredGrid/Piece")
    assert int(piece.get("NumberOfCells")) == 6 and int(piece.get("NumberOfPoints")) == 12

    def array(name):
        el = piece.find(f".//DataArray[@Name='{name}']")
        return np.array(el.text.split(), dtype=float)

    assert np.array_equal(array("connectivity"), q.ravel())
    assert np.array_equal(array("types"), np.full(6, VTK_QUAD))
    assert np.array_equal(array("offsets"), 4 * np.arange(1, 7))
    assert np.array_equal(array("sj"), sj) and array("vec").size == 12
    coords = np.array(piece.find("Points/DataArray").text.split(), float).reshape(-1, 3)
    assert np.array_equal(coords[:, :2], x) and not coords[:, 2].any()
    with pytest.raises(ValueError, match="shape"):
        write_quad_vtu(tmp_path / "bad.vtu", x, q, {"sj": sj[:-1]})


def test_plot_quads(tmp_path):
    pytest.importorskip("matplotlib")
    from ufl_frames.quads.msh import plot_quads

    x, q = merge([polygon_fan(regular_polygon(5)), grid(3, 2)])  # apart: two parts
    path = plot_quads(tmp_path / "q.png", x, q, title="pentagon and grid")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and path.stat().st_size > 5000


# --- Gmsh's qualities: an independent check of the SJ ------------------------------------


def _random_valid_quads(rng, count, spread):
    base = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    x = np.concatenate([base + rng.uniform(-spread, spread, (4, 2)) for _ in range(count)])
    q = np.arange(len(x)).reshape(-1, 4)
    p = x[q]
    nxt, prv = np.roll(p, -1, axis=1) - p, np.roll(p, 1, axis=1) - p
    ok = (cross(nxt, prv) > 0.05).all(axis=1)
    return x, q[ok]


def test_sj_against_gmsh():
    gmsh = pytest.importorskip("gmsh")
    from ufl_frames.quads.msh import gmsh_quality

    rng = np.random.default_rng(3)
    x, q = _random_valid_quads(rng, 300, 0.35)
    assert len(q) > 150
    was_initialised = gmsh.isInitialized()
    sj = scaled_jacobians(x, q)
    # Gmsh's signed inverse gradient error is the corner SJ on valid linear quads ...
    assert gmsh_quality(x, q, "minSIGE") == pytest.approx(sj, abs=1e-12)
    # ... and its "minSJ" is another measure: min corner Jacobian / Jacobian at the centre.
    p = x[q]
    det = cross(np.roll(p, -1, axis=1) - p, np.roll(p, 1, axis=1) - p)
    assert gmsh_quality(x, q) == pytest.approx(det.min(axis=1) / det.mean(axis=1), abs=1e-12)
    # A perturbed grid too (shared nodes), and Gmsh is left as it was found.
    xg, qg = grid(6, 4)
    xg += rng.uniform(-0.04, 0.04, xg.shape)
    assert gmsh_quality(xg, qg, "minSIGE") == pytest.approx(scaled_jacobians(xg, qg), abs=1e-12)
    assert gmsh.isInitialized() == was_initialised


def test_gmsh_state_restored_when_caller_initialised():
    gmsh = pytest.importorskip("gmsh")
    from ufl_frames.quads.msh import gmsh_quality

    owns = not gmsh.isInitialized()
    if owns:
        gmsh.initialize(argv=[], readConfigFiles=False)
    try:
        gmsh.model.add("caller")
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh_quality(*grid(2, 2))
        assert gmsh.isInitialized() and gmsh.model.getCurrent() == "caller"
        assert gmsh.option.getNumber("General.Terminal") == 0
    finally:
        if owns:
            gmsh.finalize()
        else:
            gmsh.model.remove()


# --- MSH 4.1 read back by Gmsh and by DOLFINx (serial and MPI) ---------------------------


def _shared_tmp(tmp_path):
    try:
        from mpi4py import MPI
    except ImportError:
        return tmp_path, None
    return Path(MPI.COMM_WORLD.bcast(str(tmp_path), root=0)), MPI.COMM_WORLD


def test_msh_read_back_by_gmsh(tmp_path):
    gmsh = pytest.importorskip("gmsh")
    from ufl_frames.quads.msh import mesh_boundary_edges, write_quad_msh

    x, q = l_shape(4)
    owns = not gmsh.isInitialized()
    path = write_quad_msh(tmp_path / "l.msh", x, q)
    assert path.read_text().startswith("$MeshFormat\n4.1 0 8\n")
    assert gmsh.isInitialized() != owns
    if owns:
        gmsh.initialize(argv=[], readConfigFiles=False)
    gmsh.model.add("read back")
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.open(str(path))
        tags, coords, _ = gmsh.model.mesh.getNodes()
        assert np.array_equal(coords.reshape(-1, 3)[np.argsort(tags), :2], x)
        types, _, nodes = gmsh.model.mesh.getElements(2)
        assert list(types) == [3] and np.array_equal(nodes[0].reshape(-1, 4) - 1, q)
        types, _, nodes = gmsh.model.mesh.getElements(1)
        lines = nodes[0].reshape(-1, 2).astype(np.int64) - 1
        assert list(types) == [1] and len(lines) == 16  # the L's perimeter: 8 units of 0.5
        assert np.array_equal(lines, mesh_boundary_edges(q))
        groups = {gmsh.model.getPhysicalName(d, t): (d, t)
                  for d, t in gmsh.model.getPhysicalGroups()}
        assert groups == {"domain": (2, 1), "boundary": (1, 2)}
    finally:
        if owns:
            gmsh.finalize()
        else:
            gmsh.model.remove()
    with pytest.raises(ValueError, match=".msh"):
        write_quad_msh(tmp_path / "l.vtk", x, q)
    with pytest.raises(ValueError, match="outside"):
        write_quad_msh(tmp_path / "bad.msh", x, q, boundary_edges=[[0, len(x)]])
    bare = write_quad_msh(tmp_path / "bare.msh", x, q, boundary_edges=np.zeros((0, 2), int))
    text = bare.read_text()
    assert '"domain"' in text and '"boundary"' not in text and "$Elements\n1 12 1 12\n" in text


def test_msh_read_back_by_dolfinx(tmp_path):
    pytest.importorskip("mpi4py")
    pytest.importorskip("petsc4py")
    pytest.importorskip("gmsh")
    import ufl_frames.bootstrap  # noqa: F401  (PETSc before DOLFINx)

    pytest.importorskip("dolfinx")
    import dolfinx.io.gmsh
    import ufl
    from dolfinx import fem
    from mpi4py import MPI

    from ufl_frames.quads.msh import BOUNDARY_TAG, write_quad_msh

    folder, comm = _shared_tmp(tmp_path)
    x, q = grid(5, 3)
    x[5] += (0.05, -0.03)  # an interior point: not a tensor grid any more
    path = folder / "grid.msh"
    if comm.rank == 0:
        write_quad_msh(path, x, q)
    comm.Barrier()
    data = dolfinx.io.gmsh.read_from_msh(path, comm, 0, gdim=2)
    mesh = data.mesh
    assert mesh.topology.cell_name() == "quadrilateral"
    assert mesh.topology.index_map(2).size_global == 15
    area = comm.allreduce(fem.assemble_scalar(fem.form(1.0 * ufl.dx(domain=mesh))), op=MPI.SUM)
    assert area == pytest.approx(2.0, rel=1e-12)
    facets = data.facet_tags
    owned = facets.indices < mesh.topology.index_map(1).size_local
    assert comm.allreduce(int(owned.sum()), op=MPI.SUM) == 2 * (5 + 3)
    assert set(facets.values.tolist()) <= {BOUNDARY_TAG}
    ds = ufl.Measure("ds", domain=mesh, subdomain_data=facets)
    perimeter = comm.allreduce(fem.assemble_scalar(fem.form(1.0 * ds(BOUNDARY_TAG))),
                               op=MPI.SUM)
    assert perimeter == pytest.approx(6.0, rel=1e-12)


def test_euler_characteristic_counts_holes_and_a_slit_may_have_twins():
    """A 3 × 3 grid is a disk (χ = 1); without its middle quad it has a hole (χ = 0). The
    2 × 2 grid cut open from its left side's midpoint to its centre (the points there
    doubled, but for the centre: a slit) is still a disk, and its twin points are
    accepted only when slits are allowed."""
    x, q = grid(3, 3)
    assert euler_characteristic(q) == 1
    assert euler_characteristic(np.delete(q, 4, axis=0)) == 0
    x, q = grid(2, 2)
    # the left side's midpoint is point 1 (point 3 ix + iy), the centre 4: the quad above
    # the slit (corners 1, 4, 5, 2) takes a twin of point 1
    twin = len(x)
    x2 = np.concatenate([x, x[1][None]])
    q2 = q.copy()
    above = [i for i in range(4) if {1, 4, 5} <= set(q[i].tolist())][0]
    q2[above] = np.where(q[above] == 1, twin, q[above])
    assert euler_characteristic(q2) == 1
    assert check_quad_mesh(x2, q2, slits=True) == []
    _one_problem(check_quad_mesh(x2, q2), "coincide")


def test_boundary_length_grows_where_quads_are_missing():
    """The 3 × 3 grid on [0, 2] × [0, 1] has the rectangle's perimeter 6; without a
    corner quad (an edge of 2/3 by 1/3) the perimeter is unchanged, without the middle
    quad of the bottom row it grows by two sides of 1/3, without the centre by its
    whole perimeter 2 (2/3 + 1/3)."""
    x, q = grid(3, 3)
    assert boundary_length(x, q) == pytest.approx(6.0, rel=1e-14)
    corner = [i for i in range(9) if 0 in q[i]][0]
    assert boundary_length(x, np.delete(q, corner, axis=0)) == pytest.approx(6.0, rel=1e-14)
    assert boundary_length(x, np.delete(q, 3, axis=0)) == pytest.approx(6 + 2 / 3, rel=1e-14)
    assert boundary_length(x, np.delete(q, 4, axis=0)) == pytest.approx(8.0, rel=1e-14)
