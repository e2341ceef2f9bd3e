"""ufl_frames.output: summary, ParaView field, figures; serial and under MPI (no subprocesses)."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from ufl_frames.bootstrap import init_petsc

init_petsc([])  # not pytest's command line

import dolfinx  # noqa: E402
import dolfinx.io  # noqa: E402
from mpi4py import MPI  # noqa: E402

from ufl_frames import output  # noqa: E402
from ufl_frames.fem import energy  # noqa: E402
from ufl_frames.frames2d import odeco  # noqa: E402

COMM = MPI.COMM_WORLD
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture
def shared_tmp(tmp_path):
    """rank 0's tmp_path on every rank (the files are written by rank 0 or collectively)."""
    return Path(COMM.bcast(str(tmp_path), root=0))


def square_mesh(n=8):
    return dolfinx.mesh.create_rectangle(
        COMM, [[0.0, 0.0], [2.0, 1.0]], [2 * n, n], dolfinx.mesh.CellType.triangle
    )


def twisted_field(mesh):
    """A non-integrable frame field: angle x, lengths 1 + y and 1 + y/2."""
    V = energy.frame_space(mesh)
    return energy.interpolate_frames(V, lambda x: (1 + x[1], 1 + 0.5 * x[1], x[0]))


def test_write_summary_json(shared_tmp):
    data = {"a": np.float64(1.5), "n": np.int32(3), "v": np.arange(3), "p": shared_tmp,
            "history": [{"it": 0, "H": 1.0}]}
    path = shared_tmp / "summary.json"
    output.write_summary(path, data)
    back = json.loads(path.read_text())
    assert back == {"a": 1.5, "n": 3, "v": [0, 1, 2], "p": str(shared_tmp),
                    "history": [{"it": 0, "H": 1.0}]}
    assert path.read_text().count("\n") > 3  # indented


def test_frames_of_rows_match_odeco():
    lengths = np.array([[1.0, 2.0], [0.5, 0.5], [3.0, 1.0]])
    angles = np.array([0.1, -0.7, 0.3])
    rows = np.vstack([odeco.frames_to_q(lengths, angles), np.zeros((1, 5))])
    got_lengths, u, v = output.fields.frame_vectors(rows)
    np.testing.assert_allclose(np.linalg.norm(u, axis=1), got_lengths[:, 0], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), got_lengths[:, 1], atol=1e-12)
    np.testing.assert_allclose(np.einsum("ni,ni->n", u, v), 0.0, atol=1e-12)
    # Same frames: the tensor rebuilt from (u, v) is q.
    t = np.arctan2(u[:3, 1], u[:3, 0])
    np.testing.assert_allclose(odeco.frames_to_q(got_lengths[:3], t), rows[:3], atol=1e-12)
    assert np.all(got_lengths[3] == 0) and np.all(u[3] == 0) and np.all(v[3] == 0)


def test_bracket_rms_integrates_to_H():
    q = twisted_field(square_mesh())
    rms = energy.bracket_rms(q)
    cell_area = 2.0 * 1.0 / (2 * 16 * 8)  # uniform right triangles
    owned = rms.function_space.dofmap.index_map.size_local
    H_from_rms = COMM.allreduce(0.5 * cell_area * float(np.sum(rms.x.array[:owned] ** 2)))
    H = energy.integrability_energy(q)
    assert H > 1e-3
    assert math.isclose(H_from_rms, H, rel_tol=1e-10)


def test_bracket_rms_vanishes_for_constant_frames():
    mesh = square_mesh(4)
    q = energy.interpolate_frames(energy.frame_space(mesh), lambda x: (1.0, 2.0, 0.3))
    assert np.abs(energy.bracket_rms(q).x.array).max() < 1e-12


def test_field_functions():
    q = twisted_field(square_mesh(4))
    functions = output.field_functions(q)
    names = [f.name for f in functions]
    assert names == ["q", "lengths", "u", "v", "bracket_rms"]
    lengths, u, v = (f.x.array.reshape(-1, 2) for f in functions[1:4])
    np.testing.assert_allclose(np.linalg.norm(u, axis=1), lengths[:, 0], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), lengths[:, 1], atol=1e-12)
    # Lengths of the interpolated frames: {1 + y, 1 + y/2} at the vertices.
    y = functions[1].function_space.tabulate_dof_coordinates()[:, 1]
    np.testing.assert_allclose(np.sort(lengths, axis=1),
                               np.stack([1 + y / 2, 1 + y], axis=1), atol=1e-10)


