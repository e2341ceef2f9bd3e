"""Files as Gmsh users write them: centre points, holes, several surfaces, quad requests,
unit scales, higher-order meshes; and Poincaré–Hopf on every test geometry. Serial and MPI.
"""

import math

import numpy as np
import pytest

from ufl_frames.bootstrap import init_petsc

init_petsc([])  # not pytest's command line

import dolfinx  # noqa: E402
import gmsh  # noqa: E402
import ufl  # noqa: E402
from mpi4py import MPI  # noqa: E402

import ufl_frames.mesh  # noqa: E402
from ufl_frames.fem import energy  # noqa: E402
from ufl_frames.fem.constraints import frame_constraints  # noqa: E402
from ufl_frames.frames2d import singularities  # noqa: E402
from ufl_frames.mesh import GeometryError, load  # noqa: E402
from ufl_frames.mesh.meshing import AUTO_TRIANGLES  # noqa: E402
from ufl_frames.solvers import mbo  # noqa: E402

COMM = MPI.COMM_WORLD

# The five lines: a disc whose circles use a centre point no triangle touches.
DISC = """Point(1) = {0, 0, 0}; Point(2) = {1, 0, 0}; Point(3) = {0, 1, 0};
Point(4) = {-1, 0, 0}; Point(5) = {0, -1, 0};
Circle(1) = {2, 1, 3}; Circle(2) = {3, 1, 4}; Circle(3) = {4, 1, 5}; Circle(4) = {5, 1, 2};
Curve Loop(1) = {1, 2, 3, 4}; Plane Surface(1) = {1};
"""


def disc_with_holes(holes):
    """Built-in kernel: the unit disc less discs (cx, cy, r), every circle by 4 arcs
    around a centre point, as Gmsh's tutorial t4 writes them."""
    lines, loops = [], []
    p = c = 0
    for cx, cy, r in [(0.0, 0.0, 1.0), *holes]:
        centre = p + 1
        lines.append(f"Point({centre}) = {{{cx}, {cy}, 0}};")
        for k in range(4):
            a = k * math.pi / 2
            lines.append(f"Point({centre + 1 + k}) = {{{cx + r * math.cos(a)}, "
                         f"{cy + r * math.sin(a)}, 0}};")
        for k in range(4):
            lines.append(f"Circle({c + 1 + k}) = {{{centre + 1 + k}, {centre}, "
                         f"{centre + 1 + (k + 1) % 4}}};")
        loops.append(f"Curve Loop({len(loops) + 1}) = {{{c + 1}, {c + 2}, {c + 3}, {c + 4}}};")
        p, c = p + 5, c + 4
    lines += loops
    lines.append(f"Plane Surface(1) = {{{', '.join(str(i + 1) for i in range(len(loops)))}}};")
    return "\n".join(lines) + "\n"


def write(tmp_path, name, text):
    path = tmp_path / name
    if COMM.rank == 0:
        path.write_text(text)
    COMM.Barrier()
    return path


def area(domain):
    form = dolfinx.fem.form(dolfinx.fem.Constant(domain.mesh, 1.0) * ufl.dx(domain=domain.mesh))
    return COMM.allreduce(dolfinx.fem.assemble_scalar(form), op=MPI.SUM)


def all_boundary_rows(domain, V):
    """(x, y, ψ) of the local boundary rows that have a CAD angle."""
    angles = domain.boundary_angles(V)
    x = V.tabulate_dof_coordinates()[:, :2]
    ok = np.isfinite(angles)
    return x[ok], angles[ok]


# --- what used to crash or be refused --------------------------------------------------


def test_disc_with_centre_points(tmp_path):
    domain = load(COMM, write(tmp_path, "disc.geo", DISC), mesh_size=0.1)
    assert area(domain) == pytest.approx(math.pi, rel=5e-3)
    assert domain.euler_characteristic == 1 and domain.corners == ()
    assert any("no triangle uses" in note for note in domain.notes)
    assert domain.boundary_curves == [1, 2, 3, 4]
    # The cross angles come from the circles' tangents: exact, not from the mesh edges.
    V = energy.frame_space(domain.mesh)
    x, psi = all_boundary_rows(domain, V)
    assert x.shape[0] > 0 or COMM.size > 1
    polar = np.arctan2(x[:, 1], x[:, 0])
    # (to the precision of the node positions Gmsh writes, ~1e-9 on the unit circle)
    assert np.abs(np.exp(4j * psi) - np.exp(4j * polar)).max(initial=0) < 1e-7


