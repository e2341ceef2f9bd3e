"""Where the non-isotropic piano's Newton steps go: a field pressed against the aspect bound.

    python benchmarks/aspect_drift.py [--sizes 0.0347 0.01737 0.008687] [--aspects 2 4 8]
                                      [--figure docs/figures/aspect_drift.png]
                                      [--probe] [--quads] [PETSc options]

The non-isotropic piano is the one case whose finest level often takes 30-55 Newton steps
(the annulus and the isotropic cases 4-11 at every size). This script asks what those
steps do. For each mesh size of ``--sizes`` (the finest level; the coarser ones as the CLI
makes them, :func:`ufl_frames.mesh.hierarchy.nested_domains`: Gmsh meshes of 2^k times the
size) and each bound l_max/l_min ≤ A of ``--aspects``, it runs the CLI's nested iteration
(:meth:`FrameField.nested`, default solver) and, through its checkpoint hook, records per
Newton step of the finest level H, the Dirichlet energy E and the share of vertices
whose frames are on the bound (aspect within 1e-6 of A).

Printed per run: triangles, every level's Newton steps, the finest level's H at its start
and end, the Newton steps it took to come within 10 % and within 1 % of its final H (what
is left after that is the tail), E at its start, at the 10 % step and at the end, the shares
of frames on the bound and within 10 % of it (l_max/l_min ≥ 0.9 A) at those steps, and the
finest level's seconds. ``--figure``: for A = 4 at the largest size, the aspect
l_max/l_min at the 10 % step and at the end, the change of q between them (where the tail
moves the field), and for every A the finest level's H / H_final − 1 against the step.
``--probe``: H along every third Newton step of the tail (from the 10 % step on), at 1,
1.5, 2, 3 and 4 times the step, retracted as the solver does and with no aspect bound —
whether longer steps would have gone further, and whether the bound's clamp stops them.
``--quads``: the quad mesh of the field at the 10 % step and at the end (what the tail
is worth to a quad mesh).
What it showed on 2026-12-05 is in benchmarks/README.md
("The non-isotropic piano's field is pressed against the aspect bound").
"""

import argparse
import os

import numpy as np

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

#: A frame counts as on the bound where l_max/l_min ≥ (1 − this) A …
ON_BOUND_RTOL = 1e-6
#: … and as near it where l_max/l_min ≥ this A.
NEAR_BOUND = 0.9
#: Multiples of a Newton step at which ``--probe`` evaluates H (the retracted point).
PROBE_LENGTHS = (1.0, 1.5, 2.0, 3.0, 4.0)


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    parser.add_argument("--sizes", type=float, nargs="+", default=[0.0347, 0.01737, 0.008687],
                        help="finest mesh sizes (default: about 4 000, 15 600 and 61 600 "
                             "triangles, the three coarsest levels of the 10⁶ hierarchy)")
    parser.add_argument("--aspects", type=float, nargs="+", default=[2.0, 4.0, 8.0],
                        help="bounds A on l_max/l_min (the CLI's default is 4)")
    parser.add_argument("--max-it", type=int, default=500, help="Newton steps a level at most")
    parser.add_argument("--figure", default=None, help="PNG of the largest size's runs")
    parser.add_argument("--quads", action="store_true",
                        help="also the quad mesh (default quad size) of the field at the "
                             "10 %% step and at the end")
    parser.add_argument("--probe", action="store_true",
                        help="also H along every third Newton step of the tail, at "
                             f"{', '.join(f'{t:g}' for t in PROBE_LENGTHS)} times its length")
    return parser.parse_known_args(argv)


def aspect(rows: np.ndarray) -> np.ndarray:
    """l_max / l_min of each frame (rows (N, 5) on the variety)."""
    lengths, _ = odeco.q_to_frames(rows)
    return lengths.max(axis=1) / np.maximum(lengths.min(axis=1), 1e-300)


def first_within(energies: list[float], rtol: float) -> int:
    """The first step whose H is within ``rtol`` of the last one."""
    final = energies[-1]
    return next(k for k, value in enumerate(energies) if value <= (1 + rtol) * final)


