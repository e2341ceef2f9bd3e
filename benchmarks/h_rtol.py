"""Where the stopping test on H (``-frames_h_rtol``) would end each solve, and what it costs.

    python benchmarks/h_rtol.py [--cases gn-piano-0.1 piano-0.025 nested-piano-0.0125]
                                [--rtols 1e-5 1e-4 3e-4 1e-3] [--figure docs/figures/h_rtol.png]

Each case is solved once with the test off (``-frames_h_rtol 0``: to TAO's gradient test).
The test only ends a solve, it changes no step (``tests/test_h_rtol.py`` checks that the
history up to the stop is the full one), so replaying it on the recorded history gives,
for every tolerance, the step it would stop at and the H it would end with. Printed per
case and level: the steps to the gradient test, and per tolerance the stopping step and
the excess of H over the full solve's, (H_stop − H_full) / H_full, which the test aims to
keep below the tolerance. In nested iteration every level is replayed on its own history:
where a coarse level stops earlier the next one starts elsewhere, which a replay cannot
see (``benchmarks/scaling.py -frames_h_rtol ε`` measures that).

Cases: ``gn-piano-H`` the non-isotropic piano at mesh size H on one mesh with Gauss–Newton
alone (``-frames_hessian gauss_newton``: the linear tail), ``piano-H`` / ``annulus-H`` the
default solver on one mesh, ``nested-piano-H`` / ``nested-annulus-H`` nested iteration as
the CLI does it (``--levels auto``). ``--figure``: H − H_full against the step for the finest
level of each case, the stops at each tolerance marked.
"""

import argparse
import sys
from pathlib import Path

from ufl_frames.bootstrap import init_petsc

init_petsc([sys.argv[0]])

from mpi4py import MPI  # noqa: E402
from petsc4py import PETSc  # noqa: E402

from ufl_frames import geometry  # noqa: E402
from ufl_frames.cli import auto_levels  # noqa: E402
from ufl_frames.pipeline import FrameField  # noqa: E402
from ufl_frames.solvers import tao  # noqa: E402


def solve_histories(case: str) -> list[list[dict]]:
    """The histories (one per level, coarse to fine) of ``case`` solved with the test off."""
    comm = MPI.COMM_WORLD
    kind, _, size = case.rpartition("-")
    h = float(size)
    opts = PETSc.Options()
    opts["frames_h_rtol"] = 0.0
    if kind.startswith("gn-"):
        opts["frames_hessian"] = "gauss_newton"
        kind = kind[3:]
    try:
        if kind.startswith("nested-"):
            shape = kind[len("nested-"):]
            fine = geometry.build(comm, shape, h)
            count = auto_levels(fine.num_cells)
            domains = [geometry.build(comm, shape, h, 2.0**k) for k in range(count - 1, 0, -1)]
            field = FrameField.nested(domains + [fine], max_it=500)
            return field.level_histories
        field = FrameField.initial(geometry.build(comm, kind, h))
        return [field.solve(max_it=500).history]
    finally:
        opts.delValue("frames_h_rtol")
        if opts.hasName("frames_hessian"):
            opts.delValue("frames_hessian")


def stopping_step(history: list[dict], rtol: float) -> int:
    """The step at which the test on H with ``rtol`` ends ``history`` (its last if never)."""
    for k in range(len(history)):
        if tao._h_converged(history[: k + 1], rtol):
            return k
    return len(history) - 1


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cases", nargs="+",
                        default=["gn-piano-0.1", "piano-0.025", "nested-piano-0.0125"])
    parser.add_argument("--rtols", nargs="+", type=float, default=[1e-5, 1e-4, 3e-4, 1e-3])
    parser.add_argument("--figure", type=Path, default=None)
    args = parser.parse_args()
    rank0 = MPI.COMM_WORLD.rank == 0
    finest = {}
    header = " | ".join(f"ε = {r:g}: step, excess" for r in args.rtols)
    if rank0:
        print(f"| case | level | steps (gradient test) | {header} |")
        print("|---|---|---|" + "---|" * len(args.rtols))
    for case in args.cases:
        histories = solve_histories(case)
        for level, history in enumerate(histories):
            H_full = history[-1]["H"]
            cells = []
            for rtol in args.rtols:
                k = stopping_step(history, rtol)
                cells.append(f"{k}, {(history[k]['H'] - H_full) / H_full:.1e}")
            if rank0:
                print(f"| {case} | {level} | {len(history) - 1} | " + " | ".join(cells) + " |",
                      flush=True)
        finest[case] = histories[-1]
    if args.figure is not None and rank0:
        figure(finest, args.rtols, args.figure)


def figure(histories: dict, rtols: list[float], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    columns = 2 if len(histories) == 4 else min(3, len(histories))
    rows = -(-len(histories) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(5 * columns, 4 * rows), squeeze=False)
    for ax in axes.flat[len(histories):]:
        ax.set_visible(False)
    markers = "osD^v"
    for ax, (case, history) in zip(axes.flat, histories.items(), strict=False):
        H_full = history[-1]["H"]
        excess = [max((e["H"] - H_full) / H_full, 1e-12) for e in history]
        ax.semilogy(range(len(history)), excess, "-", color="0.3", lw=1.2,
                    label="(H − H_end) / H_end, gradient test")
        for rtol, marker in zip(rtols, markers, strict=False):
            k = stopping_step(history, rtol)
            ax.semilogy([k], [excess[k]], marker, ms=8, label=f"stop at ε = {rtol:g}: step {k}")
        ax.set_title(f"{case} (finest level)")
        ax.set_xlabel("Newton step")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
