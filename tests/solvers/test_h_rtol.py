r"""The stopping test on H of the Newton types (``-frames_h_rtol``, :data:`tao.H_RTOL`).

Truth: for a linearly converging sequence H_k = H* + c ρ^k the decrease still to come is
known in closed form, c ρ^k; the bound of :func:`tao.remaining_decrease` must equal it
where Aitken's extrapolation is taken (ρ^w ≥ 1/2) and never be below it. On a real solve
the reference is the same solve run to the gradient test (``-frames_h_rtol 0``): Gauss–
Newton alone has a linear tail there (a minimum with a nonzero residual), which the test
must cut short without moving H by more than the tolerance.
"""

import math

import numpy as np
import pytest
from mpi4py import MPI
from petsc4py import PETSc

from ufl_frames.mesh import build
from ufl_frames.pipeline import FrameField
from ufl_frames.solvers import tao


@pytest.mark.parametrize("window", [1, 2, 3])
@pytest.mark.parametrize("rate", [0.3, 0.7, 0.9, 0.97])
def test_remaining_decrease_of_a_linearly_converging_sequence(rate, window):
    H_star, c = 2.5e-4, 3e-5
    energies = [H_star + c * rate**k for k in range(12)]
    for k in range(2 * window, len(energies)):
        left = c * rate**k  # exactly what is still to come after step k
        bound = tao.remaining_decrease(energies[: k + 1], window)
        assert bound >= left * (1 - 1e-9)
        if rate**window >= 0.5:  # Aitken's estimate is the bound, and exact here
            assert bound == pytest.approx(left, rel=1e-8)
        else:  # the last window's decrease, c ρ^(k−w) (1 − ρ^w), is the bound
            assert bound == pytest.approx(c * rate ** (k - window) * (1 - rate**window),
                                          rel=1e-8)


def test_remaining_decrease_has_no_estimate_without_contraction():
    inf = float("inf")
    assert tao.remaining_decrease([3.0, 2.0, 1.0], window=2) == inf  # too few values
    assert tao.remaining_decrease([5.0, 4.0, 3.0, 2.0, 1.0], window=2) == inf  # a stall: r = 1
    assert tao.remaining_decrease([5.0, 4.9, 4.8, 4.0, 3.0], window=2) == inf  # faster: r > 1
    assert tao.remaining_decrease([5.0, 4.0, 3.0, 3.0, 3.5], window=2) == inf  # H rose
    assert tao.remaining_decrease([3.0, 3.0, 3.0, 3.0, 3.0], window=2) == 0.0  # nothing moves
    assert tao.remaining_decrease([4.0, 3.0, 2.0, 2.0, 2.0], window=2) == 0.0  # r = 0


def _history(energies, ksp=2):
    return [{"H": H, "ksp_its": 0 if k == 0 else ksp} for k, H in enumerate(energies)]


def test_test_on_H_needs_newton_steps_and_a_positive_tolerance():
    # r = 1/8 over windows of 3: the bound is the last window's decrease, 1.4e-5 at k = 9
    energies = [1.0 + 1e-3 * 0.5**k for k in range(10)]
    assert tao._h_converged(_history(energies), rtol=2e-5)
    assert not tao._h_converged(_history(energies), rtol=1e-5)
    assert not tao._h_converged(_history(energies), rtol=0.0)  # -frames_h_rtol 0: off
    history = _history(energies)
    history[-4]["ksp_its"] = 0  # a gradient step of nls (indefinite model) in the window
    assert not tao._h_converged(history, rtol=2e-5)
    history = _history(energies)
    history[-7]["ksp_its"] = 0  # ... before the window: does not count
    assert tao._h_converged(history, rtol=2e-5)


