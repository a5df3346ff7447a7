"""The tracker against a truth that is not its model: errors, consistency, the force's variance
near the bottom dead centre, the per-stroke table, and the modes followed from the signals."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mps_core import load_scene
from mps_core.track import Sensors, Tracker, TrackingMonitor, run_truth, truth_scene
from mps_core.track.evaluation import follow, nis_inside, truth_strokes
from mps_core.track.truth import with_blanking


@pytest.fixture(scope="module")
def working():
    """The working press (locked crank-slider) followed for two strokes and a bit."""
    nominal = with_blanking(load_scene("working").with_overrides(scheme="autodiff"))
    truth = run_truth(truth_scene(nominal), 0.3, sensors=Sensors(), seed=3)
    tracker = Tracker(nominal)

    def clock() -> float:  # the comparison's record, not a time: the test never reads times
        return 0.0

    followed = follow(tracker, truth, loads=True, cpu_clock=clock)
    return nominal, truth, tracker, followed


def test_the_truth_is_not_the_model(working):
    nominal, truth, _tracker, _f = working
    t = truth.scene
    assert t.bodies["slider"].mass == pytest.approx(1.1 * nominal.bodies["slider"].mass)
    assert t.bodies["rod"].mass == pytest.approx(0.9 * nominal.bodies["rod"].mass)
    kinds = [e.kind for e in t.effects]
    assert "joint_friction" in kinds and "guide_friction" in kinds
    assert "joint_friction" not in [e.kind for e in nominal.effects]

    def part(scene):
        return next(e.params for e in scene.effects if e.kind == "blanking")

    assert part(t)["peak_force"] > 1.3 * part(nominal)["peak_force"]  # another sheet
    assert part(t)["x_contact"] != part(nominal)["x_contact"]


def test_the_encoder_is_read_in_counts_at_jittered_stamps(working):
    _n, truth, _t, _f = working
    enc = Sensors().encoder
    stamps = np.array([m.t for m in truth.measurements])
    assert np.all(np.diff(stamps) > 0.0)
    k = np.arange(1, len(stamps) + 1) * 1e-3
    assert np.max(np.abs(stamps - k)) <= 2e-4
    assert np.max(np.abs(stamps - k)) > 1e-4  # jittered, not on the grid
    counts = np.array([m.value for m in truth.measurements]) / enc.lsb - 0.5
    assert np.allclose(counts, np.round(counts), atol=1e-6)
    err = [(m.value - truth.at(m.t)["phi"] + math.pi) % (2 * math.pi) - math.pi for m in truth.measurements]
    assert np.max(np.abs(err)) < 3 * enc.lsb


def test_the_estimate_is_consistent(working):
    _n, _truth, tracker, f = working
    assert tracker.accepted == len(f.t) and not tracker.rejected
    assert f.nees_inside() >= 0.9
    assert nis_inside(tracker) >= 0.9
    # the 1-sigma bands cover the truth at least as often as they should (measured 0.85)
    assert 0.6 <= f.coverage() <= 0.97


def test_the_foundation_load_follows_the_truth(working):
    _n, _truth, _t, f = working
    assert f.foundation_rms_fraction() <= 0.05  # measured 0.037-0.039; the target: 0.03


def test_the_foundation_components_covariance_is_the_state_s_carried_through_the_loads():
    """The foundation force's x and y move together with the state (correlation near ±1
    here): their covariance is the state's covariance carried through the loads, as a
    difference along each column of its square root finds it, and the magnitude's 1-σ uses it."""
    from mps_core.track.tracker import foundation_magnitude
    from mps_core.track.truth import nominal_scene

    nominal = nominal_scene(load_scene("working").with_overrides(scheme="autodiff"))
    truth = run_truth(truth_scene(nominal), 0.06, seed=0)
    tracker = Tracker(nominal)
    for m in truth.measurements:
        tracker.update(m)
    n, i = tracker.n, 2 * tracker.n
    e = tracker.sim.solver.current
    where = [*range(2 * n), i, i + 1]
    loads = tracker.loads()
    root = np.linalg.cholesky(tracker.P[np.ix_(where, where)] + 1e-30 * np.eye(len(where)))
    base = np.array([loads["F_found_x"][0], loads["F_found_y"][0]])
    eps, cov = 1e-3, 0.0
    torque = tracker.inputs.values[1]
    for k in range(len(where)):
        d = eps * root[:, k]
        tracker.inputs.values[1] = torque + d[-1]
        moved = tracker._loads_at(e.t, e.q + d[:n], e.qd + d[n : 2 * n], tracker.x[i] + d[-2], where)
        tracker.inputs.values[1] = torque
        dx, dy = np.array([moved["F_found_x"][0], moved["F_found_y"][0]]) - base
        cov += dx * dy / eps**2
    got = loads.foundation_xy_covariance
    sx, sy = loads["F_found_x"][1], loads["F_found_y"][1]
    assert abs(got) > 0.5 * sx * sy  # strongly correlated here: the covariance matters
    assert got == pytest.approx(cov, rel=1e-3)
    fx, fy = base
    f, s = foundation_magnitude(loads)
    assert s == pytest.approx(math.sqrt(fx * fx * sx * sx + fy * fy * sy * sy + 2 * fx * fy * got) / f)


