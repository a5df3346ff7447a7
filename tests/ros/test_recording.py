"""Recordings without ROS: ``mps record``, the CDR encoders, recovery of a file cut short, the
outputs asked for and nothing else, the flood gate. rosbags (an independent implementation)
reads everything back."""

from __future__ import annotations

import json
import math
import os
import random
import signal
import stat
import subprocess
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mcap")
pytest.importorskip("mcap_ros2")
pytest.importorskip("rosbags")

from twin_probe import mps_cmd, wait_until

from mps_core import __version__, build, load_scene
from mps_core.cli import main as mps_main
from mps_ros.recording.recorder import Recorder
from mps_ros.recording.recover import read_metadata, recover
from mps_ros.run.commands import Gate
from mps_ros.run.record import record
from mps_ros.run.runner import Runner
from mps_ros.run.twin import Twin
from mps_ros.wire.cdr import ENCODERS, generic_encoder
from mps_ros.wire.topics import FOUNDATION, WRENCHES


def read_all(path):
    from rosbags.highlevel import AnyReader

    out = {}
    with AnyReader([Path(path)]) as r:
        for c in r.connections:
            out.setdefault(c.topic, [])
        for conn, t, raw in r.messages(connections=r.connections):
            out[conn.topic].append((t, r.deserialize(raw, conn.msgtype), bytes(raw)))
    return out


def _random_messages(rng):
    def s():
        return "".join(rng.choice("abc_xyzé") for _ in range(rng.randint(0, 11)))

    st = {"sec": rng.randint(0, 2**31 - 1), "nanosec": rng.randint(0, 999_999_999)}
    return {
        "sensor_msgs/msg/JointState": {
            "header": {"stamp": st, "frame_id": s()},
            "name": [s() for _ in range(rng.randint(0, 5))],
            "position": [rng.uniform(-9, 9) for _ in range(rng.randint(0, 4))],
            "velocity": [rng.uniform(-9, 9) for _ in range(rng.randint(0, 4))],
            "effort": [math.nan, rng.random()][: rng.randint(0, 2)],
        },
        "geometry_msgs/msg/WrenchStamped": {
            "header": {"stamp": st, "frame_id": s()},
            "wrench": {
                "force": {"x": rng.random(), "y": -rng.random(), "z": 0.0},
                "torque": {"x": 0.0, "y": 1e-300, "z": rng.random()},
            },
        },
        "rosgraph_msgs/msg/Clock": {"clock": st},
        "std_msgs/msg/String": {"data": s()},
    }


def test_cdr_encoders_give_the_generic_encoders_bytes():
    rng = random.Random(5)
    for _ in range(200):
        for msgtype, d in _random_messages(rng).items():
            assert ENCODERS[msgtype](d) == bytes(generic_encoder(msgtype)(d)), (msgtype, d)


def test_cdr_bytes_are_what_ros_deserializes():
    pytest.importorskip("rclpy")
    from geometry_msgs.msg import WrenchStamped
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState

    rng = random.Random(7)
    for _ in range(50):
        m = _random_messages(rng)
        d = m["sensor_msgs/msg/JointState"]
        js = deserialize_message(ENCODERS["sensor_msgs/msg/JointState"](d), JointState)
        assert js.header.frame_id == d["header"]["frame_id"] and list(js.name) == d["name"]
        np.testing.assert_array_equal(js.position, d["position"])
        np.testing.assert_array_equal(js.effort, d["effort"])
        d = m["geometry_msgs/msg/WrenchStamped"]
        w = deserialize_message(ENCODERS["geometry_msgs/msg/WrenchStamped"](d), WrenchStamped)
        assert (w.wrench.force.x, w.wrench.torque.z) == (
            d["wrench"]["force"]["x"],
            d["wrench"]["torque"]["z"],
        )