def test_disc_with_holes_and_centre_points(tmp_path):
    holes = [(0.4, 0.0, 0.15), (-0.3, 0.35, 0.1), (-0.2, -0.45, 0.2)]
    domain = load(COMM, write(tmp_path, "holes.geo", disc_with_holes(holes)), 0.08)
    exact = math.pi * (1 - sum(r * r for *_, r in holes))
    assert area(domain) == pytest.approx(exact, rel=1e-2)
    assert domain.euler_characteristic == 1 - len(holes)
    assert domain.corners == ()
    assert len(domain.boundary_curves) == 4 * (1 + len(holes))


def test_small_holes_get_enough_boundary_points(tmp_path):
    """A hole far below the mesh size is still meshed with ≥ 12 points per turn."""
    domain = load(
        COMM, write(tmp_path, "tiny.geo", disc_with_holes([(0.3, 0.2, 0.01)])), 0.2
    )
    V = energy.frame_space(domain.mesh)
    x = V.tabulate_dof_coordinates()[:, :2]
    on_hole = np.abs(np.hypot(x[:, 0] - 0.3, x[:, 1] - 0.2) - 0.01) < 1e-9
    index_map = V.dofmap.index_map
    owned = np.zeros(x.shape[0], dtype=bool)
    owned[: index_map.size_local] = True
    assert COMM.allreduce(int(np.count_nonzero(on_hole & owned)), op=MPI.SUM) >= 12


def test_unused_embedded_and_stray_points(tmp_path):
    text = """SetFactory("OpenCASCADE");
Rectangle(1) = {0, 0, 0, 2, 1};
Point(100) = {5, 5, 0};            // a stray point, far outside
Point(101) = {1, 0.5, 0};
Point{101} In Surface{1};          // an embedded point: a mesh vertex, kept
Point(102) = {3, 3, 0}; Point(103) = {4, 3, 0};
Line(200) = {102, 103};            // a free curve
"""
    domain = load(COMM, write(tmp_path, "stray.geo", text), 0.25)
    assert area(domain) == pytest.approx(2.0, rel=1e-12)
    x = np.concatenate(COMM.allgather(domain.mesh.geometry.x[:, :2]))
    assert x.max() <= 2 + 1e-12  # nothing of the stray point and curve
    assert np.any(np.all(np.isclose(x, [1.0, 0.5]), axis=1))  # the embedded point


def test_several_surfaces_sharing_a_curve(tmp_path):
    text = """Point(1) = {0, 0, 0}; Point(2) = {1, 0, 0}; Point(3) = {2, 0, 0};
Point(4) = {2, 1, 0}; Point(5) = {1, 1, 0}; Point(6) = {0, 1, 0};
Line(1) = {1, 2}; Line(2) = {2, 5}; Line(3) = {5, 6}; Line(4) = {6, 1};
Line(5) = {2, 3}; Line(6) = {3, 4}; Line(7) = {4, 5};
Curve Loop(1) = {1, 2, 3, 4}; Plane Surface(1) = {1};
Curve Loop(2) = {5, 6, 7, -2}; Plane Surface(2) = {2};
"""
    domain = load(COMM, write(tmp_path, "two.geo", text), 0.2)
    assert area(domain) == pytest.approx(2.0, rel=1e-12)
    assert domain.euler_characteristic == 1
    assert 2 not in domain.boundary_curves  # the shared curve is interior
    assert domain.boundary_curves == [1, 3, 4, 5, 6, 7]
    assert len(domain.corners) == 4  # the two T-points on the long sides are straight


def test_overlapping_opencascade_faces_are_fragmented(tmp_path):
    text = """SetFactory("OpenCASCADE");
Rectangle(1) = {0, 0, 0, 2, 1};
Rectangle(2) = {1, 0.5, 0, 2, 1};
"""
    domain = load(COMM, write(tmp_path, "overlap.geo", text), 0.2)
    assert area(domain) == pytest.approx(2 + 2 - 0.5, rel=1e-12)  # the union
    assert any("fragmented" in note for note in domain.notes)
    assert domain.euler_characteristic == 1


