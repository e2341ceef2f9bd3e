"""Meshes from ufl_frames.mesh: built-in shapes, user files, errors; serial and MPI."""

import math
from pathlib import Path

import numpy as np
import pytest

from ufl_frames.bootstrap import init_petsc

init_petsc([])  # not pytest's command line

import dolfinx  # noqa: E402
import dolfinx.fem.petsc  # noqa: E402
import gmsh  # noqa: E402
import ufl  # noqa: E402
from mpi4py import MPI  # noqa: E402

from ufl_frames.frames2d.singularities import locate_singularities  # noqa: E402
from ufl_frames.mesh import (  # noqa: E402
    Domain,
    GeometryError,
    annulus,
    build,
    build_nested,
    load,
    meshing,  # noqa: E402
    piano,
    piano_area,
    piano_perimeter,
    piano_points,
)
from ufl_frames.mesh.builtin import PIANO_CONCAVE_RADIUS, PIANO_CONVEX_RADIUS  # noqa: E402

MESHES = Path(__file__).resolve().parents[2] / "meshes"
COMM = MPI.COMM_WORLD
H = 0.1  # coarse: the suite must stay fast


def integrate(domain, measure):
    mesh = domain.mesh
    form = dolfinx.fem.form(dolfinx.fem.Constant(mesh, 1.0) * measure(domain=mesh))
    return mesh.comm.allreduce(dolfinx.fem.assemble_scalar(form), op=MPI.SUM)


def num_cells(domain):
    return domain.mesh.topology.index_map(2).size_global


def assert_p1_triangles_2d(domain):
    assert isinstance(domain, Domain)
    mesh = domain.mesh
    assert mesh.geometry.dim == 2
    assert mesh.topology.dim == 2
    assert mesh.topology.cell_type == dolfinx.mesh.CellType.triangle
    assert mesh.geometry.cmaps[0].degree == 1
    assert num_cells(domain) > 0


# --- built-in shapes --------------------------------------------------------------


def test_annulus_area_and_boundary():
    mesh = annulus(COMM, H)
    assert_p1_triangles_2d(mesh)
    # Inscribed polygons: both errors are O(h²) and negative.
    assert integrate(mesh, ufl.dx) == pytest.approx(3 * math.pi / 4, rel=2e-3)
    assert integrate(mesh, ufl.ds) == pytest.approx(3 * math.pi, rel=2e-3)
    r = np.linalg.norm(mesh.mesh.geometry.x[:, :2], axis=1)
    assert r.min() >= 0.5 - 1e-12 and r.max() <= 1.0 + 1e-12


def test_annulus_custom_radii():
    mesh = annulus(COMM, 0.2, r_inner=1.0, r_outer=2.0)
    assert integrate(mesh, ufl.dx) == pytest.approx(3 * math.pi, rel=5e-3)
    with pytest.raises(GeometryError, match="r_inner must be smaller"):
        annulus(COMM, 0.2, r_inner=1.0, r_outer=0.5)
    with pytest.raises(GeometryError, match="r_inner"):
        annulus(COMM, 0.2, r_inner=-1.0)


def test_piano_area_and_boundary():
    mesh = piano(COMM, H)
    assert_p1_triangles_2d(mesh)
    assert integrate(mesh, ufl.dx) == pytest.approx(piano_area(), rel=2e-3)
    assert integrate(mesh, ufl.ds) == pytest.approx(piano_perimeter(), rel=2e-3)
    x = COMM.allgather(mesh.mesh.geometry.x[:, :2])
    x = np.concatenate(x)
    assert np.allclose(x.min(axis=0), [0, 0]) and np.allclose(x.max(axis=0), [2, 1.2])


