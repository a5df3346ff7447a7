"""The tracking run without ROS: measurements in, the estimate out, bad inputs counted and reported."""

from __future__ import annotations

import json
import math

import pytest

from mps_core import load_scene
from mps_core.track import run_truth, truth_scene
from mps_core.track.truth import nominal_scene
from mps_ros.run.sinks import Fanout, Sink
from mps_ros.run.tracking import TrackingRun
from mps_ros.wire import diagnostics


class ListSink(Sink):
    """Keep every message handed to it."""

    def __init__(self) -> None:
        self.msgs: list = []

    def emit_all(self, msgs):
        """Keep ``msgs``."""
        self.msgs.extend(msgs)


@pytest.fixture(scope="module")
def truth():
    return run_truth(truth_scene(nominal_scene(load_scene("working"))), 0.06, seed=1)


def _run(logs=None, **kw):
    kw.setdefault("late_after", math.inf)  # the levels asserted are the inputs', whatever the machine's load
    sink = ListSink()
    run = TrackingRun(
        load_scene("working"),
        Fanout([sink]),
        log=(lambda level, text: logs.append((level, text))) if logs is not None else None,
        **kw,
    )
    return run, sink


def test_each_measurement_gives_one_estimate_with_its_sigmas_and_process_force(truth):
    run, sink = _run()
    for i, m in enumerate(truth.measurements):
        assert run.measurement(m.t, m.value, None, b"m%d" % i, float(i))
    n = len(truth.measurements)
    assert run.estimates == n and run.received == n
    keys = [k for k, *_ in sink.msgs]
    for key in ("joint_states", "/clock", "~/foundation", "~/foundation/sigma", "~/reactions/A/sigma"):
        assert keys.count(key) == n, key
    for key in ("~/process_force/now", "~/process_force/now/sigma", "~/process_force/sigma"):
        assert keys.count(key) == n, key
    # the measurements recorded as received (not published again), each before its estimate
    received = [(k, d, t) for k, d, t, r in sink.msgs if r]
    assert [d for _, d, _ in received] == [b"m%d" % i for i in range(n)]
    assert [t for *_, t in received] == [int(round(m.t * 1e9)) for m in truth.measurements]
    # each estimate stamped with its measurement's stamp
    clocks = [t for k, _, t, _ in sink.msgs if k == "/clock"]
    assert clocks == [int(round(m.t * 1e9)) for m in truth.measurements]
    s = run.stats()
    assert s["rejected"] == 0 and math.isfinite(s["cpu_p99_ms"])


def test_the_motor_s_torque_without_a_motor_in_the_scene_is_said_once_and_left(truth):
    """A press that sends its motor's torque, a scene without a motor: said once, the torque
    left out, the run as it is without it (the model without its motor follows the truth
    badly: what matters is that it goes on)."""
    from dataclasses import replace

    scene = load_scene("working")
    motorless = replace(scene, effects=tuple(e for e in scene.effects if e.kind != "motor"))
    runs, logs = [], []
    for torque in (30.0, None):
        run = TrackingRun(
            motorless,
            Fanout([ListSink()]),
            late_after=math.inf,
            max_behind=0.0,
            log=lambda lv, tx: logs.append(tx),
        )
        taken = [
            run.measurement(m.t, m.value, None, b"", float(i), torque=torque)
            for i, m in enumerate(truth.measurements)
        ]
        runs.append((taken, run.estimates, run.rejected(), run.tracker.estimate()))
        assert not run.tracker.motor_measured
    assert runs[0] == runs[1] and runs[0][1] > 0  # estimates published, the same with and without
    said = [tx for tx in logs if "motor's torque" in tx]
    assert len(said) == 1 and "no motor" in said[0], logs


def test_the_sigmas_decimated_as_stated(truth):
    run, sink = _run(sigma_every=4)
    for m in truth.measurements[:20]:
        run.measurement(m.t, m.value, None, b"", 0.0)
    keys = [k for k, *_ in sink.msgs]
    assert keys.count("~/foundation/sigma") == 5 and keys.count("~/foundation") == 20
    assert "every 4 estimate(s)" in run.summary()