def test_write_field_vtx(shared_tmp):
    assert dolfinx.io.has_adios2, "this DOLFINx build should have ADIOS2"
    paths = output.write_field(shared_tmp, twisted_field(square_mesh(4)))
    root_paths = COMM.bcast(paths, root=0)  # collectives first, then rank-local asserts
    assert paths[:2] == [shared_tmp / "frames.bp", shared_tmp / "frames.pvd"]
    assert paths == root_paths  # the same list on every rank
    assert (paths[0] / "md.idx").is_file()
    assert all(p.exists() for p in paths)
    metadata = b"".join(p.read_bytes() for p in paths[0].glob("md.*"))
    for name in (b"q", b"lengths", b"u", b"v", b"bracket_rms"):
        assert b'Name="' + name + b'"' in metadata
    # VTK: the collection, the parallel file, one piece per rank.
    assert sorted(p.suffix for p in paths[2:]) == [".pvtu"] + [".vtu"] * COMM.size


def test_write_field_xdmf_fallback(shared_tmp, monkeypatch):
    monkeypatch.setattr(dolfinx.io, "has_adios2", False)
    paths = output.write_field(shared_tmp, twisted_field(square_mesh(4)), stem="fallback")
    assert paths[:3] == [shared_tmp / "fallback.xdmf", shared_tmp / "fallback.h5",
                         shared_tmp / "fallback.pvd"]
    text = paths[0].read_text()
    for name in ("q", "lengths", "u", "v", "bracket_rms"):
        assert f'Name="{name}"' in text
    assert all(p.is_file() for p in paths)


def test_write_field_vtk_reads_back(shared_tmp):
    """The VTK written equals the field: vertex values, cell values, mesh, H."""
    mesh = square_mesh(4)
    q = twisted_field(mesh)
    paths = output.write_field(shared_tmp, q)
    # The collective parts first: an assertion failing on one rank must not leave the
    # other waiting in a collective.
    H = energy.integrability_energy(q)
    f = energy.bracket_rms(q)
    data = output.read_vtk(shared_tmp / "frames.pvd")
    x, cells = data["points"], data["cells"]
    assert set(data["point_data"]) == {"q", "lengths", "u", "v"}
    assert set(data["cell_data"]) == {"bracket_rms"}
    # Every cell once (ghosts dropped); every vertex at least once.
    assert cells.shape == (mesh.topology.index_map(2).size_global, 3)
    assert np.unique(x.round(12), axis=0).shape[0] == mesh.topology.index_map(0).size_global
    np.testing.assert_allclose(x[:, 2], 0.0)
    # Point data against the frames the field was made of: angle x, lengths 1 + y, 1 + y/2.
    l_true = np.stack([1 + x[:, 1], 1 + 0.5 * x[:, 1]], axis=1)
    np.testing.assert_allclose(data["point_data"]["q"], odeco.frames_to_q(l_true, x[:, 0]),
                               rtol=1e-14, atol=1e-14)
    lengths = data["point_data"]["lengths"]
    np.testing.assert_allclose(np.sort(lengths[:, :2], axis=1), l_true[:, ::-1], rtol=1e-13)
    for k, name in enumerate(("u", "v")):
        branch = data["point_data"][name]
        assert branch.shape == (x.shape[0], 3) and np.all(branch[:, 2] == 0)
        np.testing.assert_allclose(np.linalg.norm(branch[:, :2], axis=1), lengths[:, k],
                                   rtol=1e-13)
    # Cell data: the bracket's RMS integrates to H (cell areas from the file's points).
    e1, e2 = x[cells[:, 1], :2] - x[cells[:, 0], :2], x[cells[:, 2], :2] - x[cells[:, 0], :2]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    rms = data["cell_data"]["bracket_rms"]
    assert math.isclose(0.5 * float(np.sum(area * rms**2)), H, rel_tol=1e-12)
    # ... and equals the DG0 function cell by cell (matched by barycentre).
    owned = mesh.topology.index_map(2).size_local
    centres = f.function_space.tabulate_dof_coordinates()[:owned, :2]
    mine = {tuple(c): v for c, v in zip(centres.round(10), f.x.array[:owned], strict=True)}
    in_file = {tuple(c): v for c, v in zip(x[cells, :2].mean(axis=1).round(10), rms,
                                           strict=True)}
    assert all(math.isclose(in_file[c], v, rel_tol=1e-14) for c, v in mine.items())
    # The pieces are the files write_field listed.
    pieces = output.vtk.vtk_references(shared_tmp / "frames.pvd")
    assert pieces == paths[2:]