def test_each_stroke_within_its_uncertainty(working):
    _n, truth, tracker, _f = working
    true = truth_strokes(truth)
    done = [s for s in tracker.strokes.strokes if s.index in true and true[s.index]["complete"]]
    assert len(done) == 2
    for s in done:
        t = true[s.index]
        assert t["peak_force_N"] > 25e3  # the truth's part: 28.3 kN
        # the peak of a 2 ms pulse from 1 kHz samples: biased high (measured +5.6 %, +21 %, a
        # few of its sigmas; the target of 2 % is not met, docs/tracking.md)
        assert abs(s.peak_force / t["peak_force_N"] - 1.0) <= 0.3
        # the work: measured within 4 % and its 1-sigma of 1.4 J
        assert abs(s.work - t["work_J"]) <= 3.0 * s.work_sigma
        assert abs(s.work / t["work_J"] - 1.0) <= 0.08
        # the foundation's peak comes with the force's and overshoots with it (measured +10 to
        # +26 %, many of its sigmas: docs/tracking.md)
        assert abs(s.peak_foundation / t["peak_foundation_N"] - 1.0) <= 0.35


def test_the_force_variance_grows_where_the_crank_says_nothing_of_it():
    """Near the bottom dead centre dx_C/dphi -> 0: the force's 1-sigma grows there."""
    nominal = with_blanking(load_scene("working").with_overrides(scheme="autodiff"))
    truth = run_truth(truth_scene(nominal), 0.12, seed=5)
    tracker = Tracker(nominal)
    lag = tracker.settings.force_lag
    levers, seen = [], []
    for m in truth.measurements:
        tracker.update(m)
        levers.append(abs(tracker.sim.solver.current.kin.jac("C")[0][0]))
        est = tracker.estimate()
        if est.force_smoothed_sigma > 0.0 and len(levers) > lag:
            seen.append((levers[-lag - 1], est.force_smoothed_sigma))  # the lever of its step
    seen.sort()
    lever, sigma = np.array(seen).T
    assert lever[0] < 0.1 * lever[-1]  # the window reaches the bottom dead centre
    near, far = sigma[lever < 0.2 * lever[-1]], sigma[lever > 0.5 * lever[-1]]
    # measured: about 3 kN where the lever is long, 10-36 kN where it vanishes
    assert np.median(near) > 3.0 * np.median(far)


def test_the_modes_are_followed_from_the_signals():
    """press-cycle: engaged by its signal, the slider off its stop, the latch closing where
    the truth's does; the crank angle followed through all of it."""
    nominal = load_scene("press-cycle")
    truth = run_truth(truth_scene(nominal), 0.08, seed=7)
    tracker = Tracker(nominal)
    f = follow(tracker, truth, loads=False)
    kinds = [e["kind"] for e in tracker.sim.events if e["kind"] != "chart"]
    assert kinds[:3] == ["command", "stop-release", "latch-closes"]
    t_latch = next(e["t"] for e in tracker.sim.events if e["kind"] == "latch-closes")
    t_true = truth.t[np.argmax(truth.locked)]
    assert abs(t_latch - t_true) < 2e-3
    assert tracker.sim.structure == "locked"
    assert f.nees_inside() >= 0.9
    est = tracker.estimate()
    assert abs(est.phi - truth.at(est.t)["phi"]) < 5 * est.phi_sigma


def test_the_modes_are_followed_from_a_slider_scale_without_signals():
    """press-cycle without its mode signals, with a slider scale: engaged where the slider
    leaves its stop, the latch closing where the truth's does, disengaged where the slider
    leaves the crank-slider's path."""
    nominal = load_scene("press-cycle")
    truth = run_truth(truth_scene(nominal), 0.47, sensors=Sensors(slider=True), seed=7)
    truth.modes.clear()
    tracker = Tracker(nominal)
    f = follow(tracker, truth, loads=False)
    assert tracker.inferred == {"engage": 1, "disengage": 1}
    events = {e["kind"]: e["t"] for e in tracker.sim.events if e["kind"] in ("latch-closes", "latch-opens")}
    assert abs(events["latch-closes"] - truth.t[np.argmax(truth.locked)]) < 1e-3
    assert 0.4351 < events["latch-opens"] < 0.4351 + 0.015  # 3 slider samples missed, then
    assert f.nees_inside() >= 0.9