def test_bad_measurements_counted_reported_and_the_estimate_unharmed(truth):
    ms = truth.measurements
    logs: list = []
    run, _ = _run(logs)
    clean, _ = _run()
    for m in ms[:30]:
        run.measurement(m.t, m.value, None, b"", 0.0)
        clean.measurement(m.t, m.value, None, b"", 0.0)
    assert run.status()["level"] == diagnostics.OK
    last = ms[29]
    bad = [
        (ms[30].t, ms[30].value + math.radians(10.0), "jump"),  # a crank 10 degrees off
        (last.t, last.value, "duplicate"),
        (ms[28].t, ms[28].value, "out-of-order"),
        (ms[30].t, None, "malformed"),
        (math.nan, ms[30].value, "not-finite"),
    ]
    for t, value, _ in bad:
        assert not run.measurement(t, value, None, b"", 0.0)
    got = run.rejected()
    for *_, reason in bad:
        assert got[reason] == 1, (reason, got)
    assert run.estimates == 30
    st = run.status()
    assert st["level"] == diagnostics.WARN and "5 rejected" in st["message"]
    values = {v["key"]: v["value"] for v in st["values"]}
    assert values["rejected jump"] == "1" and values["rejected malformed"] == "1"
    said = " ".join(text for level, text in logs if level == "warn")
    for *_, reason in bad:
        assert reason in said, reason
    # the estimate is the clean run's, bit for bit, and goes on as it
    assert run.tracker.estimate() == clean.tracker.estimate()
    for m in ms[30:40]:
        assert run.measurement(m.t, m.value, None, b"", 0.0)
        clean.measurement(m.t, m.value, None, b"", 0.0)
    assert run.tracker.estimate() == clean.tracker.estimate()
    assert run.status()["level"] == diagnostics.OK  # nothing rejected since the last status


def test_a_silent_source_is_counted_and_reported_once_a_silence(truth):
    logs: list = []
    now = [100.0]  # the wall clock, as the test sets it
    run, _ = _run(logs, timeout=0.05, clock=lambda: now[0])
    m = truth.measurements[0]
    run.measurement(m.t, m.value, None, b"", 100.0)
    run.watch(100.04)
    assert run.rejected().get("timeout", 0) == 0
    run.watch(100.06)
    run.watch(100.5)
    assert run.rejected()["timeout"] == 1
    st = run.status()
    assert st["level"] == diagnostics.WARN and "no measurement for over 0.05 s" in st["message"]
    assert any("no measurement for" in text for _, text in logs)
    m = truth.measurements[1]
    now[0] = 101.0
    run.measurement(m.t, m.value, None, b"", 101.0)
    assert run.status()["level"] == diagnostics.OK


def test_estimates_out_late_are_counted_and_reported(truth):
    now = [50.0]  # the wall clock, as the test sets it: the same on any machine
    run, _ = _run(late_after=1e-3, clock=lambda: now[0])
    m = truth.measurements[0]
    run.measurement(m.t, m.value, None, b"", 49.99)  # it came 10 ms ago
    assert run.late == 1
    st = run.status()
    assert st["level"] == diagnostics.WARN and "cannot keep up: 1 of 1 estimates" in st["message"]
    assert "1 estimates over 1 ms" in run.summary()


def test_a_run_behind_its_press_takes_each_measurement_and_publishes_none_too_late(truth):
    logs: list = []
    now = [50.0]  # the wall clock, as the test sets it
    run, sink = _run(logs, max_behind=0.25, clock=lambda: now[0])
    clean, _ = _run()
    for i, m in enumerate(truth.measurements[:30]):
        # measurements 5 to 9 taken 0.3 s after they came, then ever less late: the run
        # publishes again once it takes one within 10 ms (CAUGHT_UP) of its arrival
        late = {5: 0.3, 6: 0.3, 7: 0.2, 8: 0.05, 9: 0.02, 10: 0.005}.get(i, 0.0)
        now[0] += 0.001
        assert run.measurement(m.t, m.value, None, b"", now[0] - late)
        clean.measurement(m.t, m.value, None, b"", now[0])
    assert run.skipped == 5 and run.estimates == 25
    assert [k for k, *_ in sink.msgs].count("joint_states") == 25
    assert run.tracker.estimate() == clean.tracker.estimate()  # every one taken
    st = run.status()
    assert st["level"] == diagnostics.WARN and "behind the press: 5 estimates not published" in st["message"]
    assert any("taken, not published" in text for _, text in logs)
    assert "5 taken but not published (over 0.25 s behind)" in run.summary()


