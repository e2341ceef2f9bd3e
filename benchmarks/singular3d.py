"""Time and peak memory of the 3D singular graph alone, on a structured box of tetrahedra.

    python benchmarks/singular3d.py [--cubes 55] [--chunk N]

The unit cube cut into cubes³ cubes of six (Kuhn) tetrahedra each (55: about 10⁶
tetrahedra), with a frame field turning about z by a quarter of the angle around the
vertical line through (0.5, 0.5): one singular line of quarter turns. Prints the
tetrahedra, the singular edges, the CPU seconds of :func:`singular_graph` and this
process's peak resident memory before and after it. ``--chunk`` sets how many incidences
are matched at a time (a huge value builds them all at once, as before 2026-12-07).
No DOLFINx, MPI or Gmsh.
"""

import argparse
import resource
import time

import numpy as np

from ufl_frames.frames3d import odeco, singular

#: Kuhn's six tetrahedra of a cube, as paths 000 → p → r → 111 over its corners.
_PATHS = (((1, 0, 0), (1, 1, 0)), ((1, 0, 0), (1, 0, 1)), ((0, 1, 0), (1, 1, 0)),
          ((0, 1, 0), (0, 1, 1)), ((0, 0, 1), (1, 0, 1)), ((0, 0, 1), (0, 1, 1)))


def box(k: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n, 3) and tetrahedra (6 k³, 4) of the unit cube cut into k³ cubes."""
    g = np.arange((k + 1) ** 3).reshape(k + 1, k + 1, k + 1)
    corner = {(i, j, m): g[i:k + i, j:k + j, m:k + m].ravel()
              for i in (0, 1) for j in (0, 1) for m in (0, 1)}
    cells = np.concatenate([np.stack([corner[0, 0, 0], corner[p], corner[r], corner[1, 1, 1]],
                                     axis=1) for p, r in _PATHS])
    t = np.linspace(0.0, 1.0, k + 1)
    return np.stack(np.meshgrid(t, t, t, indexing="ij"), -1).reshape(-1, 3), cells


def quarter_turn_field(x: np.ndarray) -> np.ndarray:
    """Unit frames (n, 15) turned about z by a quarter of the angle around the line
    x = 0.497, y = 0.503 (off the grid's vertices)."""
    angle = np.arctan2(x[:, 1] - 0.503, x[:, 0] - 0.497) / 4
    R = np.zeros((x.shape[0], 3, 3))
    R[:, 0, 0] = R[:, 1, 1] = np.cos(angle)
    R[:, 1, 0] = np.sin(angle)
    R[:, 0, 1] = -R[:, 1, 0]
    R[:, 2, 2] = 1.0
    return odeco.frames_to_q(np.ones((x.shape[0], 3)), R)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cubes", type=int, default=55)
    parser.add_argument("--chunk", type=int, default=None)
    args = parser.parse_args()
    if args.chunk is not None:
        singular._CHUNK = args.chunk
    x, cells = box(args.cubes)
    q = quarter_turn_field(x)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    start = time.process_time()
    graph = singular.singular_graph(cells, q, x)
    cpu = time.process_time() - start
    after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"tetrahedra {cells.shape[0]}  singular edges {len(graph.edges)} "
          f"(turns {sorted(set(graph.turn.tolist()))}, chains {graph.num_chains})  "
          f"cpu {cpu:.1f} s  peak MB before {before:.0f} after {after:.0f}")


if __name__ == "__main__":
    main()
