"""``quads.msh`` with the model's entities and physical groups: read back by Gmsh (entities,
groups, names, element counts, coordinates) and by DOLFINx (cell tags = the surface groups,
facet tags = the curve groups; the areas and lengths of every group are the geometry's),
serially and under ``mpirun -n 2``.

Gmsh, mpi4py and DOLFINx are imported inside the tests (skipped where absent: the pure
NumPy environment of ``make test-pure``).

The synthetic model: the plate [0, 2] × [0, 1] as 4 × 2 quads, two regions (x < 1: surface
1, x > 1: surface 2), curves 3 (x = 0), 4 (x = 2), 5 (y = 0 and y = 1) and the interface 6
(x = 1), model points 1..4 at the plate's corners and 7 and 8 at the interface's ends.
"""

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest


def two_regions():
    """Points, quads and the model arrays of the module's plate."""
    nx, ny = 4, 2
    xs, ys = np.linspace(0.0, 2.0, nx + 1), np.linspace(0.0, 1.0, ny + 1)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    x = np.stack([X.ravel(), Y.ravel()], axis=1)
    idx = np.arange(x.shape[0]).reshape(nx + 1, ny + 1)
    q = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 4)
    x[idx[2, 1]] += (0.1, 0.0)  # the interface bends: coordinates are kept
    region = np.where(x[q].mean(axis=1)[:, 0] < 1.0, 1, 2)
    edges, tags = [], []
    for tag, column in ((3, 0), (6, 2), (4, nx)):
        for j in range(ny):
            edges.append((idx[column, j], idx[column, j + 1]))
            tags.append(tag)
    for row in (0, ny):
        for i in range(nx):
            edges.append((idx[i, row], idx[i + 1, row]))
            tags.append(5)
    nodes = [idx[0, 0], idx[nx, 0], idx[nx, ny], idx[0, ny], idx[2, 0], idx[2, ny]]
    return dict(points=x, quads=q, quad_region=region, curve_edges=np.array(edges),
                edge_curve=np.array(tags), point_nodes=np.array(nodes),
                point_tag=np.array([1, 2, 3, 4, 7, 8]))


def group(dim, tag, name, entities):
    return SimpleNamespace(dim=dim, tag=tag, name=name, entities=tuple(entities))


GROUPS = (group(2, 1, "steel", [1]), group(2, 2, "rubber", [2]), group(1, 10, "inlet", [3]),
          group(1, 11, "outlet", [4]), group(1, 12, "wall", [5]),
          group(1, 13, "interface", [6]), group(0, 20, "corner", [1]),
          group(1, 14, "nowhere", [99]))  # an entity with no elements: left out


def _shared_tmp(tmp_path):
    from mpi4py import MPI

    return Path(MPI.COMM_WORLD.bcast(str(tmp_path), root=0)), MPI.COMM_WORLD


def _write(path, groups=GROUPS):
    from ufl_frames.quads.msh import write_quad_msh

    m = two_regions()
    return write_quad_msh(path, m.pop("points"), m.pop("quads"), groups=groups, **m)


class _Reader:
    """The file opened in a fresh Gmsh model; Gmsh left as found."""

    def __init__(self, path):
        import gmsh

        self.gmsh, self.path = gmsh, path

    def __enter__(self):
        gmsh = self.gmsh
        self.owns = not gmsh.isInitialized()
        if self.owns:
            gmsh.initialize(argv=[], readConfigFiles=False)
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("read back")
        gmsh.open(str(self.path))
        return gmsh

    def __exit__(self, *exc):
        if self.owns:
            self.gmsh.finalize()
        else:
            self.gmsh.model.remove()


def test_entities_and_groups_read_back_by_gmsh(tmp_path):
    pytest.importorskip("gmsh")
    m = two_regions()
    path = _write(tmp_path / "plate.msh")
    with _Reader(path) as gmsh:
        assert sorted(gmsh.model.getEntities(2)) == [(2, 1), (2, 2)]
        assert sorted(gmsh.model.getEntities(1)) == [(1, 3), (1, 4), (1, 5), (1, 6)]
        assert sorted(gmsh.model.getEntities(0)) == [(0, 1), (0, 2), (0, 3), (0, 4), (0, 7),
                                                     (0, 8)]
        groups = {(d, t): gmsh.model.getPhysicalName(d, t)
                  for d, t in gmsh.model.getPhysicalGroups()}
        assert groups == {(2, 1): "steel", (2, 2): "rubber", (1, 10): "inlet",
                          (1, 11): "outlet", (1, 12): "wall", (1, 13): "interface",
                          (0, 20): "corner"}
        assert list(gmsh.model.getEntitiesForPhysicalGroup(1, 12)) == [5]
        # every quad in its region, every line on its curve, the corner's node on point 1
        for r in (1, 2):
            types, tags, nodes = gmsh.model.mesh.getElements(2, r)
            assert list(types) == [3]
            assert np.array_equal(np.sort(tags[0]) - 1, np.flatnonzero(m["quad_region"] == r))
        for c, count in ((3, 2), (4, 2), (5, 8), (6, 2)):
            types, _, nodes = gmsh.model.mesh.getElements(1, c)
            lines = nodes[0].reshape(-1, 2) - 1
            assert list(types) == [1] and len(lines) == count
            mine = m["curve_edges"][m["edge_curve"] == c]
            assert {tuple(sorted(e)) for e in lines.tolist()} == \
                {tuple(sorted(e)) for e in mine.tolist()}
        types, _, nodes = gmsh.model.mesh.getElements(0, 1)
        assert list(types) == [15] and list(nodes[0]) == [m["point_nodes"][0] + 1]
        tags, coords, _ = gmsh.model.mesh.getNodes()
        assert np.array_equal(coords.reshape(-1, 3)[np.argsort(tags), :2], m["points"])
        assert sorted(gmsh.model.getBoundary([(2, 1)], oriented=False)) == \
            [(1, 3), (1, 5), (1, 6)]


