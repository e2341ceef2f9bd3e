"""Small planar triangle meshes and frame fields with known maps, for the pure NumPy
tests of the parametrisation and the quads (``tests/param``, ``tests/quads``)."""

import numpy as np

from ufl_frames.frames2d import odeco


def grid(nx, ny, x0=0.0, x1=1.0, y0=0.0, y1=1.0):
    """Structured right triangles on a rectangle (alternating diagonals)."""
    return tensor_grid(np.linspace(x0, x1, nx + 1), np.linspace(y0, y1, ny + 1))


def tensor_grid(xs, ys):
    """Triangles (alternating diagonals) of the tensor grid of ``xs`` × ``ys``: points
    (n, 2) and cells (m, 3)."""
    nx, ny = len(xs) - 1, len(ys) - 1
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    x = np.stack([X.ravel(), Y.ravel()], axis=1)
    idx = np.arange(x.shape[0]).reshape(nx + 1, ny + 1)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    flip = ((np.arange(nx)[:, None] + np.arange(ny)[None, :]) % 2).astype(bool)
    t1 = np.where(flip[..., None], np.stack([a, b, d], -1), np.stack([a, b, c], -1))
    t2 = np.where(flip[..., None], np.stack([b, c, d], -1), np.stack([a, c, d], -1))
    return x, np.concatenate([t1.reshape(-1, 3), t2.reshape(-1, 3)])


def annulus(nr, nt, r0=0.5, r1=1.0):
    """The annulus as a polar grid, periodic in θ."""
    r = np.linspace(r0, r1, nr + 1)
    t = np.linspace(0, 2 * np.pi, nt, endpoint=False)
    R, T = np.meshgrid(r, t, indexing="ij")
    x = np.stack([(R * np.cos(T)).ravel(), (R * np.sin(T)).ravel()], axis=1)
    idx = np.arange(x.shape[0]).reshape(nr + 1, nt)
    a, b = idx[:-1], idx[1:]
    c, d = np.roll(b, -1, axis=1), np.roll(a, -1, axis=1)
    cells = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3),
                            np.stack([a, c, d], -1).reshape(-1, 3)])
    return x, cells


def annulus_field(x):
    r, theta = np.hypot(x[:, 0], x[:, 1]), np.arctan2(x[:, 1], x[:, 0])
    return odeco.frames_to_q(np.stack([r, r], axis=1), theta)


def assert_polar_grid(quads, n_theta: int, n_r: int, r0: float, r1: float) -> None:
    """The quads of the annulus r0 ≤ r ≤ r1 are the structured polar grid: n_θ × n_r valid
    quads, every interior vertex of valence 4, the corners on the n_r + 1 circles
    r0 (r1/r0)^(k/n_r), n_θ on each."""
    from ufl_frames.quads.measures import check_quad_mesh, quad_quality

    assert quads.num_quads == n_theta * n_r
    assert check_quad_mesh(quads.points, quads.quads) == []
    quality = quad_quality(quads.points, quads.quads)
    assert quality["irregular_vertices"] == 0
    assert quality["interior_valence"] == ({"4": n_theta * (n_r - 1)} if n_r > 1 else {})
    r = np.hypot(*quads.points.T)
    k = np.log(r / r0) / np.log(r1 / r0) * n_r
    assert np.abs(k - np.rint(k)).max() < 0.05
    assert np.bincount(np.rint(k).astype(int)).tolist() == [n_theta] * (n_r + 1)
