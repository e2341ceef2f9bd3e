"""End-to-end cost of a frame-field run as the mesh is refined: does it scale linearly?

    python benchmarks/scaling.py [--cases piano-noniso piano-iso annulus-noniso annulus-iso]
                                 [--triangles 1e4 1e5 | --sizes 0.05 0.025]
                                 [--np 1] [--np-largest 2] [--timeout 900] [--max-it 500]
                                 [--json benchmarks/out/scaling.json] [--quads]
                                 [PETSc options]

Every (case, size) runs in a fresh process (under ``mpirun -n NP`` when NP > 1), so that its
peak memory is its own: the whole run as the CLI does it, through
:class:`ufl_frames.pipeline.FrameField` — Gmsh meshing and distribution (``mesh``), the MBO
initial field (``mbo``), the TAO solve with the defaults (``solve``), and the ParaView files
and figures (``write``), with ``--quads`` the quad mesh at the default quad size (``quads``:
its method and its integrate and quantise seconds in a second table). Sizes are given as triangle
counts (``--triangles``: the mesh size is chosen from the measured counts at h = 0.05,
N ~ 1/h²: piano 1887, annulus 2305) or as mesh sizes (``--sizes``). ``--np-largest`` runs
the largest size on that many ranks instead.

Per run it prints: triangles and vertices, ranks, the wall seconds of each stage (max over
ranks) and their total, Newton iterations, mean and max Krylov iterations per Newton step,
peak resident memory per rank (max over ranks), the final H, TAO's reason and the
singularities' indices. Then, per case, the growth per 2x refinement (h → h/2, i.e. ×4
triangles) between consecutive sizes of: Newton iterations, mean Krylov iterations, solve
time per triangle; and the issue's targets for the non-isotropic piano, each marked
``holds`` / ``fails`` / ``not measured``. A run past ``--timeout`` seconds is killed and
reported as ``timeout`` with the stages it finished.

Nested runs also get a table of every level's triangles, Newton steps and
singularities, with the share of vertices near the aspect bound and rank 0's CPU
seconds of the solve. ``--json`` keeps the records; ``--from-json`` reports on such
files again, several runs together (a serial series and a 2-rank one, say), and
``--figure`` plots the seconds and the finest level's Newton steps against the triangles.

Unknown single-dash arguments (``-tao_nls_pc_type hypre``) reach every run's PETSc options.
The solves use the ``ufl_frames`` that the interpreter imports (``PYTHONPATH=OTHER/src``
measures another checkout). Times are wall-clock on whatever else the machine runs: compare
runs made side by side.
"""

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: ``-sized``: non-isotropic frames with the uniform size target (the CLI's default for
#: them, ``mesh.sizes.SizeTarget``); ``-noniso`` the unsized, degenerate problem.
CASES = ("piano-noniso", "piano-iso", "annulus-noniso", "annulus-iso", "piano-sized",
         "annulus-sized")
#: Triangles at h = 0.05 (measured), for --triangles.
STAGES = ("mesh", "mbo", "solve", "write")
GROWTH_LIMIT = 1.3  # per 2x refinement, Newton iterations and mean Krylov iterations
#: Final H of the non-isotropic piano at h = 0.05 with the defaults before the scaling work:
#: 1.1225e-3 with the CAD boundary tangents (the default since the real-geometry loader;
#: 1.0965e-3 with the mesh's edge normals, the figure the issue quotes).
REFERENCE_H_005 = 1.1225e-3


# --- one run (in its own process) -------------------------------------------------------


def run_one(case: str, h: float, max_it: int, out: Path, petsc_argv: list[str],
            quads: bool = False, levels: int | str = "auto", nested_meshes: bool = False) -> dict:
    """The whole pipeline on ``case`` at mesh size ``h``; returns the record (rank 0).

    With ``levels`` > 1 (or 'auto', the CLI's default rule, when that gives more than one),
    nested iteration (:meth:`FrameField.nested`) over the meshes of
    :func:`ufl_frames.mesh.hierarchy.nested_domains`: ``mesh`` meshes every level, ``mbo``
    is 0 (MBO runs on the coarsest mesh, inside ``solve``), and the Newton and Krylov
    counts are the finest level's (every level's in ``levels``); with ``nested_meshes``
    the levels are :func:`ufl_frames.mesh.build_nested`'s (the coarsest split, as
    ``ufl-frames solve --nested-meshes``) instead of meshed by Gmsh."""
    from ufl_frames.bootstrap import init_petsc

    init_petsc([sys.argv[0], *petsc_argv])
    import resource

    from mpi4py import MPI

    from ufl_frames.mesh import build
    from ufl_frames.mesh.hierarchy import nested_domains
    from ufl_frames.mesh.sizes import SizeTarget
    from ufl_frames.pipeline import FrameField
    from ufl_frames.pipeline.files import write_field
    from ufl_frames.pipeline.stages import quadrangulate

    comm = MPI.COMM_WORLD
    shape, kind = case.split("-")
    size = SizeTarget.uniform() if kind == "sized" else None
    stages, cpu = {}, {}

    def stage(name, func):
        comm.Barrier()
        wall0, cpu0 = time.perf_counter(), time.process_time()
        value = func()
        cpu[name] = time.process_time() - cpu0
        stages[name] = comm.allreduce(time.perf_counter() - wall0, op=MPI.MAX)
        if comm.rank == 0:
            print(f"  {name}: {stages[name]:.2f} s", file=sys.stderr, flush=True)
        return value

    def meshes():
        fine = build(comm, shape, h)
        count = levels if levels == "auto" else int(levels)
        return nested_domains(comm, shape, fine, count, h, nested_meshes=nested_meshes)

    domains = stage("mesh", meshes)
    domain = domains[-1]
    if len(domains) > 1:
        stages["mbo"] = cpu["mbo"] = 0.0
        field = stage("solve", lambda: FrameField.nested(domains, isotropic=kind == "iso",
                                                         max_it=max_it, size=size))
        result = field.result
    else:
        field = stage("mbo", lambda: FrameField.initial(domain, isotropic=kind == "iso",
                                                        size=size))
        result = stage("solve", lambda: field.solve(max_it=max_it))
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
    comm.Barrier()
    stage("write", lambda: write_field(out, field, label=shape))
    quad_record = None
    if quads:  # the default quad size: the triangles' mean edge
        found = stage("quads", lambda: quadrangulate(field).quality)
        quad_record = {key: found[key] for key in ("quads", "irregular_vertices", "min_sj",
                                                   "mean_sj", "valid", "quantisation",
                                                   "seconds")}
    near_bound = None  # the share of vertices within 10 % of the aspect bound
    if kind != "iso" and field.max_aspect:
        import numpy as np

        from ufl_frames.frames2d.algebra import ALGEBRA

        owned = field.q.function_space.dofmap.index_map.size_local
        lengths, _ = ALGEBRA.q_to_frames(field.q.x.array.reshape(-1, ALGEBRA.count)[:owned])
        near = int(np.count_nonzero(lengths.max(1) / lengths.min(1) > 0.9 * field.max_aspect))
        near_bound = comm.allreduce(near, op=MPI.SUM) / comm.allreduce(owned, op=MPI.SUM)
    parts = None  # J's parts with a size target: H, M, S (J = H + w H_s M + C S)
    problem = field.problem
    if problem is not None and problem.size is not None:
        term = problem.size
        parts = {"H": problem.integrability_energy(), "M": problem.size_misfit(),
                 "wHs": term.weight, "S": problem.size_smoothing(),
                 "C": term.smoothing_weight, "s": term.relative_smoothing}
    peak_kb = comm.allreduce(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, op=MPI.MAX)
    krylov = result.krylov_iterations or []
    newton = [k for k in krylov if k > 0]  # steps that solved a Newton system
    # factorisations per Newton step (the active-set rounds: more than one)
    faces = [e["factorisations"] for e in result.history[1:] if "factorisations" in e]
    # the finest level's safeguard: exact factorisations checked, found indefinite and
    # made definite by a shift, redone as Gauss–Newton; the shifts' refactorisations
    last = result.history[-1] if result.history else {}
    safeguard = (last.get("exact_checks"), last.get("fallbacks"), last.get("shifted"),
                 last.get("shift_factorisations"))
    return {
        "case": case, "h": h, "ranks": comm.size,
        "triangles": int(domain.num_cells), "vertices": int(domain.num_vertices),
        "mesh_size": domain.mesh_size,
        "stages": stages, "cpu_rank0": cpu, "total": sum(stages.values()),
        "iterations": result.iterations, "converged_reason": result.converged_reason,
        "near_bound": near_bound,
        "ksp_mean": sum(newton) / len(newton) if newton else None,
        "ksp_max": max(newton) if newton else None, "ksp_per_step": krylov,
        "factorisations_mean": sum(faces) / len(faces) if faces else None,
        "exact_checks": safeguard[0], "fallbacks": safeguard[1], "shifted": safeguard[2],
        "shift_factorisations": safeguard[3],
        "H_final": result.H_final, "peak_rss_mb": peak_kb / 1024,
        "singularities": sorted(s["index"] for s in field.singularities),
        "quads": quad_record, "levels": field.levels, "parts": parts,
    }


# --- the driver ---------------------------------------------------------------------------


def launch(case, h, ranks, args, petsc_argv, partial: Path) -> dict:
    """Run one (case, h) in a fresh process; the record, or its failure."""
    command = [sys.executable, str(Path(__file__).resolve()), "--one", case, repr(h),
               "--max-it", str(args.max_it), "--record", str(partial),
               *(["--quads"] if args.quads else []), "--levels", str(args.levels),
               *(["--nested-meshes"] if args.nested_meshes else []),
               *petsc_argv]
    if ranks > 1:
        mpirun = Path(sys.executable).with_name("mpirun")
        command = [str(mpirun) if mpirun.exists() else "mpirun", "-n", str(ranks), *command]
    env = {**os.environ, "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1")}
    start = time.perf_counter()
    try:
        done = subprocess.run(command, env=env, timeout=args.timeout, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
    except subprocess.TimeoutExpired:
        return {"case": case, "h": h, "ranks": ranks, "status": "timeout",
                "elapsed": time.perf_counter() - start}
    if done.returncode != 0 or not partial.exists():
        tail = (done.stderr or "").strip().splitlines()[-3:]
        return {"case": case, "h": h, "ranks": ranks, "status": f"exit {done.returncode}",
                "error": " | ".join(tail)}
    record = json.loads(partial.read_text())
    record["status"] = "ok"
    return record


def print_quad_table(records) -> None:
    """The quad stage per run: its sub-stages' seconds and the mesh it made."""
    from _common import table_rule

    head = ("\n| case | triangles | quads | method | integrate s | quantise s | quads s "
            "| µs per triangle | irregular | min SJ | valid |")
    print(head)
    print(table_rule(head))
    for r in records:
        q = r.get("quads") if r["status"] == "ok" else None
        if not q:
            continue
        sec = q["seconds"]
        print(f"| {r['case']} | {r['triangles']} | {q['quads']} | {q['quantisation']} "
              f"| {sec['integrate']:.2f} | {sec['quantise']:.2f} | {r['stages']['quads']:.2f} "
              f"| {1e6 * r['stages']['quads'] / r['triangles']:.0f} "
              f"| {q['irregular_vertices']} | {q['min_sj']:.3f} | {q['valid']} |")


def print_levels_table(records) -> None:
    """Per nested run: every level's triangles, Newton steps and singularities, the
    share of vertices within 10 % of the aspect bound and rank 0's CPU seconds of the
    solve (steady where the wall seconds are not, on a shared machine)."""
    from _common import table_rule

    head = ("\n| case | ranks | levels: triangles / Newton steps / singularities "
            "| near bound | solve CPU s (rank 0) | J = H + w H_s M + C S: H, w H_s M, C S |")
    print(head)
    print(table_rule(head))
    for r in records:
        if r["status"] != "ok" or not r.get("levels"):
            continue
        levels = "; ".join(f"{e['triangles']} / {e['iterations']} / {len(e['singularities'])}"
                           for e in r["levels"])
        near = "-" if r.get("near_bound") is None else f"{100 * r['near_bound']:.1f} %"
        p = r.get("parts")
        parts = "-" if not p else (f"{p['H']:.4e}, {p['wHs'] * p['M']:.4e}, "
                                   f"{p['C'] * p['S']:.4e} (s = {p['s']:g})")
        print(f"| {r['case']} | {r['ranks']} | {levels} | {near} "
              f"| {r['cpu_rank0']['solve']:.1f} | {parts} |")


def _indices(values) -> str:
    if not values:
        return "none"
    counts = {}
    for v in values:
        counts[v] = counts.get(v, 0) + 1
    return " ".join(f"{v:+g}x{n}" for v, n in sorted(counts.items()))


def print_table(records) -> None:
    from _common import table_rule

    head = ("| case | h | triangles | ranks | mesh s | mbo s | solve s | write s | total s "
            "| Newton its | KSP mean | KSP max | factorisations per step | peak MB/rank "
            "| final H | reason | singularities "
            "| exact factorisations: shifted / Gauss–Newton / all (shift refactorisations) |")
    print(head)
    print(table_rule(head))
    for r in records:
        if r["status"] != "ok":
            print(f"| {r['case']} | {r['h']:.4g} | - | {r['ranks']} | {r['status']} "
                  f"{r.get('error', '')} |" + " |" * 13)
            continue
        s = r["stages"]
        mean = "-" if r["ksp_mean"] is None else f"{r['ksp_mean']:.0f}"
        peak = "-" if r["ksp_max"] is None else str(r["ksp_max"])
        faces = r.get("factorisations_mean")
        faces = "-" if faces is None else f"{faces:.2f}"
        print(f"| {r['case']} | {r['h']:.4g} | {r['triangles']} | {r['ranks']} "
              f"| {s['mesh']:.2f} | {s['mbo']:.2f} | {s['solve']:.2f} | {s['write']:.2f} "
              f"| {r['total']:.1f} | {r['iterations']} | {mean} | {peak} | {faces} "
              f"| {r['peak_rss_mb']:.0f} | {r['H_final']:.4e} | {r['converged_reason']} "
              f"| {_indices(r['singularities'])} "
              f"| {r.get('shifted', '-')} / {r.get('fallbacks', '-')} "
              f"/ {r.get('exact_checks', '-')} ({r.get('shift_factorisations', '-')}) |")


def growth_factors(records, case) -> list[tuple]:
    """(a, b, Newton, KSP mean, solve time per triangle) growth per 2x refinement between
    consecutive finished sizes of ``case``: one record a size (the first, fewest ranks
    first), each next size at least twice the triangles of the last one taken (records
    of several runs, ``--from-json``, may hold sizes too close to extrapolate from)."""
    finished = sorted((r for r in records if r["case"] == case and r["status"] == "ok"),
                      key=lambda r: (r["triangles"], r["ranks"]))
    done = []
    for r in finished:
        if not done or r["triangles"] >= 2 * done[-1]["triangles"]:
            done.append(r)
    factors = []
    for a, b in zip(done[:-1], done[1:], strict=True):
        halvings = 0.5 * math.log2(b["triangles"] / a["triangles"])  # h → h/2: ×4
        if halvings <= 0:
            continue

        def per2x(x, y, halvings=halvings):
            return (y / x) ** (1 / halvings) if x and y else float("nan")

        factors.append((a, b, per2x(a["iterations"], b["iterations"]),
                        per2x(a["ksp_mean"] or 0, b["ksp_mean"] or 0),
                        per2x(a["stages"]["solve"] / a["triangles"],
                              b["stages"]["solve"] / b["triangles"])))
    return factors


def growth(records) -> list[str]:
    """Per case, growth per 2x refinement between consecutive finished sizes."""
    lines = []
    for case in dict.fromkeys(r["case"] for r in records):
        for a, b, newton, ksp, cost in growth_factors(records, case):
            ranks = "" if a["ranks"] == b["ranks"] else f" (ranks {a['ranks']} -> {b['ranks']})"
            lines.append(f"{case}: {a['triangles']} -> {b['triangles']} triangles{ranks}, per "
                         f"2x refinement: Newton its x{newton:.2f}, mean KSP its x{ksp:.2f}, "
                         f"solve time per triangle x{cost:.2f}")
    return lines


def targets(records) -> list[str]:
    """The issue's targets for the non-isotropic piano with the defaults."""
    piano = [r for r in records if r["case"] == "piano-noniso" and r["status"] == "ok"
             and r["converged_reason"].startswith("CONVERGED")]  # a time counts if it solved

    def near(triangles, ranks=None):
        found = [r for r in piano if 0.5 * triangles <= r["triangles"] <= 2 * triangles
                 and (ranks is None or r["ranks"] == ranks)]
        return found[0] if found else None

    def mark(ok):
        return "holds" if ok else "fails"

    out = []
    r = next((r for r in piano if abs(r["h"] - 0.025) < 1e-9), None)
    out.append("h = 0.025 end to end <= 20 s: "
               + (f"{r['total']:.1f} s, {mark(r['total'] <= 20)}" if r else "not measured"))
    r = near(1e5, ranks=1)
    out.append("~1e5 triangles serial <= 60 s: "
               + (f"{r['total']:.1f} s, {mark(r['total'] <= 60)}" if r else "not measured"))
    r = near(1e6, ranks=2)
    out.append("~1e6 triangles on 2 ranks <= 300 s and <= 3 GB/rank: "
               + (f"{r['total']:.1f} s, {r['peak_rss_mb'] / 1024:.2f} GB, "
                  f"{mark(r['total'] <= 300 and r['peak_rss_mb'] <= 3072)}"
                  if r else "not measured"))
    factors = growth_factors(records, "piano-noniso")
    if factors:
        worst = max(max(f[2], f[3]) for f in factors)
        out.append(f"Newton and mean KSP its grow <= {GROWTH_LIMIT}x per 2x refinement: "
                   f"worst x{worst:.2f}, {mark(worst <= GROWTH_LIMIT)}")
    else:
        out.append("growth per 2x refinement: not measured (fewer than two sizes)")
    r = next((r for r in piano if abs(r["h"] - 0.05) < 1e-9), None)
    out.append(f"final H at h = 0.05 <= {REFERENCE_H_005:.4e} (the earlier default's): "
               + (f"{r['H_final']:.4e}, {mark(r['H_final'] <= REFERENCE_H_005 * (1 + 1e-3))}"
                  if r else "not measured"))
    return out


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", nargs="+", choices=CASES, default=["piano-noniso"])
    sizes = parser.add_mutually_exclusive_group()
    sizes.add_argument("--triangles", nargs="+", type=float)
    sizes.add_argument("--sizes", nargs="+", type=float)
    parser.add_argument("--np", type=int, default=1, help="ranks per run (default 1)")
    parser.add_argument("--np-largest", type=int, default=None,
                        help="ranks for the largest size (default: --np)")
    parser.add_argument("--timeout", type=float, default=900.0, help="seconds per run")
    parser.add_argument("--max-it", type=int, default=500)
    parser.add_argument("--json", type=Path, default=None, help="write all records here")
    parser.add_argument("--one", nargs=2, metavar=("CASE", "H"), help=argparse.SUPPRESS)
    parser.add_argument("--record", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--levels", default="auto", metavar="L",
                        help="nested iteration over L meshes (FrameField.nested), or 'auto' "
                        "(the CLI's default rule; the default)")
    parser.add_argument("--nested-meshes", action="store_true",
                        help="levels made by splitting the coarsest (ufl-frames solve "
                        "--nested-meshes) instead of each meshed by Gmsh")
    parser.add_argument("--quads", action="store_true",
                        help="also make the quad mesh (default quad size) and time its stages")
    parser.add_argument("--figure", type=Path, default=None,
                        help="plot the seconds and the finest level's Newton steps against "
                        "the triangles here (PNG)")
    parser.add_argument("--from-json", nargs="+", type=Path, default=None, metavar="JSON",
                        help="report (tables, growth, targets, --figure) on the records that "
                        "earlier --json runs wrote, running nothing")
    return parser.parse_known_args(argv)


def main(argv=None) -> int:
    args, petsc_argv = parse_args(argv)
    if args.one:
        from ufl_frames.bootstrap import init_petsc

        init_petsc([sys.argv[0], *petsc_argv])  # before mpi4py (see ufl_frames.bootstrap)
        from mpi4py import MPI

        comm = MPI.COMM_WORLD
        with tempfile.TemporaryDirectory() as own:  # rank 0's folder on every rank
            tmp = comm.bcast(own, root=0)
            record = run_one(args.one[0], float(args.one[1]), args.max_it, Path(tmp) / "out",
                             petsc_argv, quads=args.quads, levels=args.levels,
                             nested_meshes=args.nested_meshes)
            comm.Barrier()  # every rank done with the folder before rank 0 removes it
        if comm.rank == 0:
            args.record.write_text(json.dumps(record))
        return 0
    if args.from_json:
        records = [r for path in args.from_json for r in json.loads(path.read_text())]
        report(records, args)
        return 0
    if args.sizes:
        plan = {case: sorted(args.sizes, reverse=True) for case in args.cases}
    else:
        from _common import mesh_size_for

        counts = sorted(args.triangles or [1e4, 1e5])
        plan = {case: [mesh_size_for(case.split("-")[0], n) for n in counts]
                for case in args.cases}
    records = []
    with tempfile.TemporaryDirectory() as tmp:
        for case, hs in plan.items():
            for k, h in enumerate(hs):
                largest = k == len(hs) - 1
                ranks = args.np_largest if largest and args.np_largest else args.np
                print(f"{case} h = {h:.4g} on {ranks} rank(s) ...", file=sys.stderr, flush=True)
                partial = Path(tmp) / f"{case}-{k}.json"
                records.append(launch(case, h, ranks, args, petsc_argv, partial))
                if records[-1]["status"] != "ok":
                    print(f"  {records[-1]['status']} {records[-1].get('error', '')}",
                          file=sys.stderr)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(records, indent=1))
    report(records, args)
    return 0


