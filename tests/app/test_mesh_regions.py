"""``ufl-frames mesh`` on multi-region files of its own: regions with interfaces and a hole
inside a region, an embedded curve and point, named physical groups with explicit numbers,
and a file without groups. Checked against the geometry: per physical group the quads'
area and the lines' length (polygons and circles by formula, 0.5 %), the nodes of every
curve's line elements on the exact curve (1e-9 of the diameter, read back with Gmsh), the
embedded point a quad node (1e-12), DOLFINx's tags and names, and the entities of a file
without groups.

In-process (``cli.main``): runs serially and under ``mpirun -n 2 python -m pytest -m
"not serial"``; the Gmsh read-backs run on rank 0.
"""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from ufl_frames.bootstrap import init_petsc

init_petsc([])  # not pytest's command line

from mpi4py import MPI  # noqa: E402

from ufl_frames.app import cli  # noqa: E402

COMM = MPI.COMM_WORLD

# (a) three strips of [0, 3] x [0, 1] (interfaces x = 1 and x = 2) with a round hole of
# radius R in the third strip. Curves of the geometry: ("segment", a, b) or
# ("circle", centre, radius).
R = 0.2
CENTRE = (2.5, 0.5)
STRIPS_GEO = f"""
Point(1) = {{0, 0, 0}}; Point(2) = {{1, 0, 0}}; Point(3) = {{2, 0, 0}};
Point(4) = {{3, 0, 0}}; Point(5) = {{3, 1, 0}}; Point(6) = {{2, 1, 0}};
Point(7) = {{1, 1, 0}}; Point(8) = {{0, 1, 0}};
Line(1) = {{1, 2}}; Line(2) = {{2, 3}}; Line(3) = {{3, 4}}; Line(4) = {{4, 5}};
Line(5) = {{5, 6}}; Line(6) = {{6, 7}}; Line(7) = {{7, 8}}; Line(8) = {{8, 1}};
Line(9) = {{2, 7}}; Line(10) = {{3, 6}};
Point(10) = {{{CENTRE[0]}, {CENTRE[1]}, 0}};
Point(11) = {{{CENTRE[0] + R}, {CENTRE[1]}, 0}};
Point(12) = {{{CENTRE[0]}, {CENTRE[1] + R}, 0}};
Point(13) = {{{CENTRE[0] - R}, {CENTRE[1]}, 0}};
Point(14) = {{{CENTRE[0]}, {CENTRE[1] - R}, 0}};
Circle(11) = {{11, 10, 12}}; Circle(12) = {{12, 10, 13}};
Circle(13) = {{13, 10, 14}}; Circle(14) = {{14, 10, 11}};
Curve Loop(1) = {{1, 9, 7, 8}};
Curve Loop(2) = {{2, 10, 6, -9}};
Curve Loop(3) = {{3, 4, 5, -10}};
Curve Loop(4) = {{11, 12, 13, 14}};
Plane Surface(1) = {{1}};
Plane Surface(2) = {{2}};
Plane Surface(3) = {{3, 4}};
Physical Surface("left", 11) = {{1}};
Physical Surface("middle", 12) = {{2}};
Physical Surface("holed", 13) = {{3}};
Physical Curve("inlet", 21) = {{8}};
Physical Curve("outlet", 22) = {{4}};
Physical Curve("walls", 23) = {{1, 2, 3, 5, 6, 7}};
Physical Curve("interfaces", 24) = {{9, 10}};
Physical Curve("hole", 25) = {{11, 12, 13, 14}};
"""
P = {1: (0, 0), 2: (1, 0), 3: (2, 0), 4: (3, 0), 5: (3, 1), 6: (2, 1), 7: (1, 1), 8: (0, 1)}
STRIPS = {
    "diameter": math.hypot(3, 1),
    "curves": {**{i: ("segment", P[a], P[b]) for i, (a, b) in {
        1: (1, 2), 2: (2, 3), 3: (3, 4), 4: (4, 5), 5: (5, 6), 6: (6, 7), 7: (7, 8),
        8: (8, 1), 9: (2, 7), 10: (3, 6)}.items()},
        **{i: ("circle", CENTRE, R) for i in (11, 12, 13, 14)}},
    "areas": {"left": 1.0, "middle": 1.0, "holed": 1.0 - math.pi * R**2},
    "lengths": {"inlet": 1.0, "outlet": 1.0, "walls": 6.0, "interfaces": 2.0,
                "hole": 2 * math.pi * R},
    "groups": {"left": (2, 11), "middle": (2, 12), "holed": (2, 13), "inlet": (1, 21),
               "outlet": (1, 22), "walls": (1, 23), "interfaces": (1, 24),
               "hole": (1, 25)},
}