def test_mps_record_writes_the_nodes_messages(tmp_path, capsys):
    out = tmp_path / "rec.mcap"
    assert mps_main(["record", "press-cycle", "--out", str(out), "--dt", "0.001", "--t-end", "0.05"]) == 0
    assert str(out) in capsys.readouterr().out
    back = read_all(out)
    n = 50
    for topic in (
        "/joint_states",
        "/clock",
        "/press_twin/foundation",
        *(f"/press_twin/reactions/{w.name}" for w in WRENCHES),
    ):
        assert len(back[topic]) == n + 1, topic
    assert [t for t, _, _ in back["/joint_states"]] == [round(k * 1e6) for k in range(n + 1)]
    events = [json.loads(m.data) for _, m, _ in back["/press_twin/events"]]
    assert events[0]["kind"] == "run-start" and events[-1]["kind"] == "run-end"
    assert any(
        e["kind"] == "command" and e["command"] == "engage" and e["t"] == 0.008 for e in events
    )  # the scene's own schedule, at its exact time
    # the values are mps_core's
    scene = load_scene("press-cycle").with_overrides(dt=0.001, t_end=0.05)
    sim = build(scene)
    changes = []
    for k in range(n + 1):
        if k:
            sim.advance_to(k * 0.05 / n if k < n else 0.05)
        s = sim.snapshot()
        js = back["/joint_states"][k][1]
        assert (js.position[0], js.position[2], js.position[3]) == (s["phi"], s["psi"], s["x_C"])
        if not changes or changes[-1][1] != s["structure"]:
            changes.append((round(k * 1e6), s["structure"]))
    # the structure is latched: recorded where it changes, at the step it changed in
    assert [(t, m.data) for t, m, _ in back["/press_twin/structure"]] == changes
    assert len(changes) >= 2
    _frames_are_the_joints(back, scene.geometry)
    meta = read_metadata(out)
    assert meta["mps"]["version"] == __version__ and meta["mps"]["source"] == "mps record"
    assert meta["scene"]["toml"] == load_scene("press-cycle").text


def _frames_are_the_joints(back, geometry):
    """/tf at every step: press_A, press_B, press_C and press_slider in press at the points of
    φ, ψ, x_C (to 1e-9 m), parallel to it; /tf_static once: press upright in the z-up
    press_base (its x along z, its y along x), press_O at O."""
    l1, l3 = geometry.l1, geometry.l3
    tf = back["/tf"]
    assert [t for t, _, _ in tf] == [t for t, _, _ in back["/joint_states"]]
    for (t, m, _), (_t, js, _) in zip(tf, back["/joint_states"]):
        phi, psi, x_c = js.position[0], js.position[2], js.position[3]
        want = {
            "press_A": (l1 * math.cos(phi), l1 * math.sin(phi)),
            "press_B": (x_c + l3 * math.cos(psi), l3 * math.sin(psi)),
            "press_C": (x_c, 0.0),
            "press_slider": (x_c, 0.0),
        }
        got = {}
        for tr in m.transforms:
            assert tr.header.frame_id == "press"
            assert (tr.header.stamp.sec * 10**9 + tr.header.stamp.nanosec) == t
            q = tr.transform.rotation
            assert (q.x, q.y, q.z, q.w) == (0.0, 0.0, 0.0, 1.0)
            v = tr.transform.translation
            assert v.z == 0.0
            got[tr.child_frame_id] = (v.x, v.y)
        assert got.keys() == want.keys()
        for frame, (x, y) in want.items():
            assert abs(got[frame][0] - x) <= 1e-9 and abs(got[frame][1] - y) <= 1e-9, frame
    ((t, m, _),) = back["/tf_static"]
    assert t == 0
    by_child = {tr.child_frame_id: tr for tr in m.transforms}
    assert by_child["press"].header.frame_id == "press_base"
    q = by_child["press"].transform.rotation
    # the rotation's matrix (columns: where press's x, y, z go in press_base)
    x, y, z, w = q.x, q.y, q.z, q.w
    rot = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    np.testing.assert_allclose(rot, [[0, 1, 0], [0, 0, 1], [1, 0, 0]], atol=1e-15)
    assert by_child["press_O"].header.frame_id == "press"
    o = by_child["press_O"].transform.translation
    assert (o.x, o.y, o.z) == (0.0, 0.0, 0.0)