def test_touching_without_sharing_nodes_is_refused(tmp_path):
    # The small rectangle touches the square's right side along part of a curve it does
    # not share, with nodes that do not coincide (0.25 + 0.1 k against 0.1 k): the
    # built-in kernel cannot make that conforming. (Had the nodes coincided, merging them
    # would have made the mesh conforming, and the file would be accepted.)
    text = """Point(1) = {0, 0, 0}; Point(2) = {1, 0, 0}; Point(3) = {1, 1, 0};
Point(4) = {0, 1, 0};
Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 1};
Curve Loop(1) = {1, 2, 3, 4}; Plane Surface(1) = {1};
Point(5) = {1, 0.25, 0}; Point(6) = {2, 0.25, 0}; Point(7) = {2, 0.75, 0}; Point(8) = {1, 0.75, 0};
Line(5) = {5, 6}; Line(6) = {6, 7}; Line(7) = {7, 8}; Line(8) = {8, 5};
Curve Loop(2) = {5, 6, 7, 8}; Plane Surface(2) = {2};
"""
    with pytest.raises(GeometryError, match="inside the domain") as info:
        load(COMM, write(tmp_path, "touch.geo", text), 0.1)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    "request_line",
    [
        "Recombine Surface{1};",
        "Transfinite Curve{:} = 9; Transfinite Surface{1}; Recombine Surface{1};",
        "Mesh.RecombineAll = 1;",
        "Mesh.Algorithm = 11;",
        "Mesh.SubdivisionAlgorithm = 1;",
        "Mesh.ElementOrder = 2;",
        "Mesh.Algorithm = 3;",  # MeshAdapt: does not keep to the size cap on some files
    ],
)
def test_quad_and_order_requests_are_overridden(tmp_path, request_line):
    text = f'SetFactory("OpenCASCADE");\nRectangle(1) = {{0, 0, 0, 2, 1}};\n{request_line}\n'
    domain = load(COMM, write(tmp_path, "quads.geo", text), 0.25)
    assert domain.mesh.topology.cell_type == dolfinx.mesh.CellType.triangle
    assert domain.mesh.geometry.cmaps[0].degree == 1
    assert area(domain) == pytest.approx(2.0, rel=1e-12)
    assert domain.notes, "the override must be reported"
    assert domain.mesh_size <= 0.25


def gmsh_write(path, build):
    """Run ``build()`` in a fresh Gmsh session on rank 0 and write ``path``."""
    if COMM.rank == 0:
        gmsh.initialize(readConfigFiles=False, interruptible=False)
        try:
            gmsh.option.setNumber("General.Terminal", 0)
            build()
            gmsh.write(str(path))
        finally:
            gmsh.finalize()
    COMM.Barrier()
    return path


def test_msh_with_quadrilaterals_is_split(tmp_path):
    def build():
        gmsh.model.occ.addRectangle(0, 0, 0, 2, 1)
        gmsh.model.occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.2)
        gmsh.model.mesh.setRecombine(2, 1)
        gmsh.model.mesh.generate(2)

    domain = load(COMM, gmsh_write(tmp_path / "quads.msh", build))
    assert area(domain) == pytest.approx(2.0, rel=1e-12)
    assert any("quadrilaterals split" in note for note in domain.notes)


def test_second_order_msh_keeps_every_node(tmp_path):
    counts = {}

    def build():
        gmsh.model.occ.addDisk(0, 0, 0, 1, 1)
        gmsh.model.occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.3)
        gmsh.model.mesh.generate(2)
        gmsh.model.mesh.setOrder(2)
        counts["nodes"] = gmsh.model.mesh.getNodes()[0].size

    domain = load(COMM, gmsh_write(tmp_path / "p2.msh", build))
    nodes = COMM.bcast(counts.get("nodes"), root=0)
    assert domain.num_vertices == nodes
    assert any("second-order triangles split" in note for note in domain.notes)
    # The mid-edge nodes lie on the circle: the polygon has twice the points.
    assert area(domain) == pytest.approx(math.pi, rel=1e-2)


# --- sizes --------------------------------------------------------------------------------


