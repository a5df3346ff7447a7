"""Realtime pacing with steps computed ahead, without ROS: nothing is released before its
deadline, the live and the recording sinks (the recording process included) get the same
messages in the same order, and a command is applied at the first step boundary whose deadline
is not before its arrival, the steps computed beyond it dropped: the run is then bit for bit the
run that stepped in time."""

from __future__ import annotations

import json
import statistics
import struct
import threading
import time

import pytest

from mps_ros.run.commands import Command, Gate
from mps_ros.run.runner import Runner
from mps_ros.run.sinks import Sink as RunSink
from mps_ros.run.twin import Twin

DT = 1e-3
T_END = 0.2
RTF = 0.25  # 4 ms of wall time a step: room to be ahead on a slow machine too


class Sink(RunSink):
    """A run's sink that keeps what it was handed, and the wall time of each state."""

    def __init__(self, live: bool, on_clock=None):
        self.live = live
        self.got: list = []  # (key, bytes, t_ns, received)
        self.walls: list = []  # (wall time of emit, t_ns) of the states
        self.on_clock = on_clock

    def emit(self, key, data, t_ns):
        self.got.append((key, data, t_ns, False))
        if key == "/clock":
            self.walls.append((time.perf_counter(), t_ns))
            if self.on_clock is not None:
                self.on_clock(t_ns)

    def emit_all(self, msgs):
        for key, data, t_ns, received in msgs:
            if received:
                self.got.append((key, data, t_ns, True))
            else:
                self.emit(key, data, t_ns)


def _slice_here() -> float:
    """The scheduler slice (ms) this system grants a thread that asks for 0.1 ms (0: none)."""
    from mps_ros.os_threads import short_slice

    box: list = []
    t = threading.Thread(target=lambda: box.append(short_slice(1e-4)))
    t.start()
    t.join()
    return 0.1 if box[0] else 0.0


def _events(sink):
    return [json.loads(d[8:].rstrip(b"\0").decode()) for k, d, *_ in sink.got if k == "~/events"]


def _comparable(sink):
    """The messages sent (not those received) but the diagnostics and the run's start and
    end (pacing, statistics)."""
    out = []
    for key, data, t_ns, received in sink.got:
        if (
            received
            or key == "/diagnostics"
            or (key == "~/events" and (b'"run-start"' in data or b'"run-end"' in data))
        ):
            continue
        out.append((key, data, t_ns, received))
    return out


def test_released_at_deadlines_and_the_same_to_every_sink():
    tw = Twin("press-cycle", dt=DT, t_end=T_END)
    live, rec = Sink(True), Sink(False)
    runner = Runner(tw, sinks=[live, rec], pacing="realtime", real_time_factor=RTF, lead=0.05, warm_up=0.0)
    st = runner.run()
    assert st["steps"] == round(T_END / DT)
    # never before the deadline (t0's at the schedule's start)
    for wall, t_ns in live.walls:
        assert wall >= runner.clocks.wall_start + (t_ns * 1e-9 - tw.t0) / RTF - 1e-6
    assert [m for m in rec.got if not m[3]] == live.got
    stamps = [t for _, t in live.walls]
    assert stamps == sorted(stamps) and len(stamps) == round(T_END / DT) + 1
    # the releasing thread's scheduler slice, as the system granted it (none: 0)
    assert st["release_slice_ms"] == 0.0 or st["release_slice_ms"] == pytest.approx(0.1)


