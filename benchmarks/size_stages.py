"""Where the quads' sizes leave a file's sizes: the spread of size/h at each stage.

For each file, ``solve FILE --quads --quad-count N [--size-weight W]`` in this process
(:func:`ufl_frames.app.run.run`), then at the quads' centroids
(:func:`ufl_frames.pipeline.sizes.stage_size_record`): the field's frame size, the
seamless map's cell size and the quads' edge length, each against the file's h
(correlation of the logs, median and 90th percentile of |log ratio| up to the global
factor), and the widening each stage adds (map over field, quads over map). Prints a table,
asserts nothing.

    .venv/bin/python benchmarks/size_stages.py FILE [FILE ...] [--quads 400] [--size-weight W]
"""

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "src"))


def stages_of(path: str, quads: int, weight: float | None) -> tuple[dict, dict]:
    """(the stage record, the run's summary) of one file."""
    import dolfinx_solver  # noqa: F401  (before dolfinx)

    from ufl_frames.app import run as app_run
    from ufl_frames.mesh.sizes import SizeTarget, read_file_sizes
    from ufl_frames.param import seamless
    from ufl_frames.pipeline import stages
    from ufl_frames.pipeline.sizes import stage_size_record

    made = {}
    quadrangulate = stages.quadrangulate

    def kept(source, **options):  # the run's own stage, its root field kept
        root = stages._root(source)
        made["root"], made["quads"] = root, quadrangulate(root, **options)
        return made["quads"]

    stages.quadrangulate = kept
    try:
        with tempfile.TemporaryDirectory() as tmp:
            summary = app_run.run(app_run.RunConfig(
                geometry=path, quads=True, quad_count=quads, out=Path(tmp) / "out",
                quiet=True, size_weight=weight))
    finally:
        stages.quadrangulate = quadrangulate
    mesh, _ = made["root"]._cut_mesh(quad_count=quads)
    quality = made["quads"].quality
    seamless_map = seamless.integrate(mesh, seamless.scale_for_quad_size(mesh,
                                                                         quality["quad_size"]))
    target = SizeTarget.of_samples(read_file_sizes(path))
    return stage_size_record(mesh, seamless_map, made["quads"].mesh, target), summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="+")
    parser.add_argument("--quads", type=int, default=400)
    parser.add_argument("--size-weight", type=float, default=None)
    args = parser.parse_args()
    print(f"{'file':22s} {'w':>5s} {'quads':>5s} {'TAO':>22s} {'H':>8s} {'M':>6s} "
          f"{'field':>12s} {'map':>12s} {'quads':>12s} {'map/field':>9s} {'quad/map':>8s} "
          f"{'cpu s':>6s}")
    for name in args.files:
        start = time.process_time()
        found, summary = stages_of(name, args.quads, args.size_weight)
        sizes = summary["sizes"]

        def pair(stage):
            return f"{stage['log_correlation'] or float('nan'):.3f}/{stage['p90_abs_log']:.3f}"

        print(f"{Path(name).name:22s} {sizes['weight']:5.3g} {found['count']:5d} "
              f"{summary['converged_reason'][:16]:>16s}({summary['iterations']:4d}) "
              f"{summary['H_final']:8.2e} {sizes['field']['misfit']:6.3f} "
              f"{pair(found['field']):>12s} {pair(found['map']):>12s} "
              f"{pair(found['quads']):>12s} {found['map_over_field']['p90_abs_log']:9.3f} "
              f"{found['quads_over_map']['p90_abs_log']:8.3f} "
              f"{time.process_time() - start:6.1f}", flush=True)


if __name__ == "__main__":
    main()