def test_large_meshes_are_refined_coarse_meshes(monkeypatch):
    """Above REFINE_ABOVE triangles Gmsh meshes at 2^k h and splits k times: about the
    same count and edge length as meshing at h, the new boundary points on the circles
    (to rounding; a chord midpoint would be off by h²/8r), and a note says so."""
    direct = annulus(COMM, 0.05)
    monkeypatch.setattr(meshing, "REFINE_ABOVE", 300)
    refined = annulus(COMM, 0.05)
    assert any("refined 2 time(s)" in note for note in refined.notes), refined.notes
    assert not any("refined" in note for note in direct.notes)
    assert 0.7 < num_cells(refined) / num_cells(direct) < 1.4
    assert refined.mesh_size == pytest.approx(direct.mesh_size, rel=0.15)
    r = np.linalg.norm(refined.mesh.geometry.x[:, :2], axis=1)
    on_boundary = (np.abs(r - 0.5) < 1e-3) | (np.abs(r - 1.0) < 1e-3)
    distance = np.minimum(np.abs(r - 0.5), np.abs(r - 1.0))[on_boundary]
    assert distance.max(initial=0.0) < 1e-12
    assert integrate(refined, ufl.ds) == pytest.approx(3 * math.pi, rel=2e-3)


def _vertices(domain):
    """Every vertex of the mesh (all ranks), rounded for matching."""
    x = domain.mesh.geometry.x[: domain.mesh.topology.index_map(0).size_local, :2]
    return {tuple(p) for part in COMM.allgather(np.round(x, 10).tolist()) for p in part}


@pytest.mark.parametrize("shape", ["piano", "annulus"])
def test_refinements_give_a_mesh_nested_in_the_coarser_one(shape):
    """``refinements=k``: the mesh of size factor 2^k split k times, so four times its
    triangles per split and all its vertices; the new boundary vertices lie on the
    curves (the annulus' circles to rounding), the new interior ones at midpoints of
    coarse edges."""
    coarse = build(COMM, shape, mesh_size=H, size_factor=2.0)
    fine = build(COMM, shape, mesh_size=H, refinements=1)
    assert num_cells(fine) == 4 * num_cells(coarse)
    coarse_vertices, fine_vertices = _vertices(coarse), _vertices(fine)
    assert coarse_vertices <= fine_vertices
    assert len(fine_vertices) == fine.num_vertices
    if shape == "annulus":
        r = np.linalg.norm(np.array(sorted(fine_vertices)), axis=1)
        on_circle = np.minimum(np.abs(r - 0.5), np.abs(r - 1.0))
        boundary = on_circle < 1e-3 * H
        assert boundary.sum() == 2 * sum(
            1 for p in coarse_vertices
            if min(abs(np.hypot(*p) - 0.5), abs(np.hypot(*p) - 1.0)) < 1e-3 * H)
        assert on_circle[boundary].max() < 1e-9  # the coordinates are rounded to 1e-10
    assert integrate(fine, ufl.dx) == pytest.approx(integrate(coarse, ufl.dx), rel=0.02)


def test_build_nested_splits_one_coarse_mesh():
    """Coarse to fine, four times the triangles per level from one Gmsh mesh; the finest
    about the requested size (where the coarsest is not held finer by the curves' points
    per turn, as the piano's is at 0.4)."""
    levels = build_nested(COMM, "piano", 3, mesh_size=H / 2)
    direct = build(COMM, "piano", mesh_size=H / 2)
    counts = [num_cells(d) for d in levels]
    assert counts == [counts[0], 4 * counts[0], 16 * counts[0]]
    assert levels[-1].mesh_size == pytest.approx(direct.mesh_size, rel=0.15)
    assert _vertices(levels[0]) <= _vertices(levels[1]) <= _vertices(levels[2])
    assert [d.euler_characteristic for d in levels] == [direct.euler_characteristic] * 3


@pytest.mark.parametrize("value", [-1, 1.5, True, "2"])
def test_refinements_must_be_a_non_negative_integer(value):
    with pytest.raises(GeometryError, match="refinements must be a non-negative integer"):
        build(COMM, "piano", mesh_size=H, refinements=value)
    with pytest.raises(GeometryError, match="levels must be a positive integer"):
        build_nested(COMM, "piano", 0, mesh_size=H)