@pytest.mark.parametrize("unit", [1e-6, 1e-3, 1.0, 1e3])
def test_default_size_is_relative_to_the_shape(tmp_path, unit):
    """A plate with a hole drawn in mm gives about the same mesh read as µm, mm, m or km."""
    w, h, r = 65 * unit, 120 * unit, 10 * unit
    text = (f'SetFactory("OpenCASCADE");\nRectangle(1) = {{0, 0, 0, {w}, {h}}};\n'
            f"Disk(2) = {{{w / 2}, {h / 2}, 0, {r}}};\n"
            "BooleanDifference{ Surface{1}; Delete; }{ Surface{2}; Delete; }\n")
    domain = load(COMM, write(tmp_path, "plate.geo", text))
    cells = domain.num_cells
    assert 0.5 * AUTO_TRIANGLES < cells < 2 * AUTO_TRIANGLES
    reference = load(COMM, write(tmp_path, "plate.geo", text.replace(
        f"{w}, {h}", "65, 120").replace(f"{w / 2}, {h / 2}, 0, {r}", "32.5, 60, 0, 10")))
    assert abs(cells - reference.num_cells) <= 0.02 * cells
    assert domain.mesh_size / unit == pytest.approx(reference.mesh_size, rel=0.02)


def test_file_sizes_are_used_and_scaled(tmp_path):
    text = """Point(1) = {0, 0, 0, 0.1}; Point(2) = {1, 0, 0, 0.1}; Point(3) = {1, 1, 0, 0.1};
Point(4) = {0, 1, 0, 0.1};
Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 1};
Curve Loop(1) = {1, 2, 3, 4}; Plane Surface(1) = {1};
"""
    path = write(tmp_path, "sized.geo", text)
    own = load(COMM, path)
    assert own.requested_mesh_size is None  # the file's sizes
    assert own.mesh_size == pytest.approx(0.1, rel=0.15)
    finer = load(COMM, path, size_factor=0.5)
    assert 3.0 < finer.num_cells / own.num_cells < 5.0
    capped = load(COMM, path, mesh_size=0.05)  # an explicit size caps
    assert capped.num_cells > 3 * own.num_cells
    assert load(COMM, path, mesh_size=0.2).num_cells == own.num_cells  # finer kept


def test_too_many_triangles_refused_before_meshing(tmp_path):
    text = 'SetFactory("OpenCASCADE");\nRectangle(1) = {0, 0, 0, 1, 1};\n'
    with pytest.raises(GeometryError, match="about .* triangles") as info:
        load(COMM, write(tmp_path, "sq.geo", text), mesh_size=1e-5)
    assert "\n" not in str(info.value)
    with pytest.raises(GeometryError, match="limit 100"):
        load(COMM, write(tmp_path, "sq.geo", text), mesh_size=0.05, max_triangles=100)


# --- Poincaré–Hopf on every test geometry --------------------------------------------


L_SHAPE = """SetFactory("OpenCASCADE");
Rectangle(1) = {0, 0, 0, 2, 1}; Rectangle(2) = {0, 0, 0, 1, 2};
BooleanUnion{ Surface{1}; Delete; }{ Surface{2}; Delete; }
"""
TRIANGLE = """Point(1) = {0, 0, 0}; Point(2) = {1, 0, 0};
Point(3) = {0.5, 0.8660254037844386, 0};
Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 1};
Curve Loop(1) = {1, 2, 3}; Plane Surface(1) = {1};
"""


def _hexagon_hole() -> str:
    corners = [(0.4 * math.cos(k * math.pi / 3), 0.4 * math.sin(k * math.pi / 3)) for k in range(6)]
    text = 'SetFactory("OpenCASCADE");\nDisk(1) = {0, 0, 0, 1};\n'
    text += "".join(f"Point({10 + k}) = {{{x}, {y}, 0}};\n" for k, (x, y) in enumerate(corners))
    text += "".join(f"Line({10 + k}) = {{{10 + k}, {10 + (k + 1) % 6}}};\n" for k in range(6))
    return text + (
        "Curve Loop(20) = {10, 11, 12, 13, 14, 15}; Plane Surface(20) = {20};\n"
        "BooleanDifference{ Surface{1}; Delete; }{ Surface{20}; Delete; }\n"
    )


HEXAGON_HOLE = _hexagon_hole()

SHAPES = {
    "piano": (None, 0.1, 1, 0.0),
    "annulus": (None, 0.1, 0, 0.0),
    "disc": (DISC, 0.15, 1, 1.0),
    "holes": (disc_with_holes([(0.4, 0.0, 0.15), (-0.3, 0.3, 0.15)]), 0.1, -1, -1.0),
    "L": (L_SHAPE, 0.15, 1, 0.0),  # 5 convex right angles, 1 reflex
    "triangle": (TRIANGLE, 0.08, 1, 0.25),  # 60° corners round to one quarter turn each
    # The hole's corners are reflex, 240° → k = 3, (2 − k)/4 = −1/4 each, so 0 + 6/4: the cross
    # turns 6 × 30° = 180° around the hole where the tangent turns 360°.
    "hexagonal hole": (HEXAGON_HOLE, 0.1, 0, 1.5),
}


