"""Regions, interfaces, embedded curves and points, physical groups: what the loader keeps
of a file's model entities (``Domain.cell_tags``, ``curve_tags``, ``point_tags``,
``junctions``, ``physical_groups``), checked against the geometry's own areas, lengths and
points. Serial and MPI.
"""

import math

import numpy as np
import pytest

from ufl_frames.bootstrap import init_petsc

init_petsc([])  # not pytest's command line

import dolfinx  # noqa: E402
import ufl  # noqa: E402
from mpi4py import MPI  # noqa: E402

from ufl_frames.mesh import load  # noqa: E402
from ufl_frames.mesh.domain import NO_CURVE, PhysicalGroup  # noqa: E402

COMM = MPI.COMM_WORLD

# Two unit squares side by side, made conforming in the script; named groups.
TWO_REGIONS = """SetFactory("OpenCASCADE");
Rectangle(1) = {0, 0, 0, 1, 1};
Rectangle(2) = {1, 0, 0, 1, 1};
BooleanFragments{ Surface{1}; Delete; }{ Surface{2}; Delete; }
Physical Surface("iron", 5) = {1};
Physical Surface("copper", 6) = {2};
Physical Curve("inlet", 11) = {4};
Physical Curve("interface") = {2};
Physical Point("origin", 21) = {1};
"""

# The square [0, 2]² as three regions: the left half, the top and bottom of the right half;
# the interfaces meet at a T inside (1, 1) and the boundary at 90° in three points.
THREE_REGIONS = """SetFactory("OpenCASCADE");
Rectangle(1) = {0, 0, 0, 1, 2};
Rectangle(2) = {1, 0, 0, 1, 1};
Rectangle(3) = {1, 1, 0, 1, 1};
BooleanFragments{ Surface{1}; Delete; }{ Surface{2, 3}; Delete; }
"""

# Two regions, the left one with a square hole: χ = 0.
HOLE = """SetFactory("OpenCASCADE");
Rectangle(1) = {0, 0, 0, 1, 1};
Rectangle(2) = {1, 0, 0, 1, 1};
Rectangle(3) = {0.25, 0.25, 0, 0.5, 0.5};
BooleanDifference{ Surface{1}; Delete; }{ Surface{3}; Delete; }
BooleanFragments{ Surface{1}; Delete; }{ Surface{2}; Delete; }
"""

# A curve and a point embedded in one surface (OpenCASCADE): a crack path and a sensor.
EMBEDDED_OCC = """SetFactory("OpenCASCADE");
Rectangle(1) = {0, 0, 0, 2, 1};
Point(20) = {1.5, 0.5, 0};
Point(21) = {0.3, 0.2, 0}; Point(22) = {1.1, 0.8, 0};
Line(30) = {21, 22};
Curve{30} In Surface{1};
Point{20} In Surface{1};
Physical Curve("crack", 3) = {30};
"""

# The same with the built-in kernel, and two surfaces sharing a curve.
EMBEDDED_BUILTIN = """Point(1) = {0, 0, 0}; Point(2) = {1, 0, 0}; Point(3) = {2, 0, 0};
Point(4) = {2, 1, 0}; Point(5) = {1, 1, 0}; Point(6) = {0, 1, 0};
Line(1) = {1, 2}; Line(2) = {2, 5}; Line(3) = {5, 6}; Line(4) = {6, 1};
Line(5) = {2, 3}; Line(6) = {3, 4}; Line(7) = {4, 5};
Curve Loop(1) = {1, 2, 3, 4}; Plane Surface(1) = {1};
Curve Loop(2) = {5, 6, 7, -2}; Plane Surface(2) = {2};
Point(10) = {1.2, 0.3, 0}; Point(11) = {1.8, 0.6, 0}; Point(12) = {0.5, 0.5, 0};
Line(10) = {10, 11};
Curve{10} In Surface{2};
Point{12} In Surface{1};
Physical Surface("left", 1) = {1};
Physical Surface("right", 2) = {2};
Physical Curve("walls", 7) = {1, 3, 4, 5, 6, 7};
Physical Curve("line") = {10};
"""