def test_mesh_size_refines():
    coarse, fine = piano(COMM, 0.2), piano(COMM, 0.1)
    assert 3 < num_cells(fine) / num_cells(coarse) < 5


@pytest.mark.parametrize("name", ["annulus", "piano"])
def test_geo_sources_match_builders(name):
    built = build(COMM, name, H)
    loaded = load(COMM, MESHES / f"{name}.geo", H)
    assert num_cells(loaded) == num_cells(built)
    assert integrate(loaded, ufl.dx) == pytest.approx(integrate(built, ufl.dx), rel=1e-12)
    assert integrate(loaded, ufl.ds) == pytest.approx(integrate(built, ufl.ds), rel=1e-12)


@pytest.mark.parametrize("name", ["annulus", "piano"])
def test_distributed_mesh_has_all_cells(name):
    """Built on rank 0 and distributed: same global cells as a mesh built on each rank alone."""
    whole = build(COMM, name, H)
    alone = build(MPI.COMM_SELF, name, H)
    assert num_cells(whole) == num_cells(alone)
    local = whole.mesh.topology.index_map(2).size_local
    assert COMM.allreduce(local, op=MPI.SUM) == num_cells(alone)
    if COMM.size > 1:
        assert min(COMM.allgather(local)) > 0


def test_quiet_by_default(capfd, monkeypatch):
    monkeypatch.delenv("UFL_FRAMES_GMSH_VERBOSE", raising=False)
    piano(COMM, 0.3)
    out, err = capfd.readouterr()
    assert "Info" not in out + err


# --- the piano's cross field ------------------------------------------------------


def harmonic_cross_field(mesh):
    """Boundary-aligned cross field: z = e^{4iψ} (ψ the boundary normal angle) on the
    boundary, harmonic inside; returned as isotropic Odeco coefficients with C ∝ z.

    All straight sides of the piano are axis-parallel (z = 1); on the arcs z =
    e^{4i·angle(x − centre)}, which is 1 at their ends, so z is continuous.
    """
    pts = piano_points()
    arcs = [(pts[6], PIANO_CONCAVE_RADIUS), (pts[7], PIANO_CONVEX_RADIUS)]

    def boundary_z(x):
        z = np.ones(x.shape[1], dtype=complex)
        for (cx, cy), r in arcs:
            dx, dy = x[0] - cx, x[1] - cy
            on_arc = np.abs(np.hypot(dx, dy) - r) < 1e-8
            z[on_arc] = np.exp(4j * np.arctan2(dy[on_arc], dx[on_arc]))
        return z

    V = dolfinx.fem.functionspace(mesh, ("Lagrange", 1))
    mesh.topology.create_connectivity(1, 2)
    facets = dolfinx.mesh.exterior_facet_indices(mesh.topology)
    dofs = dolfinx.fem.locate_dofs_topological(V, 1, facets)
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    a = ufl.inner(ufl.grad(u), ufl.grad(v)) * ufl.dx
    L = dolfinx.fem.Constant(mesh, 0.0) * v * ufl.dx
    parts = []
    for name, part in (("re", np.real), ("im", np.imag)):
        g = dolfinx.fem.Function(V)
        g.interpolate(lambda x, part=part: part(boundary_z(x)))
        problem = dolfinx.fem.petsc.LinearProblem(
            a,
            L,
            bcs=[dolfinx.fem.dirichletbc(g, dofs)],
            petsc_options_prefix=f"test_piano_{name}_",
            petsc_options={"ksp_type": "preonly", "pc_type": "lu"},
        )
        parts.append(problem.solve())
    re, im = parts
    W = dolfinx.fem.functionspace(mesh, ("Lagrange", 1, (5,)))
    q = dolfinx.fem.Function(W)
    zero = 0.0 * re
    values = ufl.as_vector([0.75 * math.sqrt(2) + zero, zero, zero, 0.25 * re, 0.25 * im])
    q.interpolate(dolfinx.fem.Expression(values, W.element.interpolation_points))
    return q