@pytest.mark.parametrize("name", list(SHAPES))
def test_poincare_hopf_on_test_geometries(tmp_path, name):
    """The MBO cross field's singularities sum to χ − Σ_c (2 − k_c)/4 of the geometry.

    Two independent computations: the right side from the topology and the CAD corners,
    the left from the windings of the computed field around every triangle.
    """
    text, h, chi, expected = SHAPES[name]
    if text is None:
        domain = ufl_frames.mesh.build(COMM, name, h)
    else:
        domain = load(COMM, write(tmp_path, f"{name.replace(' ', '_')}.geo", text), h)
    assert domain.euler_characteristic == chi
    angles = [c.angle for c in domain.corners]
    assert singularities.poincare_hopf_sum(chi, angles) == expected
    V = energy.frame_space(domain.mesh)
    constraints = frame_constraints(V, boundary_angles=domain.boundary_angles(V))
    q = mbo.mbo_frame_field(V, constraints=constraints)
    found = singularities.locate_singularities(q)
    check = singularities.index_theorem(found, chi, angles)
    assert check["agrees"], (name, check, found)


SLIT_SQUARE = """Point(1) = {0, 0, 0}; Point(2) = {1, 0, 0}; Point(3) = {1, 1, 0};
Point(4) = {0, 1, 0}; Point(5) = {0, 0.5, 0}; Point(6) = {0.5, 0.5, 0};
Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 5};
Line(5) = {5, 6}; Line(6) = {5, 1};
Curve Loop(1) = {1, 2, 3, 4, 5, -5, 6}; Plane Surface(1) = {1};
"""


def boundary_length(domain):
    mesh = domain.mesh
    form = dolfinx.fem.form(dolfinx.fem.Constant(mesh, 1.0) * ufl.ds(domain=mesh))
    return mesh.comm.allreduce(dolfinx.fem.assemble_scalar(form), op=MPI.SUM)


def test_a_slit_is_cut_open(tmp_path):
    """A square whose one surface runs along a slit and back (curve 5 twice in its loop):
    the mesh is cut open along the slit, so both of its sides are boundary — the boundary
    is 4 + 2 × 0.5 long — and the domain stays a disk (χ = 1): the slit's nodes are
    doubled but for its tip, which the triangles surround."""
    domain = load(COMM, write(tmp_path, "slit.geo", SLIT_SQUARE), 0.05)
    assert area(domain) == pytest.approx(1.0, rel=1e-12)
    assert boundary_length(domain) == pytest.approx(5.0, rel=1e-12)
    assert domain.euler_characteristic == 1
    assert any("slit" in note for note in domain.notes)
    # the tip is a corner of a full turn; the slit's base two corners of a quarter turn
    angles = sorted(round(c.angle / (math.pi / 2)) for c in domain.corners
                    if math.dist((c.x, c.y), (0.0, 0.5)) < 1e-9
                    or math.dist((c.x, c.y), (0.5, 0.5)) < 1e-9)
    assert angles == [1, 1, 4]


def test_a_notch_narrower_than_the_probe_is_not_refused(tmp_path):
    """A V-notch 10⁻⁵ wide at its mouth in one surface: its two sides face each other
    closer than the check for touching surfaces looks, yet they are one surface's
    boundary — the shape itself, not surfaces that overlap."""
    text = """Point(1) = {0, 0, 0}; Point(2) = {0.99999, 0, 0}; Point(3) = {1, 0.4, 0};
Point(4) = {1.00001, 0, 0}; Point(5) = {2, 0, 0}; Point(6) = {2, 1, 0}; Point(7) = {0, 1, 0};
Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 5}; Line(5) = {5, 6};
Line(6) = {6, 7}; Line(7) = {7, 1};
Curve Loop(1) = {1, 2, 3, 4, 5, 6, 7}; Plane Surface(1) = {1};
"""
    domain = load(COMM, write(tmp_path, "notch.geo", text), 0.1)
    assert area(domain) == pytest.approx(2 - 0.5 * 0.4 * 2e-5, rel=1e-12)
