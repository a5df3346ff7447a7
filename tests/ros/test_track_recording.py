"""``mps track --out FILE.mcap``: the tracked run as a recording, read back by rosbags (an
independent reader), by ``mps loads`` and by ``mps view``, its values those of the estimates
file; the measurements on their own topics; the 1-σ beside each estimated wrench."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import pytest

from mps_core.cli import main
from mps_core.track.measurement_csv import read_measurements

FOUNDATION_COLUMNS = ("F_found_x", "F_found_y", "M_found_O")


@pytest.fixture(scope="module")
def tracked(tmp_path_factory):
    """press-cycle's truth emulated for 0.33 s (idle, engage, the latch closing, two cuts: a
    whole revolution for the load report), then tracked into an estimates file and a recording."""
    d = tmp_path_factory.mktemp("track")
    m, est, rec = d / "m.csv", d / "est.csv", d / "run.mcap"
    assert main(["emulate", "press-cycle", "--t-end", "0.33", "--csv", str(m)]) == 0
    args = ["track", "press-cycle", "--csv", str(m), "--out", str(est), "--out", str(rec), "--loads"]
    assert main(args) == 0
    rows = list(csv.DictReader(est.open()))
    return d, m, rows, rec


def _ns(t: str | float) -> int:
    return int(round(float(t) * 1e9))


def _messages(path: Path) -> dict[str, list]:
    """Every message by topic: (log time ns, type, message), with rosbags."""
    from rosbags.highlevel import AnyReader

    out: dict[str, list] = {}
    with AnyReader([path]) as reader:
        for conn, t_ns, raw in reader.messages():
            out.setdefault(conn.topic, []).append((t_ns, conn.msgtype, reader.deserialize(raw, conn.msgtype)))
    return out


def test_rosbags_reads_the_estimates_of_the_csv(tracked):
    _d, _m, rows, rec = tracked
    msgs = _messages(rec)
    by_t = {_ns(r["t"]): r for r in rows}
    loads = {_ns(r["t_loads"]): r for r in rows}  # a later estimate of a time replaces an earlier
    joints = msgs["/joint_states"]
    # every estimate the smoother gave loads for is a step: all but a few (the last two, and
    # one at each restart of the lags: engage, latch)
    assert len(rows) - 8 <= len(joints) < len(rows)
    assert len(joints) == len([t for t in by_t if t in loads])
    for t_ns, msgtype, js in joints:
        assert msgtype == "sensor_msgs/msg/JointState"
        r = by_t[t_ns]
        assert list(js.name) == ["crank", "rod", "rocker", "slider"]
        assert js.position[0] == float(r["phi"]) and js.velocity[0] == float(r["phi_dot"])
        assert js.position[3] == float(r["x_C"])
        assert js.effort[0] == float(loads[t_ns]["M_motor"])
    found = {t: msg for t, _ty, msg in msgs["/press_twin/foundation"]}
    found_sd = {t: msg for t, _ty, msg in msgs["/press_twin/foundation/sigma"]}
    assert set(found) == set(found_sd) == {t for t, _ty, _m in joints}
    for t_ns, w in found.items():
        r = loads[t_ns]
        assert (w.wrench.force.x, w.wrench.force.y, w.wrench.torque.z) == tuple(
            float(r[c]) for c in FOUNDATION_COLUMNS
        )
        sd = found_sd[t_ns].wrench
        assert (sd.force.x, sd.force.y, sd.torque.z) == tuple(
            float(r[c + "_sigma"]) for c in FOUNDATION_COLUMNS
        )
        assert w.header.stamp.sec * 10**9 + w.header.stamp.nanosec == t_ns
    types = {topic: ms[0][1] for topic, ms in msgs.items()}
    for topic in ("/press_twin/reactions/A", "/press_twin/reactions/A/sigma", "/press_twin/process_force"):
        assert types[topic] == "geometry_msgs/msg/WrenchStamped"
    assert types["/clock"] == "rosgraph_msgs/msg/Clock"
    assert types["/diagnostics"] == "diagnostic_msgs/msg/DiagnosticArray"
    statuses = [s for _t, _ty, a in msgs["/diagnostics"] for s in a.status]
    assert {s.name for s in statuses} == {"press_twin: tracking"}
    assert {s.level for s in statuses} == {0}  # a healthy run: OK
    assert [m.data for _t, _ty, m in msgs["/press_twin/structure"]] == ["held", "free", "locked"]
    kinds = [json.loads(m.data)["kind"] for _t, _ty, m in msgs["/press_twin/events"]]
    assert "latch-closes" in kinds


def test_the_measurements_are_on_their_own_topics(tracked):
    _d, m, _rows, rec = tracked
    msgs = _messages(rec)
    measured, modes = read_measurements(m, {"crank_angle": 1e-10})
    got = msgs["/press/joint_states"]
    assert [t for t, _ty, _m in got] == [_ns(x.t) for x in measured]
    assert all(list(js.name) == ["crank"] for _t, _ty, js in got)
    assert [js.position[0] for _t, _ty, js in got] == [x.value for x in measured]
    assert [(t, msg.data) for t, _ty, msg in msgs["/press/mode"]] == [(_ns(s.t), s.command) for s in modes]
    assert [s.command for s in modes] == ["engage", "disengage"]  # the scene's signals, all written


def test_mps_loads_and_mps_view_read_it_as_the_twins(tracked, capsys):
    from mps_ros.recording.replay import load_columns

    d, _m, rows, rec = tracked
    columns, events, _name = load_columns(rec)  # what `mps loads FILE.mcap` reads
    loads = {_ns(r["t_loads"]): r for r in rows}
    by_t = {_ns(r["t"]): r for r in rows}
    for i, t in enumerate(columns["t"]):
        t_ns = _ns(t)
        assert columns["phi"][i] == float(by_t[t_ns]["phi"])
        assert columns["F_found_x"][i] == float(loads[t_ns]["F_found_x"])
        assert columns["F_A_y"][i] == float(loads[t_ns]["F_A_y"])
    assert not any(math.isnan(v) for v in columns["F_found_x"])
    assert {e["kind"] for e in events} >= {"command", "latch-closes"}
    capsys.readouterr()
    assert main(["loads", str(rec), "--json", str(d / "loads.json")]) == 0
    report = json.loads((d / "loads.json").read_text())
    cycle = report["cycle"]
    peak = next(q["peak"] for q in report["quantities"] if q["name"] == "F_found_x")
    inside = [
        abs(float(r["F_found_x"]))
        for r in loads.values()
        if cycle["t0_s"] <= float(r["t_loads"]) <= cycle["t1_s"]
    ]
    assert peak == pytest.approx(max(inside), rel=0.02)  # the report's spline through the steps
    assert main(["view", str(rec), "--save", str(d / "run.rrd"), "--no-spawn"]) == 0
    assert (d / "run.rrd").stat().st_size > 0


def test_bad_outputs_are_named(tracked, capsys):
    d, m, _rows, _rec = tracked
    argv = ["track", "press-cycle", "--csv", str(m), "--out", str(d / "a.mcap"), "--out", str(d / "b.mcap")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "--out = " in err and "a.mcap" in err and "expected at most one FILE.mcap (a recording)" in err
    assert not (d / "a.mcap").exists()


def test_the_loads_1_sigma_every_nth_measurement(tracked, capsys):
    """``--sigma-every N``: the loads at every step as before, their 1-σ at every N-th
    measurement (the same numbers as at every step) and NaN between; the recording's sigma
    topics at those steps only, its loads at every step; N under 1 named as an error."""
    d, m, rows, rec = tracked
    est, rec5 = d / "est5.csv", d / "run5.mcap"
    argv = [
        "track",
        "press-cycle",
        "--csv",
        str(m),
        "--out",
        str(est),
        "--out",
        str(rec5),
        "--sigma-every",
        "5",
    ]
    assert main(argv) == 0
    rows5 = list(csv.DictReader(est.open()))
    assert len(rows5) == len(rows)
    loads = [c for c in rows[0] if c + "_sigma" in rows[0] and c.startswith(("F_", "M_"))]
    assert loads and all(r[c] == s[c] for r, s in zip(rows, rows5) for c in loads)
    given = [i for i, r in enumerate(rows5) if r["F_found_x_sigma"] != "nan"]
    assert 0 < len(given) < len(rows5) // 4
    assert all(rows5[i][c + "_sigma"] == rows[i][c + "_sigma"] for i in given for c in loads)
    assert all(rows5[i][c + "_sigma"] == "nan" for i in range(len(rows5)) if i not in given for c in loads)
    every, fifth = _messages(rec), _messages(rec5)
    assert len(fifth["/press_twin/foundation"]) == len(every["/press_twin/foundation"])
    for topic in ("/press_twin/foundation/sigma", "/press_twin/reactions/A/sigma"):
        full = {t: msg.wrench.force.x for t, _type, msg in every[topic]}
        some = {t: msg.wrench.force.x for t, _type, msg in fifth[topic]}
        assert 0 < len(some) <= len(given) and len(some) < len(full) // 4
        assert all(full[t] == v for t, v in some.items())  # at their steps, the same 1-σ
    assert main(["track", "press-cycle", "--csv", str(m), "--sigma-every", "0"]) == 2
    assert "--sigma-every = 0: expected a whole number of measurements, 1 or more" in capsys.readouterr().err
    assert main(["track", "press-cycle", "--against-truth", "0.1", "--sigma-every", "3"]) == 2
    assert "--sigma-every = 3: expected 1 with --against-truth" in capsys.readouterr().err


def test_the_packed_messages_are_the_dicts_encoded():
    """The estimated topics' fixed-layout messages, packed as the node packs its own, are the
    bytes of their message dicts encoded: /tf, joint states (with NaN where nothing is
    estimated, without efforts) and wrenches in each frame, at stamps of several seconds."""
    from mps_core.scene import load_scene
    from mps_ros.recording import track_recording as tr
    from mps_ros.wire.cdr import encoder, generic_encoder
    from mps_ros.wire.frames import MSGTYPE, TfLayout

    tf = TfLayout.of_scene(load_scene("press-cycle"))
    packed = tr._Packed(tf)
    for t in (0.0, 0.001, 1.2345678905, 61.000000001):
        stamp = tr._stamp(t)
        values = tf.values(0.3 + t, 1.1, 0.02 - t * 1e-3)
        assert packed.tf(t, values) == generic_encoder(MSGTYPE)(tf.message(stamp, values))
        for pos, vel, eff in (
            ((0.1, math.nan, 0.2, 0.03), (4.0, math.nan, -1.0, 0.5), (1.0, math.nan, -2.5, 3e3)),
            ((1e-6, math.nan, math.nan, 2e-5), (3e-3, math.nan, math.nan, math.nan), ()),
        ):
            assert packed.joints(t, pos, vel, eff) == encoder(tr._JOINTS)(tr._joints(stamp, pos, vel, eff))
        for frame in ("press_frame", "press_C", "press_B"):
            got = packed.wrench(t, frame, -1.5e4 * (1 + t), 2.5, 0.0 if t else -7.0)
            want = encoder(tr._WRENCH)(_wrench(stamp, frame, -1.5e4 * (1 + t), 2.5, 0.0 if t else -7.0))
            assert got == want


def _wrench(stamp: dict, frame_id: str, fx: float, fy: float, mz: float) -> dict:
    """Return a WrenchStamped message dict: force (fx, fy, 0), torque (0, 0, mz)."""
    return {
        "header": {"stamp": stamp, "frame_id": frame_id},
        "wrench": {"force": {"x": fx, "y": fy, "z": 0.0}, "torque": {"x": 0.0, "y": 0.0, "z": mz}},
    }