def test_only_the_outputs_asked_for(tmp_path, monkeypatch):
    import mps_core.dynamics.reactions as R

    def no(*a, **k):
        raise AssertionError("reactions solved though nobody asked")

    monkeypatch.setattr(R, "compute_reactions", no)
    out = tmp_path / "js.mcap"
    path, stats, counts = record(
        "press-cycle",
        out,
        dt=0.001,
        t_end=0.05,
        outputs=("joint_states", "clock"),
        publish_every=10,
        stop_on_signals=False,
    )
    back = read_all(out)
    assert {t for t, v in back.items() if v} == {"/joint_states", "/clock"}
    assert [t for t, _, _ in back["/clock"]] == [k * 10_000_000 for k in range(6)]
    assert list(back["/joint_states"][0][1].effort) == []  # no reactions, no efforts


def test_recover_a_file_cut_short(tmp_path):
    full = tmp_path / "full.mcap"
    twin = Twin("press-cycle", dt=0.001, t_end=0.2)
    from mps_ros.run.sinks import RecordingSink

    with Recorder(full, scene_name="press-cycle", scene_text=twin.scene.text, chunk_size=16 * 1024) as rec:
        Runner(twin, sinks=[RecordingSink(rec)]).run()
    whole = read_all(full)
    data = full.read_bytes()
    # a complete file recovers to the same messages
    same = recover(full, tmp_path / "same.mcap")
    assert same.complete and same.messages == sum(len(v) for v in whole.values())
    for cut in (len(data) // 3, len(data) // 2, len(data) - 100):
        cut_path = tmp_path / f"cut{cut}.mcap"
        cut_path.write_bytes(data[:cut])
        out = tmp_path / f"rec{cut}.mcap"
        rep = recover(cut_path, out)
        assert not rep.complete and rep.chunks >= 1
        back = read_all(out)
        assert sum(len(v) for v in back.values()) == rep.messages > 0
        for topic, msgs in back.items():
            assert [raw for _, _, raw in msgs] == [raw for _, _, raw in whole[topic][: len(msgs)]]
        assert read_metadata(out)["scene"]["toml"] == twin.scene.text
    # nothing but the header and metadata: an empty, valid recording
    head = tmp_path / "head.mcap"
    head.write_bytes(data[:200])
    rep = recover(head, tmp_path / "head-rec.mcap")
    assert rep.messages == 0
    read_all(tmp_path / "head-rec.mcap")


@pytest.mark.parametrize("force", [False, True], ids=["new", "force"])
def test_mps_record_finishes_the_file_on_sigint(tmp_path, force):
    """Ctrl-C: the file finished and readable, one line saying where it is and to which t,
    exit 130, no traceback; over a recording (--force), that one is kept as it was and the
    new one goes beside it."""
    out = tmp_path / "int.mcap"
    old = b""
    if force:
        assert mps_main(["record", "paper", "--out", str(out), "--t-end", "0.01"]) == 0
        old = out.read_bytes()
    cmd = mps_cmd("record", "press-cycle", "--out", str(out), "--pacing", "realtime", "--dt", "0.001")
    cmd += ["--t-end", "60", *(["--force"] if force else [])]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)
    written = tmp_path / "int-partial.mcap" if force else out
    try:
        # the header first, then a chunk of steps (written within a second of stepping):
        # the run is under way once the file has grown past its header
        def growing():
            if not force:
                return out if out.exists() else None
            return next(iter(tmp_path.glob(".int.*.partial.mcap")), None)

        wait_until(lambda: growing() and growing().stat().st_size >= 1000, 60, "the file's header")
        head = growing().stat().st_size
        wait_until(lambda: growing().stat().st_size > head, 60, "a chunk of steps in the file")
        proc.send_signal(signal.SIGINT)
        assert proc.wait(20) == 130
        said = proc.stdout.read().decode()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
        proc.stdout.close()
    lines = said.splitlines()
    assert len(lines) == 1 and lines[0].startswith("mps record: interrupted (SIGINT) at t = "), said
    assert f"{str(written)!r} keeps " in lines[0] and "messages to t = " in lines[0]
    if force:
        assert out.read_bytes() == old and f"{str(out)!r} is as it was" in lines[0]
    back = read_all(written)  # complete: rosbags reads it as it is
    end_ev = json.loads(back["/press_twin/events"][-1][1].data)
    assert end_ev["kind"] == "run-end" and end_ev["reason"] == "SIGINT"
    assert len(back["/joint_states"]) > 10
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted({out.name, written.name})


