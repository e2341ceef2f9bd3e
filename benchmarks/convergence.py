"""Convergence of the second-order solvers against the note's projected gradient descent.

    python benchmarks/convergence.py [--sizes 0.1 0.05] [--cases annulus-iso piano-noniso ...]
                                     [--methods bncg nls ntr bntr lmvm] [--max-it-gd 2000]
                                     [--max-it 500] [--max-aspect 4.0 | --no-aspect-bound]
                                     [--no-pin] [--out benchmarks/out] [PETSc options]
    mpirun -n 2 python benchmarks/convergence.py ...

For every case (geometry ``annulus`` or ``piano``, isotropic or not) and mesh size it builds
the mesh and the MBO field once, then runs each TAO type from that same field
(``q.x.array`` is copied back before every run) with the project's defaults, as the CLI
uses them: singular triangles pinned, non-isotropic frames bounded by l_max/l_min <= 4.

* ``bncg``: the note's projected gradient descent (``-tao_bncg_type gd``, Armijo), the
  reference, with ``--max-it-gd`` iterations (default 2000);
* ``nls``, ``ntr``, ``bntr``: Newton line search / trust regions on the Riemannian
  Gauss–Newton model (``solvers.GaussNewtonModel``), ``lmvm``: L-BFGS; ``--max-it``
  iterations (default 500).

Each method runs under its own options prefix (``nls_``, ``bncg_``, ...), so PETSc options
for one method are given as ``-nls_tao_nls_ksp_type cg``; unprefixed ``-tao_*`` options are
not seen by the runs. All stop at ``-tao_gttol 1e-6`` (relative Riemannian gradient).

The table (printed, and written to ``<out>/convergence.md``) has per run: iterations (the
solver's history entries; ``ntr`` also reports its rejected trust-region steps there, each
of which costs a Newton solve, so it may show more than ``--max-it``), objective/gradient
evaluations (``f evals``, line-search trials included: ``bncg``'s Armijo search backtracks
from a unit step, about 13 per iteration) and how many of them computed the gradient too
(``g evals``), wall and CPU seconds of the whole ``solve`` call
(CPU: this process, the fairer number on a shared machine; both max over ranks), the final
H, the final relative Riemannian gradient norm |g|/|g0|, TAO's converged reason, the
number of singular triangles of the final field, and the first iteration at which H is at
most the final H of ``bncg`` in the same case, with the ratios ``bncg its / its`` and
``bncg time / time to get there`` (targets: >= 20x fewer iterations, >= 5x less wall time).
The summary says which targets hold for the best method of each case and size (the one
with the largest margin on both, max of min(its ratio / 20, wall ratio / 5)), and how the
iteration count of every method changes from h to h/2 (target for the best method: at most
1.5x; a method that did not converge at both sizes is marked).

``--replay <out>/convergence.json`` rebuilds the table, summary and figures of an earlier run
without solving anything. One figure
per case, ``<out>/convergence_<case>.png``: H against iteration and against wall time for
all methods, and H minus the lowest final H of the case against iteration, one column per
mesh size; ``<out>/convergence.json`` holds every history.
"""

import argparse
import json
import sys
import time
from pathlib import Path

CASES = ("annulus-iso", "annulus-noniso", "piano-iso", "piano-noniso")
METHODS = ("bncg", "nls", "ntr", "bntr", "lmvm")
REFERENCE = "bncg"
ITERATION_TARGET, TIME_TARGET, GROWTH_LIMIT = 20.0, 5.0, 1.5