def test_read_vtk_rejects_binary(tmp_path):
    path = tmp_path / "b.vtu"
    path.write_text(
        '<VTKFile type="UnstructuredGrid"><UnstructuredGrid><Piece NumberOfPoints="1" '
        'NumberOfCells="0"><Points><DataArray type="Float64" NumberOfComponents="3" '
        'format="binary">AAAA</DataArray></Points></Piece></UnstructuredGrid></VTKFile>'
    )
    with pytest.raises(ValueError, match="ASCII"):
        output.read_vtk(path)


def test_grid_points_centred():
    points = output.glyphs.grid_points(np.array([0.0, 0.0]), np.array([2.0, 1.0]), 0.3)
    assert points.shape[1] == 3
    x, y = np.unique(points[:, 0]), np.unique(points[:, 1])
    assert x.size == 7 and y.size == 4
    assert math.isclose(x.mean(), 1.0) and math.isclose(y.mean(), 0.5)
    np.testing.assert_allclose(np.diff(x), 0.3)


def test_glyph_samples_fine_mesh_uses_grid():
    q = twisted_field(square_mesh(16))  # h = 1/16, finer than 2/12
    points, rows, spacing = output.glyph_samples(q, glyphs_across=12)
    assert math.isclose(spacing, 2.0 / 12)
    if COMM.rank == 0:
        assert points.shape == (13 * 7, 2)  # the whole grid lies in the rectangle
        # The field at a sample point is the P1 interpolant there: angle x, lengths 1+y, 1+y/2.
        lengths, _ = odeco.q_to_frames(rows)
        np.testing.assert_allclose(np.sort(lengths, axis=1)[:, 1], 1 + points[:, 1], atol=0.02)
    else:
        assert points is None and rows is None


def test_glyph_samples_coarse_mesh_uses_vertices():
    mesh = square_mesh(2)
    q = twisted_field(mesh)
    points, rows, spacing = output.glyph_samples(q, glyphs_across=36)
    if COMM.rank == 0:
        assert points.shape == (mesh.topology.index_map(0).size_global, 2)
        assert rows.shape == (points.shape[0], 5)
        assert spacing > 2.0 / 36


def annulus(annulus_mesh, h):
    """The annulus 0.5 <= r <= 1 as a dolfinx mesh (geometry may wrap it in a Domain)."""
    mesh = annulus_mesh(h)
    return getattr(mesh, "mesh", mesh)


def test_glyph_samples_count_follows_the_domain_area(annulus_mesh):
    """About ``glyphs`` crosses in the domain, not in its bounding box (4 vs 3π/4 here)."""
    q = energy.interpolate_frames(energy.frame_space(annulus(annulus_mesh, 0.04)),
                                  lambda x: (1.0, 1.0, x[0]))
    points, _, spacing = output.glyph_samples(q, glyphs=300)
    assert math.isclose(spacing, math.sqrt(0.75 * math.pi / 300), rel_tol=1e-3)  # mesh area
    if COMM.rank == 0:
        assert 0.85 * 300 < points.shape[0] < 1.15 * 300
        r = np.linalg.norm(points, axis=1)
        assert np.all((r > 0.5 - 1e-9) & (r < 1 + 1e-9))


@pytest.mark.parametrize(("lo", "hi"), [((0, 0), (2, 1)), ((0, 0), (20, 1)), ((0, 0), (1, 20)),
                                        ((0, 0), (65, 120)), ((-3, 5), (-1, 7))])