def probe(field, trace: dict, first: int) -> list[str]:
    """H along every third Newton step from step ``first`` on: the step from the iterate k
    to k + 1 taken :data:`PROBE_LENGTHS` times and retracted as the solver does (the
    solver's own path at 1), and retracted with no aspect bound (whether the bound's
    clamp is what bends the path)."""
    problem = field.problem
    manifold = problem.manifold
    unbounded = FrameManifold(manifold.constraints.for_frames(False, None),
                              radius2=manifold.radius2)
    vector = dolfinx.fem.petsc.create_vector(field.q.function_space)

    def bounded_energy(rows):
        vector.getArray()[:] = manifold.to_x(rows).ravel()
        problem.set_from_x(vector)
        return problem.energy()

    def unbounded_energy(rows):
        problem.q.x.array[:] = unbounded.retraction(rows).ravel()
        return problem.energy()

    lines = []
    try:
        for k in range(first, len(trace["rows"]) - 1, 3):
            start, end = trace["rows"][k], trace["rows"][k + 1]
            for label, energy in (("bound", bounded_energy), ("no bound", unbounded_energy)):
                changes = [energy(start + t * (end - start)) / trace["H"][k] - 1
                           for t in PROBE_LENGTHS]
                lines.append(f"  step {k} ({label}): H {trace['H'][k]:.4e}; H / H_k − 1 at "
                             + ", ".join(f"{t:g}×: {c:+.2%}" for t, c in zip(
                                 PROBE_LENGTHS, changes, strict=True)))
    finally:
        vector.destroy()
    return lines


def quads_at(field, rows: np.ndarray) -> str:
    """The quad mesh measures of ``field`` with its frames set to ``rows`` (serial)."""
    field.q.x.array[:] = rows.ravel()
    quality = quadrangulate(field).quality
    return (f"{quality['quads']} quads, {quality['irregular_vertices']} irregular vertices, "
            f"scaled Jacobian min {quality['min_sj']:.3f}, edge ratio max "
            f"{quality['edge_length_ratio']['max']:.2f}, seamless misfit "
            f"{quality['misfit_seamless']:.4f} ({quality['quantisation']})")


def run(h: float, max_aspect: float, max_it: int, with_probe: bool = False,
        with_quads: bool = False) -> dict:
    """Nested iteration (:meth:`FrameField.nested`) on the piano at finest size ``h`` with
    the bound ``max_aspect``; its checkpoint hook traces the finest level step by step."""
    comm = MPI.COMM_WORLD
    fine_domain = build(comm, "piano", h)
    domains = nested_domains(comm, "piano", fine_domain, "auto", h)
    trace = {"H": [], "E": [], "bound": [], "near": [], "rows": []}

    def keep(state, finest):
        if not finest:
            return
        ratio = aspect(state.rows)
        trace["H"].append(state.history[-1]["H"])
        trace["E"].append(state.history[-1]["E"])
        trace["bound"].append(float(np.mean(ratio >= (1 - ON_BOUND_RTOL) * max_aspect)))
        trace["near"].append(float(np.mean(ratio >= NEAR_BOUND * max_aspect)))
        trace["rows"].append(state.rows)

    field = FrameField.nested(domains, max_aspect=max_aspect, max_it=max_it, checkpoint=keep)
    ten, one = first_within(trace["H"], 0.1), first_within(trace["H"], 0.01)
    V = field.q.function_space
    probes = probe(field, trace, ten) if with_probe else []
    if with_quads:
        probes += [f"  quads at step {ten} (10 %): {quads_at(field, trace['rows'][ten])}",
                   f"  quads at the end: {quads_at(field, trace['rows'][-1])}"]
    return {"probes": probes, "h": h, "A": max_aspect, "triangles": fine_domain.num_cells,
            "steps": [level["iterations"] for level in field.levels],
            "seconds": field.levels[-1]["seconds"], "ten": ten, "one": one, "trace": trace,
            "x": V.tabulate_dof_coordinates()[: field.problem.owned, :2],
            "cells": V.dofmap.list}