# Overlapping rectangles with groups, fragmented by the loader (not by the script).
OVERLAPPING = """SetFactory("OpenCASCADE");
Rectangle(1) = {0, 0, 0, 1, 1};
Rectangle(2) = {1, 0, 0, 1, 1};
Disk(3) = {0.5, 0.5, 0, 0.2};
Physical Surface("left", 7) = {1};
Physical Surface("right") = {2};
Physical Curve("inlet", 11) = {4};
"""


def write(tmp_path, name, text):
    path = tmp_path / name
    if COMM.rank == 0:
        path.write_text(text)
    COMM.Barrier()
    return path


def region_areas(domain) -> dict[int, float]:
    """Sum of the cell areas per surface tag (owned cells, summed over the ranks)."""
    mesh = domain.mesh
    owned = mesh.topology.index_map(2).size_local
    x = mesh.geometry.x[:, :2]
    nodes = mesh.geometry.dofmaps[0][:owned]
    e1, e2 = x[nodes[:, 1]] - x[nodes[:, 0]], x[nodes[:, 2]] - x[nodes[:, 0]]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    tags = domain.cell_tags
    assert np.array_equal(np.sort(tags.indices[tags.indices < owned]), np.arange(owned))
    local = {}
    for index, value in zip(tags.indices, tags.values, strict=True):
        if index < owned:
            local[int(value)] = local.get(int(value), 0.0) + float(area[index])
    total = {}
    for part in COMM.allgather(local):
        for k, v in part.items():
            total[k] = total.get(k, 0.0) + v
    return total


def curve_lengths(domain) -> tuple[dict[int, float], dict[int, float]]:
    """Length of the tagged facets per curve tag: (on the boundary, inside); owned facets,
    summed over the ranks."""
    mesh = domain.mesh
    mesh.topology.create_connectivity(1, 2)
    owned = mesh.topology.index_map(1).size_local
    exterior = set(dolfinx.mesh.exterior_facet_indices(mesh.topology).tolist())
    tags = domain.curve_tags
    keep = tags.indices < owned
    facets = tags.indices[keep]
    nodes = dolfinx.mesh.entities_to_geometry(mesh, 1, facets.astype(np.int32))
    x = mesh.geometry.x[:, :2]
    length = np.linalg.norm(x[nodes[:, 1]] - x[nodes[:, 0]], axis=1)
    local = ({}, {})
    for f, value, ell in zip(facets, tags.values[keep], length, strict=True):
        part = local[0 if int(f) in exterior else 1]
        part[int(value)] = part.get(int(value), 0.0) + float(ell)
    total = ({}, {})
    for parts in COMM.allgather(local):
        for side in range(2):
            for k, v in parts[side].items():
                total[side][k] = total[side].get(k, 0.0) + v
    return total


def tagged_points(domain) -> dict[int, tuple[float, float]]:
    """Position of the vertex of every point tag (gathered over the ranks)."""
    mesh = domain.mesh
    tags = domain.point_tags
    mesh.topology.create_connectivity(0, 2)
    nodes = dolfinx.mesh.entities_to_geometry(mesh, 0, tags.indices.astype(np.int32))
    x = mesh.geometry.x[nodes.ravel(), :2]
    local = {int(t): (float(p[0]), float(p[1])) for t, p in zip(tags.values, x, strict=True)}
    out = {}
    for part in COMM.allgather(local):
        out.update(part)
    return out


def area(domain):
    form = dolfinx.fem.form(dolfinx.fem.Constant(domain.mesh, 1.0) * ufl.dx(domain=domain.mesh))
    return COMM.allreduce(dolfinx.fem.assemble_scalar(form), op=MPI.SUM)