@pytest.mark.parametrize("theta", [1e-3, 1e-2])
def test_nested_test_compares_what_is_left_with_the_coarser_levels_gain(theta):
    """The finest level's test (``-frames_nested_rtol θ``): on H_k = H* + c ρ^k (ρ³ ≥ 1/2,
    so the bound is exactly what is left, c ρ^k) it stops at the first k with
    c ρ^k ≤ θ (H_c − H_k), H_c the coarser level's H, whatever ``rtol`` adds."""
    H_star, c, rate, gain = 1e-4, 2e-5, 0.85, 1.6e-4
    energies = [H_star + c * rate**k for k in range(60)]
    coarse = H_star + gain
    expected = next(k for k in range(6, 60)
                    if c * rate**k <= theta * (coarse - energies[k]))
    stops = [k for k in range(6, 60)
             if tao._h_converged(_history(energies[: k + 1]), rtol=0.0,
                                 coarse_energy=coarse, nested_rtol=theta)]
    assert stops[0] == expected
    margin = [abs(c * rate**k / (theta * (coarse - energies[k])) - 1) for k in (expected - 1,
                                                                              expected)]
    assert min(margin) > 1e-3  # no tie at the boundary: the comparison is decided
    # without the coarser level, or with θ = 0, only rtol counts (0 here: never)
    assert not any(tao._h_converged(_history(energies[: k + 1]), rtol=0.0)
                   for k in range(6, 60))
    assert not any(tao._h_converged(_history(energies[: k + 1]), rtol=0.0,
                                    coarse_energy=coarse, nested_rtol=0.0)
                   for k in range(6, 60))
    # a level still above the coarser level's H has gained nothing yet: no stop
    assert not tao._h_converged(_history(energies[:30]), rtol=0.0,
                                coarse_energy=energies[29] - 1e-12, nested_rtol=theta)


@pytest.fixture(scope="module")
def gauss_newton_piano():
    """The non-isotropic piano at h = 0.1 solved by Gauss–Newton alone (its linear tail),
    with the test on H (the default tolerance) and without it."""
    results = {}
    for name, rtol in (("h_rtol", tao.H_RTOL), ("gradient", 0.0)):
        prefix = f"hrtol_{name}_"
        opts = PETSc.Options()
        opts[f"{prefix}frames_hessian"] = "gauss_newton"
        opts[f"{prefix}frames_h_rtol"] = rtol
        domain = build(MPI.COMM_WORLD, "piano", mesh_size=0.1)
        field = FrameField.initial(domain, isotropic=False, max_aspect=4.0)
        result = field.solve(max_it=300, options_prefix=prefix)
        results[name] = (result, sorted(s["index"] for s in field.singularities))
        for key in ("frames_hessian", "frames_h_rtol"):
            opts.delValue(f"{prefix}{key}")
    return results


def test_test_on_H_cuts_the_gauss_newton_tail(gauss_newton_piano):
    (stopped, stopped_singular), (full, full_singular) = (gauss_newton_piano["h_rtol"],
                                                          gauss_newton_piano["gradient"])
    assert full.converged_reason in ("CONVERGED_GATOL", "CONVERGED_GTTOL")
    assert stopped.converged_reason == tao.H_RTOL_REASON
    excess = (stopped.H_final - full.H_final) / full.H_final
    if MPI.COMM_WORLD.rank == 0:
        print(f"\nGauss-Newton piano h = 0.1: {full.iterations} steps to the gradient test, "
              f"{stopped.iterations} with -frames_h_rtol {tao.H_RTOL:g}; H {full.H_final:.8e} "
              f"/ {stopped.H_final:.8e} (excess {excess:.1e})")
    # measured: 99 → 23 steps, excess 5.2e-6
    assert stopped.iterations <= full.iterations / 2
    assert 0.0 <= excess <= tao.H_RTOL
    assert stopped_singular == full_singular
    # the history up to the stop is the full solve's: the test only ends it
    same = np.array([e["H"] for e in full.history[: len(stopped.history)]])
    assert np.allclose([e["H"] for e in stopped.history], same, rtol=1e-10)
    assert math.isfinite(stopped.H_final)