def parse_args(argv=None):
    """(benchmark arguments, remaining arguments for PETSc)."""
    parser = argparse.ArgumentParser(
        description="Second-order frame solvers against the note's projected gradient "
        "(see the module docstring).",
        allow_abbrev=False,
    )
    parser.add_argument(
        "--sizes",
        type=float,
        nargs="+",
        default=[0.1, 0.05],
        help="Gmsh mesh sizes (default 0.1 0.05)",
    )
    parser.add_argument("--cases", nargs="+", choices=CASES, default=list(CASES))
    parser.add_argument(
        "--methods",
        nargs="+",
        choices=METHODS,
        default=list(METHODS),
        help=f"TAO types; {REFERENCE} is the reference of the ratios",
    )
    parser.add_argument(
        "--max-it-gd", type=int, default=2000, help=f"iterations of {REFERENCE} (default 2000)"
    )
    parser.add_argument(
        "--max-it", type=int, default=500, help="iterations of the other methods (default 500)"
    )
    aspect = parser.add_mutually_exclusive_group()
    aspect.add_argument(
        "--max-aspect",
        type=float,
        default=4.0,
        help="bound on l_max/l_min of non-isotropic frames (default 4)",
    )
    aspect.add_argument(
        "--no-aspect-bound",
        dest="max_aspect",
        action="store_const",
        const=None,
        help="no aspect bound (degenerate minimisers, see odeco)",
    )
    parser.add_argument(
        "--no-pin",
        dest="pin",
        action="store_false",
        help="let the singularities move (default: pinned)",
    )
    parser.add_argument(
        "--replay",
        type=Path,
        help="convergence.json of an earlier run: only rebuild the table and figures",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=Path(__file__).parent / "out",
        help="folder of the table, figures and histories",
    )
    return parser.parse_known_args(argv)


ARGS, PETSC_ARGV = parse_args() if __name__ == "__main__" else (None, [])

from ufl_frames.bootstrap import init_petsc  # noqa: E402

init_petsc(sys.argv[:1] + PETSC_ARGV)

import numpy as np  # noqa: E402
from _common import table_rule  # noqa: E402
from mpi4py import MPI  # noqa: E402

from ufl_frames import solvers  # noqa: E402
from ufl_frames.fem import energy  # noqa: E402
from ufl_frames.frames2d import singularities  # noqa: E402
from ufl_frames.mesh import build  # noqa: E402
from ufl_frames.solvers import mbo  # noqa: E402


def log(comm, *args):
    if comm.rank == 0:
        print(*args, flush=True)


def run_method(problem, method, max_it):
    """Solve with TAO type ``method``; the history gets wall and CPU times since the call."""
    comm = problem.constraints.comm
    start, start_cpu = time.perf_counter(), time.process_time()
    times = []

    def monitor(entry):
        times.append((time.perf_counter() - start, time.process_time() - start_cpu))

    # TAO evaluates the objective alone (line-search trials: problem.energy) or with the
    # gradient (problem.riemannian_gradient, which returns H as well).
    counts = {"energy": 0, "gradient": 0}
    energy, gradient = problem.energy, problem.riemannian_gradient

    def counted_energy():
        counts["energy"] += 1
        return energy()

    def counted_gradient(g):
        counts["gradient"] += 1
        return gradient(g)

    problem.energy, problem.riemannian_gradient = counted_energy, counted_gradient
    comm.Barrier()
    result = solvers.solve(
        problem,
        max_it=max_it,
        options_prefix=f"{method}_",
        defaults={"tao_type": method},
        monitor=monitor,
    )
    wall = comm.allreduce(time.perf_counter() - start, op=MPI.MAX)
    cpu = comm.allreduce(time.process_time() - start_cpu, op=MPI.MAX)
    local = np.array(times, dtype=float).reshape(-1, 2)  # same length on every rank
    times = np.empty_like(local)
    comm.Allreduce(local, times, op=MPI.MAX)
    history = [
        {**entry, "wall": float(t[0]), "cpu": float(t[1])}
        for entry, t in zip(result.history, times, strict=True)
    ]
    gnorm0 = history[0]["gnorm"]
    return {
        "method": method,
        "iterations": result.iterations,
        "evaluations": counts["energy"],
        "gradients": counts["gradient"],
        "wall": wall,
        "cpu": cpu,
        "H": result.H_final,
        "rel_grad": history[-1]["gnorm"] / gnorm0 if gnorm0 > 0 else 0.0,
        "reason": result.converged_reason,
        "singularities": len(singularities.locate_singularities(problem.q)),
        "history": history,
    }