def test_two_regions_with_an_interface_and_named_groups(tmp_path):
    domain = load(COMM, write(tmp_path, "two.geo", TWO_REGIONS), 0.15)
    areas = region_areas(domain)
    assert sorted(areas) == [1, 2]
    for value in areas.values():
        assert value == pytest.approx(1.0, rel=1e-10)
    outside, inside = curve_lengths(domain)
    assert sorted(inside) == [2]  # the shared side x = 1 is an interface
    assert inside[2] == pytest.approx(1.0, rel=1e-10)
    assert 2 not in outside and sum(outside.values()) == pytest.approx(6.0, rel=1e-10)
    for tag, length in outside.items():
        assert length == pytest.approx(1.0, rel=1e-10), tag
    assert domain.boundary_curves == sorted(outside)
    assert domain.physical_groups == (
        PhysicalGroup(dim=0, tag=21, name="origin", entities=(1,)),
        PhysicalGroup(dim=1, tag=11, name="inlet", entities=(4,)),
        PhysicalGroup(dim=1, tag=12, name="interface", entities=(2,)),
        PhysicalGroup(dim=2, tag=5, name="iron", entities=(1,)),
        PhysicalGroup(dim=2, tag=6, name="copper", entities=(2,)),
    )
    points = tagged_points(domain)
    assert len(points) == 6
    assert np.allclose(sorted(points.values()),
                       [(0, 0), (0, 1), (1, 0), (1, 1), (2, 0), (2, 1)], rtol=0, atol=1e-12)
    assert points[1] == pytest.approx((0.0, 0.0), abs=1e-12)
    # the interface meets the straight boundary at 90°: no corner, no singularity
    assert len(domain.corners) == 4
    assert sorted((j.x, j.y) for j in domain.junctions) == [(1.0, 0.0), (1.0, 1.0)]
    assert all(j.on_boundary and j.index == 0 for j in domain.junctions)
    assert all(sum(j.sectors) == pytest.approx(math.pi) for j in domain.junctions)


def test_three_regions_meeting_at_a_t(tmp_path):
    domain = load(COMM, write(tmp_path, "three.geo", THREE_REGIONS), 0.2)
    areas = region_areas(domain)
    assert len(areas) == 3
    assert sorted(areas.values()) == pytest.approx([1.0, 1.0, 2.0], rel=1e-10)
    outside, inside = curve_lengths(domain)
    assert sum(inside.values()) == pytest.approx(3.0, rel=1e-10)  # x = 1 and y = 1 (x > 1)
    assert sum(outside.values()) == pytest.approx(8.0, rel=1e-10)
    assert domain.euler_characteristic == 1 and len(domain.corners) == 4
    at = {(round(j.x, 9), round(j.y, 9)): j for j in domain.junctions}
    assert sorted(at) == [(1, 0), (1, 1), (1, 2), (2, 1)]
    assert not at[(1, 1)].on_boundary
    assert sorted(at[(1, 1)].sectors) == pytest.approx([math.pi / 2, math.pi / 2, math.pi])
    assert all(j.index == 0 for j in domain.junctions)
    assert domain.physical_groups == ()  # a file without groups
    points = tagged_points(domain)
    assert (1.0, 1.0) in {(round(x, 12), round(y, 12)) for x, y in points.values()}


def test_a_hole_inside_a_region(tmp_path):
    domain = load(COMM, write(tmp_path, "hole.geo", HOLE), 0.1)
    areas = region_areas(domain)
    assert sorted(areas.values()) == pytest.approx([0.75, 1.0], rel=1e-10)
    assert area(domain) == pytest.approx(1.75, rel=1e-10)
    assert domain.euler_characteristic == 0
    outside, inside = curve_lengths(domain)
    assert sum(inside.values()) == pytest.approx(1.0, rel=1e-10)
    assert sum(outside.values()) == pytest.approx(6.0 + 2.0, rel=1e-10)
    assert len(domain.corners) == 8  # the outline's four and the hole's four (reflex)
    assert sorted(round(c.angle / (math.pi / 2)) for c in domain.corners) == [1] * 4 + [3] * 4


def test_an_embedded_curve_and_point(tmp_path):
    domain = load(COMM, write(tmp_path, "embedded.geo", EMBEDDED_OCC), 0.1)
    assert area(domain) == pytest.approx(2.0, rel=1e-12)
    assert domain.euler_characteristic == 1  # not cut open: no slit, no hole
    assert not any("slit" in note or "cut open" in note for note in domain.notes)
    assert len(domain.corners) == 4
    outside, inside = curve_lengths(domain)
    assert sorted(inside) == [30]
    assert inside[30] == pytest.approx(math.hypot(0.8, 0.6), rel=1e-10)
    assert sum(outside.values()) == pytest.approx(6.0, rel=1e-10)
    points = tagged_points(domain)
    assert points[20] == pytest.approx((1.5, 0.5), abs=1e-12)
    assert points[21] == pytest.approx((0.3, 0.2), abs=1e-12)
    assert points[22] == pytest.approx((1.1, 0.8), abs=1e-12)
    # the crack's ends: index 0, not a singularity
    ends = sorted((round(j.x, 9), round(j.y, 9)) for j in domain.junctions)
    assert ends == [(0.3, 0.2), (1.1, 0.8)]
    assert all(j.index == 0 and j.sectors == pytest.approx((2 * math.pi,))
               for j in domain.junctions)
    assert domain.physical_groups == (PhysicalGroup(1, 3, "crack", (30,)),)


