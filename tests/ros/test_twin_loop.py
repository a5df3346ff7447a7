"""The stepping loop's own parts, without ROS: the step's messages as kept buffers (the same
bytes as the message dicts encoded), the latched structure, events held back one step after an
impact, impulses worked out later and the same, timings in flat memory, and the recording
process that finishes the file however the stepping process ends."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

pytest.importorskip("mcap")
pytest.importorskip("rosbags")

from mps_core import build, load_scene
from mps_core.dynamics.reaction_observer import ReactionObserver
from mps_ros.recording.background import BackgroundRecorder
from mps_ros.run.metrics import Timings
from mps_ros.run.runner import Runner
from mps_ros.run.sinks import RecordingSink
from mps_ros.run.twin import Twin
from mps_ros.wire.cdr import encoder
from mps_ros.wire.topics import BY_KEY


def test_payloads_are_the_message_dicts_encoded_and_the_structure_is_latched():
    tw = Twin("press-cycle", dt=1e-3, t_end=0.12)
    structures, statics = [], 0
    while True:
        msgs = tw.state_messages()
        pays = tw.state_payloads()
        assert [(k, encoder(BY_KEY[k].msgtype)(m)) for k, m in msgs] == pays, tw.t
        structures += [m["data"] for k, m in msgs if k == "~/structure"]
        statics += sum(1 for k, _m in msgs if k == "/tf_static")
        assert tw.state_messages() == [m for m in msgs if m[0] not in ("~/structure", "/tf_static")]
        if tw.done:
            break
        tw.step()
        tw.new_events()
    assert structures[0] == "held" and "locked" in structures
    assert all(a != b for a, b in zip(structures, structures[1:]))
    assert statics == 1


def test_the_derivatives_override_the_scenes():
    """``derivatives``: the twin steps the scene with that scheme, as mps_core does."""
    scene = load_scene("press-cycle")
    assert scene.solver.scheme == "autodiff"  # the live twin's default
    tw = Twin(scene, dt=1e-3, t_end=0.05, derivatives="central")
    assert tw.describe()["derivatives"] == "central"
    sim = build(scene.with_overrides(dt=1e-3, t_end=0.05, scheme="central"))
    exact = Twin(scene, dt=1e-3, t_end=0.05)
    assert exact.describe()["derivatives"] == "autodiff"
    while not tw.done:
        tw.step()
        exact.step()
        sim.advance_to(tw.sim.t)
        assert tw.sim.joint_state() == sim.joint_state()
    assert tw.sim.joint_state() != exact.sim.joint_state()


def test_deferred_impulses_are_the_immediate_ones():
    scene = load_scene("press-cycle").with_overrides(dt=1e-3, t_end=0.6)
    runs = []
    for defer in (False, True):
        sim = build(scene)
        ob = ReactionObserver(defer_impacts=defer)
        sim.observers.append(ob)
        for k in range(1, 601):
            sim.advance_to(k * 1e-3)
        if defer:
            assert all("impulses_Ns" not in e for e in ob.impacts)
            ob.resolve()
        runs.append([e for e in sim.events if e["kind"] == "impulse"])
    now, later = runs
    assert len(now) >= 2 and len(now) == len(later)
    for a, b in zip(now, later):
        assert a == b


def test_events_of_an_impact_step_are_held_one_step_in_order():
    tw = Twin("press-cycle", dt=1e-3, t_end=0.6)
    got, held = [], 0
    while not tw.done:
        tw.step()
        ev = tw.new_events(hold=True)
        if not ev and tw.sim.events:
            held += 1
        got += ev
    got += tw.new_events()
    assert held >= 2
    impulses = [e for e in got if e["kind"] == "impulse"]
    assert impulses and all("impulses_Ns" in e for e in impulses)
    times = [e["t"] for e in got]
    assert times == sorted(times)


def test_timings_percentiles_to_one_percent_in_flat_memory():
    rng = np.random.default_rng(1)
    x = rng.lognormal(mean=math.log(2e-4), sigma=0.7, size=20000)
    t = Timings()
    for v in x:
        t.add(float(v))
    for p in (50, 90, 99):
        assert t.percentile(p) == pytest.approx(np.percentile(x, p), rel=0.015)
    assert t.max == x.max() and t.n == x.size
    assert len(t.counts) == Timings._BINS
    assert Timings().percentile(50) == 0.0


def _read(path):
    from rosbags.highlevel import AnyReader

    with AnyReader([path]) as r:
        return {c.topic: c.msgcount for c in r.connections}


def test_the_recording_process_writes_what_it_is_handed(tmp_path):
    tw = Twin("press-cycle", dt=1e-3, t_end=0.2)
    rec = BackgroundRecorder(
        tmp_path / "bg.mcap", scene_name="press-cycle", scene_text=tw.scene.text, flush_period=0.1
    )
    st = Runner(tw, sinks=[RecordingSink(rec)]).run()
    rec.finish()
    assert rec.written == rec.messages == st["messages"]
    counts = _read(tmp_path / "bg.mcap")
    assert counts["/joint_states"] == 201 and sum(counts.values()) == rec.messages


def test_the_recording_process_finishes_the_file_when_the_stepper_dies(tmp_path):
    """The stepping process ends without finish() (os._exit: no cleanup at all): the pipe
    closes, and the recording process still writes the summary and footer."""
    out = tmp_path / "orphan.mcap"
    code = textwrap.dedent(f"""
        import os
        from mps_ros.recording.background import BackgroundRecorder
        from mps_ros.run.sinks import RecordingSink
        from mps_ros.run.runner import Runner
        from mps_ros.run.twin import Twin
        tw = Twin("press-cycle", dt=1e-3, t_end=0.1)
        rec = BackgroundRecorder({str(out)!r}, flush_period=0.05)
        Runner(tw, sinks=[RecordingSink(rec)]).run()
        rec.flush()
        os._exit(3)
    """)
    res = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, env=dict(os.environ)
    )
    assert res.returncode == 3, res.stderr
    for _ in range(300):  # the writer finishes on its own, shortly after (30 s at most)
        try:
            counts = _read(out)
            break
        except Exception:
            import time

            time.sleep(0.1)
    else:
        raise AssertionError("the recording was not finished")
    assert counts["/joint_states"] == 101


def test_a_paced_recording_counts_what_was_written(tmp_path):
    """``mps record`` paced: the steps go to the recording process as lists (write_steps); its
    counts by topic are those the process wrote, and the file holds them."""
    from mps_ros.run.record import record

    path, stats, counts = record(
        "press-cycle",
        tmp_path / "paced.mcap",
        dt=1e-3,
        t_end=0.05,
        pacing="realtime",
        real_time_factor=4.0,
        stop_on_signals=False,
    )
    assert counts == _read(path)
    assert counts["/joint_states"] == 51 and sum(counts.values()) == stats["messages"]
