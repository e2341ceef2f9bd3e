"""Throughput of the 3D Odeco projection (frames per second, one core).

    python benchmarks/projection3d.py [--n 100000] [--repeat 3] [--seed 0]

Times :func:`ufl_frames.frames3d.odeco.project` on N rows, best of ``--repeat`` runs, the
compiled kernel (:mod:`ufl_frames.frames3d.kernel`) and the NumPy reference side by side:
``near variety`` (random frames, lengths in [0.5, 2], plus noise of 1e-3 relative: the
situation after MBO's projection has converged), ``isotropic frames`` (the same with
equal lengths), ``noisy`` (noise of 10 % relative: early MBO steps), ``gaussian``
(independent N(0, 1) entries), the isotropic projection and the projection aligned to
a random normal.

Target (issue 41): at least 10⁵ projections per second.
"""

import argparse

import numpy as np
from _common import best_time

from ufl_frames.frames3d import odeco

TARGET = 1e5  # projections per second


def rotations(rng, n):
    q = rng.normal(size=(n, 4))
    a, b, c, d = (q / np.linalg.norm(q, axis=1)[:, None]).T
    return np.stack([
        np.stack([a * a + b * b - c * c - d * d, 2 * (b * c - a * d), 2 * (b * d + a * c)], -1),
        np.stack([2 * (b * c + a * d), a * a - b * b + c * c - d * d, 2 * (c * d - a * b)], -1),
        np.stack([2 * (b * d - a * c), 2 * (c * d + a * b), a * a - b * b - c * c + d * d], -1),
    ], axis=1)


def near_variety(rng, n, isotropic, noise):
    lengths = np.ones((n, 3)) if isotropic else rng.uniform(0.5, 2.0, (n, 3))
    q = odeco.frames_to_q(lengths, rotations(rng, n))
    dq = rng.standard_normal(q.shape)
    dq *= noise * np.linalg.norm(q, axis=1, keepdims=True) / np.linalg.norm(dq, axis=1)[:, None]
    return q + dq


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=100_000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    n = args.n
    cases = {
        "near variety": near_variety(rng, n, False, 1e-3),
        "isotropic frames": near_variety(rng, n, True, 1e-3),
        "noisy (10 %)": near_variety(rng, n, False, 0.1),
        "gaussian": rng.standard_normal((n, odeco.NUM_COEFFICIENTS)),
    }
    normals = rng.standard_normal((n, 3))
    compiled = odeco.kernel.load() is not None
    print(f"{'case':<34}{'compiled per cpu s':>20}{'NumPy per cpu s':>18}{'cpu s (C, NumPy)':>20}")
    rows = [(f"project, {name}", lambda c, q=q: odeco.project(q, compiled=c))
            for name, q in cases.items()]
    rows.append(("project(isotropic=True), near",
                 lambda c: odeco.project(cases["near variety"], isotropic=True, compiled=c)))
    rows.append(("project_aligned, near",
                 lambda c: odeco.project_aligned(cases["near variety"], normals, compiled=c)))
    for name, run in rows:
        cpu_c = best_time(lambda run=run: run(True), args.repeat)[1] if compiled else float("nan")
        cpu_n = best_time(lambda run=run: run(False), args.repeat)[1]
        print(f"{name:<34}{n / cpu_c:>20.3g}{n / cpu_n:>18.3g}{cpu_c:>10.3f}{cpu_n:>10.3f}")
    if not compiled:
        print("the compiled kernel is unavailable (no cffi or no C compiler)")
    print(f"target: {TARGET:.0e} per second")


if __name__ == "__main__":
    main()