def test_frame_layout_follows_the_aspect_ratio(lo, hi):
    layout = output.frame_layout(lo, hi, title="t")
    (x0, x1), (y0, y1) = layout.limits
    w, h = layout.axes_size
    # The data area has the aspect of the domain plus margins, at the scale given.
    assert math.isclose(w / h, (x1 - x0) / (y1 - y0), rel_tol=1e-12)
    assert math.isclose(layout.scale * (x1 - x0), w, rel_tol=1e-12)
    assert x0 < lo[0] and x1 > hi[0] and y0 < lo[1] and y1 > hi[1]
    assert layout.horizontal == ((x1 - x0) / (y1 - y0) >= 1.4)  # wide: colour bar below
    long_side, short_side = max(w, h), min(w, h)
    assert long_side <= output.figures.AXES_LONG_MAX_IN[0 if w >= h else 1] + 1e-12
    assert w * h <= output.figures.AXES_AREA_IN2 * (1 + 1e-12)
    if long_side < min(output.figures.AXES_LONG_MAX_IN):  # compact shape: the full area
        assert math.isclose(w * h, output.figures.AXES_AREA_IN2, rel_tol=1e-12)
    assert short_side > 0.6  # a 20:1 strip is still ~120 px thick at 200 dpi
    minimum = output.figures.FIGURE_MIN_IN
    assert layout.figsize[0] >= minimum[0] and layout.figsize[1] >= minimum[1]
    assert layout.figsize[0] > w and layout.figsize[1] > h
    # Only the shape counts: the same domain in other units gives the same figure.
    scaled = output.frame_layout(1e-3 * np.asarray(lo), 1e-3 * np.asarray(hi), title="t")
    assert scaled.figsize == layout.figsize and scaled.axes_size == pytest.approx((w, h))
    assert math.isclose(scaled.scale, 1e3 * layout.scale, rel_tol=1e-9)


def test_frame_layout_orientation_and_title():
    wide, tall = output.frame_layout((0, 0), (20, 1)), output.frame_layout((0, 0), (1, 20))
    assert wide.axes_size[0] > 10 * wide.axes_size[1] and wide.horizontal
    assert tall.axes_size[1] > 10 * tall.axes_size[0] and not tall.horizontal
    title = "a long title " * 12
    layout = output.frame_layout((0, 0), (1, 1), title=title)
    assert layout.title.count("\n") >= 1
    assert "".join(layout.title.split()) == "".join(title.split())  # wrapped, not cut


@pytest.fixture
def captured(monkeypatch):
    """Figures of plot_frames, kept instead of written (rank 0; closed afterwards)."""
    figures = []
    monkeypatch.setattr(output.figures, "_save", lambda fig, path, dpi: figures.append(fig))
    yield figures
    import matplotlib.pyplot as plt

    for fig in figures:
        plt.close(fig)


def _inside(inner, outer, tol=0.5):
    return (inner.x0 >= outer.x0 - tol and inner.y0 >= outer.y0 - tol
            and inner.x1 <= outer.x1 + tol and inner.y1 <= outer.y1 + tol)