def test_the_node_s_mode_commands_are_refused_and_answered():
    from mps_ros.run.commands import Command

    logs: list = []
    run, sink = _run(logs)
    answers: list = []
    run.inbox.put(Command("engage", "service", answers.append))
    run.inbox.put(Command("disengage", "topic"))
    run.answer_commands()
    assert [a["command"] for a in answers] == ["engage"] and not answers[0]["accepted"]
    acks = [json.loads(d[8:].rstrip(b"\0").decode()) for k, d, *_ in sink.msgs if k == "~/mode/status"]
    assert [(a["command"], a["accepted"]) for a in acks] == [("engage", False), ("disengage", False)]
    assert "its mode comes from the press (track_mode)" in acks[1]["reason"]
    assert sum("refused command" in text for _, text in logs) == 2


def test_a_bad_setting_names_its_field():
    with pytest.raises(ValueError, match="track_sigma_every = 0: expected an integer >= 1"):
        _run(sigma_every=0)


@pytest.mark.parametrize("sigma_every", [1, 10])
def test_each_stroke_finished_is_published_once_with_its_figures(sigma_every):
    """``~/strokes``: one JSON object a stroke at its end, the tracker's own stroke table's
    figures; the filter's foundation peak where the loads are computed at every estimate only
    (the fitted cut's always); the run keeps no stroke once published."""
    from mps_core.track import Tracker

    truth = run_truth(truth_scene(nominal_scene(load_scene("working"))), 0.35, seed=4)
    run, sink = _run(sigma_every=sigma_every)
    offline = Tracker(nominal_scene(load_scene("working")))
    for m in truth.measurements:
        run.measurement(m.t, m.value, None, b"", 0.0)
        offline.update(m)
        offline.observe_stroke()
    strokes = [(json.loads(string_of(d)), t) for k, d, t, _ in sink.msgs if k == "~/strokes"]
    expected = offline.strokes.strokes
    assert len(expected) >= 2 and len(strokes) == len(expected) == run.strokes
    assert not run.tracker.strokes.strokes
    for (row, t_ns), s in zip(strokes, expected, strict=True):
        assert t_ns == int(round(s.t_end * 1e9))
        for key in ("stroke", "t_end", "peak_force_N", "peak_force_sigma_N", "work_J", "work_sigma_J"):
            assert row[key] == s.row()[key], key
        # the foundation's peak the fitted cut's; the filter's where its loads are computed at
        # every estimate only
        assert math.isfinite(row["peak_foundation_N"])
        assert math.isfinite(row["filter_peak_foundation_N"]) == (sigma_every == 1)


def test_cuts_fitted_in_a_process_of_their_own_give_the_same_strokes():
    """The node's way (``fit_elsewhere``): each cut's fit made in the fitting process, taken
    back as it comes, its stroke held back until then. Every estimate's messages are those of
    a run that fits its cuts itself, in the same order, and so is every stroke's row, byte
    for byte; the process ends with the run."""
    truth = run_truth(truth_scene(nominal_scene(load_scene("working"))), 0.45, seed=4)
    here, sink_here = _run()
    there, sink_there = _run(fit_elsewhere=True)
    try:
        for m in truth.measurements:
            for run in (here, there):
                run.measurement(m.t, m.value, None, b"", 0.0)
        there.finish_fits()
        assert there.fits is not None and not there.fits.failed
        proc = there.fits._proc
    finally:
        there.close()
    assert proc is not None and proc.returncode == 0

    def strokes(sink):
        return [(d, t) for k, d, t, _ in sink.msgs if k == "~/strokes"]

    def others(sink):
        return [msg for msg in sink.msgs if msg[0] not in ("~/strokes", "/diagnostics")]

    assert len(strokes(sink_here)) >= 2 and strokes(sink_there) == strokes(sink_here)
    assert all(math.isfinite(json.loads(string_of(d))["contact_m"]) for d, _ in strokes(sink_here))
    assert others(sink_there) == others(sink_here)
    assert there.tracker.cuts_fitted == here.tracker.cuts_fitted >= 3


def string_of(data: bytes) -> str:
    """Return a CDR std_msgs/String's text."""
    from mps_ros.recording.replay import string_data

    return string_data(data)


