"""``ufl-frames solve`` on a 3D CAD part (issue 41): its tetrahedra, boundary vertices,
times and singular graph at several mesh sizes, and the comparison of two runs.

    python benchmarks/cad3d.py [FILE] [--sizes 12 6 4] [--keep DIR]
    mpirun -n 2 python benchmarks/cad3d.py [FILE] [--sizes ...] [--keep DIR]
    python benchmarks/cad3d.py --compare DIR_A DIR_B

FILE defaults to the Gmsh benchmark part ``benchmarks/shapes3d/gmsh_part.step`` (see
``benchmarks/shapes3d/SOURCES.md``). Each size runs the command in this process (mesh,
MBO, singular graph, files); a row gives the tetrahedra and vertices, the boundary
vertices aligned with one CAD normal and those held on sharp edges, the seconds of MBO,
of the graph and in all (wall), the CPU seconds and peak resident memory of rank 0, and
the singular graph: edges, chains, quarter and half turns, nodes (degree ≥ 3), open ends
inside the volume. ``--keep DIR`` keeps each size's output folder as ``DIR/h<size>``;
``--compare`` reads two such folders (say, one rank and two) and prints whether the
singular edges are the same and how far the frames differ up to the cube's symmetry.
"""

import argparse
import json
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from _common import ROOT

DEFAULT_PART = ROOT / "benchmarks" / "shapes3d" / "gmsh_part.step"


def run_sizes(path: Path, sizes, keep: Path | None) -> None:
    from ufl_frames.bootstrap import init_petsc

    init_petsc([])
    from mpi4py import MPI

    from ufl_frames.app import cli

    comm = MPI.COMM_WORLD
    scratch = tempfile.mkdtemp() if comm.rank == 0 and keep is None else None
    base = Path(comm.bcast(str(keep) if keep is not None else scratch, root=0))
    if comm.rank == 0:
        print(f"{path.name} on {comm.size} rank(s)")
        print("| h | tets | vertices | aligned | sharp | MBO s | graph s | total s | CPU s "
              "(rank 0) | singular edges | chains | quarter / half turns | nodes | open ends "
              "| peak MB (rank 0) |")
        print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for h in sizes:
        out = base / f"h{h:g}"
        cpu = resource.getrusage(resource.RUSAGE_SELF).ru_utime
        start = time.perf_counter()
        code = cli.main(["solve", str(path), "--mesh-size", f"{h:g}", "--out", str(out), "-q",
                         "--force"])
        wall = time.perf_counter() - start
        cpu = resource.getrusage(resource.RUSAGE_SELF).ru_utime - cpu
        if code != 0:
            if comm.rank == 0:
                print(f"| {h:g} | failed (exit {code}) |")
            continue
        if comm.rank == 0:
            s = json.loads((out / "summary.json").read_text())
            g, b = s["singular_graph"], s["boundary_vertices"]
            peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
            print(f"| {h:g} | {s['tetrahedra']} | {s['vertices']} | {b['aligned']} | "
                  f"{b['sharp']} | {s['mbo']['seconds']:.1f} | {g['seconds']:.1f} | {wall:.1f} | "
                  f"{cpu:.1f} | {g['edges']} | {g['chains']} | {g['quarter_turns']} / "
                  f"{g['half_turns']} | {g['nodes']} | {g['open_ends']} | {peak:.0f} |",
                  flush=True)


def compare(a: Path, b: Path) -> bool:
    """Print how the two output folders' fields and singular edges differ; whether the
    singular edges are the same."""
    from ufl_frames.frames3d.singular import OCTAHEDRAL, closest_symmetry
    from ufl_frames.output.vtk import read_vtk

    fa, fb = read_vtk(a / "frames3d.vtu"), read_vtk(b / "frames3d.vtu")
    if fa["points"].shape != fb["points"].shape or not np.array_equal(fa["points"],
                                                                      fb["points"]):
        print("the two meshes differ")
        return False
    Ra, Rb = (np.stack([f["point_data"][f"u{i}"] for i in (1, 2, 3)], axis=2)
              for f in (fa, fb))
    M = np.einsum("nji,njk->nik", Ra, Rb)
    gap = np.abs(M - OCTAHEDRAL[closest_symmetry(M)]).max()
    ea, eb = ({tuple(sorted(e)) for e in read_vtk(d / "singular.vtu")["cells"].tolist()}
              for d in (a, b))
    print(f"vertices {fa['points'].shape[0]}; frames equal up to the cube's symmetry within "
          f"{gap:.1e}; singular edges {len(ea)} and {len(eb)}, "
          f"{'the same' if ea == eb else f'{len(ea ^ eb)} not in both'}")
    return ea == eb


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("file", nargs="?", type=Path, default=DEFAULT_PART)
    parser.add_argument("--sizes", type=float, nargs="+", default=[12.0, 6.0, 4.0])
    parser.add_argument("--keep", type=Path, default=None,
                        help="keep each size's output folder as KEEP/h<size>")
    parser.add_argument("--compare", type=Path, nargs=2, metavar=("DIR_A", "DIR_B"))
    args = parser.parse_args()
    if args.compare:
        sys.exit(0 if compare(*args.compare) else 1)
    run_sizes(args.file, args.sizes, args.keep)


if __name__ == "__main__":
    main()