@pytest.mark.parametrize("release_period", [0.0, 4 * DT / RTF])
def test_a_command_comes_back_to_its_boundary_and_the_run_is_the_one_that_stepped_in_time(
    tmp_path, release_period
):
    from mcap.reader import make_reader

    from mps_ros.recording.background import BackgroundRecorder
    from mps_ros.run.sinks import RecordingSink
    from mps_ros.wire.topics import resolve

    K = 60  # the command is sent as step K's state goes out
    tw = Twin("press-cycle", dt=DT, t_end=T_END, scene_commands=False)
    sent = {}

    def on_clock(t_ns):
        if not sent and t_ns >= round(K * DT * 1e9):
            cmd = Command("engage")
            sent["wall"] = cmd.wall
            runner.inbox.put(cmd)

    live, rec = Sink(True, on_clock), Sink(False)
    # the recording process, handed each released step in one call (RecordingSink.emit_all)
    bg = BackgroundRecorder(tmp_path / "paced.mcap")
    runner = Runner(
        tw,
        sinks=[live, rec, RecordingSink(bg)],
        pacing="realtime",
        real_time_factor=RTF,
        lead=0.05,
        warm_up=0.0,
        release_period=release_period,
    )
    taken = []  # the wall time the stepping thread took the command from the inbox
    drain = runner.inbox.drain

    def drain_seen():
        got = drain()
        if got:
            taken.append(time.perf_counter())
        return got

    runner.inbox.drain = drain_seen
    st = runner.run()
    bg.finish()
    with open(tmp_path / "paced.mcap", "rb") as f:
        recorded = [
            (ch.topic, bytes(m.data), m.log_time)
            for _, ch, m in make_reader(f).iter_messages(log_time_order=False)
        ]
    assert recorded == [(resolve(k), d, t) for k, d, t, _ in rec.got]
    assert st["commands_accepted"] == 1
    acks = [json.loads(d[8:].rstrip(b"\0").decode()) for k, d, *_ in live.got if k == "~/mode/status"]
    # the boundary: the first step whose deadline is not before the command's arrival where
    # the run keeps its schedule; where it runs behind (a busy machine), the last step
    # computed as the command came (the one going out, or one after it), which is earlier;
    # never before the step that was going out when it was sent
    deadline = [runner.clocks.wall_start + k * DT / RTF for k in range(round(T_END / DT) + 1)]
    last = next(k for k, d in enumerate(deadline) if d >= sent["wall"])
    # a machine so busy that the stepping thread takes the command only after that step has
    # gone out: the first step not yet out then
    out_by_then = [round(t_ns * 1e-9 / DT) for w, t_ns in live.walls if w <= taken[0]]
    last = max(last, max(out_by_then, default=-1) + 1)
    j = round(acks[0]["t"] / DT)
    assert abs(acks[0]["t"] - tw.time_of(j)) < 1e-12 and K <= j <= last, (acks, j, last)
    # where the run was ahead of its schedule it came back over steps computed ahead, which
    # nobody got (a machine too busy to compute ahead has none to come back over): either
    # way the run is the one below
    # the same run as fast as possible, the command applied at that boundary
    tw2 = Twin("press-cycle", dt=DT, t_end=T_END, scene_commands=False)

    box: list = []  # the command sent once

    def at_j(t_ns):
        if not box and t_ns >= round(j * DT * 1e9):
            box.append(1)
            afap.inbox.put(Command("engage"))

    same = Sink(True, at_j)
    afap = Runner(tw2, sinks=[same], pacing="as_fast_as_possible", warm_up=0.0)
    afap.run()
    assert _comparable(rec) == _comparable(live)
    assert ("~/mode", b"\x00\x01\x00\x00\x07\x00\x00\x00engage\x00", round(j * DT * 1e9), True) in rec.got
    assert _comparable(live) == _comparable(same)
    kinds = [e["kind"] for e in _events(live)]
    assert "latch-closes" in kinds


