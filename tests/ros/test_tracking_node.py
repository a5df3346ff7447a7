"""The node following the emulator, end to end: every estimate published and recorded, a bad one
counted; mps track over its recording gives the same estimates and strokes."""

from __future__ import annotations

import csv
import json
import math
import os
import signal
import struct
import subprocess
import threading
from pathlib import Path

import pytest
from track_estimates import differences, node_estimates, tracked
from twin_probe import NodeProcess, mps_cmd, stop_group, wait_until

from mps_ros.wire.topics import TOPICS, resolve
from mps_ros.wire.track_topics import RECEIVED_JOINTS, TRACKING_TOPICS

pytestmark = pytest.mark.slow

OUTPUTS = ["joint_states", "foundation", "clock", "structure", "events", "diagnostics"]
T_END = 0.25  # the press's seconds: about 250 measurements at 1 kHz
#: the emulator at a fifth of the press's pace: the node's work spread thin beside the other tests
RATE = 0.2
GLITCH_T = 0.12  # the crank read 20 degrees off at the first measurement after it


def _stamp_ns(data: bytes) -> int:
    """Return the header stamp of a CDR JointState or WrenchStamped (after the 4-byte encapsulation)."""
    sec, nsec = struct.unpack_from("<iI", data, 4)
    return sec * 1_000_000_000 + nsec


class RawListener:
    """Subscribe to ``names`` (topic -> message class), keep the bytes received in order."""

    def __init__(self, rclpy, names: dict) -> None:
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

        self.node = rclpy.create_node(f"tracking_probe_{os.getpid()}")
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=20000, reliability=ReliabilityPolicy.RELIABLE)
        self.lock = threading.Lock()
        self.msgs: dict[str, list[bytes]] = {n: [] for n in names}
        for name, cls in names.items():
            self.node.create_subscription(cls, name, self._cb(name), qos, raw=True)
        from mps_ros.ros.spinning import SpinThread

        executor = SingleThreadedExecutor()
        executor.add_node(self.node)
        self.spin = SpinThread(executor, "tracking-probe")

    def _cb(self, name: str):
        def cb(data: bytes) -> None:
            with self.lock:
                self.msgs[name].append(bytes(data))

        return cb

    def get(self, name: str) -> list[bytes]:
        """Return the bytes received on ``name`` so far."""
        with self.lock:
            return list(self.msgs[name])

    def close(self) -> None:
        """Stop spinning, then destroy the node."""
        from mps_ros.ros.spinning import close

        assert close(self.spin, [self.node]), "the probe's executor thread did not end"


def _padded(data: bytes) -> bytes:
    """Return ``data`` as a DDS reader hands it over: zero-padded to a multiple of 4 bytes (RTPS)."""
    return data + b"\0" * (-len(data) % 4)


def _recorded(path: Path) -> dict[str, list[bytes]]:
    """Return each topic's recorded bytes, in the file's order."""
    from mcap.reader import make_reader

    out: dict[str, list[bytes]] = {}
    with open(path, "rb") as f:
        for _s, ch, m in make_reader(f).iter_messages(log_time_order=False):
            out.setdefault(ch.topic, []).append(_padded(bytes(m.data)))
    return out