@pytest.mark.parametrize("h", [0.1, 0.05])
def test_piano_has_plus_left_and_minus_right(h):
    found = locate_singularities(harmonic_cross_field(piano(COMM, h).mesh))
    assert [s["index"] for s in found] == [0.25, -0.25], found
    plus, minus = found
    assert plus["x"] < 0.7 and minus["x"] > 1.3
    assert np.hypot(plus["x"] - 0.41, plus["y"] - 0.79) < 0.1
    assert np.hypot(minus["x"] - 1.43, minus["y"] - 0.63) < 0.1


def test_annulus_has_no_singularity():
    mesh = annulus(COMM, 0.15).mesh
    W = dolfinx.fem.functionspace(mesh, ("Lagrange", 1, (5,)))
    q = dolfinx.fem.Function(W)
    # Cross aligned with e_r: 4t = 4 * polar angle.
    q.interpolate(
        lambda x: np.vstack(
            [
                np.full(x.shape[1], 0.75 * math.sqrt(2)),
                0 * x[0],
                0 * x[0],
                0.25 * np.cos(4 * np.arctan2(x[1], x[0])),
                0.25 * np.sin(4 * np.arctan2(x[1], x[0])),
            ]
        )
    )
    assert locate_singularities(q) == []


# --- user files -------------------------------------------------------------------


def write_rectangle(tmp_path, suffix, width=2.0, height=1.0):
    """A width × height rectangle written by Gmsh (every rank writes its own copy)."""
    path = tmp_path / f"rect{suffix}"
    if suffix == ".geo":
        path.write_text(
            'SetFactory("OpenCASCADE");\n'
            f"Rectangle(1) = {{0, 0, 0, {width}, {height}}};\n"
            "Mesh.MeshSizeMax = 1.0;\n"  # overridden by load()'s mesh_size
        )
        return path
    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.occ.addRectangle(0, 0, 0, width, height)
        gmsh.model.occ.synchronize()
        if suffix == ".msh":
            gmsh.option.setNumber("Mesh.MeshSizeMax", 0.25)
            gmsh.model.mesh.generate(2)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()
    return path


@pytest.mark.parametrize("suffix", [".geo", ".msh", ".brep", ".step", ".stp"])
def test_load_user_rectangle(tmp_path, suffix):
    if suffix == ".stp":
        path = write_rectangle(tmp_path, ".step").rename(tmp_path / "rect.stp")
    else:
        path = write_rectangle(tmp_path, suffix)
    mesh = load(COMM, path, mesh_size=0.25)
    assert_p1_triangles_2d(mesh)
    assert integrate(mesh, ufl.dx) == pytest.approx(2.0, rel=1e-12)
    assert integrate(mesh, ufl.ds) == pytest.approx(6.0, rel=1e-12)
    # build() takes paths (str or Path) too; mesh_size matters except for .msh.
    finer = build(COMM, str(path), mesh_size=0.125)
    if suffix == ".msh":
        assert num_cells(finer) == num_cells(mesh)
    else:
        assert num_cells(finer) > 2 * num_cells(mesh)


def test_msh_without_physical_groups_and_second_order(tmp_path):
    path = tmp_path / "p2.msh"
    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.occ.addDisk(0, 0, 0, 1, 1)
        gmsh.model.occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.3)
        gmsh.model.mesh.generate(2)
        gmsh.model.mesh.setOrder(2)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()
    mesh = load(COMM, path)
    assert_p1_triangles_2d(mesh)
    assert integrate(mesh, ufl.dx) == pytest.approx(math.pi, rel=0.05)


