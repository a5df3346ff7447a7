"""A fixed-step solver's own step, apart from the output interval (``[solver] step_s``):
shorter, several steps an output; longer, the outputs inside a step from its interpolant."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mps_core import build, load_scene
from mps_core.errors import SceneError
from mps_core.scene import scene_from_text

PAPER = load_scene("paper").with_overrides(t_end=0.1, scheme="autodiff")


def _ref_at(ref, traj, name):
    idx = np.searchsorted(ref.t, traj.t - 1e-12)
    assert np.allclose(ref.t[idx], traj.t, atol=1e-12)
    return getattr(ref, name)[idx]


def test_outputs_inside_long_steps_from_the_steps_interpolant(paper_reference):
    """RK8 at 5 ms steps with outputs every millisecond: the outputs at the steps' ends are
    those of a run whose outputs are its steps (9.2e-7 rad off the exact motion); the ones
    inside come from DOP853's seventh-order interpolant (three more evaluations a step) and
    one evaluation each. Through the run's fastest stretch, before its last change of chart,
    the interpolant is 1.7e-5 rad off, cubic Hermite of the step's ends would be 9e-5."""
    fine = build(PAPER.with_overrides(solver="rk8", dt=1e-3, step=5e-3)).run(0.1, 1e-3)
    assert len(fine.t) == 101 and np.allclose(np.diff(fine.t), 1e-3)
    err = np.abs(fine.phi - _ref_at(paper_reference, fine, "phi"))
    assert err[::5].max() < 1e-6
    assert err[fine.t < 0.08].max() < 1e-6 and err.max() < 3e-5
    assert fine.counts["steps"] == 20
    # 12 a step, 3 more a step for its interpolant, 1 an output inside, 1 a change of chart
    charts = sum(e["kind"] == "chart" for e in fine.events)
    assert fine.counts["evaluations"] == 1 + 12 * 20 + 3 * 20 + 80 + charts
    coarse = build(PAPER.with_overrides(solver="rk8", dt=5e-3)).run(0.1, 5e-3)
    assert np.allclose(fine.t[::5], coarse.t, atol=1e-12)
    assert np.allclose(fine.phi[::5], coarse.phi, rtol=0, atol=1e-11)
    assert np.allclose(fine.T[::5], coarse.T, rtol=1e-11)
    assert [e["to"] for e in fine.events if e["kind"] == "chart"] == [
        e["to"] for e in coarse.events if e["kind"] == "chart"
    ]


def test_short_steps_record_every_nth():
    """RK4 at 0.25 ms steps with outputs every millisecond: the run of 0.25 ms outputs, every
    fourth."""
    short = build(PAPER.with_overrides(solver="rk4", dt=1e-3, step=2.5e-4)).run(0.1, 1e-3)
    every = build(PAPER.with_overrides(solver="rk4", dt=2.5e-4)).run(0.1, 2.5e-4)
    assert len(short.t) == 101 and short.counts["steps"] == 400
    assert np.allclose(short.t, every.t[::4], atol=1e-12)
    assert np.allclose(short.phi, every.phi[::4], rtol=0, atol=1e-10)


def test_outputs_inside_steps_through_events_carry_their_steps_structure():
    """The press cycle with 2 ms steps and 1 ms outputs: events still end steps at their roots,
    every change of structure between two outputs has its event between them, the work is
    continuous and the reactions come with every output."""
    scene = load_scene("press-cycle").with_overrides(
        scheme="autodiff", solver="rk4", dt=1e-3, step=2e-3, t_end=0.6
    )
    sim = build(scene)
    from mps_core.dynamics.reaction_observer import ReactionObserver

    sim.observers.append(ReactionObserver())
    traj = sim.run(0.6, 1e-3)
    assert len(traj.t) == 601 and np.allclose(np.diff(traj.t), 1e-3)
    impacts = [
        e["t"]
        for e in traj.events
        if e["kind"] in ("latch-closes", "latch-opens", "stop-contact", "stop-release")
    ]
    assert len(impacts) >= 3
    changed = np.nonzero(traj.structure[1:] != traj.structure[:-1])[0]
    assert len(changed) >= 3
    for k in changed:
        assert any(traj.t[k] - 1e-12 <= t <= traj.t[k + 1] + 1e-12 for t in impacts), traj.t[k]
    # at the steps' ends: the run whose outputs are its steps (the same steps, the same cuts)
    plain = build(scene.with_overrides(dt=2e-3, step=None)).run(0.6, 2e-3)
    assert np.allclose(traj.t[::2], plain.t, atol=1e-12)
    for name in ("phi", "psi_dot", "W", "E_impact", "T"):
        assert np.allclose(traj[name][::2], plain[name], rtol=1e-9, atol=1e-9), name
    assert list(traj.structure[::2]) == list(plain.structure)
    assert len(traj["F_found_x"]) == len(traj.t) and np.all(np.isfinite(traj["F_found_x"]))


def test_a_step_for_an_adaptive_solver_is_refused_by_name():
    with pytest.raises(SceneError, match="solver.step_s"):
        PAPER.with_overrides(solver="dop853", step=1e-3)
    text = load_scene("paper").text.replace("[solver]", "[solver]\nstep_s = 0.002")
    assert build(scene_from_text(text)).settings.step == 0.002
    with pytest.raises(SceneError, match="solver.step_s"):
        scene_from_text(text.replace('method = "linear-acceleration"', 'method = "dop853"'))
    with pytest.raises(SceneError, match="solver.step_s"):
        scene_from_text(text.replace("step_s = 0.002", "step_s = -1.0"))
    assert math.isfinite(build(scene_from_text(text)).run(0.01, 1e-3).phi[-1])