def test_builtin_kernel_regions_embedded_curve_and_point(tmp_path):
    domain = load(COMM, write(tmp_path, "builtin.geo", EMBEDDED_BUILTIN), 0.1)
    areas = region_areas(domain)
    assert sorted(areas) == [1, 2]
    assert areas[1] == pytest.approx(1.0, rel=1e-10) and areas[2] == pytest.approx(1.0,
                                                                                 rel=1e-10)
    outside, inside = curve_lengths(domain)
    assert sorted(inside) == [2, 10]
    assert inside[2] == pytest.approx(1.0, rel=1e-10)
    assert inside[10] == pytest.approx(math.hypot(0.6, 0.3), rel=1e-10)
    assert sorted(outside) == [1, 3, 4, 5, 6, 7]
    points = tagged_points(domain)
    assert points[12] == pytest.approx((0.5, 0.5), abs=1e-12)
    assert points[10] == pytest.approx((1.2, 0.3), abs=1e-12)
    groups = {(g.dim, g.tag): g for g in domain.physical_groups}
    assert groups[(2, 1)] == PhysicalGroup(2, 1, "left", (1,))
    assert groups[(2, 2)] == PhysicalGroup(2, 2, "right", (2,))
    assert groups[(1, 7)] == PhysicalGroup(1, 7, "walls", (1, 3, 4, 5, 6, 7))
    assert groups[(1, 8)] == PhysicalGroup(1, 8, "line", (10,))
    assert len(domain.corners) == 4


def test_groups_survive_the_loaders_fragmentation(tmp_path):
    """Overlapping surfaces fragmented by the loader: a surface group holds the pieces
    of its surface, a curve group its (renumbered) curve."""
    domain = load(COMM, write(tmp_path, "overlap.geo", OVERLAPPING), 0.1)
    groups = {g.name: g for g in domain.physical_groups}
    assert sorted(groups) == ["inlet", "left", "right"]
    areas = region_areas(domain)
    left = sum(areas[t] for t in groups["left"].entities)
    assert left == pytest.approx(1.0, rel=1e-3)  # the disk's piece is a polygon
    assert sum(areas[t] for t in groups["right"].entities) == pytest.approx(1.0, rel=1e-10)
    outside, _ = curve_lengths(domain)
    (inlet,) = groups["inlet"].entities
    assert outside[inlet] == pytest.approx(1.0, rel=1e-10)
    # the inlet is the side x = 0
    mesh = domain.mesh
    facets = domain.curve_tags.find(inlet)
    nodes = dolfinx.mesh.entities_to_geometry(mesh, 1, facets.astype(np.int32))
    assert np.allclose(mesh.geometry.x[nodes.ravel(), 0], 0.0, atol=1e-12)


def test_msh_without_model_keeps_no_curve_tags(tmp_path):
    """A bare .msh (no curves): every cell in its surface, no tagged curve facets."""
    text = """$MeshFormat
2.2 0 8
$EndMeshFormat
$Nodes
4
1 0 0 0
2 1 0 0
3 1 1 0
4 0 1 0
$EndNodes
$Elements
2
1 2 2 0 1 1 2 3
2 2 2 0 1 1 3 4
$EndElements
"""
    domain = load(COMM, write(tmp_path, "bare.msh", text))
    assert area(domain) == pytest.approx(1.0, rel=1e-12)
    assert sorted(region_areas(domain)) == [1]  # the elementary surface of the elements
    assert COMM.allreduce(domain.curve_tags.values.size, op=MPI.SUM) == 0
    assert COMM.allreduce(int(np.count_nonzero(domain.facet_tags.values == NO_CURVE)),
                          op=MPI.SUM) > 0  # the boundary is there, on no curve
    assert domain.junctions == ()