def report(record: dict) -> str:
    trace, ten, one = record["trace"], record["ten"], record["one"]
    H, E, bound, near = trace["H"], trace["E"], trace["bound"], trace["near"]
    steps = " / ".join(str(s) for s in record["steps"])
    return (f"| {record['triangles']} | {record['A']:g} | {steps} | {H[0]:.3e} → {H[-1]:.4e} "
            f"| {ten} / {one} | {E[0]:.2f} / {E[ten]:.2f} / {E[-1]:.2f} "
            f"| {bound[0]:.0%} / {bound[ten]:.0%} / {bound[-1]:.0%} "
            f"| {near[0]:.0%} / {near[ten]:.0%} / {near[-1]:.0%} | {record['seconds']:.1f} |")


def figure(records: list[dict], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.tri as mtri

    largest = max(r["triangles"] for r in records)
    runs = [r for r in records if r["triangles"] == largest]
    main = min(runs, key=lambda r: abs(r["A"] - 4.0))
    rows = main["trace"]["rows"]
    tri = mtri.Triangulation(main["x"][:, 0], main["x"][:, 1], main["cells"])
    fig, axes = plt.subplots(2, 2, figsize=(12, 8), layout="constrained")
    for ax, step, label in ((axes[0, 0], main["ten"], "within 10 % of the final H"),
                            (axes[0, 1], len(rows) - 1, "the end")):
        shade = ax.tripcolor(tri, aspect(rows[step]), shading="gouraud", vmin=1,
                             vmax=main["A"], cmap="viridis")
        ax.set_title(f"l_max / l_min at step {step} ({label})")
        fig.colorbar(shade, ax=ax)
    change = np.linalg.norm(rows[-1] - rows[main["ten"]], axis=1)
    shade = axes[1, 0].tripcolor(tri, change / np.linalg.norm(rows[-1], axis=1).mean(),
                                 shading="gouraud", cmap="magma")
    axes[1, 0].set_title(f"|q(end) − q(step {main['ten']})| / mean |q|: what the tail moves")
    fig.colorbar(shade, ax=axes[1, 0])
    for ax in axes[0, 0], axes[0, 1], axes[1, 0]:
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
    for r in sorted(runs, key=lambda r: r["A"]):
        H = np.array(r["trace"]["H"])
        axes[1, 1].semilogy(H[:-1] / H[-1] - 1, label=f"A = {r['A']:g}: H {H[-1]:.2e}, "
                                                       f"{len(H) - 1} steps")
    axes[1, 1].axhline(0.1, color="grey", lw=0.8, ls="--")
    axes[1, 1].axhline(0.01, color="grey", lw=0.8, ls=":")
    axes[1, 1].set_xlabel("Newton step on the finest level")
    axes[1, 1].set_ylabel("H / H_final − 1")
    axes[1, 1].set_title(f"the finest level's H, {largest} triangles")
    axes[1, 1].legend()
    fig.suptitle(f"Non-isotropic piano, A = {main['A']:g}: frames near the aspect bound on "
                 "half the domain, and the tail moving the wall between two such regions")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    args, petsc_args = parse_args(argv)
    import sys

    sys.argv = [sys.argv[0], *petsc_args]
    if MPI.COMM_WORLD.size > 1:
        raise SystemExit("aspect_drift.py runs in one process")
    records = []
    for h in args.sizes:
        for max_aspect in args.aspects:
            records.append(run(h, max_aspect, args.max_it, args.probe, args.quads))
            print(report(records[-1]), flush=True)
            for line in records[-1]["probes"]:
                print(line, flush=True)
    print("\n| triangles | A | Newton steps per level | finest H: start → end "
          "| steps to 10 % / 1 % of the final H | E: start / 10 % step / end "
          "| on the bound: start / 10 % step / end | within 10 % of it | finest s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for record in records:
        print(report(record))
    if args.figure:
        figure(records, args.figure)
        print(f"wrote {args.figure}")


if __name__ == "__main__":
    from ufl_frames.bootstrap import init_petsc

    init_petsc()
    import dolfinx.fem.petsc
    from mpi4py import MPI

    from ufl_frames.fem.manifold import FrameManifold
    from ufl_frames.frames2d import odeco
    from ufl_frames.mesh import build
    from ufl_frames.mesh.hierarchy import nested_domains
    from ufl_frames.pipeline import FrameField
    from ufl_frames.pipeline.stages import quadrangulate

    main()