def test_without_groups_every_element_is_saved(tmp_path):
    pytest.importorskip("gmsh")
    path = _write(tmp_path / "bare.msh", groups=())
    with _Reader(path) as gmsh:
        assert gmsh.model.getPhysicalGroups() == []
        counts = {dim: sum(len(t) for t in gmsh.model.mesh.getElements(dim)[1])
                  for dim in (0, 1, 2)}
        assert counts == {0: 6, 1: 14, 2: 8}
        assert len(gmsh.model.getEntities(2)) == 2


def test_bad_model_arrays_are_refused(tmp_path):
    pytest.importorskip("gmsh")
    from ufl_frames.quads.msh import write_quad_msh

    m = two_regions()
    x, q = m.pop("points"), m.pop("quads")
    with pytest.raises(ValueError, match="quad_region must have shape"):
        write_quad_msh(tmp_path / "a.msh", x, q, **{**m, "quad_region": m["quad_region"][1:]})
    with pytest.raises(ValueError, match="positive"):
        write_quad_msh(tmp_path / "a.msh", x, q, **{**m, "edge_curve": 0 * m["edge_curve"]})
    with pytest.raises(ValueError, match="outside"):
        write_quad_msh(tmp_path / "a.msh", x, q, **{**m, "point_nodes": m["point_nodes"] + 99})
    with pytest.raises(ValueError, match="coordinates must be finite with shape"):
        write_quad_msh(tmp_path / "a.msh", x, q, coordinates=np.zeros((len(x), 2)), **m)


def test_written_at_given_3d_coordinates(tmp_path):
    pytest.importorskip("gmsh")
    from ufl_frames.quads.msh import write_quad_msh, write_quad_vtu

    m = two_regions()
    x, q = m.pop("points"), m.pop("quads")
    xyz = np.c_[x, 0.5 * x[:, 0] - 2.0]  # the plate in the plane z = x/2 - 2
    for model in (m, {}):  # with the model's entities, and the bare surface
        path = write_quad_msh(tmp_path / "tilted.msh", x, q, coordinates=xyz, **model)
        with _Reader(path) as gmsh:
            tags, coords, _ = gmsh.model.mesh.getNodes()
            assert np.array_equal(coords.reshape(-1, 3)[np.argsort(tags)], xyz)
    from ufl_frames.output.vtk import read_vtk

    back = read_vtk(write_quad_vtu(tmp_path / "tilted.vtu", xyz, q))
    assert np.allclose(back["points"], xyz, rtol=0, atol=1e-12)
    assert np.array_equal(back["cells"], q)


def test_regions_read_back_by_dolfinx(tmp_path):
    pytest.importorskip("mpi4py")
    pytest.importorskip("petsc4py")
    pytest.importorskip("gmsh")
    import ufl_frames.bootstrap  # noqa: F401  (PETSc before DOLFINx)

    pytest.importorskip("dolfinx")
    import dolfinx.io.gmsh
    import ufl
    from dolfinx import fem
    from mpi4py import MPI

    folder, comm = _shared_tmp(tmp_path)
    path = folder / "plate.msh"
    if comm.rank == 0:
        _write(path)
    comm.Barrier()
    shared = dolfinx.mesh.create_cell_partitioner(dolfinx.mesh.GhostMode.shared_facet, 2)
    data = dolfinx.io.gmsh.read_from_msh(path, comm, 0, gdim=2, partitioner=shared)
    mesh = data.mesh
    assert mesh.topology.cell_name() == "quadrilateral"
    assert mesh.topology.index_map(2).size_global == 8
    assert {name: (g.dim, g.tag) for name, g in data.physical_groups.items()} == {
        "steel": (2, 1), "rubber": (2, 2), "inlet": (1, 10), "outlet": (1, 11),
        "wall": (1, 12), "interface": (1, 13), "corner": (0, 20)}

    def total(form):
        return comm.allreduce(fem.assemble_scalar(fem.form(form)), op=MPI.SUM)

    dx = ufl.Measure("dx", domain=mesh, subdomain_data=data.cell_tags)
    ds = ufl.Measure("ds", domain=mesh, subdomain_data=data.facet_tags)
    dS = ufl.Measure("dS", domain=mesh, subdomain_data=data.facet_tags)
    one = fem.Constant(mesh, 1.0)
    # the interface bends 0.1 to the right: a triangle 1 × 0.1 / 2 moves to region 1
    assert total(one * dx(1)) == pytest.approx(1.05, rel=1e-12)
    assert total(one * dx(2)) == pytest.approx(0.95, rel=1e-12)
    assert total(one * ds(10)) == pytest.approx(1.0, rel=1e-12)
    assert total(one * ds(11)) == pytest.approx(1.0, rel=1e-12)
    assert total(one * ds(12)) == pytest.approx(4.0, rel=1e-12)
    assert total(one("+") * dS(13)) == pytest.approx(2 * np.hypot(0.5, 0.1), rel=1e-12)
    assert set(np.unique(data.facet_tags.values).tolist()) <= {10, 11, 12, 13}