def report(records: list[dict], args) -> None:
    """The tables, the growth per refinement, the targets and ``--figure``."""
    print_table(records)
    if any(r.get("levels") for r in records if r["status"] == "ok"):
        print_levels_table(records)
    if any(r.get("quads") for r in records):
        print_quad_table(records)
    print()
    for line in growth(records) + targets(records):
        print(f"- {line}")
    if args.figure is not None:
        figure(records, args.figure)


def figure(records: list[dict], path: Path) -> None:
    """End-to-end and solve seconds (log-log, a line ∝ N for reference) and the finest
    level's Newton steps against the triangles, one colour per case, ranks marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    done = [r for r in records if r["status"] == "ok"]
    fig, (seconds, steps) = plt.subplots(1, 2, figsize=(12, 4.8))
    for colour, case in zip(plt.cm.tab10.colors, dict.fromkeys(r["case"] for r in done),
                            strict=False):
        for ranks in sorted({r["ranks"] for r in done if r["case"] == case}):
            runs = sorted((r for r in done if r["case"] == case and r["ranks"] == ranks),
                          key=lambda r: r["triangles"])
            n = [r["triangles"] for r in runs]
            marker = "o" if ranks == 1 else "s"
            label = case + ("" if ranks == 1 else f", {ranks} ranks")
            seconds.loglog(n, [r["total"] for r in runs], marker + "-", color=colour,
                           label=f"{label}: end to end")
            seconds.loglog(n, [r["stages"]["solve"] for r in runs], marker + ":",
                           color=colour, alpha=0.7)
            steps.semilogx(n, [r["iterations"] for r in runs], marker + "-", color=colour,
                           label=label)
    if done:
        smallest = min(done, key=lambda r: r["triangles"])
        n = sorted({r["triangles"] for r in done})
        seconds.loglog(n, [smallest["total"] * m / smallest["triangles"] for m in n], "--",
                       color="0.6", label="∝ triangles (linear cost)")
    seconds.set_xlabel("triangles")
    seconds.set_ylabel("seconds (solid: end to end, dotted: solve)")
    seconds.grid(True, which="both", alpha=0.3)
    seconds.legend(fontsize=7)
    steps.set_xlabel("triangles")
    steps.set_ylabel("Newton steps on the finest level")
    steps.set_ylim(bottom=0)
    steps.grid(True, which="both", alpha=0.3)
    steps.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


if __name__ == "__main__":
    sys.exit(main())