# (b) the unit square with an embedded crack (0.25, 0.5)-(0.75, 0.5) and an embedded point.
PROBE = (0.5, 0.25)
EMBEDDED_GEO = f"""
Point(1) = {{0, 0, 0}}; Point(2) = {{1, 0, 0}}; Point(3) = {{1, 1, 0}}; Point(4) = {{0, 1, 0}};
Line(1) = {{1, 2}}; Line(2) = {{2, 3}}; Line(3) = {{3, 4}}; Line(4) = {{4, 1}};
Curve Loop(1) = {{1, 2, 3, 4}};
Plane Surface(1) = {{1}};
Point(5) = {{0.25, 0.5, 0}}; Point(6) = {{0.75, 0.5, 0}};
Line(5) = {{5, 6}};
Point(7) = {{{PROBE[0]}, {PROBE[1]}, 0}};
Curve{{5}} In Surface{{1}};
Point{{7}} In Surface{{1}};
Physical Surface("plate", 7) = {{1}};
Physical Curve("boundary", 8) = {{1, 2, 3, 4}};
Physical Curve("crack", 9) = {{5}};
"""
Q = {1: (0, 0), 2: (1, 0), 3: (1, 1), 4: (0, 1)}
EMBEDDED = {
    "diameter": math.sqrt(2),
    "curves": {**{i: ("segment", Q[a], Q[b]) for i, (a, b) in {
        1: (1, 2), 2: (2, 3), 3: (3, 4), 4: (4, 1)}.items()},
        5: ("segment", (0.25, 0.5), (0.75, 0.5))},
    "areas": {"plate": 1.0},
    "lengths": {"boundary": 4.0, "crack": 0.5},
    "groups": {"plate": (2, 7), "boundary": (1, 8), "crack": (1, 9)},
}

# (c) no physical groups: a square [0, 2]^2 with a square [0.5, 1.5]^2 as a second surface.
BARE_GEO = """
Point(1) = {0, 0, 0}; Point(2) = {2, 0, 0}; Point(3) = {2, 2, 0}; Point(4) = {0, 2, 0};
Point(5) = {0.5, 0.5, 0}; Point(6) = {1.5, 0.5, 0}; Point(7) = {1.5, 1.5, 0};
Point(8) = {0.5, 1.5, 0};
Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 1};
Line(5) = {5, 6}; Line(6) = {6, 7}; Line(7) = {7, 8}; Line(8) = {8, 5};
Curve Loop(1) = {1, 2, 3, 4};
Curve Loop(2) = {5, 6, 7, 8};
Plane Surface(1) = {1, 2};
Plane Surface(2) = {2};
"""
B = {1: (0, 0), 2: (2, 0), 3: (2, 2), 4: (0, 2), 5: (0.5, 0.5), 6: (1.5, 0.5),
     7: (1.5, 1.5), 8: (0.5, 1.5)}
BARE = {
    "diameter": 2 * math.sqrt(2),
    "curves": {i: ("segment", B[a], B[b]) for i, (a, b) in {
        1: (1, 2), 2: (2, 3), 3: (3, 4), 4: (4, 1), 5: (5, 6), 6: (6, 7), 7: (7, 8),
        8: (8, 5)}.items()},
    "surface_areas": {1: 3.0, 2: 1.0},
}


def mesh_file(tmp_path_factory, name, text, *extra):
    """``ufl-frames mesh NAME.geo`` (in-process, collective): (out folder, summary)."""
    root = Path(COMM.bcast(str(tmp_path_factory.mktemp(name)), root=0))
    geo = root / f"{name}.geo"
    if COMM.rank == 0:
        geo.write_text(text)
    COMM.Barrier()
    out = root / "out"
    assert cli.main(["mesh", str(geo), "--out", str(out), "-q", *extra]) == 0
    return out, json.loads((out / "summary.json").read_text())


@pytest.fixture(scope="module")
def strips(tmp_path_factory):
    # a finer size than the default (see test_strips_at_the_default_size)
    return mesh_file(tmp_path_factory, "strips", STRIPS_GEO, "--quad-size", "0.035")


@pytest.fixture(scope="module")
def embedded(tmp_path_factory):
    return mesh_file(tmp_path_factory, "embedded", EMBEDDED_GEO)


@pytest.fixture(scope="module")
def bare(tmp_path_factory):
    return mesh_file(tmp_path_factory, "bare", BARE_GEO)


