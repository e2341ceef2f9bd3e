"""The singular graph of 3D frame fields with known singular lines (pure NumPy): frames
that turn by a quarter (or a half) of the polar angle about the z-axis have exactly one
singular line, the axis."""

import numpy as np
import pytest

from ufl_frames.frames3d import odeco, singular


def box_tets(n=9, m=4):
    """Tetrahedra of [-1, 1]² × [0, 1] on an n × n × m grid, six per cube (Kuhn), and the
    grid spacing in x. With n odd no vertex lies on the z-axis."""
    xs, zs = np.linspace(-1, 1, n + 1), np.linspace(0, 1, m + 1)
    X, Y, Z = np.meshgrid(xs, xs, zs, indexing="ij")
    x = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    idx = np.arange(x.shape[0]).reshape(n + 1, n + 1, m + 1)
    paths = [(0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)]
    cells = []
    for i in range(n):
        for j in range(n):
            for k in range(m):
                for path in paths:
                    p = np.zeros(3, int)
                    tet = [idx[i, j, k]]
                    for axis in path:
                        p[axis] += 1
                        tet.append(idx[i + p[0], j + p[1], k + p[2]])
                    cells.append(tet)
    return x, np.array(cells), 2.0 / n


def turning_field(x, share):
    """Unit frames turned about z by ``share`` × the polar angle."""
    t = share * np.arctan2(x[:, 1], x[:, 0])
    c, s = np.cos(t), np.sin(t)
    R = np.zeros((x.shape[0], 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    return odeco.frames_to_q(np.ones((x.shape[0], 3)), R)


def test_constant_field_has_no_singular_edge():
    x, cells, _ = box_tets()
    q = odeco.frames_to_q(np.ones((x.shape[0], 3)), np.broadcast_to(np.eye(3), (x.shape[0], 3, 3)))
    graph = singular.singular_graph(cells, q, x)
    assert graph.edges.shape == (0, 2) and graph.num_chains == 0
    assert graph.boundary_edges > 0


@pytest.mark.parametrize("share, turn", [(0.25, 1), (-0.25, 1)])
def test_the_axis_is_the_one_singular_line(share, turn):
    x, cells, h = box_tets()
    graph = singular.singular_graph(cells, turning_field(x, share), x)
    assert len(graph.edges) > 0
    mid = x[graph.edges].mean(axis=1)
    assert np.hypot(mid[:, 0], mid[:, 1]).max() < h  # around the axis, nowhere else
    assert set(graph.turn.tolist()) == {turn}
    assert graph.num_chains == 1 and graph.open_ends.size == 0  # one line, ends on ∂Ω
    z = x[np.unique(graph.edges), 2]
    assert z.min() == 0.0 and z.max() == 1.0  # from the bottom face to the top
    # the whole axis: every layer of the grid is crossed
    assert np.unique(np.round(mid[:, 2] * 8)).size >= 4


def test_octahedral_group():
    g = singular.OCTAHEDRAL
    assert g.shape == (24, 3, 3)
    assert np.allclose(np.linalg.det(g), 1.0)
    products = np.einsum("aij,bjk->abik", g, g).reshape(-1, 9)
    assert {tuple(np.round(p).astype(int)) for p in products} == {
        tuple(np.round(e).astype(int).ravel()) for e in g}