def test_refined_meshes_keep_regions_curves_and_points(tmp_path):
    """The meshes of nested iteration (Gmsh's refinement) keep every entity: the hole
    file refined once has the same regions' areas and interface length, and its points."""
    path = write(tmp_path, "hole.geo", HOLE)
    coarse = load(COMM, path, 0.4)  # refinements=1 meshes at twice the size, then splits
    fine = load(COMM, path, 0.2, refinements=1)
    assert fine.num_cells == 4 * coarse.num_cells
    assert sorted(region_areas(fine).values()) == pytest.approx([0.75, 1.0], rel=1e-10)
    _, inside = curve_lengths(fine)
    assert sum(inside.values()) == pytest.approx(1.0, rel=1e-10)
    points, before = tagged_points(fine), tagged_points(coarse)
    assert sorted(points) == sorted(before) and len(points) == 10
    assert np.allclose([points[k] for k in before], list(before.values()), rtol=0, atol=1e-12)
    assert len(fine.junctions) == 2


def test_an_embedded_curve_from_the_boundary_is_no_slit(tmp_path):
    """A crack path embedded from a boundary point into the surface (built-in kernel)
    stays interior: not cut open, no corner where it leaves the boundary, a boundary
    junction whose two sectors split the straight angle."""
    text = """Point(1) = {0, 0, 0}; Point(2) = {2, 0, 0}; Point(3) = {2, 1, 0};
Point(4) = {0, 1, 0}; Point(5) = {1, 0, 0}; Point(6) = {1.3, 0.5, 0};
Line(1) = {1, 5}; Line(2) = {5, 2}; Line(3) = {2, 3}; Line(4) = {3, 4}; Line(5) = {4, 1};
Curve Loop(1) = {1, 2, 3, 4, 5}; Plane Surface(1) = {1};
Line(6) = {5, 6};
Curve{6} In Surface{1};
"""
    domain = load(COMM, write(tmp_path, "crack.geo", text), 0.1)
    assert domain.euler_characteristic == 1 and domain.notes == ()
    assert area(domain) == pytest.approx(2.0, rel=1e-12)
    outside, inside = curve_lengths(domain)
    assert inside == pytest.approx({6: math.hypot(0.3, 0.5)}, rel=1e-10)
    assert sum(outside.values()) == pytest.approx(6.0, rel=1e-10)
    assert len(domain.corners) == 4
    at = {(round(j.x, 9), round(j.y, 9)): j for j in domain.junctions}
    assert sorted(at) == [(1.0, 0.0), (1.3, 0.5)]
    foot = at[(1.0, 0.0)]
    assert foot.on_boundary
    assert foot.sectors == pytest.approx((math.atan2(0.5, 0.3), math.pi - math.atan2(0.5, 0.3)))
    assert foot.index == 0 and at[(1.3, 0.5)].index == 0


def test_a_msh_file_keeps_its_regions_interface_and_groups(tmp_path):
    """A ``.msh`` Gmsh wrote from the two-region file (MSH 4.1, with its entities): the
    same regions, interface, points and named groups as the ``.geo``."""
    import gmsh

    path = tmp_path / "two.msh"
    if COMM.rank == 0:
        (tmp_path / "two.geo").write_text(TWO_REGIONS)
        gmsh.initialize(argv=[], readConfigFiles=False)
        try:
            gmsh.option.setNumber("General.Terminal", 0)
            gmsh.merge(str(tmp_path / "two.geo"))
            gmsh.option.setNumber("Mesh.MeshSizeMax", 0.2)
            gmsh.option.setNumber("Mesh.SaveAll", 1)
            gmsh.model.mesh.generate(2)
            gmsh.write(str(path))
        finally:
            gmsh.finalize()
    COMM.Barrier()
    domain = load(COMM, path)
    areas = region_areas(domain)
    assert sorted(areas) == [1, 2]
    assert list(areas.values()) == pytest.approx([1.0, 1.0], rel=1e-10)
    outside, inside = curve_lengths(domain)
    assert inside == pytest.approx({2: 1.0}, rel=1e-10)
    assert sum(outside.values()) == pytest.approx(6.0, rel=1e-10)
    assert len(tagged_points(domain)) == 6
    assert {(g.dim, g.tag, g.name) for g in domain.physical_groups} == {
        (0, 21, "origin"), (1, 11, "inlet"), (1, 12, "interface"), (2, 5, "iron"),
        (2, 6, "copper")}