def test_the_node_follows_the_emulator(ros, tmp_path):
    from mps_ros.ros.endpoints import MSG_CLASSES

    published = [
        t
        for t in (*TOPICS, *TRACKING_TOPICS)
        if (not t.output or t.output in OUTPUTS) and t.msgtype in MSG_CLASSES and t.key != RECEIVED_JOINTS.key
    ]
    names = {resolve(t.key): MSG_CLASSES[t.msgtype] for t in published}
    listener = RawListener(ros, names)
    rec = tmp_path / "track.mcap"
    params = {
        "track": "/press/joint_states",
        "track_mode": "/press/mode",
        "recording": str(rec),
        "outputs": "[" + ", ".join(OUTPUTS) + "]",
        "wait_for_subscribers": 1,  # every topic has this test's subscriber before it follows
        "wait_timeout": 120.0,
        "diagnostics_period": 0.2,
        "track_timeout": 5.0,  # a slow machine's pauses are not the press's silence
        "track_max_behind": 0.0,  # every estimate published, however far behind a busy machine is
    }
    emu = None
    try:
        with NodeProcess(tmp_path, params, scene="working", name="tracking-node") as node:
            emu_log = open(tmp_path / "emulator.log", "wb")
            emu = subprocess.Popen(
                mps_cmd(
                    "emulator",
                    "working",
                    "--t-end",
                    str(T_END),
                    "--glitch",
                    f"{GLITCH_T}:jump",
                    "--wait",
                    "120",
                    "--real-time-factor",
                    str(RATE),
                ),
                stdout=emu_log,
                stderr=subprocess.STDOUT,
                env=dict(os.environ, PYTHONUNBUFFERED="1"),
                start_new_session=True,
            )
            assert emu.wait(timeout=240) == 0, (tmp_path / "emulator.log").read_text()
            said = (tmp_path / "emulator.log").read_text()
            sent = int(said.split("published ")[1].split(" measurements")[0])
            assert sent >= 240, said
            # every measurement but the glitch gives one estimate, all received here
            js = resolve("joint_states")
            wait_until(
                lambda: len(listener.get(js)) >= sent - 1, 120.0, "an estimate a measurement taken", 0.05
            )

            def reported():
                for d in listener.get("/diagnostics"):
                    if b"tracking input" in d and b"rejected jump" in d:
                        return d
                return None

            wait_until(reported, 60.0, "the jump reported in /diagnostics", 0.05)
            # a mode command to the node: refused (the press gives its mode), answered
            from std_msgs.msg import String

            status = resolve("~/mode/status")
            mode = listener.node.create_publisher(String, resolve("~/mode"), 10)
            wait_until(lambda: mode.get_subscription_count() > 0, 60.0, "the node's ~/mode", 0.05)
            mode.publish(String(data="engage"))
            wait_until(lambda: listener.get(status), 60.0, "the command's answer", 0.05)
            node.signal(signal.SIGINT)
            assert node.wait(60) == 0, node.log()
            log = node.log()
    finally:
        if emu is not None:
            stop_group(emu)
        listener.close()
    assert "rejected: jump 1" in log, log
    assert f"{sent} measurements received, {sent - 1} estimates published" in log, log
    assert f"tracking: measurement at t = {GLITCH_T}" in log and "jump (1 so far)" in log, log
    got = _recorded(rec)
    measured = got["/press/joint_states"]
    assert len(measured) == sent
    estimates = listener.get(resolve("joint_states"))
    assert len(estimates) == sent - 1
    # each estimate at its measurement's stamp; the glitch's alone has none
    stamps = [_stamp_ns(d) for d in measured]
    missing = sorted(set(stamps) - {_stamp_ns(d) for d in estimates})
    assert len(missing) == 1 and abs(missing[0] * 1e-9 - GLITCH_T) < 2e-3, missing
    # the recording holds what was published, byte for byte, in order (but the alignment a
    # DDS reader adds to a payload: a string's message ends off a 4-byte boundary)
    for t in published:
        name = resolve(t.key)
        if t.key == "/diagnostics":
            # the last status goes out as the node ends, after this test stopped listening
            n = len(listener.get(name))
            assert got[name][:n] == listener.get(name) and n >= 1
            continue
        assert got.get(name, []) == listener.get(name), name
    ack = listener.get(resolve("~/mode/status"))[0]
    assert b'"accepted":false' in ack and b"the node follows a press" in ack
    for key in ("~/process_force/now", "~/process_force/now/sigma", "~/process_force"):
        assert len(got[resolve(key)]) == sent - 1, key
    # the loads' 1-sigma every track_sigma_every (10) estimates, from the first
    assert len(got[resolve("~/foundation/sigma")]) == len(range(0, sent - 1, 10))
    # mps track over the node's recording gives the node's live estimates, bit for bit
    node_est = node_estimates(rec)
    assert len(node_est) == sent - 1
    offline = tracked("working", rec, tmp_path / "tracked.csv", "--strokes", str(tmp_path / "strokes.csv"))
    assert all(offline[t] == est for t, est in node_est.items()), differences(node_est, offline)
    # the strokes' cuts fitted in the node's fitting process, as mps track fits them in its own
    from mps_ros.recording.replay import string_data

    rows = [json.loads(string_data(d)) for d in got.get(resolve("~/strokes"), [])]
    assert rows and all(math.isfinite(r["contact_m"]) for r in rows), rows
    with (tmp_path / "strokes.csv").open() as fh:
        again = list(csv.DictReader(fh))
    for key in ("peak_force_N", "peak_force_sigma_N", "contact_m", "breakthrough_depth_m", "work_J"):
        assert [r[key] for r in rows] == [float(r[key]) for r in again[: len(rows)]], key


def test_an_emulator_with_no_follower_on_its_mode_topic_names_it(ros):
    """The emulator waits for a follower of its measurements and, where it has mode signals to
    send, of its mode topic; where the second is missing it names that topic and how to do
    without it, and publishes nothing."""
    from mps_core.track.measurements import ModeSignal
    from mps_ros.ros.emulator import Samples, publish

    said: list[str] = []
    code = publish(
        [Samples(0.001, 0.0, None, None)],
        [ModeSignal(0.0005, "engage")],
        [],
        topic=f"/emulator_test_{os.getpid()}/joint_states",
        mode_topic=f"/emulator_test_{os.getpid()}/mode",
        subscribers=1,
        wait=0.2,
        log=said.append,
    )
    assert code == 1
    assert len(said) == 1
    assert f"/emulator_test_{os.getpid()}/joint_states and /emulator_test_{os.getpid()}/mode" in said[0]
    assert "--mode-topic ''" in said[0] and "published nothing" in said[0]