def test_caller_gmsh_session_is_kept():
    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.model.add("mine")
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("Mesh.MeshSizeMax", 7.0)
        piano(COMM, 0.3)
        with pytest.raises(GeometryError):
            load(COMM, MESHES / "no-such-file.geo")
        assert gmsh.isInitialized()
        assert gmsh.model.getCurrent() == "mine"
        assert gmsh.option.getNumber("Mesh.MeshSizeMax") == 7.0
        assert gmsh.option.getNumber("General.AbortOnError") == 2
    finally:
        gmsh.finalize()


# --- errors -----------------------------------------------------------------------


def raises_one_line(match, call, *args, **kwargs):
    with pytest.raises(GeometryError, match=match) as info:
        call(*args, **kwargs)
    message = str(info.value)
    assert message and "\n" not in message
    assert not gmsh.isInitialized(), "gmsh left initialised after an error"
    return message


def test_missing_file(tmp_path):
    for suffix in (".geo", ".msh", ".step"):
        raises_one_line("not found", load, COMM, tmp_path / f"none{suffix}")
    raises_one_line("not found", build, COMM, str(tmp_path / "none.msh"))


@pytest.mark.parametrize(
    "suffix, content, match",
    [
        (".msh", b"this is not a mesh\n\x00\x01\x02", "not a Gmsh mesh"),
        (".msh", b"$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\ngarbage\n", "cannot read|no 2D"),
        (".geo", b"this is not a script\nat all\n", "syntax error"),
        (".step", b"ISO-10303-21;\ngarbage\n", "cannot read"),
        (".brep", b"garbage\n", "cannot read"),
    ],
)
def test_corrupt_file(tmp_path, suffix, content, match):
    path = tmp_path / f"corrupt{suffix}"
    path.write_bytes(content)
    message = raises_one_line(match, load, COMM, path)
    assert "corrupt" in message
    # A failed parse must not break later ones (Gmsh keeps a broken lexer otherwise).
    mesh = load(COMM, write_rectangle(tmp_path, ".geo"), mesh_size=0.5)
    assert integrate(mesh, ufl.dx) == pytest.approx(2.0)


def test_3d_mesh_rejected(tmp_path):
    path = tmp_path / "box.msh"
    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.occ.addBox(0, 0, 0, 1, 1, 1)
        gmsh.model.occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.5)
        gmsh.model.mesh.generate(3)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()
    raises_one_line("3D mesh.*tetrahedra", load, COMM, path)


def test_volume_geometry_rejected(tmp_path):
    path = tmp_path / "box.geo"
    path.write_text('SetFactory("OpenCASCADE");\nBox(1) = {0, 0, 0, 1, 1, 1};\n')
    raises_one_line("volumes", load, COMM, path)


def test_tilted_plane_meshed_in_it_non_planar_and_empty_rejected(tmp_path):
    from ufl_frames.fem.scales import area

    tilted = tmp_path / "tilted.geo"
    tilted.write_text(
        'SetFactory("OpenCASCADE");\nRectangle(1) = {0, 0, 0, 1, 1};\n'
        "Rotate {{1, 0, 0}, {0, 0, 0}, 0.3} { Surface{1}; }\n"
    )
    domain = load(COMM, tilted, mesh_size=0.2)  # in its own plane: the unit square again
    assert any("tilted plane" in note for note in domain.notes)
    assert area(domain.mesh) == pytest.approx(1.0, rel=1e-12)
    assert sorted(round(c.angle, 9) for c in domain.corners) == [round(np.pi / 2, 9)] * 4
    # the domain's plane takes the mesh back into the tilted plane: the square's corners
    c, s = np.cos(0.3), np.sin(0.3)
    corners = np.array([[0, 0, 0], [1, 0, 0], [1, c, s], [0, c, s]])
    xyz = domain.plane.to_3d(domain.mesh.geometry.x[:, :2])
    assert np.abs(xyz @ np.array([0, -s, c])).max() < 1e-12
    gathered = np.concatenate(COMM.allgather(xyz))
    nearest = np.linalg.norm(gathered[None] - corners[:, None], axis=2).min(axis=1)
    assert nearest.max() < 1e-12
    assert np.allclose(domain.plane.to_plane(xyz), domain.mesh.geometry.x[:, :2], atol=1e-12)
    assert load(COMM, MESHES / "piano.geo", mesh_size=0.2).plane is None
    bent = tmp_path / "bent.geo"  # two squares in two planes
    bent.write_text(
        'SetFactory("OpenCASCADE");\nRectangle(1) = {0, 0, 0, 1, 1};\n'
        "Rectangle(2) = {2, 0, 0, 1, 1};\n"
        "Rotate {{1, 0, 0}, {0, 0, 0}, 0.3} { Surface{2}; }\n"
    )
    raises_one_line("not planar", load, COMM, bent)
    empty = tmp_path / "points.geo"
    empty.write_text("Point(1) = {0, 0, 0};\n")
    raises_one_line("no 2D surface", load, COMM, empty)