def reach(run, target):
    """(iteration, wall, cpu) of the first history entry with H <= target, or None."""
    for entry in run["history"]:
        if entry["H"] <= target:
            return entry["it"], entry["wall"], entry["cpu"]
    return None


def compare(runs):
    """Add to every run the iteration/time to reach the reference's final H, and the ratios."""
    ref = next((r for r in runs if r["method"] == REFERENCE), None)
    for run in runs:
        run["reach"] = run["its_ratio"] = run["wall_ratio"] = run["cpu_ratio"] = None
        if ref is None:
            continue
        hit = reach(run, ref["H"])
        if hit is None:
            continue
        run["reach"] = hit[0]
        run["its_ratio"] = ref["iterations"] / max(hit[0], 1)
        run["wall_ratio"] = ref["wall"] / max(hit[1], 1e-9)
        run["cpu_ratio"] = ref["cpu"] / max(hit[2], 1e-9)


def run_case(comm, name, h, args):
    geometry_name, kind = name.split("-")
    isotropic = kind == "iso"
    runs = []
    for method in args.methods:
        args.state.q.x.array[:] = args.state.q0
        problem = solvers.frame_problem(
            args.state.q,
            isotropic=isotropic,
            pin_singularities=args.pin,
            max_aspect=None if isotropic else args.max_aspect,
        )
        max_it = args.max_it_gd if method == REFERENCE else args.max_it
        run = run_method(problem, method, max_it)
        runs.append(run)
        log(
            comm,
            f"  {name:15s} h={h:<6g} {method:5s} {run['iterations']:5d} its "
            f"({run['evaluations']:5d} f, {run['gradients']:5d} g) {run['wall']:8.2f} s "
            f"(cpu {run['cpu']:7.2f}) "
            f"H={run['H']:.4e} "
            f"|g|/|g0|={run['rel_grad']:.1e} {run['reason']} "
            f"sing={run['singularities']}",
        )
    compare(runs)
    return runs


class MeshState:
    """The mesh, its MBO field and a copy of it, for the runs at one (geometry, size)."""

    def __init__(self, comm, geometry_name, h):
        start = time.perf_counter()
        mesh = build(comm, geometry_name, h).mesh
        self.q = mbo.mbo_frame_field(energy.frame_space(mesh))
        self.q0 = self.q.x.array.copy()
        self.cells = mesh.topology.index_map(2).size_global
        self.seconds = comm.allreduce(time.perf_counter() - start, op=MPI.MAX)


def fmt(value, spec, missing="-"):
    return missing if value is None else format(value, spec)


def table(results, sizes):
    header = (
        "| case | h | triangles | method | its | f evals | g evals | wall s | cpu s | final H "
        f"| rel grad | reason | sing. | its to {REFERENCE} H | its ratio | wall ratio | cpu ratio |"
    )
    lines = [header, table_rule(header)]
    for (name, h), (cells, runs) in results.items():
        for run in runs:
            lines.append(
                f"| {name} | {h:g} | {cells} | {run['method']} | {run['iterations']} "
                f"| {run['evaluations']} | {run['gradients']} "
                f"| {run['wall']:.1f} | {run['cpu']:.1f} | {run['H']:.4e} "
                f"| {run['rel_grad']:.1e} | {run['reason']} | {run['singularities']} "
                f"| {fmt(run['reach'], 'd')} | {fmt(run['its_ratio'], '.1f')} "
                f"| {fmt(run['wall_ratio'], '.1f')} | {fmt(run['cpu_ratio'], '.1f')} |"
            )
    return "\n".join(lines)


