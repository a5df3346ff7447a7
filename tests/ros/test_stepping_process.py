"""The live node's stepping process (mps_ros.run.stepping): its frames, a SIGKILL of it mid-run (the
node ends with one line naming it, nonzero; the recording is finished and reads back; no
process is left), and the real-time scheduling it asks for by default (granted, or one warning
where the system refuses it, and the run goes on)."""

from __future__ import annotations

import os
import re
import resource
import shutil
import signal
import subprocess
import threading
from types import SimpleNamespace

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("rosbags")

from twin_probe import Listener, NodeProcess, ns, wait_until

from mps_ros.bench.processes import _children as _kids
from mps_ros.bench.processes import _cmdline
from mps_ros.run.stepping import Hold, _Ahead
from mps_ros.wire.pipe import FrameReader, FrameWriter

DT = 1e-3


def test_frames_cross_a_pipe_whole_and_in_order():
    r, w = os.pipe()
    out, back = FrameWriter(w), FrameReader(r)
    sent = [(b"M", os.urandom(n)) for n in (0, 1, 5, 70_000, 3)]

    def write():
        for kind, payload in sent:
            out.frame(kind, payload)
        os.close(w)

    t = threading.Thread(target=write)
    t.start()
    got = []
    while True:
        frames = back.read()
        if not frames:
            break
        got += frames
    t.join()
    os.close(r)
    assert got == sent


def test_a_killed_stepping_process_ends_the_node_with_one_line(ros, tmp_path):
    from rosbags.highlevel import AnyReader

    rec = tmp_path / "cut.mcap"
    params = dict(
        pacing="realtime",
        dt=DT,
        t_end=30.0,
        recording=str(rec),
        recording_flush_period=0.2,
        wait_for_subscribers=1,
        wait_timeout=30.0,
        outputs="[joint_states, clock, events]",
    )
    lis = Listener(keys=["joint_states", "/clock", "~/events", "~/mode/status"])
    try:
        with NodeProcess(tmp_path, params, name="killed") as node:
            lis.wait_for(lambda: (lis.clock() or 0.0) >= 0.5, 60, "/clock >= 0.5 s")
            stepper = [k for k in _kids(node.pid) if "mps_ros.run.stepping" in _cmdline(k)]
            assert len(stepper) == 1, _kids(node.pid)
            os.kill(stepper[0], signal.SIGKILL)
            t_kill = lis.clock()
            rc = node.wait(60)
            log = node.log()

            # no process of the node's is left: its group is empty once it has exited
            def group_gone():
                try:
                    os.killpg(node.pid, 0)
                except ProcessLookupError:
                    return True
                return False

            lis.wait_for(group_gone, 30, "the node's process group to be gone", poll=0.02)
        got = lis.get("joint_states")
    finally:
        lis.close()
    assert rc != 0, log
    lines = [ln for ln in log.splitlines() if "stepping process" in ln and "killed" in ln]
    assert len(lines) == 1, log
    assert f"pid {stepper[0]}" in lines[0] and "SIGKILL" in lines[0]
    assert "Traceback" not in log
    # the recording process finished the file: it reads back without recovery, in order, up
    # to a step near the kill, and what it holds is what the subscriber received
    with AnyReader([rec]) as r:
        conn = [c for c in r.connections if c.topic == "/joint_states"]
        stamps = [t for _, t, _ in r.messages(connections=conn)]
    assert stamps == sorted(stamps) and len(stamps) >= 400
    assert stamps[-1] * 1e-9 >= t_kill - 0.3
    received = {ns(m.header.stamp) for m in got}
    assert {s for s in stamps if s <= max(received)} <= received


def _refusing_prefix() -> list[str] | None:
    """A command prefix under which SCHED_FIFO is refused: as root, without CAP_SYS_NICE in
    the bounding set (setpriv); as another user, none where the rtprio limit is already 0."""
    if os.geteuid() != 0 and resource.getrlimit(resource.RLIMIT_RTPRIO)[0] == 0:
        return []
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        return None
    probe = subprocess.run(
        [
            setpriv,
            "--bounding-set=-sys_nice",
            "python3",
            "-c",
            "import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))",
        ],
        capture_output=True,
    )
    return [setpriv, "--bounding-set=-sys_nice"] if probe.returncode != 0 else None