def test_a_release_period_sends_the_steps_due_together_never_early_and_the_same_messages():
    """release_period = 4 steps' periods: the releasing thread wakes about once per 4 steps
    and sends those due; none before its deadline, each at most 3 periods after it (and the
    machine's delay); the messages are those of a run that sends each step at its deadline.
    The kernels are built before the clock starts (``warm_up``): a step computed late goes out
    late in either run, which is not what is measured here."""
    period = DT / RTF
    runs = {}
    for rp in (0.0, 4 * period):
        tw = Twin("press-cycle", dt=DT, t_end=T_END)
        live = Sink(True)
        runner = Runner(
            tw,
            sinks=[live],
            pacing="realtime",
            real_time_factor=RTF,
            lead=0.05,
            warm_up=T_END,
            release_period=rp,
        )
        runner.run()
        late = [
            wall - (runner.clocks.wall_start + (t_ns * 1e-9 - tw.t0) / RTF) for wall, t_ns in live.walls[1:]
        ]
        # the wake-ups: states sent less than a fifth of a period apart went out together
        walls = [w for w, _ in live.walls[1:]]
        wakes = 1 + sum(1 for a, b in zip(walls, walls[1:]) if b - a > 0.2 * period)
        runs[rp] = (_comparable(live), late, wakes)
    (plain, late0, wakes0), (grouped, late4, wakes4) = runs.values()
    n = round(T_END / DT)
    assert grouped == plain
    assert min(late0) > -1e-6 and min(late4) > -1e-6
    assert wakes4 < 0.4 * n  # about one per four steps ...
    assert wakes0 > 2 * wakes4  # ... against one a step (a busy machine

    #                                             merges a few)
    # the first of four goes out 3 periods late, the last at its deadline; the machine's own
    # delays come on top of that: as much as they delayed the run that sends each step at its
    # deadline (its own lateness, measured the same way just before), with room for a busy
    # machine's moments
    def p(late, q):
        return sorted(late)[int(q * len(late))]

    assert 1.0 * period < statistics.median(late4) < 3 * period + p(late0, 0.5) + 0.02
    assert p(late4, 0.9) < 3 * period + p(late0, 0.9) + 0.05


def test_commands_already_waiting_are_applied_at_the_start():
    tw = Twin("press-cycle", dt=DT, t_end=0.02, scene_commands=False)
    live = Sink(True)
    runner = Runner(tw, sinks=[live], pacing="realtime", real_time_factor=1.0, lead=0.05, warm_up=0.0)
    runner.inbox.put(Command("engage"))
    runner.run()
    acks = [json.loads(d[8:].rstrip(b"\0").decode()) for k, d, *_ in live.got if k == "~/mode/status"]
    assert [(a["command"], a["t"], a["accepted"]) for a in acks] == [("engage", 0.0, True)]


def test_the_stepping_loop_writes_the_run_in_one_process_byte_for_byte_in_bursts():
    """The stepping process's loop (:class:`~mps_ros.run.stepping._Ahead`, here in this
    process, its frames down a real pipe and read back): the steps' messages, in order, are
    those of the same run stepped in one process as fast as possible, byte for byte (the
    diagnostics and the run's start and end aside); their deadlines keep the schedule; and it
    sleeps between bursts of steps, not before each one."""
    import collections
    import marshal
    import os

    from mps_ros.run.stepping import Hold, _Ahead
    from mps_ros.wire.pipe import Frame, FrameReader, FrameWriter

    tw = Twin("press-cycle", dt=DT, t_end=T_END)
    runner = Runner(tw, pacing="realtime", real_time_factor=RTF, lead=0.05, command_delay=0.0, warm_up=0.0)
    runner.prepare()
    r, w = os.pipe()
    frames: list = []

    def read():
        reader = FrameReader(r)
        while got := reader.read():
            frames.extend(got)

    reading = threading.Thread(target=read)
    reading.start()

    class Wake(threading.Event):
        naps = 0

        def wait(self, timeout=None):
            Wake.naps += 1
            return super().wait(timeout)

    loop = _Ahead(runner, FrameWriter(w), collections.deque(), Wake(), Hold())
    try:
        loop.run()
    finally:
        os.close(w)
        reading.join(30)
        os.close(r)
    entries = [marshal.loads(p) for kind, p in frames if kind == Frame.MESSAGES]
    stepped = Sink(True)
    for _k, _gen, _deadline, _state, _structure, _refusals, msgs in entries:
        stepped.emit_all(msgs)
    same = Sink(True)
    Runner(Twin("press-cycle", dt=DT, t_end=T_END), sinks=[same], warm_up=0.0).run()
    assert _comparable(stepped) == _comparable(same)
    ks = [e[0] for e in entries if e[3]]
    assert ks == list(range(round(T_END / DT) + 1))
    deadlines = [e[2] for e in entries]
    assert deadlines == sorted(deadlines)
    # bursts: a refill is half the lead here (no command delay), some 12 steps at 4 ms a step
    assert 0 < Wake.naps <= len(ks) / 5, Wake.naps