def best_run(runs):
    """The non-reference run with the largest margin on both targets.

    That is the largest min(its ratio / 20, wall ratio / 5) among the runs that reach the
    reference's final H (ties: the larger wall ratio).
    """
    candidates = [r for r in runs if r["method"] != REFERENCE and r["reach"] is not None]
    if not candidates:
        return None

    def margin(run):
        its, wall = run["its_ratio"] / ITERATION_TARGET, run["wall_ratio"] / TIME_TARGET
        return min(its, wall), wall

    return max(candidates, key=margin)


def summary(results, cases, sizes):
    lines = []
    for name in cases:
        for h in sizes:
            if (name, h) not in results:
                continue
            runs = results[(name, h)][1]
            best = best_run(runs)
            if best is None:
                lines.append(f"- {name} h={h:g}: no method reached {REFERENCE}'s final H")
                continue
            ok_its = best["its_ratio"] >= ITERATION_TARGET
            ok_wall = best["wall_ratio"] >= TIME_TARGET
            lines.append(
                f"- {name} h={h:g}: best {best['method']} reaches {REFERENCE}'s H "
                f"{next(r['H'] for r in runs if r['method'] == REFERENCE):.4e} at iteration "
                f"{best['reach']}: {best['its_ratio']:.1f}x fewer iterations "
                f"({'met' if ok_its else 'MISSED'}, target {ITERATION_TARGET:g}x), "
                f"{best['wall_ratio']:.1f}x less wall time, {best['cpu_ratio']:.1f}x less CPU "
                f"({'met' if ok_wall else 'MISSED'}, target {TIME_TARGET:g}x on wall time)"
            )
        for coarse, fine in zip(sizes, sizes[1:], strict=False):
            if (name, coarse) not in results or (name, fine) not in results:
                continue
            best = best_run(results[(name, fine)][1])
            if best is None:
                continue
            parts = []
            for run in results[(name, fine)][1]:
                if run["method"] == REFERENCE:
                    continue
                other = next(r for r in results[(name, coarse)][1] if r["method"] == run["method"])
                growth = run["iterations"] / max(other["iterations"], 1)
                both = run["reason"].startswith("CONVERGED") and other["reason"].startswith(
                    "CONVERGED"
                )
                stopped = "" if both else ", not converged"
                parts.append(
                    f"{run['method']} {other['iterations']} -> {run['iterations']} "
                    f"({growth:.2f}x{stopped})"
                )
                if run is best:
                    best_growth = growth
            verdict = "MORE than" if best_growth > GROWTH_LIMIT else "within"
            lines.append(
                f"- {name}, iterations to stop h={coarse:g} -> {fine:g}: {', '.join(parts)}; "
                f"best ({best['method']}) grows {verdict} {GROWTH_LIMIT:g}x"
            )
    return "\n".join(lines)


COLOURS = {
    "bncg": "#7f7f7f",
    "nls": "#1f77b4",
    "ntr": "#ff7f0e",
    "bntr": "#2ca02c",
    "lmvm": "#d62728",
}