@pytest.mark.parametrize("extent", [(20.0, 1.0), (1.0, 20.0), (2.0, 1.0)])
def test_plot_frames_figure_fits_any_aspect(captured, extent):
    """Data area at equal aspect filling its box (no sliver in white), all text inside."""
    mesh = dolfinx.mesh.create_rectangle(
        COMM, [[0.0, 0.0], list(extent)], [int(4 * extent[0]), int(4 * extent[1])],
        dolfinx.mesh.CellType.triangle)
    q = energy.interpolate_frames(energy.frame_space(mesh), lambda x: (1.0 + 0.05 * x[1], 1.0,
                                                                        0.1 * x[0]))
    title = "Frame field: a rectangle, non-isotropic, with a long title that has to wrap " * 2
    sings = [{"index": 0.25, "x": 0.5, "y": 0.5}, {"index": -0.25, "x": 0.6, "y": 0.5}]
    output.plot_frames("unused.png", q, title=title, singularities=sings)
    if COMM.rank != 0:
        return
    (fig,) = captured
    fig.draw_without_rendering()
    renderer = fig.canvas.get_renderer()
    page = fig.bbox
    ax = fig.axes[0]
    box = ax.get_window_extent(renderer)
    # Equal aspect: the axes box has the shape of the data limits.
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    assert math.isclose(box.width / box.height, (x1 - x0) / (y1 - y0), rel_tol=0.01)
    # The data area fills its share of the figure: no band of white around a thin strip
    # (except beside a narrow one, where the figure is at its minimum size).
    allotted, used = ax.get_position(original=True), ax.get_position()
    at_minimum = np.isclose(fig.get_size_inches(), output.figures.FIGURE_MIN_IN)
    assert at_minimum[0] or used.width > 0.97 * allotted.width
    assert at_minimum[1] or used.height > 0.97 * allotted.height
    assert not np.all(at_minimum)
    assert min(box.width, box.height) / fig.dpi > 0.6  # inches
    # Title (wrapped, whole), legend, colour bar, labels: inside the figure.
    title_text = fig._suptitle
    assert "".join(title_text.get_text().split()) == "".join(title.split())  # not cut
    assert _inside(title_text.get_window_extent(renderer), page)
    assert _inside(ax.get_legend().get_window_extent(renderer), page)
    for other in fig.axes:
        assert _inside(other.get_tightbbox(renderer), page)


def test_plot_frames_glyphs_stay_off_holes(captured, annulus_mesh):
    """Crosses shrink near the boundary: none reaches into the hole by more than the
    smallest arm, and interior ones keep the full arm."""
    q = energy.interpolate_frames(energy.frame_space(annulus(annulus_mesh, 0.04)),
                                  lambda x: (1.0, 1.0, np.arctan2(x[1], x[0])))
    output.plot_frames("unused.png", q, glyphs=400)
    if COMM.rank != 0:
        return
    (fig,) = captured
    from matplotlib.collections import LineCollection

    (glyphs,) = [c for c in fig.axes[0].collections
                 if isinstance(c, LineCollection) and c.get_array() is not None]
    segments = np.asarray(glyphs.get_segments())
    half = 0.5 * np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1)
    arm = half.max()
    assert half.min() >= output.glyphs.GLYPH_MIN_ARM * arm * (1 - 1e-9)
    assert np.mean(half > 0.999 * arm) > 0.5  # most crosses are away from the boundary
    r = np.linalg.norm(segments.reshape(-1, 2), axis=1)
    slack = output.glyphs.GLYPH_MIN_ARM * arm + 1e-3  # + the sagitta of the boundary facets
    assert r.min() > 0.5 - slack and r.max() < 1.0 + slack


def test_marker_size_shrinks_with_the_count():
    area = 2e5  # points², about a 6 x 6 inch domain
    sizes = [output.figures._marker_size(n, area) for n in (1, 20, 21, 100, 200, 2000, 20000)]
    assert sizes[0] == sizes[1] == 80.0
    assert all(a > b for a, b in zip(sizes[1:], sizes[2:], strict=False))
    for n, s in zip((1, 20, 21, 100, 200, 2000), sizes, strict=False):
        assert n * s <= 0.05 * area * (1 + 1e-12) or n <= 20  # together <= 5% of the domain
    assert sizes[-2] < 5.0 and sizes[-1] >= 1.0  # dots, still visible


def test_plot_frames_many_singularities_are_dots(captured):
    mesh = square_mesh(8)
    q = energy.interpolate_frames(energy.frame_space(mesh), lambda x: (1.0, 1.0, x[0]))
    rng = np.random.default_rng(0)
    sings = [{"index": (-1) ** k * 0.25, "x": 2 * rng.random(), "y": rng.random()}
             for k in range(1000)]
    output.plot_frames("unused.png", q, singularities=sings)
    if COMM.rank != 0:
        return
    (fig,) = captured
    from matplotlib.collections import PathCollection

    markers = [c for c in fig.axes[0].collections if isinstance(c, PathCollection)]
    assert sum(len(c.get_offsets()) for c in markers) == 1000
    for c in markers:
        assert c.get_sizes().max() < 10.0 and c.get_linewidths().max() == 0.0