def test_publishing_every_nth_step_releases_those_and_every_event():
    tw = Twin("press-cycle", dt=DT, t_end=0.1)
    live = Sink(True)
    runner = Runner(
        tw, sinks=[live], pacing="realtime", real_time_factor=2.0, lead=0.05, publish_every=10, warm_up=0.0
    )
    runner.run()
    stamps = [t for _, t in live.walls]
    assert stamps == [round(k * DT * 1e9) for k in range(0, 101, 10)]
    kinds = [e["kind"] for e in _events(live)]
    assert kinds[0] == "run-start" and kinds[-1] == "run-end" and "stop-release" in kinds


def test_a_solver_that_cannot_come_back_runs_one_step_ahead_and_commands_apply_at_once():
    from dataclasses import replace

    from mps_core import load_scene

    scene = load_scene("press-cycle").with_overrides(solver="radau", dt=DT, t_end=0.05)
    tw = Twin(replace(scene, commands=()), scene_commands=False)
    assert not tw.rewindable
    sent = {}

    def on_clock(t_ns):
        if not sent and t_ns >= round(0.02 * 1e9):
            sent["t"] = t_ns
            runner.inbox.put(Command("engage"))

    live = Sink(True, on_clock)
    runner = Runner(tw, sinks=[live], pacing="realtime", real_time_factor=0.5, lead=0.05, warm_up=0.0)
    st = runner.run()
    assert st["steps_recomputed"] == 0 and st["commands_accepted"] == 1
    acks = [json.loads(d[8:].rstrip(b"\0").decode()) for k, d, *_ in live.got if k == "~/mode/status"]
    # applied at the last step computed: the one whose state was going out or the next, a few
    # later where the machine is busy and the stepping thread catches up
    assert sent["t"] * 1e-9 <= acks[0]["t"] <= sent["t"] * 1e-9 + 5.5 * DT


def test_a_live_sink_that_fails_ends_the_run_and_the_rest_is_still_handed_over():
    class Broken(Sink):
        def emit(self, key, data, t_ns):
            if t_ns >= round(0.01 * 1e9):
                raise OSError("the network is gone")
            super().emit(key, data, t_ns)

    tw = Twin("press-cycle", dt=DT, t_end=0.2)
    live, rec = Broken(True), Sink(False)
    runner = Runner(tw, sinks=[live, rec], pacing="realtime", real_time_factor=RTF, lead=0.05, warm_up=0.0)
    st = runner.run()
    assert runner.stop_reason == "error" and "the network is gone" in runner.error
    assert st["steps"] < round(0.2 / DT)
    ends = [e for e in _events(rec) if e["kind"] == "run-end"]
    assert len(ends) == 1 and ends[0]["reason"] == "error"


class _Publishers(RunSink):
    """A split run's live side (the ROS publishers): what goes out, in order."""

    def __init__(self, on_clock):
        self.got: list = []
        self.on_clock = on_clock

    def emit_all(self, msgs):
        import struct

        n = 0
        for key, data, _t, received in msgs:
            if received:
                continue
            n += 1
            self.got.append((key, data))
            if key == "/clock":
                sec, nsec = struct.unpack_from("<iI", data, 4)
                self.on_clock(sec * 1_000_000_000 + nsec)
        return n


class _Recorder(RunSink):
    """A split run's other sink: each released step's messages, as handed over."""

    def __init__(self):
        self.got: list = []

    def emit_all(self, msgs):
        self.got.extend(tuple(m) for m in msgs)


REFUSED = {
    "disengage": [("disengage", False, "the press is not engaged")],
    "engage, engage": [("engage", True, None), ("engage", False, "already engaging")],
}


