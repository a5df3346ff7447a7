"""Late mode signals: the command searched for over the signal's latency, the measurements since
taken again; a signal on time kept at its stamp; the tracker's checkpoints exact."""

from __future__ import annotations

import re

import numpy as np
import pytest

from mps_core import load_scene
from mps_core.track import Sensors, Tracker, TrackingMonitor, run_truth, truth_scene
from mps_core.track.measurements import MeasurementError, ModeSignal
from mps_core.track.settings import TrackSettings

LATE = 3e-3  # how late each signal comes after its command (s)


@pytest.fixture(scope="module")
def cycle():
    """press-cycle with a slider scale through its engage and its disengage (seed 0)."""
    nominal = load_scene("press-cycle")
    return nominal, run_truth(truth_scene(nominal), 0.5, sensors=Sensors(slider=True), seed=0)


def _follow(nominal, truth, latency, late=0.0, keep=None):
    """Run a tracker over the truth's measurements, its signals ``late`` seconds after their
    commands (``keep``: the innovations it keeps at least); return the tracker, its monitor and
    the estimates (t, φ, φ̇, x_C) after each."""
    tracker = Tracker(nominal, TrackSettings(signal_latency=latency))
    tracker.keep_innovations = keep
    monitor = TrackingMonitor()
    modes = sorted((ModeSignal(s.t + late, s.command) for s in truth.modes), key=lambda s: s.t)
    rows = []
    for m in truth.measurements:
        while modes and modes[0].t <= m.t:
            tracker.mode(modes.pop(0))
        tracker.update(m)
        monitor.observe(tracker, m)
        e = tracker.estimate()
        rows.append((e.t, e.phi, e.phi_dot, e.x_C))
    return tracker, monitor, np.array(rows)


def test_late_signals_are_found_where_their_commands_were(cycle):
    """Signals 3 ms late: applied when they come, the slider is measured moving as the model
    does not and measurements are rejected; searched for over 10 ms, each command is found
    within a millisecond of where it was, nothing is rejected and the status stays OK."""
    nominal, truth = cycle
    plain, plain_monitor, _ = _follow(nominal, truth, 0.0, LATE)
    assert plain.rejected["outlier"] > 0
    tracker, monitor, _ = _follow(nominal, truth, 0.01, LATE)
    assert tracker.timing is not None and len(tracker.timing.shifts) == 2
    assert all(abs(shift - LATE) < 1e-3 for shift in tracker.timing.shifts), tracker.timing.shifts
    # each search's hypotheses and CPU (what holds up the measurement that closes it)
    assert all(f.searched and f.tried > 0 and f.cpu > 0.0 for f in tracker.timing.found)
    assert sum(f.tried for f in tracker.timing.found) == tracker.timing.tried
    assert tracker.rejected["outlier"] == 0
    assert [s.level for s in monitor.events] == ["OK"]
    assert tracker.sim.structure != "locked"  # disengaged
    nis = [v for _t, _k, v in tracker.innovations]
    assert len(nis) == tracker.accepted  # the innovations are the kept hypothesis's, once each


def test_a_signal_on_time_is_kept_at_its_stamp(cycle):
    """Signals at their commands' times: the search keeps each at its stamp, and every estimate
    is the one a tracker without the search gives, bit for bit."""
    nominal, truth = cycle
    tracker, _, searched = _follow(nominal, truth, 0.01)
    _, _, plain = _follow(nominal, truth, 0.0)
    assert tracker.timing is not None and tracker.timing.shifts == [0.0, 0.0]
    assert [f.searched for f in tracker.timing.found] == [True, True] and tracker.timing.tried > 0
    assert np.array_equal(searched, plain)


def test_a_measurement_taken_again_from_a_checkpoint_gives_the_same_estimate(cycle):
    """Back to a checkpoint, a command applied and the measurements since taken again: the
    same state, covariance and logs as the run that went straight through."""
    nominal, truth = cycle
    straight, again = Tracker(nominal), Tracker(nominal)
    modes = sorted(truth.modes, key=lambda s: s.t)
    engage = modes[0]
    measurements = [m for m in truth.measurements if m.t < engage.t + 0.02]
    before = [m for m in measurements if m.t < engage.t]
    for m in before:
        straight.update(m)
        again.update(m)
    cp = again.checkpoint()
    for m in measurements[len(before) :]:  # a hypothesis without the command...
        again.update(m)
    again.restore(cp)  # ... dropped
    straight.mode(engage)
    again.mode(engage)
    for m in measurements[len(before) :]:
        straight.update(m)
        again.update(m)
    assert np.array_equal(straight.x, again.x) and np.array_equal(straight.P, again.P)
    assert straight.innovations == again.innovations and straight.rejected == again.rejected
    assert straight.sim.structure == again.sim.structure == "locked"


def test_a_latency_out_of_range_or_a_solver_that_cannot_rewind_is_named():
    expected = "track.signal_latency = 0.5: expected a time in [0, 0.1] s"
    with pytest.raises(MeasurementError, match=re.escape(expected)):
        TrackSettings(signal_latency=0.5)
    nominal = load_scene("press-cycle").with_overrides(solver="radau")
    with pytest.raises(MeasurementError, match="track.signal_latency = 0.01: expected 0 with solver 'radau'"):
        Tracker(nominal, TrackSettings(signal_latency=0.01))


def test_from_the_crank_alone_a_signal_on_time_stays_at_its_stamp():
    """From the crank alone the measurements near an engage say little: a command moved by
    their noise would put the latch's impact off the press's (seed 1 once moved it 0.45 ms
    early and lost the track); the signal on time is kept unless another time is clearly likelier."""
    nominal = load_scene("press-cycle")
    truth = run_truth(truth_scene(nominal), 0.1, sensors=Sensors(), seed=1)
    tracker, monitor, _ = _follow(nominal, truth, 0.01)
    assert tracker.timing is not None and tracker.timing.shifts[0] == 0.0
    assert [s.level for s in monitor.events] == ["OK"]


@pytest.mark.parametrize("every", [1, 7])
def test_the_search_is_the_same_from_sparser_or_denser_checkpoints(cycle, monkeypatch, every):
    """A hypothesis starts from the last checkpoint before its gap and takes the measurements
    between again: the same estimates, whichever stamps the checkpoints were kept at."""
    from mps_core.track import signal_timing

    nominal, truth = cycle
    tracker, _, rows = _follow(nominal, truth, 0.01, LATE)
    monkeypatch.setattr(signal_timing, "CHECKPOINT_EVERY", every)
    other, _, other_rows = _follow(nominal, truth, 0.01, LATE)
    assert other.timing is not None and tracker.timing is not None
    assert other.timing.shifts == tracker.timing.shifts
    assert np.array_equal(other_rows, rows)


def test_a_bounded_log_of_innovations_gives_the_same_estimates_and_status(cycle):
    """A node keeps the last innovations only (a press followed for days): the searches and
    the tracking status work on the log's numbers, the estimates and statuses the same."""
    nominal, truth = cycle
    tracker, monitor, rows = _follow(nominal, truth, 0.01, LATE)
    bounded, bounded_monitor, bounded_rows = _follow(nominal, truth, 0.01, LATE, keep=50)
    assert np.array_equal(bounded_rows, rows)
    assert [(s.level, s.message) for s in bounded_monitor.events] == [
        (s.level, s.message) for s in monitor.events
    ]
    assert len(bounded.innovations) <= 100 and bounded.innovations_dropped > 0
    assert bounded.innovations == tracker.innovations[-len(bounded.innovations) :]
