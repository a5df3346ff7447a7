"""The tracking status: each fault injected into the truth reported as ERROR within a crank
revolution, saying what departed; healthy runs without a report; the windowed innovation test
and the lost track on a stand-in tracker; bad settings named."""

from __future__ import annotations

import math
import re
from collections import Counter
from types import SimpleNamespace

import pytest

from mps_core import load_scene
from mps_core.track import Fault, Measurement, MeasurementError, Tracker, run_truth, truth_scene
from mps_core.track.diagnostics import DiagnosticSettings, TrackingMonitor
from mps_core.track.strokes import StrokeTable
from mps_core.track.truth import Sensors, TruthChanges, with_blanking

#: one crank revolution at the presets' rated crank speed (43.5 rad/s), s
REVOLUTION = 2.0 * math.pi / 43.5


def _working():
    return with_blanking(load_scene("working").with_overrides(scheme="autodiff"))


def _watched(nominal, t_end, faults=(), seed=0, sensors=None, tracker=None):
    """Follow the truth of ``nominal`` with faults; return the monitor's status changes."""
    truth = run_truth(truth_scene(nominal), t_end, seed=seed, faults=tuple(faults), sensors=sensors)
    tracker, monitor = tracker or Tracker(nominal), TrackingMonitor()
    modes = sorted(truth.modes, key=lambda s: s.t)
    for m in truth.measurements:
        while modes and modes[0].t <= m.t:
            tracker.mode(modes.pop(0))
        tracker.update(m)
        monitor.observe(tracker, m)
    return monitor.events


def _first_error(events, t_fault):
    """Return the first ERROR, none but OK before the fault."""
    before = [e for e in events if e.t < t_fault and e.level != "OK"]
    assert not before, before[0].line()
    return next(e for e in events if e.level == "ERROR")


def test_a_healthy_run_is_ok_throughout():
    """Four strokes of the working press, another part than the model's: no WARN, no ERROR."""
    events = _watched(_working(), 0.6, seed=0)
    assert [e.level for e in events] == ["OK"]


def test_a_healthy_run_with_the_motors_torque_is_ok_and_finds_the_motor_off_its_catalogue():
    """The motor's torque measured too (2 % of its reading): the motor 3 % under its catalogue
    is a share the tracker estimates (a state from the first torque measured), no WARN for
    it; without the torque measured that state never moves."""
    nominal = _working()
    tracker = Tracker(nominal)
    events = _watched(nominal, 0.45, seed=2, sensors=Sensors(motor_torque=True), tracker=tracker)
    assert [e.level for e in events] == ["OK"]
    assert tracker.motor_measured
    est = tracker.estimate()
    truth = TruthChanges().motor_torque - 1.0  # -0.03
    assert abs(est.motor_scale - truth) <= 4.0 * est.motor_scale_sigma  # measured: -2.99 ± 0.12 %
    assert 0.0 < est.motor_scale_sigma < 0.005
    plain = Tracker(nominal)
    _watched(nominal, 0.1, seed=2, tracker=plain)
    assert not plain.motor_measured
    assert (plain.estimate().motor_scale, plain.estimate().motor_scale_sigma) == (0.0, 0.0)


def test_a_healthy_press_cycle_is_ok_throughout():
    """press-cycle's idle, engage, latch closing and strokes (seed 1): no report."""
    events = _watched(load_scene("press-cycle"), 0.43, seed=1)
    assert [e.level for e in events] == ["OK"]


def test_a_healthy_press_cycle_through_its_disengage_and_idle_is_ok_throughout():
    """press-cycle with a slider scale through its disengage (0.4351 s) and the idle four-bar's
    free swings: the slider's side moves apart from the crank there, its model noise is the
    unlocked one, and no innovation test fires (with the locked one's it WARNs here)."""
    events = _watched(load_scene("press-cycle"), 0.9, seed=0, sensors=Sensors(slider=True))
    assert [e.level for e in events] == ["OK"], [e.line() for e in events]