@pytest.mark.parametrize("words", list(REFUSED))
@pytest.mark.parametrize("split", [False, True], ids=["one process", "stepping process"])
def test_a_command_the_machine_refuses_is_answered_at_its_boundary_and_redoes_no_step(split, words):
    """A command the machine refuses at its boundary (``disengage`` while the press is not
    engaged; a second ``engage`` right after the first, while that one is being applied) is
    answered where its boundary's step says so, no step computed ahead is redone for it, and
    the run is the one that stepped in time."""
    from mps_ros.run.releasing import SteppingProcess
    from mps_ros.wire.topics import OUTPUTS

    K = 60
    words = words.split(", ")
    tw = Twin("press-cycle", dt=DT, t_end=T_END, scene_commands=False)
    sent = {}

    def on_clock(t_ns):
        if not sent and t_ns >= round(K * DT * 1e9):
            sent["t_ns"] = t_ns
            for w in words:  # one after the other, before any answer is read
                runner.inbox.put(Command(w))

    if split:
        rec = _Recorder()
        spec = {
            "scene": "press-cycle",
            "twin": dict(dt=DT, t_end=T_END, scene_commands=False, outputs=list(OUTPUTS)),
            "runner": dict(real_time_factor=RTF, lead=0.05, warm_up=0.0),
            "grid": [tw.t0, tw.t_end, tw.n],
        }
        runner = SteppingProcess(spec, _Publishers(on_clock), lambda *a: None, Gate(), 0)
        runner.sinks.append(rec)
        try:
            st = runner.run()
        finally:
            runner.close()
        got = rec.got
        # refused once: in the node's process where its boundary's step was held (the usual
        # case), else by the stepping process at that boundary (a machine too busy for the
        # node to hold that step yet: the steps computed beyond it are then redone); st
        # counts both
        assert runner.commands_refused <= 1
        in_the_node = runner.commands_refused == 1
        # the publishing thread (this process's) asked for a short slice: as granted here
        assert st["release_slice_ms"] == pytest.approx(_slice_here())
    else:
        live = Sink(True, on_clock)
        runner = Runner(tw, sinks=[live], pacing="realtime", real_time_factor=RTF, lead=0.05, warm_up=0.0)
        st = runner.run()
        got = live.got
        in_the_node = True
    expected = REFUSED[", ".join(words)]
    assert st["commands_refused"] == 1
    assert st["commands_accepted"] == sum(1 for *_w, ok, _r in expected if ok)
    if len(words) == 1 and in_the_node:
        assert st["steps_recomputed"] == 0
    acks = [json.loads(d[8:].rstrip(b"\0").decode()) for k, d, *_ in got if k == "~/mode/status"]
    assert [(a["command"], a["accepted"], a["reason"]) for a in acks] == expected
    # each at a step boundary, the first at the step whose state was going out or one of the
    # next, the second at the same or a later one (its own arrival: later on a busy machine)
    times = [a["t"] for a in acks]
    assert times == sorted(times) and sent["t_ns"] * 1e-9 <= times[0] + 1e-12
    for t in times:
        assert min(abs(t - tw.time_of(k)) for k in range(tw.n + 1)) < 1e-12
    # the same run as fast as possible, each command given at its boundary, in an
    # interpreter as fresh as the stepping process (a reaction kernel is generated at the
    # first state that needs it in a process, and one generated elsewhere can differ in the
    # last bit)
    done = Sink(True)
    done.got = list(got)
    schedule = [(round(a["t"] * 1e9), a["command"]) for a in acks]
    assert _comparable(done) == _afap_with(schedule, fresh=split)