class ReadBack:
    """``quads.msh`` read back with Gmsh: nodes, the quads and lines of every entity, the
    physical groups with their names and entities, the nodes of the model points."""

    def __init__(self, path):
        import gmsh

        gmsh.initialize(argv=[], readConfigFiles=False)
        try:
            gmsh.option.setNumber("General.Terminal", 0)
            gmsh.open(str(path))
            tags, coords, _ = gmsh.model.mesh.getNodes()
            self.x = np.full((int(tags.max()) + 1, 2), np.nan)
            self.x[tags.astype(int)] = coords.reshape(-1, 3)[:, :2]
            self.entities = {dim: sorted(t for _, t in gmsh.model.getEntities(dim))
                             for dim in (0, 1, 2)}
            self.cells = {}  # (dim, tag) -> {element type: (k, nodes) array}
            for dim in (1, 2):
                for tag in self.entities[dim]:
                    kinds, _, nodes = gmsh.model.mesh.getElements(dim, tag)
                    self.cells[dim, tag] = {
                        int(k): np.asarray(n, dtype=int).reshape(len(n) // (k_nodes), k_nodes)
                        for k, n in zip(kinds, nodes, strict=True)
                        for k_nodes in [{1: 2, 3: 4, 2: 3}[int(k)]]}
            self.points = {}
            for tag in self.entities[0]:
                node_tags, point, _ = gmsh.model.mesh.getNodes(0, tag)
                self.points[tag] = (node_tags.astype(int), np.asarray(point)[:2])
            self.groups = {}  # name -> (dim, number, entities)
            for dim, number in gmsh.model.getPhysicalGroups():
                name = gmsh.model.getPhysicalName(dim, number)
                self.groups[name] = (dim, number, sorted(
                    int(t) for t in gmsh.model.getEntitiesForPhysicalGroup(dim, number)))
        finally:
            gmsh.finalize()

    def area(self, surfaces):
        total = 0.0
        for s in surfaces:
            assert set(self.cells[2, s]) == {3}, "quads only"
            p = self.x[self.cells[2, s][3]]
            total += 0.5 * np.sum(p[:, :, 0] * np.roll(p[:, :, 1], -1, axis=1)
                                  - np.roll(p[:, :, 0], -1, axis=1) * p[:, :, 1])
        return abs(total)

    def length(self, curves):
        return sum(float(np.linalg.norm(np.diff(self.x[self.cells[1, c][1]], axis=1),
                                        axis=2).sum()) for c in curves)


def distance(x, curve):
    """Distance of the points (k, 2) to an exact curve of the geometry."""
    if curve[0] == "circle":
        return np.abs(np.linalg.norm(x - curve[1], axis=1) - curve[2])
    a, b = np.array(curve[1], float), np.array(curve[2], float)
    t = np.clip((x - a) @ (b - a) / np.sum((b - a) ** 2), 0, 1)
    return np.linalg.norm(x - a - t[:, None] * (b - a), axis=1)


def check_groups(out, shape):
    """Per physical group: names and numbers, quads' area and lines' length vs exact."""
    back = ReadBack(out / "quads.msh")
    assert {n: g[:2] for n, g in back.groups.items()} == shape["groups"]
    for name, exact in shape["areas"].items():
        assert back.area(back.groups[name][2]) == pytest.approx(exact, rel=5e-3), name
    for name, exact in shape["lengths"].items():
        assert back.length(back.groups[name][2]) == pytest.approx(exact, rel=5e-3), name
    return back


def check_nodes_on_curves(back, shape):
    """The nodes of every curve's line elements on the exact curve (1e-9 of the diameter);
    each of the file's curves has line elements."""
    assert set(back.entities[1]) == set(shape["curves"])
    for tag, curve in shape["curves"].items():
        lines = back.cells[1, tag][1]
        assert len(lines) > 0, tag
        worst = distance(back.x[np.unique(lines)], curve).max()
        assert worst < 1e-9 * shape["diameter"], (tag, worst)


def check_dolfinx(out, shape):
    """DOLFINx's read-back: cell tags = the surface groups, facet tags = the curve groups
    (each tagged facet count = the group's line count), the names."""
    import dolfinx.io.gmsh

    data = dolfinx.io.gmsh.read_from_msh(out / "quads.msh", COMM, 0, gdim=2)
    assert data.mesh.topology.cell_name() == "quadrilateral"
    assert {n: (g.dim, g.tag) for n, g in data.physical_groups.items()} == shape["groups"]
    surfaces = sorted(t for d, t in shape["groups"].values() if d == 2)
    curves = sorted(t for d, t in shape["groups"].values() if d == 1)
    cells = data.cell_tags.values[data.cell_tags.indices
                                  < data.mesh.topology.index_map(2).size_local]
    facets = data.facet_tags.values[data.facet_tags.indices
                                    < data.mesh.topology.index_map(1).size_local]
    found_cells = sorted(set().union(*COMM.allgather(set(cells.tolist()))))
    found_facets = sorted(set().union(*COMM.allgather(set(facets.tolist()))))
    assert found_cells == surfaces and found_facets == curves
    n_cells = COMM.allreduce(len(cells), op=MPI.SUM)
    assert n_cells == data.mesh.topology.index_map(2).size_global  # each quad in a region
    return {t: COMM.allreduce(int(np.sum(facets == t)), op=MPI.SUM) for t in curves}


def test_strips_groups_areas_and_lengths(strips):
    out, summary = strips
    assert summary["quads"]["valid"] and summary["quads"]["features"]["regions"] == 3
    if COMM.rank == 0:
        check_groups(out, STRIPS)


def test_strips_nodes_on_the_curves(strips):
    out, summary = strips
    assert summary["quads"]["cad"]["refused"] == 0
    if COMM.rank == 0:
        check_nodes_on_curves(ReadBack(out / "quads.msh"), STRIPS)


def test_strips_dolfinx_tags(strips):
    out, _ = strips
    counts = check_dolfinx(out, STRIPS)
    if COMM.rank == 0:
        back = ReadBack(out / "quads.msh")
        for name, (dim, number, curves) in back.groups.items():
            if dim == 1:
                assert counts[number] == sum(len(back.cells[1, c][1]) for c in curves), name


def test_embedded_groups_and_nodes(embedded):
    out, summary = embedded
    assert summary["quads"]["valid"]
    if COMM.rank == 0:
        back = check_groups(out, EMBEDDED)
        check_nodes_on_curves(back, EMBEDDED)


def test_embedded_point_is_a_quad_node(embedded):
    out, _ = embedded
    if COMM.rank == 0:
        back = ReadBack(out / "quads.msh")
        assert 7 in back.entities[0]
        nodes, _ = back.points[7]
        assert len(nodes) == 1
        assert np.linalg.norm(back.x[nodes[0]] - PROBE) < 1e-12
        quad_nodes = np.unique(back.cells[2, 1][3])
        assert nodes[0] in quad_nodes
        # the crack's ends too
        for tag, where in ((5, (0.25, 0.5)), (6, (0.75, 0.5))):
            node = back.points[tag][0][0]
            assert node in quad_nodes and np.linalg.norm(back.x[node] - where) < 1e-12


def test_embedded_dolfinx_tags(embedded):
    out, _ = embedded
    counts = check_dolfinx(out, EMBEDDED)
    assert counts[9] > 0  # the crack: interior facets, tagged


def test_bare_file_keeps_its_entities(bare):
    """A file without physical groups: its entities with their tags, each its own unnamed
    group (group tag = entity tag), so that DOLFINx reads the surfaces back as cell tags."""
    from dolfinx.io import gmsh as gmshio

    out, summary = bare
    assert summary["quads"]["valid"]
    data = gmshio.read_from_msh(str(out / "quads.msh"), COMM, rank=0, gdim=2)
    tags = {int(t) for part in COMM.allgather(np.unique(data.cell_tags.values).tolist())
            for t in part}
    assert tags == {1, 2}
    if COMM.rank == 0:
        back = ReadBack(out / "quads.msh")
        assert set(back.groups) == {""}  # unnamed
        assert back.entities[2] == [1, 2]
        for surface, exact in BARE["surface_areas"].items():
            assert back.area([surface]) == pytest.approx(exact, rel=5e-3)
        check_nodes_on_curves(back, BARE)
        assert back.length([5, 6, 7, 8]) == pytest.approx(4.0, rel=5e-3)
        # every model point is a node at its place
        for tag, where in B.items():
            node = back.points[tag][0][0]
            assert np.linalg.norm(back.x[node] - where) < 1e-12


def test_strips_at_the_default_size(tmp_path_factory):
    """Without a size asked: the default size (0.054, about 6 quad edges a quarter of the
    hole) gives valid quads; were it to fail the stage's checks, the command would take a
    smaller size and say so (``adapted_size``, tested in tests/pipeline)."""
    out, summary = mesh_file(tmp_path_factory, "strips_default", STRIPS_GEO)
    adapted = summary["quads"].get("adapted_size")
    assert adapted is None or adapted["used"] < adapted["asked"]
    assert summary["quads"]["valid"] and summary["quads"]["min_sj"] > 0.3
    if COMM.rank == 0:
        back = ReadBack(out / "quads.msh")
        holed = back.groups["holed"][2]
        assert back.area(holed) == pytest.approx(STRIPS["areas"]["holed"], rel=5e-3)
        check_nodes_on_curves(back, STRIPS)