def test_from_the_crank_alone_the_idle_slider_s_swings_are_followed_by_acquiring_the_crank_again():
    """press-cycle from its crank alone through the disengage and the idle four-bar's swings
    (seed 3): the crank does not see the slider there, and its impacts at the stop move the
    crank where the model's slider is off; latch open, the crank is acquired again after three
    angles rejected running, and the track is never lost. Without that it is lost twice, the
    second time for good."""
    from dataclasses import replace

    from mps_core.track import TrackSettings

    nominal = load_scene("press-cycle")
    tracker = Tracker(nominal)
    events = _watched(nominal, 0.9, seed=3, tracker=tracker)
    assert [e.level for e in events] == ["OK"], [e.line() for e in events]
    assert tracker.acquired >= 1 and sum(tracker.rejected.values()) <= 8  # measured: 1, and 4 outliers
    never = Tracker(nominal, replace(TrackSettings(), reacquire_after=10**9))
    events = _watched(nominal, 0.9, seed=3, tracker=never)
    assert [e.level for e in events].count("ERROR") == 2  # at 0.538 s, then from 0.702 s on
    assert sum(never.rejected.values()) > 50  # measured: 257 (92 outliers, 156 jumps)


def test_a_double_blank_is_reported_within_a_revolution():
    """Injected just after a cut (the worst case: the next cut is most of a revolution on)."""
    t_fault = 0.2
    error = _first_error(_watched(_working(), 0.45, [Fault(t_fault, "double-blank")]), t_fault)
    assert t_fault < error.since <= t_fault + REVOLUTION  # measured: 0.129 s after
    assert "process force beyond the part's" in error.message and "double blank" in error.message


def test_a_clutch_slip_is_reported_within_a_revolution():
    t_fault = 0.3
    error = _first_error(_watched(_working(), 0.4, [Fault(t_fault, "clutch-slip")]), t_fault)
    assert t_fault < error.since <= t_fault + REVOLUTION  # measured: 18 ms after
    assert "load torque on the crank" in error.message and "slipping drive" in error.message


def test_each_stroke_says_the_worst_status_it_ran_under():
    """The strokes before a clutch slip say OK; the stroke it slips in says ERROR, in its row too
    (its work is no part's: the slip's), as the status did while it ran."""
    t_fault = 0.3
    nominal = _working()
    tracker = Tracker(nominal)
    _watched(nominal, 0.45, [Fault(t_fault, "clutch-slip")], tracker=tracker)
    strokes = tracker.strokes.strokes
    assert [s.tracking for s in strokes if s.t_end < t_fault] == ["OK"] * 2, [s.row() for s in strokes]
    slipped = next(s for s in strokes if s.t_start <= t_fault < s.t_end)
    assert slipped.tracking == "ERROR" and slipped.row()["tracking"] == "ERROR"


def test_a_broken_spring_is_reported_within_a_revolution():
    """press-cycle, latch closed: the springs' 2.5 kN gone loses the track at once."""
    t_fault = 0.25
    error = _first_error(_watched(load_scene("press-cycle"), 0.3, [Fault(t_fault, "broken-spring")]), t_fault)
    assert t_fault < error.since <= t_fault + REVOLUTION  # measured: 6 ms after
    assert "track lost" in error.message and "broken spring" in error.message


def test_a_missed_part_warns_at_its_stroke_s_end_and_clears_at_the_next_part():
    """No part in the die for one cut: a WARN naming the stroke when it closes (within a
    revolution), OK again once a stroke blanks; nothing else said."""
    t_fault = 0.3
    events = _watched(_working(), 0.6, [Fault(t_fault, "missed-part")])
    assert [e.level for e in events] == ["OK", "WARN", "OK"], [e.line() for e in events]
    warn = events[1]
    assert t_fault < warn.since <= t_fault + REVOLUTION  # measured: 0.113 s after
    assert "no part blanked in stroke" in warn.message and "part missing" in warn.message
    assert events[2].since > warn.since