def test_as_fast_as_possible_in_a_stepping_process_each_command_at_the_last_step_released(tmp_path):
    """As fast as possible in a stepping process of its own (the node's way where the twin can
    come back to a step): the steps go out as they come; a command is applied at the boundary
    of the last step released when it came, its answer right after that step's messages (the
    steps computed beyond it are computed again, or, where the machine refuses it there, stand);
    the run is bit for bit the one given each command at that boundary in one process, and the
    recorder gets what was published, in the same order; the recording process too, handed
    the steps as the stepping process encoded them and the answers made here as lists."""
    from mcap.reader import make_reader

    from mps_ros.recording.background import BackgroundRecorder
    from mps_ros.run.releasing import SteppingProcess
    from mps_ros.run.sinks import RecordingSink
    from mps_ros.wire.topics import OUTPUTS, resolve

    plan = {40: "engage", 41: "engage", 150: "disengage"}  # at the step whose /clock went out
    tw = Twin("press-cycle", dt=DT, t_end=T_END, scene_commands=False)
    sent = []

    def on_clock(t_ns):
        k = round(t_ns * 1e-9 / DT)
        if k in plan and k not in [j for j, _ in sent]:
            sent.append((k, plan[k]))
            runner.inbox.put(Command(plan[k]))

    rec = _Recorder()
    live = _Publishers(on_clock)
    spec = {
        "scene": "press-cycle",
        "twin": dict(dt=DT, t_end=T_END, scene_commands=False, outputs=list(OUTPUTS)),
        "runner": dict(warm_up=0.0),
        "grid": [tw.t0, tw.t_end, tw.n],
        "afap": True,
    }
    runner = SteppingProcess(spec, live, lambda *a: None, Gate(), 0)
    runner.sinks.append(rec)
    bg = BackgroundRecorder(tmp_path / "split.mcap")
    runner.sinks.append(RecordingSink(bg))
    try:
        st = runner.run()
    finally:
        runner.close()
        bg.finish()
    assert runner.error is None and st["steps"] == tw.n
    assert st["real_time_factor"] > 0 and "latency_p50_ms" not in st
    with open(tmp_path / "split.mcap", "rb") as f:
        recorded = [
            (ch.topic, bytes(m.data), m.log_time)
            for _, ch, m in make_reader(f).iter_messages(log_time_order=False)
        ]
    assert recorded == [(resolve(k), d, t) for k, d, t, _ in rec.got]
    assert [k for k, _ in sent] == sorted(plan)
    acks = [json.loads(d[8:].rstrip(b"\0").decode()) for k, d, *_ in rec.got if k == "~/mode/status"]
    # each at the step whose /clock it came on: the last step released then
    assert [(round(a["t"] / DT), a["command"]) for a in acks] == sorted(plan.items())
    assert [(a["accepted"], a["reason"]) for a in acks[:2]] == [(True, None), (False, "already engaging")]
    assert st["commands_accepted"] == sum(a["accepted"] for a in acks)
    assert [(k, d) for k, d, _t, received in rec.got if not received] == live.got
    done = Sink(True)
    done.got = list(rec.got)
    schedule = [(round(a["t"] * 1e9), a["command"]) for a in acks]
    assert _comparable(done) == _afap_with(schedule, fresh=True)


def test_as_fast_as_possible_steps_on_past_what_it_may_compute_ahead():
    """A run as fast as possible longer than the steps its stepping process may compute past the
    last step released: told of the releases now and then (``TOLD_EVERY``, fewer than
    ``_Ahead.AHEAD``), it steps on to the end, every step released once, in order."""
    from mps_ros.run.releasing import TOLD_EVERY, SteppingProcess
    from mps_ros.run.stepping import _Ahead

    assert 0 < TOLD_EVERY < _Ahead.AHEAD
    n = 3 * _Ahead.AHEAD + 7
    tw = Twin("press-cycle", dt=DT, t_end=n * DT, scene_commands=False)
    live = _Publishers(lambda t_ns: None)
    spec = {
        "scene": "press-cycle",
        "twin": dict(dt=DT, t_end=n * DT, scene_commands=False, outputs=["joint_states", "clock"]),
        "runner": dict(warm_up=0.0),
        "grid": [tw.t0, tw.t_end, tw.n],
        "afap": True,
    }
    runner = SteppingProcess(spec, live, lambda *a: None, Gate(), 0)
    try:
        st = runner.run()
    finally:
        runner.close()
    assert runner.error is None and st["steps"] == n
    clocks = [struct.unpack_from("<iI", d, 4) for k, d in live.got if k == "/clock"]
    assert [round((sec + ns * 1e-9) / DT) for sec, ns in clocks] == list(range(n + 1))