def test_fifo_is_asked_for_by_default_and_a_refusal_is_one_warning(tmp_path):
    prefix = _refusing_prefix()
    if prefix is None:
        pytest.skip("no way here to run a process that the system refuses SCHED_FIFO")
    params = dict(pacing="realtime", dt=DT, t_end=0.05, recording="none")
    node = NodeProcess(tmp_path, params, name="refused")
    node.cmd = [*prefix, *node.cmd]
    with node:
        rc = node.wait(60)
        log = node.log()
    assert rc == 0, log
    warnings = [ln for ln in log.splitlines() if "SCHED_FIFO refused" in ln]
    assert len(warnings) == 1, log
    assert "realtime_priority 40" in warnings[0] and "rtprio" in warnings[0]
    assert "realtime priority 0" in log and "run ended at t = 0.05 s" in log


def test_fifo_where_the_system_allows_it(tmp_path):
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
    except OSError:
        pytest.skip("SCHED_FIFO is not allowed here")
    finally:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    params = dict(pacing="realtime", dt=DT, t_end=30.0, recording="none", realtime_priority=10)
    granted = "stepping process and publishing thread: SCHED_FIFO, priority 10"
    with NodeProcess(tmp_path, params, name="fifo") as node:
        wait_until(lambda: granted in node.log() or not node.alive(), 60, "the node's line on its priority")
        assert granted in node.log(), node.log()
        # the node's process: its publishing (main) thread at 10, every other one (rclpy's
        # executor, the middleware's) one below, so that none holding what a release needs
        # waits behind an ordinary process
        policies = {}
        for tid in map(int, os.listdir(f"/proc/{node.pid}/task")):
            try:
                policies[tid] = (os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority)
            except OSError:
                pass  # a thread that ended meanwhile
        node.signal(signal.SIGTERM)
        rc = node.wait(60)
        log = node.log()
    assert rc == 0, log
    assert policies.pop(node.pid) == (os.SCHED_FIFO, 10)
    assert len(policies) >= 3 and set(policies.values()) == {(os.SCHED_FIFO, 9)}, policies
    assert "realtime priority 10" in log


def test_a_node_that_cannot_keep_real_time_says_so_once(tmp_path):
    """Ten million steps a wall second asked (0.1 ms steps at x1000): no machine steps that in
    Python, however fast; the node says so once, with the rate it measured, and runs on to
    its end."""
    params = dict(pacing="realtime", dt=1e-4, real_time_factor=1000.0, t_end=0.5, recording="none")
    with NodeProcess(tmp_path, params, name="slow") as node:
        rc = node.wait(120)
        log = node.log()
    warnings = [ln for ln in log.splitlines() if "cannot keep real time" in ln]
    assert rc == 0 and len(warnings) == 1, log
    assert "where real time needs 10000000" in warnings[0] and "larger dt" in warnings[0]
    said = re.search(
        r"(\d+) steps to t = \S+ s took (\S+) wall s, about (\d+) steps a wall second", warnings[0]
    )
    assert said, warnings[0]
    steps, wall, rate = int(said[1]), float(said[2]), int(said[3])
    assert 0 < steps <= 5000 and abs(rate - steps / wall) <= 0.01 * rate + 1
    assert "run ended at t = 0.5 s after 5000 steps" in log


class _Said:
    def __init__(self):
        self.lines = []

    def log(self, level, text):
        self.lines.append((level, text))


def _judged(steps: int, wall: float, dt: float = 1e-3, rtf: float = 1.0, paused_s: float = 0.0):
    """What a stepping process says of ``steps`` made in ``wall`` seconds (no node: the
    judgement alone, on made-up clocks)."""
    ahead = _Ahead.__new__(_Ahead)
    ahead.runner = runner = _Said()
    runner.rtf = rtf
    ahead.twin = SimpleNamespace(dt=dt, t=steps * dt)
    ahead.hold = Hold()
    ahead.hold.shift = paused_s
    ahead.k0, ahead.begun, ahead.warned = 0, 100.0, False
    ahead._judge_rate(steps, 100.0 + wall + paused_s, late=False)
    return runner.lines


def test_a_run_that_falls_a_third_behind_is_said_with_the_rate_it_made():
    # 1 kHz asked, 630 steps in a wall second made (the 2.5 of 4 of a slow machine)
    (said,) = _judged(630, 1.0)
    assert said[0] == "warn" and "about 630 steps a wall second where real time needs 1000" in said[1]
    (said,) = _judged(2500, 1.0, dt=1e-4, rtf=4.0)
    assert "about 2500 steps a wall second where real time needs 40000" in said[1]
    # keeping up, or within a tenth of it (a busy moment), or a pause (not counted): nothing said
    assert _judged(1000, 1.0) == [] and _judged(950, 1.0) == [] and _judged(1000, 1.0, paused_s=5.0) == []