def test_unknown_name_and_extension(tmp_path):
    message = raises_one_line("unknown geometry 'violin'", build, COMM, "violin")
    assert "annulus" in message and "piano" in message
    text = tmp_path / "shape.txt"
    text.write_text("hello")
    raises_one_line("unsupported geometry file extension '.txt'", load, COMM, text)
    raises_one_line("unsupported", build, COMM, text)


@pytest.mark.parametrize("bad", [-0.1, 0.0, float("nan"), float("inf"), "0.1", None, True])
def test_bad_mesh_size(bad):
    raises_one_line("mesh_size must be a positive finite number", piano, COMM, bad)
    raises_one_line("mesh_size", annulus, COMM, bad)
    if bad is None:
        return  # build() and load() take None: a size relative to the shape
    raises_one_line("mesh_size", build, COMM, "piano", bad)
    raises_one_line("mesh_size", load, COMM, MESHES / "piano.geo", bad)
    raises_one_line("size_factor", build, COMM, "piano", 0.1, bad)


def test_tilted_msh_keeps_its_plane(tmp_path_factory):
    import gmsh

    root = Path(COMM.bcast(str(tmp_path_factory.mktemp("tilted_msh")), root=0))
    path = root / "tilted.msh"
    c, s = np.cos(0.4), np.sin(0.4)
    if COMM.rank == 0:  # a triangle mesh of the unit square tilted about y, moved up by 2
        owns = not gmsh.isInitialized()
        if owns:
            gmsh.initialize(argv=[], readConfigFiles=False)
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("tilted")
        gmsh.model.occ.addRectangle(0, 0, 0, 1, 1)
        gmsh.model.occ.rotate([(2, 1)], 0, 0, 0, 0, 1, 0, 0.4)
        gmsh.model.occ.translate([(2, 1)], 0, 0, 2)
        gmsh.model.occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.25)
        gmsh.model.mesh.generate(2)
        gmsh.write(str(path))
        gmsh.model.remove()
        if owns:
            gmsh.finalize()
    COMM.Barrier()
    domain = load(COMM, path)
    assert domain.plane is not None
    xyz = domain.plane.to_3d(domain.mesh.geometry.x[:, :2])
    normal = np.array([s, 0, c])  # the rotated z axis
    assert np.abs((xyz - [0, 0, 2]) @ normal).max() < 1e-12
    assert abs(abs(np.dot(np.cross(domain.plane.e1, domain.plane.e2), normal)) - 1) < 1e-12
    gathered = np.concatenate(COMM.allgather(xyz))
    corners = np.array([[0, 0, 2], [c, 0, 2 - s], [c, 1, 2 - s], [0, 1, 2]])
    assert np.linalg.norm(gathered[None] - corners[:, None], axis=2).min(axis=1).max() < 1e-12