def _afap_with(schedule: list, fresh: bool) -> list:
    """:func:`_comparable` of the run as fast as possible with each command of ``schedule``
    ((step time ns, word), in order) given at its step time (``fresh``: in a new
    interpreter, this same function)."""
    if fresh:
        import os
        import pickle
        import subprocess
        import sys

        code = (
            f"import pickle, sys; sys.path.insert(0, {os.path.dirname(__file__)!r}); "
            "from test_paced_runner import _afap_with; "
            f"sys.stdout.buffer.write(pickle.dumps(_afap_with({schedule!r}, False)))"
        )
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, check=True, timeout=300)
        return pickle.loads(out.stdout)

    box: set = set()  # the commands sent (each once)

    def at_j(t_ns):
        for i, (j_ns, word) in enumerate(schedule):
            if i not in box and t_ns >= j_ns:
                box.add(i)
                afap.inbox.put(Command(word))

    same = Sink(True, at_j)
    afap = Runner(
        Twin("press-cycle", dt=DT, t_end=T_END, scene_commands=False),
        sinks=[same],
        pacing="as_fast_as_possible",
        warm_up=0.0,
    )
    afap.run()
    return _comparable(same)


def test_the_pacing_status_warns_while_deadlines_are_missed_and_clears_after():
    """/diagnostics' pacing status is WARN where deadlines were missed since the last message,
    OK again once a period passes without; its hardware_id names the scene's press."""
    tw = Twin("press-cycle", dt=DT, t_end=T_END)
    runner = Runner(tw, sinks=[Sink(True)], pacing="realtime", warm_up=0.0)
    sent = []
    runner.emit = lambda key, msg, t_ns: sent.append(msg)  # the message before encoding
    said = []
    for misses in (0, 3, 3, 5, 5, 11, 11):  # ten steps a report
        tw.k += 10
        runner.measurements.misses = misses
        runner.publish_diagnostics(0)
        status = sent[-1]["status"][0]
        assert status["name"] == "press_twin: pacing"
        said.append(status["level"])
    # WARN where deadlines were missed since the last report, ERROR where more than half of
    # its steps were late (it cannot keep up), OK again after
    assert said == [0, 1, 0, 1, 0, 2, 0]
    assert status["hardware_id"] == "mps press-cycle"
    assert "0 deadline misses since the last report, 11 in all" in status["message"]
    assert "cannot keep up: 6 of 10 steps late" in sent[-2]["status"][0]["message"]


def test_the_commands_status_warns_of_floods_and_losses_and_clears_after():
    """/diagnostics' commands status counts what was accepted, refused (as floods) and lost,
    the node's process's own counts included (a split run's gate answers there); WARN where a
    flood was refused or a command lost since the last report."""
    tw = Twin("press-cycle", dt=DT, t_end=T_END, scene_commands=False)
    runner = Runner(tw, sinks=[Sink(True)], pacing="realtime", warm_up=0.0, gate=Gate(burst=2, rate=1e-9))
    sent = []
    runner.emit = lambda key, msg, t_ns: sent.append(msg)

    def status():
        runner.publish_diagnostics(0)
        st = next(x for x in sent[-1]["status"] if x["name"] == "press_twin: commands")
        return st["level"], {v["key"]: v["value"] for v in st["values"]}

    assert status() == (
        0,
        {
            "commands_accepted": "0",
            "commands_refused": "0",
            "commands_refused_as_floods": "0",
            "commands_lost": "0",
        },
    )
    for w in ("engage", "disengage", "engage", "stop"):  # the last two: a flood
        runner.inbox.put(Command(w))
    runner.take_commands()
    level, v = status()
    assert level == 1 and v["commands_refused_as_floods"] == "2", v
    assert status()[0] == 0
    runner.commands.elsewhere = (4, 3, 0)  # the node's process: 4 refused there, 3 as floods
    level, v = status()
    assert level == 1 and (v["commands_refused"], v["commands_refused_as_floods"]) == ("6", "5")
    runner.commands_lost = 1
    level, v = status()
    assert level == 1 and v["commands_lost"] == "1"
    assert status()[0] == 0


