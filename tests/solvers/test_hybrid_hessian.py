"""The hybrid Newton model of non-isotropic frames (``-frames_hessian hybrid``, the
default): Gauss–Newton until |g| ≤ τ |g₀|, then the exact Riemannian Hessian
(``GaussNewtonModel._switch``).

Serial and under MPI (``mpirun -n 2 python -m pytest -m "not serial"``).
"""

import pytest
from mpi4py import MPI

from ufl_frames.bootstrap import options_scope
from ufl_frames.mesh import build
from ufl_frames.pipeline import FrameField
from ufl_frames.solvers.hessian import HYBRID_SWITCH, GaussNewtonModel

COMM = MPI.COMM_WORLD
#: The non-isotropic piano at this size ends in a linear Gauss–Newton tail (97 steps,
#: |g| down by ~5 % per step at the end, measured), which the hybrid model ends.
MESH_SIZE = 0.1


def piano_solve(options=None, checkpoint=None, resume=None, field=None):
    """The non-isotropic piano from MBO with ``options`` on top of the defaults."""
    if field is None:
        field = FrameField.initial(build(COMM, "piano", mesh_size=MESH_SIZE))
    with options_scope(list((options or {}).items())):
        return field.solve(max_it=500, checkpoint=checkpoint, resume=resume)


def test_hybrid_ends_the_linear_tail_of_gauss_newton():
    """Same minimum as Gauss–Newton, in fewer than half its steps; Gauss–Newton's last
    steps shrink |g| by less than 2x each (linear), the hybrid's last one by 10x or more."""
    # both to the gradient test: the stopping test on H (-frames_h_rtol) would end
    # Gauss–Newton's tail after 23 of its 99 steps (tests/test_h_rtol.py)
    hybrid = piano_solve({"frames_h_rtol": 0.0})
    gauss_newton = piano_solve({"frames_hessian": "gauss_newton", "frames_h_rtol": 0.0})
    for result in (hybrid, gauss_newton):
        assert result.converged_reason.startswith("CONVERGED"), result.converged_reason
    assert hybrid.H_final == pytest.approx(gauss_newton.H_final, rel=1e-6)
    assert hybrid.iterations < 0.5 * gauss_newton.iterations
    tail = [e["gnorm"] for e in gauss_newton.history[-6:]]
    steps = zip(tail[:-1], tail[1:], strict=True)
    assert all(later > 0.5 * earlier for earlier, later in steps), tail
    last = [e["gnorm"] for e in hybrid.history[-2:]]
    assert last[1] <= 0.1 * last[0], last


def test_the_model_switches_once_at_the_threshold(monkeypatch):
    """The exact Hessian from the first Newton step with |g| ≤ τ |g₀| on, never before;
    with τ = 0 never (the iterates of ``-frames_hessian gauss_newton``)."""
    seen = []
    update = GaussNewtonModel.update

    def recording(self, tao, x, H, P):
        update(self, tao, x, H, P)
        seen.append((tao.getGradient()[0].norm(), self.gnorm0, self.exact))

    monkeypatch.setattr(GaussNewtonModel, "update", recording)
    piano_solve()
    modes = [exact for _, _, exact in seen]
    first = modes.index(True)  # it switched
    assert all(modes[first:]) and not any(modes[:first])
    gnorm, gnorm0, _ = seen[first]
    assert gnorm <= HYBRID_SWITCH * gnorm0
    assert all(g > HYBRID_SWITCH * g0 for g, g0, _ in seen[1:first])

    seen.clear()
    never = piano_solve({"frames_hessian_switch": 0.0})
    assert not any(exact for _, _, exact in seen)
    monkeypatch.undo()
    gauss_newton = piano_solve({"frames_hessian": "gauss_newton"})
    assert never.iterations == gauss_newton.iterations
    assert never.H_final == pytest.approx(gauss_newton.H_final, rel=1e-12)


def test_resume_after_the_switch_gives_the_uninterrupted_result(monkeypatch):
    """A solve resumed from a state saved after the switch starts with the exact Hessian
    (before any gradient test could switch it) and ends as the solve that saved it."""
    states = []
    reference = piano_solve(checkpoint=states.append)
    after = [s for s in states if s.exact_hessian]
    assert after and not states[0].exact_hessian
    state = after[0]
    assert state.iterations < reference.iterations
    at_entry = []
    update = GaussNewtonModel.update

    def recording(self, tao, x, H, P):
        at_entry.append(self.exact)
        update(self, tao, x, H, P)

    monkeypatch.setattr(GaussNewtonModel, "update", recording)
    resumed = piano_solve(resume=state)
    assert at_entry and all(at_entry)
    assert resumed.iterations == reference.iterations
    assert resumed.converged_reason == reference.converged_reason
    assert resumed.H_final == pytest.approx(reference.H_final, rel=1e-10)
