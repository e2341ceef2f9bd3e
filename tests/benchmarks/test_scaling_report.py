"""The report of ``benchmarks/scaling.py`` (pure Python: records in, growth lines and a
figure out): the growth per 2x refinement it prints decides the issue's "holds" / "fails".

Truth: records made up so that every factor is known in closed form.
"""

import importlib.util
from pathlib import Path

import pytest

pytestmark = pytest.mark.serial  # one process: nothing here is parallel

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "scaling.py"


@pytest.fixture(scope="module")
def scaling():
    spec = importlib.util.spec_from_file_location("scaling_benchmark", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def record(triangles, iterations, ksp, solve, ranks=1, case="piano-noniso"):
    return {"case": case, "status": "ok", "triangles": triangles, "ranks": ranks,
            "iterations": iterations, "ksp_mean": ksp, "stages": {"solve": solve},
            "h": 0.05, "total": solve + 1.0, "peak_rss_mb": 100.0, "H_final": 1e-3,
            "converged_reason": "CONVERGED_HRTOL", "singularities": [-0.25, 0.25]}


def test_growth_is_per_2x_refinement_between_sizes_2x_apart(scaling):
    """×4 triangles is one halving of h: the factors are the ratios themselves; ×16 two,
    their square roots. A size within 2x of the last one taken (1 300 after 1 000) and a
    second record of a size (2 ranks at 4 000) are passed over, not extrapolated from."""
    records = [record(1000, 10, 2.0, 1.0), record(1300, 30, 9.0, 9.0),
               record(4000, 13, 2.0, 5.2), record(4000, 99, 9.0, 1.0, ranks=2),
               record(64000, 52, 3.0, 166.4, ranks=2)]
    factors = scaling.growth_factors(records, "piano-noniso")
    assert [(a["triangles"], b["triangles"]) for a, b, *_ in factors] == [(1000, 4000),
                                                                          (4000, 64000)]
    (_, _, newton1, ksp1, cost1), (_, _, newton2, ksp2, cost2) = factors
    assert (newton1, ksp1, cost1) == pytest.approx((1.3, 1.0, 1.3))
    assert (newton2, ksp2, cost2) == pytest.approx((2.0, 1.5 ** 0.5, 2.0 ** 0.5))
    lines = scaling.growth(records)
    assert "(ranks 1 -> 2)" in lines[1] and "ranks" not in lines[0]
    verdict = [line for line in scaling.targets(records) if "grow <=" in line]
    assert verdict and "worst x2.00, fails" in verdict[0]


def test_figure_is_written(scaling, tmp_path):
    pytest.importorskip("matplotlib")
    records = [record(1000, 10, 2.0, 1.0), record(4000, 13, 2.0, 5.2),
               record(1000, 5, 2.0, 0.5, case="annulus-iso")]
    path = tmp_path / "scaling.png"
    scaling.figure(records, path)
    assert path.stat().st_size > 10_000