def test_mps_record_force_that_fails_keeps_the_old_recording(tmp_path, capsys):
    """A run that fails (chart switching off: the crank cannot pass the chart's edge) over a
    recording: the old one as it was, the new one beside it, one line saying both."""
    out = tmp_path / "keep.mcap"
    assert mps_main(["record", "paper", "--out", str(out), "--t-end", "0.01"]) == 0
    old = out.read_bytes()
    scene = tmp_path / "stuck.toml"
    scene.write_text(load_scene("press-cycle").text + "\n[charts]\nswitching = false\n")
    capsys.readouterr()
    assert mps_main(["record", str(scene), "--out", str(out), "--dt", "0.001", "--force", "-q"]) == 2
    _out, err = capsys.readouterr()
    assert err.count("\n") == 1 and err.startswith("mps: error: t = ") and "chart switching is off" in err
    kept = tmp_path / "keep-partial.mcap"
    assert f"{str(kept)!r} keeps " in err and f"{str(out)!r} is as it was" in err
    assert out.read_bytes() == old
    end_ev = json.loads(read_all(kept)["/press_twin/events"][-1][1].data)
    assert end_ev["kind"] == "run-end" and end_ev["reason"] == "error"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep-partial.mcap", "keep.mcap", "stuck.toml"]


def test_mps_record_on_a_full_disk_says_what_was_kept_and_how_to_complete_it(tmp_path):
    """A real full disk (a 300 kB tmpfs in a mount namespace of the test's own): one line
    naming the file, the disk full, what it keeps to which t and the recover command, exit 1;
    the command it names completes the file."""
    import shutil

    if shutil.which("unshare") is None:
        pytest.skip("no unshare here to mount a small file system")
    small = tmp_path / "small"
    small.mkdir()
    rec = small / "r.mcap"
    script = f'mount -t tmpfs -o size=300k tmpfs {small} && exec "$@"'
    cmd = ["unshare", "-rm", "sh", "-c", script, "sh", *mps_cmd("record", "press-cycle")]
    cmd += ["--out", str(rec), "--dt", "0.001", "-q"]
    got = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    if "mount" in got.stderr and "mps" not in got.stderr:
        pytest.skip(f"cannot mount a small file system here: {got.stderr.strip()}")
    lines = got.stderr.splitlines()
    assert got.returncode == 1 and len(lines) == 1, got.stderr
    line = lines[0]
    assert line.startswith(f"mps record: error: recording {str(rec)!r} stopped at t = ")
    assert "No space left on device" in line and "messages to t = " in line
    assert f"`mps recover {rec} OUT.mcap`" in line
    assert "Traceback" not in got.stderr