class _StandIn:
    """A tracker's face as the monitor reads it: innovations, rejections, estimate, strokes."""

    phi_tdc = 0.0

    def __init__(self):
        self.innovations: list = []
        self.rejected: Counter = Counter()
        self.accepted = 0
        self.strokes = StrokeTable()
        self.replaced_from = None

    def take_replaced(self):
        out, self.replaced_from = self.replaced_from, None
        return out

    def estimate(self):
        return SimpleNamespace(
            structure="held", phi=0.0, phi_dot=43.5, torque=0.0, torque_sigma=1.0, work=0.0, work_sigma=0.0
        )

    def take(self, t, nis):
        self.innovations.append((t, "crank_angle", nis))
        self.accepted += 1


def _m(t):
    return Measurement(t, "crank_angle", 0.0, 1e-10)


def test_innovations_beyond_their_bound_warn_and_a_lost_track_is_an_error():
    s = DiagnosticSettings(window=20, lost_after=3, recover_after=4)
    mon, tr = TrackingMonitor(s), _StandIn()
    assert mon.nis_bound == pytest.approx(1.7085, abs=1e-3)  # chi2.ppf(0.975, 20) / 20
    for k in range(20):
        tr.take(k * 1e-3, 1.0)
        assert mon.observe(tr, _m(k * 1e-3)).level == "OK"
    for k in range(20, 40):  # the mean NIS climbs past 1.71
        tr.take(k * 1e-3, 4.0)
        mon.observe(tr, _m(k * 1e-3))
    assert mon.status.level == "WARN" and "mean NIS 4.00 over the last 20" in mon.status.message
    warned = mon.status.since
    assert 0.020 < warned < 0.030
    for k in range(40, 43):  # three measurements running rejected: lost
        tr.rejected["outlier"] += 1
        mon.observe(tr, _m(k * 1e-3))
    assert mon.status.level == "ERROR" and mon.status.since == pytest.approx(0.042)
    assert "track lost: 3 measurements running rejected (outlier 3 in all)" in mon.status.message
    for k in range(43, 46):  # taken again, but not yet for recover_after running
        tr.take(k * 1e-3, 1.0)
        assert mon.observe(tr, _m(k * 1e-3)).level == "ERROR"
    tr.take(0.046, 1.0)
    assert mon.observe(tr, _m(0.046)).level == "WARN"  # found again; the window still high
    assert [e.level for e in mon.events] == ["OK", "WARN", "ERROR", "WARN"]


def test_innovations_taken_again_replace_theirs_in_the_window():
    s = DiagnosticSettings(window=20)
    mon, tr = TrackingMonitor(s), _StandIn()
    for k in range(20):
        tr.take(k * 1e-3, 1.0)
        mon.observe(tr, _m(k * 1e-3))
    for k in range(20, 25):  # a late signal applied at its stamp: the model off the press
        tr.take(k * 1e-3, 9.0)
        mon.observe(tr, _m(k * 1e-3))
    assert mon.status.level == "WARN"
    del tr.innovations[18:]  # the command found earlier: taken again from the 19th
    tr.replaced_from = 18
    for k in range(18, 26):
        tr.take(k * 1e-3, 1.0)
    assert mon.observe(tr, _m(0.025)).level == "OK"
    assert "mean NIS 1.00 over the last 20" in mon.status.message


@pytest.mark.parametrize(
    ("field", "value", "expected"),
    [
        ("window", 3, "an integer >= 10"),
        ("confidence", 1.5, "a probability in (0.5, 1)"),
        ("torque_z", 0.5, "a number > 1"),
        ("lost_after", 0, "an integer >= 1"),
    ],
)
def test_bad_settings_are_named(field, value, expected):
    with pytest.raises(
        MeasurementError, match=re.escape(f"diagnostics.{field} = {value!r}: expected {expected}")
    ):
        DiagnosticSettings(**{field: value})


def test_the_chi2_quantile_is_scipy_stats():
    import numpy as np
    from scipy.stats import chi2

    from mps_core.track.diagnostics import chi2_quantile

    for p in (0.95, 0.975, 0.9995):
        for dof in (1, 2, 3, 10, 50):
            assert chi2_quantile(p, dof) == chi2.ppf(p, dof)
    assert np.array_equal(chi2_quantile(0.95, [1, 4, 9]), chi2.ppf(0.95, [1, 4, 9]))