@pytest.mark.parametrize("isotropic", [False, True])
def test_plot_frames_writes_png(shared_tmp, isotropic):
    mesh = square_mesh(6)
    V = energy.frame_space(mesh)
    q = energy.interpolate_frames(
        V, lambda x: (1 + x[1], (1 + x[1]) if isotropic else 1.0, 0.5 * x[0])
    )
    path = shared_tmp / f"frames_{isotropic}.png"
    sings = [{"index": 0.25, "x": 0.5, "y": 0.5}, {"index": -0.25, "x": 1.5, "y": 0.5},
             {"index": 0.5, "x": 1.0, "y": 0.2}]
    output.plot_frames(path, q, title="test", singularities=sings)
    COMM.Barrier()
    assert path.read_bytes()[:8] == PNG_MAGIC


def test_is_isotropic():
    is_isotropic = output.figures._is_isotropic
    V = energy.frame_space(square_mesh(3))
    assert is_isotropic(energy.interpolate_frames(V, lambda x: (1 + x[0], 1 + x[0], x[1])))
    assert not is_isotropic(energy.interpolate_frames(V, lambda x: (1.0, 1.1, x[1])))


@pytest.mark.parametrize("H0", [1.0, 0.0])
def test_plot_convergence_writes_png(shared_tmp, H0):
    history = [{"it": k, "H": H0 * 0.5**k, "E": 2.0 + 0.1 * k, "gnorm": 1.0, "step": 1.0}
               for k in range(8)]
    path = shared_tmp / f"convergence_{H0}.png"
    output.plot_convergence(path, history, title="test")
    COMM.Barrier()
    assert path.read_bytes()[:8] == PNG_MAGIC


def test_plot_convergence_of_nested_levels(shared_tmp, monkeypatch):
    """Nested iteration: the meshes one after another on one axis (cumulative iterations),
    one line per mesh with its label; a malformed level history is refused."""
    levels = [(f"{n} triangles", [{"it": k, "H": 0.1 / n * 0.5**k, "E": 1.0 + k}
                                  for k in range(m)]) for n, m in ((100, 5), (400, 3))]
    drawn = {}
    real = output.figures._draw_convergence

    def spy(path, history, title, parts=None):
        drawn["parts"] = parts
        real(path, history, title, parts)

    monkeypatch.setattr(output.figures, "_draw_convergence", spy)
    path = shared_tmp / "nested.png"
    output.plot_convergence(path, levels[-1][1], title="nested", levels=levels)
    COMM.Barrier()
    assert path.read_bytes()[:8] == PNG_MAGIC
    if COMM.rank == 0:
        assert [label for label, _ in drawn["parts"]] == ["100 triangles", "400 triangles"]
    with pytest.raises(ValueError):
        output.plot_convergence(path, levels[-1][1], levels=[("bad", [{"it": 0}])])


def test_describe_singularities():
    assert output.describe_singularities([]) == "none"
    text = output.describe_singularities(
        [{"index": 0.25, "x": 0.349, "y": 0.796}, {"index": -0.25, "x": 1.5, "y": 0.7}]
    )
    assert text == "+1/4 at (0.349, 0.796), -1/4 at (1.5, 0.7)"


def test_describe_many_singularities_counts_them():
    rng = np.random.default_rng(0)
    indices = [0.25] * 1379 + [-0.25] * 721 + [0.5] * 2
    sings = [{"index": k, "x": rng.random(), "y": rng.random()} for k in rng.permutation(indices)]
    text = output.describe_singularities(sings)
    assert text == "+2/4: 2, +1/4: 1379, -1/4: 721, index sum 165.5"
    assert "\n" not in text
    assert output.describe_singularities(sings[:6], limit=6).count(" at (") == 6
    assert " at (" not in output.describe_singularities(sings[:7], limit=6)


@pytest.mark.skipif(COMM.size == 1, reason="needs ranks given different folders")
def test_write_field_folders_differing_by_rank_fail_on_every_rank(tmp_path):
    """Each rank its own folder (a caller's mistake: VTK pieces land apart): one error on
    every rank, not rank 0 alone with the others left waiting in a collective."""
    with pytest.raises(OSError, match="same folder"):
        output.write_field(tmp_path, twisted_field(square_mesh(4)))
