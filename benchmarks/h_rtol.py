"""Where the stopping tests on H (``-frames_h_rtol``, ``-frames_nested_rtol``) would end each
solve, and what they cost.

    python benchmarks/h_rtol.py [--cases gn-piano-0.1 piano-0.025 nested-piano-0.0125]
                                [--rtols 1e-5 1e-4 3e-4 1e-3] [--thetas 1e-3 3e-3 1e-2]
                                [--figure docs/figures/h_rtol.png]

Each case is solved once with the tests off (``-frames_h_rtol 0 -frames_nested_rtol 0``: to
TAO's gradient test).
The test only ends a solve, it changes no step (``tests/solvers/test_h_rtol.py`` checks that the
history up to the stop is the full one), so replaying it on the recorded history gives,
for every tolerance, the step it would stop at and the H it would end with. Printed per
case and level: the steps to the gradient test, and per tolerance the stopping step and
the excess of H over the full solve's, (H_stop − H_full) / H_full, which the test aims to
keep below the tolerance. In nested iteration every level is replayed on its own history:
where a coarse level stops earlier the next one starts elsewhere, which a replay cannot
see (``benchmarks/scaling.py -frames_h_rtol ε`` measures that).

For nested cases a second table replays the test against the coarser level's gain
(``-frames_nested_rtol θ``, the solver's default on the finest level only, combined with
the default ε as in the solver) on every level after the first, with H_c the coarser
level's final H: the step, and the excess both over H_full and over the gain
H_c − H_full (what θ bounds).

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

from ufl_frames.mesh import build  # noqa: E402
from ufl_frames.mesh.hierarchy import nested_domains  # noqa: E402
from ufl_frames.pipeline import FrameField  # noqa: E402
from ufl_frames.solvers import tao  # noqa: E402


def solve_histories(case: str) -> list[list[dict]]:
    """The histories (one per level, coarse to fine) of ``case`` solved with the test off."""
    comm = MPI.COMM_WORLD
    kind, _, size = case.rpartition("-")
    h = float(size)
    opts = PETSc.Options()
    opts["frames_h_rtol"] = 0.0
    opts["frames_nested_rtol"] = 0.0
    if kind.startswith("gn-"):
        opts["frames_hessian"] = "gauss_newton"
        kind = kind[3:]
    try:
        if kind.startswith("nested-"):
            shape = kind[len("nested-"):]
            fine = build(comm, shape, h)
            field = FrameField.nested(nested_domains(comm, shape, fine, "auto", h), max_it=500)
            return field.level_histories
        field = FrameField.initial(build(comm, kind, h))
        return [field.solve(max_it=500).history]
    finally:
        opts.delValue("frames_h_rtol")
        opts.delValue("frames_nested_rtol")
        if opts.hasName("frames_hessian"):
            opts.delValue("frames_hessian")


def stopping_step(history: list[dict], rtol: float, coarse_energy: float | None = None,
                  nested_rtol: float = 0.0) -> int:
    """The step at which the test on H with ``rtol`` (and ``nested_rtol`` against
    ``coarse_energy``) ends ``history`` (its last if never)."""
    for k in range(len(history)):
        if tao._h_converged(history[: k + 1], rtol, coarse_energy=coarse_energy,
                            nested_rtol=nested_rtol):
            return k
    return len(history) - 1


def nested_rows(case: str, histories: list[list[dict]], thetas: list[float]) -> list[str]:
    """The table rows of the test against the coarser level's gain, levels 1 on."""
    rows = []
    for level in range(1, len(histories)):
        history, coarse = histories[level], histories[level - 1][-1]["H"]
        H_full = history[-1]["H"]
        cells = []
        for theta in thetas:
            k = stopping_step(history, tao.H_RTOL, coarse, theta)
            excess = history[k]["H"] - H_full
            cells.append(f"{k}, {excess / H_full:.1e}, {excess / (coarse - H_full):.1e}")
        finest = " (finest)" if level == len(histories) - 1 else ""
        rows.append(f"| {case} | {level}{finest} | {len(history) - 1} | "
                    f"{(coarse - H_full) / H_full:.2f} | " + " | ".join(cells) + " |")
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cases", nargs="+",
                        default=["gn-piano-0.1", "piano-0.025", "nested-piano-0.0125"])
    parser.add_argument("--rtols", nargs="+", type=float, default=[1e-5, 1e-4, 3e-4, 1e-3])
    parser.add_argument("--thetas", nargs="+", type=float, default=[1e-3, 3e-3, 1e-2])
    parser.add_argument("--figure", type=Path, default=None)
    args = parser.parse_args()
    rank0 = MPI.COMM_WORLD.rank == 0
    finest, nested = {}, []
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
        finest[case] = histories if len(histories) > 1 else histories[-1:]
        nested += nested_rows(case, histories, args.thetas)
    if nested and rank0:
        header = " | ".join(f"θ = {t:g}: step, excess / H, / gain" for t in args.thetas)
        print(f"\n| case | level | steps (gradient test) | gain (H_c − H) / H | {header} |")
        print("|---|---|---|---|" + "---|" * len(args.thetas))
        print("\n".join(nested))
    if args.figure is not None and rank0:
        figure(finest, args.rtols, args.thetas, args.figure)


def figure(levels: dict, rtols: list[float], thetas: list[float], path: Path) -> None:
    """H − H_full against the step on each case's finest level, the stops marked: the test
    on H at each ε, and for nested cases the test against the coarser level's gain at
    each θ (with the default ε)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    histories = {case: hs[-1] for case, hs in levels.items()}
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
        if len(levels[case]) > 1:
            coarse = levels[case][-2][-1]["H"]
            ax.axhline(tao.NESTED_RTOL * (coarse - H_full) / H_full, ls="--", color="0.5",
                       lw=1, label=f"default θ = {tao.NESTED_RTOL:g} times the coarser gain")
            for theta, marker in zip(thetas, markers, strict=False):
                k = stopping_step(history, tao.H_RTOL, coarse, theta)
                ax.semilogy([k], [excess[k]], marker, ms=11, mfc="none", mew=1.6,
                            label=f"stop at θ = {theta:g} (nested): step {k}")
        kind, _, size = case.rpartition("-")
        ax.set_title(f"{kind}-{float(size):.6g} (finest level)")
        ax.set_xlabel("Newton step")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