def plot(path, name, results, sizes):
    """H against iteration and wall time (log-log), and H − H_best against iteration.

    H_best is the lowest final H of the case at that size (over all methods): the bottom
    row shows the convergence to it, which the top rows hide when H levels off far from 0.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sizes = [h for h in sizes if (name, h) in results]
    fig, axes = plt.subplots(
        3, len(sizes), figsize=(4.6 * len(sizes), 10.0), squeeze=False, layout="constrained"
    )
    for col, h in enumerate(sizes):
        runs = results[(name, h)][1]
        ref = next((r for r in runs if r["method"] == REFERENCE), None)
        best = min(r["H"] for r in runs)
        for row, key in enumerate(("it", "wall", "gap")):
            ax = axes[row, col]
            for run in runs:
                H = np.array([e["H"] for e in run["history"]])
                x = np.array([e["wall" if key == "wall" else "it"] for e in run["history"]])
                x = x.astype(float) + (0 if key == "wall" else 1)
                if key == "gap":
                    H = H - best
                    keep = H > 1e-14 * best
                    x, H = x[keep], H[keep]
                style = {"marker": ".", "ms": 3} if key == "gap" and x.size < 60 else {}
                ax.plot(
                    x, H, lw=1.4, label=run["method"], color=COLOURS.get(run["method"]), **style
                )
            if ref is not None and key != "gap":
                ax.axhline(ref["H"], color="k", ls=":", lw=0.8, label=f"{REFERENCE} final H")
            if ref is not None and key == "gap" and ref["H"] > best:
                ax.axhline(ref["H"] - best, color="k", ls=":", lw=0.8)
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlabel("wall time [s]" if key == "wall" else "iteration + 1")
            ax.set_ylabel(f"H(q) - {best:.6g}" if key == "gap" else "H(q)")
            ax.set_title(f"{name}, h = {h:g}")
            ax.grid(True, which="both", alpha=0.3)
        axes[0, col].legend(fontsize=8)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def report(comm, results, cases, sizes, out, options):
    """Print the table and summary; write them, the histories and the figures to ``out``."""
    if comm.rank != 0:
        return
    text = table(results, sizes)
    notes = summary(results, cases, sizes)
    print("\n" + text + "\n\n" + notes + "\n\n" + options, flush=True)
    (out / "convergence.md").write_text(
        f"# benchmarks/convergence.py\n\n{options}\n\n{text}\n\n{notes}\n"
    )
    serialisable = {
        "options": options,
        "results": [
            {"case": name, "h": h, "triangles": cells, "runs": runs}
            for (name, h), (cells, runs) in results.items()
        ],
    }
    (out / "convergence.json").write_text(json.dumps(serialisable, indent=1))
    for name in cases:
        plot(out / f"convergence_{name}.png", name, results, sizes)
    print(f"wrote {out}/convergence.md, convergence.json, convergence_<case>.png")


def replay(comm, args):
    data = json.loads(args.replay.read_text())
    results = {}
    for item in data["results"]:
        compare(item["runs"])
        results[(item["case"], item["h"])] = (item["triangles"], item["runs"])
    cases = list(dict.fromkeys(name for name, _ in results))
    sizes = list(dict.fromkeys(h for _, h in results))
    report(comm, results, cases, sizes, args.out, data["options"] + f" (replayed {args.replay})")


def main(args):
    comm = MPI.COMM_WORLD
    args.out.mkdir(parents=True, exist_ok=True)
    if args.replay is not None:
        return replay(comm, args)
    log(
        comm,
        f"{len(args.cases)} cases x {len(args.sizes)} sizes x {len(args.methods)} "
        f"methods on {comm.size} rank(s); pinned={args.pin}, max_aspect={args.max_aspect}",
    )
    start = time.perf_counter()
    results = {}
    for geometry_name in dict.fromkeys(c.split("-")[0] for c in args.cases):
        for h in args.sizes:
            args.state = MeshState(comm, geometry_name, h)
            log(
                comm,
                f"{geometry_name} h={h:g}: {args.state.cells} triangles, mesh + MBO "
                f"{args.state.seconds:.1f} s",
            )
            for name in args.cases:
                if name.startswith(geometry_name + "-"):
                    results[(name, h)] = (args.state.cells, run_case(comm, name, h, args))
            log(comm, f"  ... {time.perf_counter() - start:.0f} s so far")
    args.state = None
    total = comm.allreduce(time.perf_counter() - start, op=MPI.MAX)
    options = (
        f"sizes {args.sizes}, max_it {args.max_it_gd} ({REFERENCE}) / "
        f"{args.max_it} (others), pinned singularities {args.pin}, max_aspect "
        f"{args.max_aspect} (non-isotropic), {comm.size} MPI rank(s), PETSc options "
        f"{' '.join(PETSC_ARGV) or 'none'}; total {total:.0f} s"
    )
    report(comm, results, args.cases, args.sizes, args.out, options)


if __name__ == "__main__":
    main(ARGS)
