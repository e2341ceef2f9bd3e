"""Does the optimised field integrate? The misfit of its map against the MBO field's.

    python benchmarks/param_misfit.py [--sizes 0.05 0.025 0.0125] [--cases piano-noniso ...]
                                      [--gd-iterations 2000] [--no-gd]

For each case (``piano`` or ``annulus``, isotropic or not) and mesh size: the MBO field, the
field of the default solver (TAO ``nls``), unless ``--no-gd`` the note's projected
gradient descent (``bncg``, ``--gd-iterations``), and for isotropic cases the conformal
field of the MBO directions (:meth:`~ufl_frames.pipeline.field.FrameField.conformal`), each
parametrised by
:func:`ufl_frames.pipeline.stages.parametrise` (default quad size). Printed per row:
triangles, H, the relative L² misfit of the seamless map, flipped triangles, cuts; then
the misfit's rate per halving of h for each field. An integrable field's misfit is the P1
error, O(h); a field that does not integrate keeps a misfit that does not fall.
"""

import argparse
import math
import sys

from ufl_frames.bootstrap import init_petsc

init_petsc(sys.argv[:1])

from mpi4py import MPI  # noqa: E402

from ufl_frames.mesh import build  # noqa: E402
from ufl_frames.pipeline import FrameField  # noqa: E402
from ufl_frames.pipeline.stages import parametrise  # noqa: E402

CASES = ("piano-noniso", "piano-iso", "annulus-noniso", "annulus-iso")


def measure(case: str, h: float, gd_iterations: int | None) -> list[dict]:
    shape, kind = case.split("-")
    comm = MPI.COMM_WORLD
    rows = []
    variants = [("MBO", None, None), ("nls", "nls", 500)]
    if kind == "iso":
        variants.append(("conformal", "conformal", None))
    if gd_iterations:
        variants.append(("bncg", "bncg", gd_iterations))
    for name, tao_type, max_it in variants:
        field = FrameField.initial(build(comm, shape, h), isotropic=kind == "iso")
        H, reason = float("nan"), "-"
        if tao_type == "conformal":  # one Poisson solve for the lengths, no TAO
            field = field.conformal()
            from ufl_frames.fem import energy

            H, reason = energy.integrability_energy(field.q), "(conformal scale)"
        elif tao_type is not None:
            from petsc4py import PETSc

            PETSc.Options().setValue("pm_tao_type", tao_type)
            try:
                result = field.solve(max_it=max_it, options_prefix="pm_")
            finally:
                PETSc.Options().delValue("pm_tao_type")
            H, reason = result.H_final, result.converged_reason
        quality = parametrise(field).quality
        rows.append({"case": case, "h": h, "field": name, "triangles": field.domain.num_cells,
                     "H": H, "reason": reason, **quality})
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", nargs="+", type=float, default=[0.05, 0.025, 0.0125])
    parser.add_argument("--cases", nargs="+", choices=CASES, default=["piano-noniso"])
    parser.add_argument("--gd-iterations", type=int, default=2000)
    parser.add_argument("--no-gd", action="store_true")
    args = parser.parse_args(argv)
    rows = []
    for case in args.cases:
        for h in sorted(args.sizes, reverse=True):
            rows += measure(case, h, None if args.no_gd else args.gd_iterations)
    if MPI.COMM_WORLD.rank:
        return 0
    print("| case | h | triangles | field | H | TAO reason | misfit | flipped | cuts |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['case']} | {r['h']:g} | {r['triangles']} | {r['field']} | {r['H']:.4e} "
              f"| {r['reason']} | {r['misfit']:.4f} | {r['flipped_triangles']} | {r['cuts']} |")
    print()
    for case in args.cases:
        for name in ("MBO", "nls", "bncg", "conformal"):
            seq = [r for r in rows if r["case"] == case and r["field"] == name]
            rates = [math.log2(a["misfit"] / b["misfit"]) * math.log(2) / math.log(a["h"] / b["h"])
                     for a, b in zip(seq[:-1], seq[1:], strict=True)]
            if rates:
                print(f"- {case}, {name}: misfit rate per halving of h: "
                      + ", ".join(f"{x:.2f}" for x in rates))
    return 0


if __name__ == "__main__":
    sys.exit(main())