def test_mps_recover_of_a_file_with_no_whole_chunk_writes_nothing(tmp_path, capsys):
    good = tmp_path / "good.mcap"
    assert mps_main(["record", "paper", "--out", str(good), "--t-end", "0.01"]) == 0
    before = good.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(before[:600])  # the header and a little: no whole chunk
    capsys.readouterr()
    assert mps_main(["recover", str(cut), str(good), "--force"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no message to recover" in err and "nothing written" in err
    assert good.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cut.mcap", "good.mcap"]


def test_mps_record_warns_of_a_coarse_step_as_mps_run_does(tmp_path, capsys):
    out = str(tmp_path / "c.mcap")
    assert mps_main(["record", "press-cycle", "--out", out, "--dt", "0.05", "--t-end", "0.5", "-q"]) == 0
    err = capsys.readouterr().err
    assert "mps: warning: the step 0.05 s is coarse for this run" in err


def test_a_recording_is_never_written_into_a_stream(tmp_path, capsys):
    fifo = tmp_path / "ff.mcap"
    os.mkfifo(fifo)
    assert mps_main(["record", "paper", "--out", str(fifo), "--t-end", "0.01", "--force"]) == 2
    assert "a FIFO; expected a file path" in capsys.readouterr().err
    assert stat.S_ISFIFO(fifo.stat().st_mode)


def test_gate_refuses_empty_long_and_floods():
    now = [0.0]
    g = Gate(burst=3, rate=2.0, clock=lambda: now[0])
    assert g.check("").startswith("empty command")
    assert g.check("y" * 65).startswith("a 65-character command")
    assert g.check("engage") is None
    assert g.check("engage").startswith("flood")
    now[0] += 0.5  # one token back
    assert g.check("stop") is None
    assert g.check("stop").startswith("flood")


def test_gate_refuses_unknown_words_before_the_machine_sees_them():
    g = Gate(burst=10, rate=20.0)
    for word in ("launch", "ENGAGE", "engage now", " engage"):
        assert g.check(word) == "expected one of engage, disengage, stop, start", word
    for word in ("engage", "disengage", "stop", "start"):
        assert g.check(word) is None


def test_foundation_wrench_is_the_reactions_resultant():
    """The foundation topic carries F_found and M_found_O about O in the press frame."""
    twin = Twin("working", dt=1e-3, t_end=0.01)
    twin.step()
    msgs = dict(twin.state_messages())
    f = msgs[FOUNDATION.key]
    rx = twin.reactions()
    assert f["header"]["frame_id"] == "press"
    assert (f["wrench"]["force"]["x"], f["wrench"]["force"]["y"], f["wrench"]["torque"]["z"]) == (
        rx["F_found_x"],
        rx["F_found_y"],
        rx["M_found_O"],
    )


def test_rod_angle_and_rate():
    """The rod's joint state: its angle from A to B and a rate consistent with it."""
    twin = Twin("paper", dt=1e-4, t_end=0.002)
    angles, rates = [], []
    for _ in range(10):
        twin.step()
        js = dict(twin.state_messages())["joint_states"]
        angles.append(js["position"][1])
        rates.append(js["velocity"][1])
    fd = np.gradient(np.array(angles), 1e-4)
    np.testing.assert_allclose(fd[2:-2], np.array(rates)[2:-2], rtol=2e-3, atol=1e-3)


def test_rerun_reads_the_recording(tmp_path):
    """Rerun (its own MCAP reader) checks and converts a recording, where it is installed."""
    import shutil
    import sys

    rerun = Path(sys.executable).with_name("rerun")
    if not rerun.exists():
        rerun = shutil.which("rerun")
        if rerun is None:
            pytest.skip("no rerun command here (pip install rerun-sdk)")
    out = tmp_path / "r.mcap"
    record("press-cycle", out, dt=0.001, t_end=0.05, stop_on_signals=False)
    chk = subprocess.run([str(rerun), "mcap", "check", str(out)], capture_output=True, text=True, timeout=120)
    assert chk.returncode == 0 and "/joint_states" in chk.stdout, chk.stdout + chk.stderr
    lines = [ln for ln in chk.stdout.splitlines() if "/press_twin/" in ln or "/joint_states" in ln]
    assert lines and all(ln.split()[0] == "ok" for ln in lines), chk.stdout
    rrd = tmp_path / "r.rrd"
    conv = subprocess.run(
        [str(rerun), "mcap", "convert", str(out), "-o", str(rrd)], capture_output=True, text=True, timeout=120
    )
    assert conv.returncode == 0 and rrd.stat().st_size > 10_000, conv.stderr


def test_record_needs_no_rclpy(tmp_path):
    """`mps record` and `mps recover` run where rclpy is missing; `mps node` says what to
    install."""
    import sys

    out = tmp_path / "noros.mcap"
    code = (
        "import sys; sys.modules['rclpy'] = None\n"
        "from mps_core.cli import main\n"
        f"rc = main(['record', 'press-cycle', '--out', {str(out)!r}, '--dt', '0.001',"
        " '--t-end', '0.01'])\n"
        "assert 'rclpy' not in [m for m in sys.modules if sys.modules[m] is not None]\n"
        "sys.exit(rc or main(['node']))\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 2, res.stderr
    assert "this command needs ROS 2 Jazzy's rclpy: install the ros extra" in res.stderr
    assert len(read_all(out)["/joint_states"]) == 11


def test_record_and_recover_never_write_over_a_file(tmp_path, capsys):
    from mps_ros.recording.mcap_writer import MAGIC

    rec = tmp_path / "r.mcap"
    assert mps_main(["record", "paper", "--out", str(rec), "--t-end", "0.01"]) == 0
    before = rec.read_bytes()
    steps = len(read_all(rec)["/clock"])
    capsys.readouterr()
    # an existing recording, the scene itself: refused before anything runs
    scene = tmp_path / "s.toml"
    scene.write_text(load_scene("paper").text)
    for out, words in ((rec, "exists"), (scene, "the command's input")):
        src = "paper" if out is rec else str(scene)
        assert mps_main(["record", src, "--out", str(out), "--t-end", "0.01"]) == 2
        out_text, err = capsys.readouterr()
        assert out_text == "" and words in err, err
    assert rec.read_bytes() == before and scene.read_text() == load_scene("paper").text
    assert mps_main(["record", "paper", "--out", str(rec), "--t-end", "0.02", "--force"]) == 0
    assert len(read_all(rec)["/clock"]) > steps  # the new run's
    # recover: never over a file without --force, never over its input, whole or not at all
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(before[: len(before) * 2 // 3])
    good = tmp_path / "good.mcap"
    good.write_bytes(b"precious")
    assert mps_main(["recover", str(cut), str(good)]) == 2
    assert "exists" in capsys.readouterr().err and good.read_bytes() == b"precious"
    assert mps_main(["recover", str(cut), str(cut), "--force"]) == 2
    assert "the command's input" in capsys.readouterr().err
    assert mps_main(["recover", str(cut), str(good), "--force"]) == 0
    assert good.read_bytes()[:8] == MAGIC
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cut.mcap", "good.mcap", "r.mcap", "s.toml"]


def test_new_recordings_never_share_a_file(tmp_path, monkeypatch):
    from mps_ros.recording import recorder as recording

    # two runs started in the same millisecond: the second gets a name of its own
    monkeypatch.setattr(
        recording,
        "default_path",
        lambda scene, d="recordings": tmp_path / f"{scene}-20261125-120000-123.mcap",
    )
    a = recording.new_recording("press-cycle", tmp_path)
    b = recording.new_recording("press-cycle", tmp_path)
    assert (a.name, b.name) == (
        "press-cycle-20261125-120000-123.mcap",
        "press-cycle-20261125-120000-123-2.mcap",
    )
    assert a.exists() and b.exists()


@pytest.mark.parametrize("pacing", ["as_fast_as_possible", "realtime"])
def test_a_recording_that_cannot_be_written_stops_alone(tmp_path, pacing, ros):
    """The recording's file cannot grow (here a file size limit on the node's processes, as a
    full disk would): one line when it happens, the run goes on to its end and publishes, an
    ERROR status ``press_twin: recording`` on /diagnostics from then on, the node ends with
    status 1 and says the recording is incomplete; what was written is recovered whole by mps
    recover."""
    import sys

    from diagnostic_msgs.msg import DiagnosticStatus
    from twin_probe import Listener, NodeProcess

    rec = tmp_path / "r.mcap"
    params = dict(
        pacing=pacing,
        real_time_factor=2.0,
        dt=0.001,
        t_end=8.0,
        recording=str(rec),
        wait_for_subscribers=1,
        wait_timeout=30.0,
    )
    limit = 1_500_000
    node = NodeProcess(tmp_path, params, name=pacing)
    node.cmd = [
        sys.executable,
        "-c",
        "import os, resource, sys; "
        f"resource.setrlimit(resource.RLIMIT_FSIZE, ({limit}, {limit})); "
        "os.execv(sys.argv[1], sys.argv[1:])",
        *node.cmd,
    ]
    lis = Listener()  # every topic: the node waits for a subscriber on each
    try:
        with node:
            rc = node.wait(120)
            log = node.log()
        diagnostics = lis.get("/diagnostics")
    finally:
        lis.close()
    statuses = [(s.name, s.level, s.message) for m in diagnostics for s in m.status]
    # the recording's status: OK while it records, ERROR from its failure on, saying why
    said = [s for s in statuses if s[0] == "press_twin: recording"]
    stop = next(i for i, s in enumerate(said) if s[1] != DiagnosticStatus.OK)
    assert all(msg.startswith(f"recording to {rec}") for _n, _l, msg in said[:stop]), said
    alarms = said[stop:]
    assert all(lvl == DiagnosticStatus.ERROR and "File too large" in msg for _n, lvl, msg in alarms), alarms
    first = statuses.index(alarms[0])
    assert any(n == "press_twin: pacing" for n, _l, _m in statuses[first:]), statuses
    stopped = [ln for ln in log.splitlines() if "recording stopped at t = " in ln]
    assert rc == 1 and len(stopped) == 1, log
    assert "File too large" in stopped[0] and f"mps recover {rec}" in stopped[0]
    assert "run ended at t = 8 s after 8000 steps" in log and "Traceback" not in log
    assert "recording incomplete" in log
    assert rec.stat().st_size <= limit
    out = tmp_path / "back.mcap"
    assert mps_main(["recover", str(rec), str(out)]) == 0
    clock = read_all(out)["/clock"]
    assert 1000 < len(clock) < 8001


@pytest.mark.parametrize("background", [False, True], ids=["recorder", "background"])
def test_a_recorder_used_with_with_finishes_the_file_also_on_an_error(tmp_path, background):
    from mps_ros.recording.background import BackgroundRecorder
    from mps_ros.run.sinks import RecordingSink

    path = tmp_path / "with.mcap"
    twin = Twin("press-cycle", dt=0.001, t_end=0.05, outputs=["joint_states", "clock"])
    make = BackgroundRecorder if background else Recorder
    with pytest.raises(RuntimeError, match="the caller's own"):
        with make(path, scene_name="press-cycle") as rec:
            Runner(twin, sinks=[RecordingSink(rec)]).run()
            raise RuntimeError("the caller's own error")
    back = read_all(path)  # finished: it reads back without recovery
    assert [t for t, _m, _raw in back["/clock"]][-1] == 50_000_000


def test_message_definitions_are_kept_in_the_disk_cache_as_rosbags_makes_them(monkeypatch, tmp_path):
    """A definition is rosbags' text, kept for the next process; an entry that is not valid is
    made again from rosbags, never used."""
    import subprocess
    import sys

    from rosbags.typesys import Stores, get_typestore

    from mps_core.codegen import disk_cache
    from mps_ros.wire import cdr

    monkeypatch.setenv("MPS_CACHE_DIR", str(tmp_path))
    script = (
        "import json; from mps_core.codegen import disk_cache; from mps_ros.wire import cdr; "
        "texts = [cdr.msgdef(t) for t in ('tf2_msgs/msg/TFMessage', 'sensor_msgs/msg/JointState')]; "
        "print(json.dumps([texts, disk_cache.COUNTS]))"
    )

    def fresh():
        out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
        return json.loads(out.stdout)

    ts = get_typestore(Stores.ROS2_JAZZY)
    truth = [
        ts.generate_msgdef(t, ros_version=2)[0]
        for t in ("tf2_msgs/msg/TFMessage", "sensor_msgs/msg/JointState")
    ]
    texts, counts = fresh()
    assert texts == truth and counts["written"] == 2 and counts["read"] == 0
    texts, counts = fresh()
    assert texts == truth and counts["read"] == 2 and counts["written"] == 0
    entry = disk_cache.entry("ros2msg definition", ("tf2_msgs/msg/TFMessage", cdr._rosbags_files()))
    assert entry is not None and entry.path.exists()
    data = entry.path.read_bytes()
    entry.path.write_bytes(data.replace(b"geometry_msgs/Transform", b"geometry_msgs/Transfxrm"))
    texts, counts = fresh()
    assert texts == truth and counts["rejected"] == 1 and counts["written"] == 1 and counts["read"] == 1