def test_a_run_as_fast_as_possible_pauses_and_goes_on_the_same():
    """pause() holds the run at its step (the node's deactivate): nothing goes out but the
    diagnostics, which say it is paused (STALE), and a command is taken at that step; resume()
    goes on, and the run is the one never paused but for that command."""
    import threading

    from twin_probe import wait_until

    def run(pause_at: int | None):
        tw = Twin("press-cycle", dt=DT, t_end=T_END, scene_commands=False)
        sink = Sink(True)
        runner = Runner(tw, sinks=[sink], pacing="as_fast_as_possible", diagnostics_period=0.01)
        box = {}

        def on_clock(t_ns):
            if pause_at is not None and t_ns == pause_at * 1_000_000 and not box:
                box["why"] = runner.pause()
                box["n"] = len(sink.got)

        sink.on_clock = on_clock
        thread = threading.Thread(target=runner.run)
        thread.start()
        if pause_at is not None:

            def stale():
                return (
                    [
                        d
                        for k, d, *_ in sink.got[box["n"] :]
                        if k == "/diagnostics" and b"paused at t = 0.030000 s" in d
                    ]
                    if box
                    else []
                )

            wait_until(lambda: len(stale()) >= 2, 30, "two STALE statuses")
            assert box["why"] is None
            # the paused step's own messages, then nothing but diagnostics
            assert all(t == pause_at * 1_000_000 for _k, _d, t, _r in sink.got[box["n"] :])
            assert sink.got[-1][0] == "/diagnostics"
            runner.inbox.put(Command("engage"))
            wait_until(
                lambda: any(k == "~/mode/status" for k, *_ in sink.got[box["n"] :]),
                30,
                "the engage answered while paused",
            )
            stepped = []
            assert runner.step_paused(stepped.append) is None  # ~/step: one step
            wait_until(lambda: stepped, 30, "the step taken while paused")
            assert stepped == [pytest.approx((pause_at + 1) * DT, abs=1e-12)]
            assert max(t for _k, _d, t, _r in sink.got) == (pause_at + 1) * 1_000_000
            runner.resume()
        else:
            runner.inbox.put(Command("engage"))  # taken at the first boundary: step 0
        thread.join(60)
        assert not thread.is_alive()
        return [(k, d, t) for k, d, t, _r in sink.got if k in ("joint_states", "~/foundation")]

    paused = run(30)
    ack_step = 30
    plain_twin = Twin("press-cycle", dt=DT, t_end=T_END, scene_commands=False)
    sink = Sink(True)
    runner = Runner(plain_twin, sinks=[sink], pacing="as_fast_as_possible")
    # the same run never paused: the engage at step 30, from its first boundary after it
    sink.on_clock = lambda t_ns: runner.inbox.put(Command("engage")) if t_ns == ack_step * 1_000_000 else None
    runner.run()
    plain = [(k, d, t) for k, d, t, _r in sink.got if k in ("joint_states", "~/foundation")]
    assert paused == plain
    assert len(paused) == 2 * (round(T_END / DT) + 1)


def test_an_overload_turns_the_pacing_status_warn_and_it_clears_after():
    """A sink that holds the stepping thread (a stalled disk, the machine busy) until the
    deadline of a step 0.2 simulated s after the one it holds has passed makes the steps due
    meanwhile late: the pacing status says so (WARN, or ERROR where most of a window's steps
    were late), then OK again once the run has caught up."""
    from twin_probe import wait_until

    class Stall(RunSink):
        stalled = False

        def emit_all(self, msgs):
            t_ns = msgs[0][2]
            if t_ns >= 100_000_000 and not self.stalled:
                self.stalled = True
                due = runner.clocks.wall_start + (t_ns * 1e-9 + 0.2) / runner.rtf
                wait_until(
                    lambda: time.perf_counter() >= due,
                    30,
                    "the deadline 0.2 simulated s past the stalled step",
                )

    tw = Twin("press-cycle", dt=DT, t_end=0.8, scene_commands=False)
    runner = Runner(
        tw,
        sinks=[Sink(True), Stall()],
        pacing="realtime",
        real_time_factor=0.5,
        diagnostics_period=0.05,
        warm_up=0.0,
    )
    levels = []
    emit = runner.emit

    def keep(key, msg, t_ns):
        if key == "/diagnostics":
            levels.append(next(s["level"] for s in msg["status"] if s["name"].endswith(": pacing")))
        emit(key, msg, t_ns)

    runner.emit = keep
    runner.run()
    assert runner.measurements.misses > 0
    last_trouble = max(i for i, lv in enumerate(levels) if lv != 0)
    assert levels[last_trouble] in (1, 2)
    assert 0 in levels[last_trouble + 1 :], levels