def test_after_the_disengage_the_idle_four_bar_is_followed_from_a_slider_scale_without_signals():
    """press-cycle's idle four-bar after its disengage, a slider scale and no signals: the
    model's slider, off the press's in the free swings, is acquired again where its positions
    are rejected running (as the crank is), and an engage is inferred where the slider is
    measured below where the idle model puts it, not below its stop: no engage is inferred
    in the swings. Before, 879 measurements were rejected as outliers here, two more engages
    and a disengage inferred, and the status stayed ERROR for 0.7 s."""
    nominal = load_scene("press-cycle")
    truth = run_truth(truth_scene(nominal), 1.2, sensors=Sensors(slider=True), seed=0)
    truth.modes.clear()
    tracker = Tracker(nominal)
    monitor = TrackingMonitor()
    for m in truth.measurements:
        tracker.update(m)
        monitor.observe(tracker, m)
    assert tracker.inferred == {"engage": 1, "disengage": 1}
    assert tracker.rejected["outlier"] < 30 and tracker.slider_acquired >= 1
    assert tracker.sim.structure != "locked"
    assert monitor.events[-1].level == "OK" and monitor.events[-1].t < 0.6


def test_a_correction_that_lets_the_stop_go_carries_the_state_into_the_free_structure():
    """press-cycle after its disengage, with a slider scale (seed 3): a correction moves the
    slider where the held top stop would pull it, the stop lets go as the run restarts there,
    and the estimate is carried into the free structure's two coordinates (before, it kept the
    held structure's one and the estimate failed on it)."""
    from mps_core.track import lags
    from mps_core.track.truth import nominal_scene

    nominal = nominal_scene(load_scene("press-cycle"))
    truth = run_truth(truth_scene(nominal), 0.62, sensors=Sensors(slider=True), seed=3)
    tracker = Tracker(nominal)
    modes = sorted(truth.modes, key=lambda s: s.t)
    structures = set()
    for m in truth.measurements:
        while modes and modes[0].t <= m.t:
            tracker.mode(modes.pop(0))
        tracker.update(m)
        n = tracker.n
        assert len(tracker.x) == lags.core_size(n) + tracker.settings.force_lag * (2 * n + 1), m
        assert tracker.P.shape == (len(tracker.x), len(tracker.x))
        tracker.estimate()
        structures.add(tracker.sim.structure)
    assert {"held", "free"} <= structures and tracker.sim.structure == "free"


def test_a_run_that_fails_is_started_again_at_the_crank_measured(monkeypatch):
    """The model's run cannot go on from its state (a singular position): the tracker starts a
    run again in the scene's initial structure at the crank measured, keeps the load torque,
    counts it and logs an event; the measurement is taken, nothing raises."""
    from mps_core.errors import SingularConfiguration

    nominal = load_scene("press-cycle")
    truth = run_truth(truth_scene(nominal), 0.05, seed=1)
    tracker = Tracker(nominal)
    ms = truth.measurements
    for m in ms[:20]:
        tracker.update(m)
    torque = tracker.estimate().torque
    failing = tracker.sim

    def fail(t1):
        raise SingularConfiguration("no chart of structure 'free' is regular here", t1, {})

    monkeypatch.setattr(failing, "advance_to", fail)
    assert tracker.update(ms[20])
    assert tracker.sim is not failing and tracker.restarted == 1
    est = tracker.estimate()
    assert abs(est.phi - ms[20].value) < 1e-3 and est.torque == pytest.approx(torque)
    event = next(e for e in tracker.take_events() if e["kind"] == "tracker-restart")
    assert event["t"] == ms[20].t and "no chart of structure 'free'" in event["why"]
    assert event["structure"] == nominal.structure == "held"
    for m in ms[21:]:
        tracker.update(m)
    assert np.isfinite(tracker.x).all() and tracker.restarted == 1


def test_the_model_s_derivatives_are_the_setting_s_and_the_schemes_agree():
    """The tracker's model runs on ``TrackSettings.derivatives`` whatever the scene's scheme;
    exact derivatives (the default) and the seed's central differences give the same estimates
    but for the differences' own error."""
    from dataclasses import replace

    from mps_core.track import TrackSettings

    nominal = with_blanking(load_scene("working"))
    assert nominal.solver.scheme == "central"
    truth = run_truth(truth_scene(nominal), 0.1, seed=4)
    trackers = {s: Tracker(nominal, replace(TrackSettings(), derivatives=s)) for s in ("autodiff", "central")}
    assert [t.sim.engine.scheme for t in trackers.values()] == ["autodiff", "central"]
    assert Tracker(nominal).sim.engine.scheme == "autodiff"
    worst = {"phi": 0.0, "force": 0.0}
    for m in truth.measurements:
        ests = {}
        for s, tracker in trackers.items():
            assert tracker.update(m)
            ests[s] = tracker.estimate()
        a, c = ests["autodiff"], ests["central"]
        worst["phi"] = max(worst["phi"], abs(a.phi - c.phi) / a.phi_sigma)
        force = abs(a.force_smoothed - c.force_smoothed) / max(a.force_smoothed_sigma, 1.0)
        worst["force"] = max(worst["force"], force)
    # measured: 5e-5 of their 1-sigma at most
    assert 0.0 < worst["phi"] < 1e-3 and worst["force"] < 1e-3, worst