def test_the_machine_is_watched_live_and_a_double_blank_reported():
    """The tracking status of mps track on the node: OK while the press moves as the model
    says; a double blank reported as ERROR within a revolution, said in the log and on
    /diagnostics (the strokes taken off the table as they are published do not blind it)."""
    from mps_core.track import Fault

    t_fault, revolution = 0.2, 2.0 * math.pi / 43.5
    truth = run_truth(
        truth_scene(nominal_scene(load_scene("working"))),
        0.45,
        seed=0,
        faults=(Fault(t_fault, "double-blank"),),
    )
    logs: list = []
    run, _sink = _run(logs)
    levels = []
    for m in truth.measurements:
        run.measurement(m.t, m.value, None, b"", 0.0)
        levels.append((m.t, run.monitor.status.level))
    assert all(level == "OK" for t, level in levels if t < t_fault)
    first = next(t for t, level in levels if level == "ERROR")
    assert t_fault < first <= t_fault + revolution
    said = [text for level, text in logs if level == "error"]
    assert said and "process force beyond the part's" in said[0]
    names = {st["name"]: st for st in run.statuses()}
    st = names["press_twin: tracking"]
    assert st["level"] == diagnostics.ERROR and "double blank" in st["message"]
    assert names["press_twin: tracking input"]["level"] == diagnostics.OK


def test_a_prepared_run_meets_no_code_it_has_not_made_and_estimates_as_an_unprepared_one():
    """prepare() takes the nominal press's first second in a copy of the run: the code a press
    that engages and disengages meets is made then, none when its measurements come, and the
    run's messages are those of a run that made its code as it went."""
    from mps_core import caches
    from mps_core.codegen import emitter
    from mps_core.track import Sensors

    nominal = nominal_scene(load_scene("press-cycle"))
    press = run_truth(truth_scene(nominal), 0.6, sensors=Sensors(slider=True), seed=2)
    stamps = len({m.t for m in press.measurements})

    def follow(run: TrackingRun) -> int:
        made = emitter._SERIAL[0]  # code made, or read from the disk cache, so far
        assert run.take_all(press.measurements, press.modes, 100.0) == stamps
        return emitter._SERIAL[0] - made

    sinks = ListSink(), ListSink()
    caches.clear()
    cold = TrackingRun(nominal, Fanout([sinks[0]]))
    assert follow(cold) > 0
    caches.clear()
    warm = TrackingRun(nominal, Fanout([sinks[1]]))
    warm.prepare()
    assert follow(warm) == 0
    assert cold.tracker.accepted == warm.tracker.accepted == 2 * stamps
    published = [[msg for msg in sink.msgs if msg[0] != "/diagnostics"] for sink in sinks]
    assert published[0] == published[1] and len(published[0]) > 10 * stamps


def test_a_warm_up_that_cannot_run_is_said_and_the_run_goes_on(monkeypatch, truth):
    """A scene whose own run stops in the warm-up: a warning, and the run follows its press."""
    import mps_core.track

    def failing(*args, **kwargs):
        raise ValueError("no configuration at t = 0.3 s")

    monkeypatch.setattr(mps_core.track, "run_truth", failing)
    logs: list = []
    run, _sink = _run(logs)
    run.prepare()
    run.prepare()  # the node's second call (as the run starts) does nothing
    said = [level for level, text in logs if "warm-up" in text and "no configuration at t = 0.3 s" in text]
    assert said == ["warn"]
    for i, m in enumerate(truth.measurements):
        assert run.measurement(m.t, m.value, None, b"m%d" % i, float(i))
    assert run.estimates == len(truth.measurements)


@pytest.mark.parametrize("freeze", [True, False])
def test_a_prepared_run_freezes_the_garbage_collector_where_asked(freeze):
    """freeze_gc (the node's): once prepared, what the process has made is out of the garbage
    collector's passes, so a full collection during the run scans only what came since. In a
    process of its own: a freeze holds for the process."""
    import subprocess
    import sys

    code = (
        "import gc, sys\n"
        "from mps_core import load_scene\n"
        "from mps_ros.run.sinks import Fanout\n"
        "from mps_ros.run.tracking import TrackingRun\n"
        "run = TrackingRun(load_scene('working'), Fanout([]), freeze_gc=sys.argv[1] == 'True')\n"
        "before = gc.get_freeze_count()\n"
        "run.prepare()\n"
        "print(before, gc.get_freeze_count())\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code, str(freeze)], capture_output=True, text=True, timeout=300, check=True
    )
    before, after = map(int, out.stdout.split())
    assert before == 0
    assert (after > 10_000) if freeze else (after == 0)
