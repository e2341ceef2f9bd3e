"""Throughput of the pointwise Odeco projections (vertices per second, one core).

    python benchmarks/projection.py [--n 1000000] [--repeat 3] [--seed 0]

Times :func:`ufl_frames.frames2d.odeco.project` on N random vertices, best of ``--repeat`` runs:

* ``gaussian``: q with independent N(0, 1) entries, far from the variety (about 10 % of
  the rows take the slow, multi-start path of the closest-point search);
* ``near variety``: random frames (l2/l1 log-uniform in [0.1, 10]) plus noise of 1e-3
  relative, the situation in the solver; ``isotropic frames``: the same with l1 = l2;
* ``isotropic=True`` (projection onto isotropic frames), ``method="mandel"`` (the note's
  eigentensor projection, for comparison), the closest-point projection without the
  row blocking (``_CHUNK_ROWS`` = N), and :func:`ufl_frames.frames2d.odeco.tangent_project`.

Target (issue 2): at least 2 million vertices per second for ``project`` on one core.
The closest-point code is element-wise NumPy (one thread); for the LAPACK-based
variants (``mandel``, ``tangent_project``) run with OMP_NUM_THREADS=1 to time one core.
"""

import argparse

import numpy as np
from _common import best_time

from ufl_frames.frames2d import odeco

TARGET = 2.0  # million vertices per second


def near_variety(rng, n, isotropic, noise=1e-3):
    ratio = np.ones(n) if isotropic else np.exp(rng.uniform(np.log(0.1), np.log(10.0), n))
    lengths = np.stack([np.ones(n), ratio], axis=1) * rng.uniform(0.5, 2.0, (n, 1))
    q = odeco.frames_to_q(lengths, rng.uniform(-np.pi, np.pi, n))
    dq = rng.standard_normal(q.shape)
    dq *= noise * np.linalg.norm(q, axis=1, keepdims=True) / np.linalg.norm(dq, axis=1)[:, None]
    return q + dq


def unchunked(func):
    def run():
        saved = odeco._CHUNK_ROWS
        odeco._CHUNK_ROWS = 1 << 62
        try:
            func()
        finally:
            odeco._CHUNK_ROWS = saved

    return run


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=int, default=1_000_000, help="vertices (default 10^6)")
    parser.add_argument("--repeat", type=int, default=3, help="best of this many runs")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    rng = np.random.default_rng(args.seed)
    n = args.n
    inputs = {
        "gaussian": rng.standard_normal((n, 5)),
        "near variety": near_variety(rng, n, isotropic=False),
        "isotropic frames": near_variety(rng, n, isotropic=True),
    }
    steps = rng.standard_normal((n, 5))
    cases = []
    for name, q in inputs.items():
        cases.append((f"project  {name}", lambda q=q: odeco.project(q)))
    for name, q in inputs.items():
        cases.append(
            (f"project  {name}, isotropic=True", lambda q=q: odeco.project(q, isotropic=True))
        )
    for name in ("gaussian", "near variety"):
        q = inputs[name]
        cases.append((f"project  {name}, unchunked", unchunked(lambda q=q: odeco.project(q))))
    for name in ("gaussian", "near variety", "isotropic frames"):
        q = inputs[name]
        cases.append(
            (f"project  {name}, method='mandel'", lambda q=q: odeco.project(q, method="mandel"))
        )
    near = inputs["near variety"]
    cases.append(("tangent_project  near variety", lambda: odeco.tangent_project(near, steps)))

    print(f"N = {n} vertices, best of {args.repeat}")
    print(f"{'variant':<44} {'M vertices/s':>12} {'(CPU time)':>10} {'s per run':>10}")
    results = {}
    for label, func in cases:
        wall, cpu = best_time(func, args.repeat)
        results[label] = n / wall / 1e6, n / cpu / 1e6
        print(f"{label:<44} {results[label][0]:>12.2f} {results[label][1]:>10.2f} {wall:>10.3f}")
    closest = [
        v
        for k, v in results.items()
        if k.startswith("project") and "'mandel'" not in k and "unchunked" not in k
    ]
    worst_wall, worst_cpu = min(v[0] for v in closest), min(v[1] for v in closest)
    verdict = "meets" if worst_wall >= TARGET else "MISSES"
    print(
        f"slowest closest-point variant: {worst_wall:.2f} M/s wall, {worst_cpu:.2f} M/s CPU "
        f"({verdict} the {TARGET:g} M/s target in wall time)"
    )
    return results


if __name__ == "__main__":
    main()
