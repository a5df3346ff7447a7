"""Benchmarks of the node (not tests): what the README reports, measured on this machine.

    .venv/bin/python -m mps_ros.bench [--steps 10000] [--json FILE]

1. **realtime, 1 kHz**: press-cycle at dt = 1 ms, realtime x1, recording on, for ``--steps``
   steps, with an external subscriber in another process taking every topic (reliable): the
   node's achieved real-time factor, step compute time p50/p99, latency (publication after the
   step's deadline) p50/p99, deadline misses per 10^4 steps, the messages a second the
   subscriber received, and the node's CPU a step: its own count (its process's CPU time over
   the run's steps) and, from outside, its user + system time in ``/proc`` over the wall time.
2. **as fast as possible**: the same scene and step, no subscriber, recording on and off: the
   largest real-time factor; and ``mps record`` (no ROS at all) for comparison.

``soak``: the realtime run for ``--minutes`` (memory, drift, messages lost); ``table``: the node
as fast as possible by outputs; ``wakeup``: the CPU one wake-up from a 1 ms timed wait costs a
thread on this machine (no ROS); ``writer``: the recording's MCAP writer against the ``mcap``
library's, CPU a message side by side (no ROS). Messages lost are counted by topic too: the recording holds
every message the node published, the subscriber counts what it received on each topic.
``--keep DIR`` keeps the realtime or soak run's logs (the node's, the subscriber's) and figures
there, which a run in the temporary folder otherwise takes with it.

Every process stays on loopback (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST unless set) with ROS
logs in a temporary folder; give it a ROS_DOMAIN_ID of its own. ``probe`` is the subscriber's
entry point (``python -m mps_ros.bench probe``). ``MPS_BENCH_NODE_PREFIX``, where set, is put
before the node's command line (split at spaces): a profiler, e.g.
``MPS_BENCH_NODE_PREFIX="perf record -e cpu-clock -F 10000 -o node.perf --"``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from ..commands.demo import ros_env, stop_group
from ..ros.environment import env_defaults


def _stat_cpu(stat: str) -> float:
    """User + system CPU seconds of a ``/proc/.../stat`` line."""
    fields = stat.rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _cpu_seconds(pid: int) -> float:
    return _stat_cpu(Path(f"/proc/{pid}/stat").read_text())


def _threads(pid: int) -> dict:
    """Every thread of the process: tid -> (name, CPU s, voluntary and involuntary context
    switches), from ``/proc``."""
    out = {}
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            stat = (task / "stat").read_text()
            status = (task / "status").read_text()
        except (FileNotFoundError, ProcessLookupError):
            continue
        name = stat[stat.index("(") + 1 : stat.rindex(")")]
        sw = dict(line.split(":", 1) for line in status.splitlines() if "ctxt_switches" in line)
        out[int(task.name)] = (
            name,
            _stat_cpu(stat),
            int(sw["voluntary_ctxt_switches"]),
            int(sw["nonvoluntary_ctxt_switches"]),
        )
    return out


def _thread_table(a: dict, b: dict, wall: float) -> list[dict]:
    """Per thread name (the Python threads but the publishing one are all ``python``; the
    middleware's are Fast DDS's ``dds.*``), between two :func:`_threads` readings ``wall``
    seconds apart at 1 kHz: CPU µs a step, voluntary and involuntary switches a step."""
    steps = wall * 1e3
    rows: dict = {}
    for tid, (name, cpu, vol, inv) in b.items():
        _, cpu0, vol0, inv0 = a.get(tid, (name, 0.0, 0, 0))
        r = rows.setdefault(name, {"thread": name, "cpu_us": 0.0, "voluntary": 0.0, "involuntary": 0.0})
        r["cpu_us"] += (cpu - cpu0) / steps * 1e6
        r["voluntary"] += (vol - vol0) / steps
        r["involuntary"] += (inv - inv0) / steps
    return sorted(
        (r for r in rows.values() if r["cpu_us"] > 0.5 or r["voluntary"] > 0.01), key=lambda r: -r["cpu_us"]
    )


def _children(pid: int) -> list[int]:
    out = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            out += [int(c) for c in (task / "children").read_text().split()]
        except (FileNotFoundError, ProcessLookupError, ValueError):
            pass
    return out


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def _node_processes(pid: int) -> tuple[list[int], list[int]]:
    """(the node's processes: itself and its stepping process, where it has one; its recording
    processes), from ``/proc``."""
    node, rec = [pid], []
    for kid in _children(pid):
        line = _cmdline(kid)
        if "mps_ros.run.stepping" in line:
            node.append(kid)
            rec += [k for k in _children(kid) if "mps_ros.recording.background" in _cmdline(k)]
        elif "mps_ros.recording.background" in line:
            rec.append(kid)
    return node, rec


def _all_threads(pids: list[int]) -> dict:
    """:func:`_threads` of several processes, keyed by thread id."""
    out = {}
    for pid in pids:
        try:
            out.update(_threads(pid))
        except (FileNotFoundError, ProcessLookupError):
            pass
    return out


def neighbours(n: int) -> list[subprocess.Popen]:
    """``n`` pure-Python busy loops, each a process of its own session (what a user's machine
    also runs beside the node); end them with :func:`stop_group`."""
    return [
        subprocess.Popen([sys.executable, "-c", "while True: pass"], start_new_session=True)
        for _ in range(max(0, n))
    ]


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def _final_stats(log: str) -> dict:
    m = re.search(
        r"real-time factor ([\d.e+-]+), step p50 ([\d.e+-]+) ms, p99 ([\d.e+-]+) ms, "
        r"publish p50 ([\d.e+-]+) ms, p99 ([\d.e+-]+) ms, "
        r"(?:latency p50 ([\d.e+-]+) ms, p99 ([\d.e+-]+) ms, )?(\d+) deadline misses, "
        r"(\d+) messages, stepping thread CPU ([\d.e+-]+) us a step"
        r"(?:, process CPU ([\d.e+-]+) us a step)?"
        r"(?:, stepping process ([\d.e+-]+) us and ROS process ([\d.e+-]+) us of it)?"
        r"(?:, realtime priority (\d+))?"
        r"(?:, publishing thread's slice ([\d.e+-]+) ms)?",
        log,
    )
    if not m:
        raise RuntimeError("no final statistics in the node's log:\n" + log[-3000:])
    g = m.groups()
    out = {
        "rtf": float(g[0]),
        "step_p50_ms": float(g[1]),
        "step_p99_ms": float(g[2]),
        "publish_p50_ms": float(g[3]),
        "publish_p99_ms": float(g[4]),
        "misses": int(g[7]),
        "messages": int(g[8]),
        "step_thread_cpu_us": float(g[9]),
        "process_cpu_us": float(g[10]) if g[10] is not None else float("nan"),
        "stepping_process_cpu_us": float(g[11]) if g[11] is not None else float("nan"),
        "ros_process_cpu_us": float(g[12]) if g[12] is not None else float("nan"),
        "priority": int(g[13]) if g[13] is not None else 0,
        "release_slice_ms": float(g[14]) if g[14] is not None else float("nan"),
    }
    if g[5] is not None:
        out["latency_p50_ms"], out["latency_p99_ms"] = float(g[5]), float(g[6])
    c = re.search(r"(\d+) commands applied, (\d+) refused", log)
    out["commands_applied"], out["commands_refused"] = (int(c.group(1)), int(c.group(2))) if c else (0, 0)
    return out


def _node(params: dict, env, log_path: Path) -> subprocess.Popen:
    args = []
    for k, v in params.items():
        args += ["-p", f"{k}:={str(v).lower() if isinstance(v, bool) else v}"]
    prefix = os.environ.get("MPS_BENCH_NODE_PREFIX", "").split()  # e.g. a profiler
    return subprocess.Popen(
        [*prefix, sys.executable, "-m", "mps_core.cli", "node", "press-cycle", "--ros-args", *args],
        env=env,
        stdout=open(log_path, "wb"),
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )


def loop_cost(steps: int = 3000, outputs: str | None = None, derivatives: str | None = None) -> float:
    """CPU µs a step of the node's own work done in a plain loop in this process (no ROS, no
    threads, no waiting): press-cycle at 1 kHz, each step stepped, its messages made, its
    checkpoint taken and its events collected, over the run's first ``steps`` steps. Measured
    beside a realtime run, it says what the same work costs this machine outside the node at
    that moment; the node's CPU a step is a multiple of it (the threads, the waiting, the
    middleware; the multiple itself varies from run to run on a virtual machine)."""
    from ..run.twin import Twin
    from ..wire.topics import OUTPUTS

    outs = outputs.split(",") if outputs else OUTPUTS
    tw = Twin("press-cycle", dt=1e-3, t_end=steps * 1e-3, outputs=outs, derivatives=derivatives)
    tw.warm_up(1.0)
    t0 = time.thread_time()
    while not tw.done:
        tw.step()
        tw.state_payloads()
        tw.checkpoint()
        tw.new_events()
    return (time.thread_time() - t0) / tw.k * 1e6


#: the subscriber's executor: rclpy's ``single`` threaded one, or its ``events`` executor
PROBE_EXECUTOR = os.environ.get("MPS_BENCH_EXECUTOR", "events")


def realtime(
    steps: int,
    env,
    tmp: Path,
    deserialize: bool = False,
    outputs: str | None = None,
    publish_every: int = 1,
    priority: int | None = None,
    lead: float | None = None,
    release_period: float | None = None,
    derivatives: str | None = None,
    release_slice: float | None = None,
    n_neighbours: int = 0,
    in_process: bool = False,
    commands_every: float | None = None,
    command_delay: float | None = None,
    flood: int = 0,
) -> dict:
    t_end = steps * 1e-3
    params = dict(
        pacing="realtime",
        dt=0.001,
        t_end=t_end,
        recording=tmp / "rt.mcap",
        wait_for_subscribers=1,
        wait_timeout=30.0,
        start_delay=0.5,
        publish_every=publish_every,
    )
    if commands_every or flood:
        # an operator instead of the scene's schedule: the subscriber sends the commands
        params.update(scene_commands=False, wait_for_commanders=1)
    if command_delay is not None:
        params["command_delay"] = command_delay
    if priority is not None:
        params["realtime_priority"] = priority
    if in_process:
        params["stepping_process"] = False
    if lead is not None:
        params["lead"] = lead
    if release_period is not None:
        params["release_period"] = release_period
    if release_slice is not None:
        params["release_slice"] = release_slice
    if derivatives is not None:
        params["derivatives"] = derivatives
    busy = neighbours(n_neighbours)  # for the whole run, the plain loop's too
    try:
        return _realtime(steps, env, tmp, deserialize, outputs, params, derivatives, commands_every, flood)
    finally:
        for b in busy:
            stop_group(b)


def _realtime(
    steps, env, tmp, deserialize, outputs, params, derivatives, commands_every=None, flood=0
) -> dict:
    t_end = steps * 1e-3
    loop = loop_cost(steps, outputs, derivatives)  # the same steps as the run's
    if outputs:
        params["outputs"] = "[" + outputs + "]"
    node = _node(params, env, tmp / "rt.log")
    probe = _probe(env, tmp / "probe.log", deserialize, commands_every, flood)
    try:
        log = tmp / "rt.log"
        end = time.monotonic() + 60
        while time.monotonic() < end and "stepping starts" not in log.read_text():
            time.sleep(0.01)
        # from the run's start (its kernels already built), after its first lead is banked
        time.sleep(0.2)
        usage = _Usage(node.pid, probe.pid)
        ended = False
        while node.poll() is None and not ended:
            # up to the run's end (not the process's shutdown after it)
            text = log.read_text()
            ended = "run ended at t = " in text or "run stopped (" in text
            try:
                usage.read(ended)
            except (FileNotFoundError, ProcessLookupError):
                break
            time.sleep(0.05)
        node.wait(t_end * 3 + 60)
        out, _ = probe.communicate(timeout=60)
        got = json.loads(out.strip().splitlines()[-1])
        st = _final_stats(log.read_text())
        usage.figures(st)
        _subscriber_figures(st, got, tmp / "rt.mcap")
        st["misses_per_1e4"] = st["misses"] * 1e4 / steps
        st["threads"] = usage.threads()
        st["loop_us"] = loop
    finally:
        stop_group(node)
        stop_group(probe)
    st["ros_floor_us"] = ros_floor(env, tmp, tmp / "rt.mcap", deserialize)
    return st


def ros_floor(env, tmp: Path, recording: Path, deserialize: bool = False) -> float:
    """CPU µs a step of rclpy publishing a run's messages, already serialized, to the same
    subscriber in a bare loop: the recording's messages, step by step, on publishers with the
    node's QoS, in a process of its own (:func:`publish_floor`); the floor under the node's
    ROS process. NaN where it could not be measured."""
    probe = _probe(env, tmp / "floor-probe.log", deserialize, None, 0)
    pub = subprocess.Popen(
        [sys.executable, "-m", "mps_ros.bench", "floor", str(recording)],
        env=env,
        stdout=subprocess.PIPE,
        stderr=open(tmp / "floor.log", "wb"),
        start_new_session=True,
    )
    try:
        out, _ = pub.communicate(timeout=600)
        probe.communicate(timeout=60)
        return float(json.loads(out.strip().splitlines()[-1])["cpu_us_per_step"])
    except (subprocess.TimeoutExpired, ValueError, IndexError, KeyError):
        return math.nan
    finally:
        stop_group(pub)
        stop_group(probe)


def publish_floor(recording: str) -> int:
    """The floor's publisher (``python -m mps_ros.bench floor REC.mcap``): the node's
    publishers (its name, topics, QoS and middleware settings), each step's recorded messages
    published as they are (serialized) in a bare loop once the subscriber has joined every
    topic; prints one JSON line (the steps, CPU µs a step of the process and of the loop's
    thread)."""
    env_defaults()
    import rclpy
    from mcap.reader import make_reader
    from rclpy.event_handler import PublisherEventCallbacks
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    from ..ros.endpoints import MSG_CLASSES
    from ..wire.topics import DEPTH, LATCHED, TOPICS, resolve

    steps: list[list] = []
    last = None
    with open(recording, "rb") as fh:
        for _schema, channel, message in make_reader(fh).iter_messages(log_time_order=False):
            if message.log_time != last:
                steps.append([])
                last = message.log_time
            steps[-1].append((channel.topic, message.data))
    rclpy.init()
    node = Node("press_twin")
    qos = QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=DEPTH,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )
    latched = QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=1,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )
    raw, pubs = {}, []
    for t in TOPICS:
        if t.msgtype not in MSG_CLASSES or t.key == "~/mode":
            continue
        p = node.create_publisher(
            MSG_CLASSES[t.msgtype],
            resolve(t.key),
            latched if t.key in LATCHED else qos,
            event_callbacks=PublisherEventCallbacks(use_default_callbacks=False),
        )
        pubs.append(p)
        raw[p.topic_name] = p.handle.publish_raw
    end = time.monotonic() + 30
    while time.monotonic() < end and not all(p.get_subscription_count() for p in pubs):
        time.sleep(0.01)
    time.sleep(0.5)  # the subscriber's side of discovery settled
    steps = [[(raw[topic], data) for topic, data in step if topic in raw] for step in steps]
    cpu0, th0 = time.process_time(), time.thread_time()
    for step in steps:
        for publish, data in step:
            publish(data)
    cpu, th = time.process_time() - cpu0, time.thread_time() - th0
    n = max(1, len(steps))
    print(json.dumps({"steps": n, "cpu_us_per_step": cpu / n * 1e6, "thread_us_per_step": th / n * 1e6}))
    time.sleep(1.0)  # the last messages delivered before the publishers go
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def _probe(env, log_path: Path, deserialize, commands_every, flood) -> subprocess.Popen:
    """The external subscriber (:func:`probe`), started in a session of its own; its JSON line
    on its stdout, its log at ``log_path``."""
    return subprocess.Popen(
        [sys.executable, "-m", "mps_ros.bench", "probe"]
        + (["--deserialize"] if deserialize else [])
        + ([] if PROBE_EXECUTOR == "single" else ["--events-executor"])
        + ([f"--commands-every={commands_every}"] if commands_every else [])
        + ([f"--flood={flood}"] if flood else []),
        env=env,
        stdout=subprocess.PIPE,
        stderr=open(log_path, "wb"),
        text=True,
        start_new_session=True,
    )


class _Usage:
    """The CPU, threads and memory of the node's processes (the node, its stepping process;
    its recording processes apart) and of the subscriber's, from ``/proc``: read first at
    construction (the run's start), then at each :meth:`read` up to the run's end."""

    def __init__(self, node_pid: int, probe_pid: int):
        self.node_pid, self.probe_pid = node_pid, probe_pid
        self.mine, self.kids = _node_processes(node_pid)  # the node's; the recording process
        self.cpu0, self.wall0 = sum(_cpu_seconds(k) for k in self.mine), time.monotonic()
        self.kid0 = sum(_cpu_seconds(k) for k in self.kids)
        self.sub0 = _cpu_seconds(probe_pid)
        self.threads0 = _all_threads(self.mine)
        self.threads1, self.wall_t = dict(self.threads0), self.wall0  # the last reading of each thread
        self.cpu1 = self.wall1 = self.kid1 = self.sub1 = None
        self.rss0 = self.rss1 = None

    def read(self, ended: bool) -> None:
        """A reading (``ended``: the run has ended, its threads' last readings kept); raises
        FileNotFoundError or ProcessLookupError where a process is gone."""
        mine, kids = self.mine, self.kids
        self.cpu1, self.wall1 = sum(_cpu_seconds(k) for k in mine), time.monotonic()
        self.kid1 = sum(_cpu_seconds(k) for k in kids)
        self.sub1 = _cpu_seconds(self.probe_pid)
        if not ended:  # a thread that ends keeps its last reading
            self.threads1.update(_all_threads(mine))
            self.wall_t = time.monotonic()
        self.rss1 = _rss_mb(self.node_pid)
        if self.rss0 is None and self.wall1 - self.wall0 >= 5.0:
            self.rss0 = self.rss1

    def figures(self, st: dict) -> None:
        """The shares of a core (the node's, its recording's, the subscriber's), the node's
        processes, its CPU a step and its memory at 5 s and at the end, into ``st``."""
        wall0, wall1 = self.wall0, self.wall1
        st["cpu_share"] = (self.cpu1 - self.cpu0) / (wall1 - wall0) if wall1 else float("nan")
        st["recorder_cpu_share"] = (
            (self.kid1 - self.kid0) / (wall1 - wall0) if wall1 and self.kids else float("nan")
        )
        st["subscriber_cpu_share"] = (self.sub1 - self.sub0) / (wall1 - wall0) if wall1 else float("nan")
        st["node_processes"] = len(self.mine)
        st["cpu_per_step_us"] = st["cpu_share"] * 1e3  # at 1 kHz, realtime x1
        st["rss_start_mb"], st["rss_end_mb"] = self.rss0, self.rss1

    def threads(self) -> list[dict]:
        """:func:`_thread_table` from the first reading to each thread's last."""
        if self.wall_t > self.wall0:
            return _thread_table(self.threads0, self.threads1, self.wall_t - self.wall0)
        return []


def _subscriber_figures(st: dict, got: dict, recording: Path) -> None:
    """What the subscriber received (its JSON line ``got``) into ``st``: messages a second and
    in all, the messages lost by topic (against the ``recording``, which holds every message
    the node published, and no other), the drift and the flood's time."""
    st["subscriber_msgs_per_s"] = got["rate"]
    st["subscriber_received"] = got["received"]
    try:
        from ..wire.topics import MODE, resolve

        published = recorded_counts(recording)
        published.pop(resolve(MODE.key), None)  # recorded as received, not published
        for topic in got.get("unknown", []):  # recorded, not published here
            published.pop(topic, None)
        st["lost_by_topic"] = lost_by_topic(published, got.get("by_topic", {}))
    except (OSError, RuntimeError) as exc:  # the other figures still stand
        st["lost_by_topic"], st["recording_error"] = None, str(exc)
    st["drift_ms"] = got.get("drift_ms")
    st["flood_s"] = got.get("flood_s")
    st["drift_end_to_end_ms"] = got.get("drift_end_to_end_ms")


def recorded_counts(path) -> dict[str, int]:
    """Messages by topic in a finished recording (its summary's statistics; a channel with
    none counts 0)."""
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    why = "it has none"
    with open(path, "rb") as f:
        try:
            summary = make_reader(f).get_summary()
        except McapError as exc:
            summary, why = None, f"{type(exc).__name__}: {exc}"
    if summary is None or summary.statistics is None:
        raise RuntimeError(
            f"recording {str(path)!r}: no summary to count its messages by "
            f"({why}; an unfinished recording has none)"
        )
    counts = summary.statistics.channel_message_counts
    return {ch.topic: counts.get(c, 0) for c, ch in summary.channels.items()}


def lost_by_topic(published: dict, received: dict) -> dict[str, int]:
    """Published less received, by topic, where they differ (a topic received but never
    published counts as published 0 times)."""
    out = {t: n - received.get(t, 0) for t, n in published.items()}
    out.update({t: -n for t, n in received.items() if t not in published})
    return {t: d for t, d in sorted(out.items()) if d}


def keep_logs(tmp: Path, keep: Path, what: str, result: dict) -> None:
    """Copy a run's logs (the node's, the subscriber's) and its figures to ``keep``."""
    import shutil

    keep.mkdir(parents=True, exist_ok=True)
    for name, kept in (("rt.log", "node.log"), ("probe.log", "subscriber.log")):
        if (tmp / name).exists():
            shutil.copyfile(tmp / name, keep / f"{what}-{kept}")
    (keep / f"{what}.json").write_text(json.dumps(result, indent=2))


def afap(
    recording: bool, env, tmp: Path, steps: int, outputs: str | None = None, in_process: bool = False
) -> dict:
    """The node as fast as possible (``in_process``: stepping in the node's own process,
    ``stepping_process:=false``); its final statistics."""
    params = dict(
        pacing="as_fast_as_possible",
        dt=0.001,
        t_end=steps * 1e-3,
        # a file of its own for each run (a recording never replaces a file)
        recording=(tmp / f"afap-{len(list(tmp.glob('afap-*.mcap')))}.mcap") if recording else "none",
        stepping_process=not in_process,
    )
    if outputs:
        params["outputs"] = "[" + outputs + "]"
    node = _node(params, env, tmp / "afap.log")
    try:
        node.wait(600)
        return _final_stats((tmp / "afap.log").read_text())
    finally:
        stop_group(node)


def record_only(tmp: Path, steps: int) -> dict:
    from ..run.record import record

    _, st, _ = record("press-cycle", tmp / "rec.mcap", dt=0.001, t_end=steps * 1e-3, stop_on_signals=False)
    return {
        "rtf": st["real_time_factor"],
        "step_p50_ms": st["step_time_p50_ms"],
        "step_p99_ms": st["step_time_p99_ms"],
    }


#: what the benchmark's operator sends, in turn
OPERATOR_WORDS = ("engage", "disengage", "stop", "start")


def _operator(node, every: float | None, state: dict, flood: int = 0) -> None:
    """A thread of the subscriber's process that sends :data:`OPERATOR_WORDS` in turn on
    ``/press_twin/mode``, one every ``every`` wall seconds from the first message received,
    until the run's end; ``flood``: 2 s after the first message, that many ``engage`` at once
    (as fast as the publisher takes them)."""
    import threading

    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import String

    from ..wire.topics import MODE, resolve

    pub = node.create_publisher(
        String, resolve(MODE.key), QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    )

    def send():
        while state["first"] is None:
            time.sleep(0.01)
        if flood:
            time.sleep(2.0)
            t0 = time.monotonic()
            msg = String(data="engage")
            for _ in range(flood):
                pub.publish(msg)
            state["flood_s"] = time.monotonic() - t0
        i = 0
        while every and not state["ended"]:
            time.sleep(every)
            if state["ended"]:
                return
            pub.publish(String(data=OPERATOR_WORDS[i % len(OPERATOR_WORDS)]))
            i += 1

    threading.Thread(target=send, name="operator", daemon=True).start()


def probe() -> int:
    """The external subscriber: every topic of press_twin, reliable; prints one JSON line."""
    env_defaults()
    import rclpy
    from rclpy.node import Node

    rclpy.init()
    node = Node("press_twin_probe")
    got = _Received()
    unknown = _subscribe_all(node, got, raw="--deserialize" not in sys.argv)
    executor = _probe_executor("--events-executor" in sys.argv)
    executor.add_node(node)
    every = next((float(a.split("=", 1)[1]) for a in sys.argv if a.startswith("--commands-every=")), None)
    flood = next((int(a.split("=", 1)[1]) for a in sys.argv if a.startswith("--flood=")), 0)
    if every or flood:
        _operator(node, every, got.state, flood)
    _spin_to_the_end(executor, got.state)
    print(json.dumps(got.figures(unknown)), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


class _Received:
    """What the benchmark's subscriber received: the messages in all and by topic, the first
    and the last one's arrival (wall), the run's end (its ``run-end`` event), and ``/clock``'s
    simulated time against wall time (the drift). :attr:`state` is shared with the operator
    (:func:`_operator`)."""

    def __init__(self):
        self.state = {"n": 0, "first": None, "last": None, "ended": False, "clock0": None, "clock1": None}
        self.by_topic: dict[str, int] = {}  # topic -> messages received on it
        self.lowest: dict = {}  # whole simulated seconds -> the lowest (wall − simulated) in it

    def counter(self, topic: str):
        """The callback that counts what arrives on ``topic``."""
        state, by_topic = self.state, self.by_topic
        by_topic[topic] = 0

        def count(msg):
            now = time.monotonic()
            state["n"] += 1
            by_topic[topic] += 1
            state["first"] = state["first"] or now
            state["last"] = now

        return count

    def events(self, topic: str):
        """The callback of ``~/events``: counted, and the run's end seen."""
        state = self.state
        count = self.counter(topic)

        def on_event(msg):
            count(msg)
            if '"kind":"run-end"' in msg.data:
                state["ended"] = True

        return on_event

    def clock(self, topic: str):
        """The callback of ``/clock``: counted, its simulated time against wall time kept."""
        state, lowest = self.state, self.lowest
        count = self.counter(topic)

        def on_clock(msg):
            count(msg)
            at = (msg.clock.sec + msg.clock.nanosec * 1e-9, time.monotonic())
            state["clock0"] = state["clock0"] or at
            state["clock1"] = at
            k = int(at[0] - state["clock0"][0])
            off = at[1] - at[0]
            if off < lowest.get(k, math.inf):
                lowest[k] = off

        return on_clock

    def figures(self, unknown: list) -> dict:
        """The subscriber's JSON line: received, rate, by topic, the flood's time, the topics
        not subscribed to (``unknown``) and the drift."""
        state, lowest = self.state, self.lowest
        span = (state["last"] or 0) - (state["first"] or 0)
        out = {
            "received": state["n"],
            "rate": state["n"] / span if span > 0 else 0.0,
            "by_topic": self.by_topic,
            "flood_s": state.get("flood_s"),
            "unknown": unknown,
        }
        if state["clock0"] and state["clock1"]:
            (s0, w0), (s1, w1) = state["clock0"], state["clock1"]
            # first message against last: their own delivery delays are in it
            out["drift_end_to_end_ms"] = ((w1 - w0) - (s1 - s0)) * 1e3
            # the drift: the lowest wall − simulated offset (a message that met no delay) over
            # the last whole 5 simulated seconds against that over the first 5 (wall behind: > 0)
            whole = sorted(lowest)[:-1]  # the last second is not whole
            if len(whole) >= 10:
                first = min(lowest[k] for k in whole[:5])
                last = min(lowest[k] for k in whole[-5:])
                out["drift_ms"] = (last - first) * 1e3
            else:
                out["drift_ms"] = out["drift_end_to_end_ms"]
        return out


def _subscribe_all(node, got: _Received, raw: bool) -> list[str]:
    """The subscriber's subscriptions: every topic of press_twin, reliable, each counted by
    ``got``; the topics of a type not importable here (the node records them only)."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from ..ros.endpoints import MSG_CLASSES
    from ..wire.topics import TOPICS, resolve

    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    unknown = []
    for t in TOPICS:
        topic = resolve(t.key)
        if t.msgtype not in MSG_CLASSES:
            unknown.append(topic)
        elif t.key == "/clock":  # deserialized: simulated against wall time (the drift)
            node.create_subscription(MSG_CLASSES[t.msgtype], topic, got.clock(topic), qos)
        elif t.key == "~/events":
            node.create_subscription(MSG_CLASSES[t.msgtype], topic, got.events(topic), qos)
        else:  # counted as delivered, serialized (raw) unless --deserialize
            node.create_subscription(MSG_CLASSES[t.msgtype], topic, got.counter(topic), qos, raw=raw)
    return unknown


def _probe_executor(events: bool):
    """One executor for the whole run (rclpy.spin_once(node) adds and removes the node at every
    call: a subscriber that did so would spend most of its time there, not in its callbacks):
    rclpy's events executor (C++, Jazzy's wheels have it) where the subscriber asks for it,
    else its single-threaded one."""
    if events:
        from rclpy.experimental import EventsExecutor

        return EventsExecutor()
    from rclpy.executors import SingleThreadedExecutor

    return SingleThreadedExecutor()


def _spin_to_the_end(executor, state: dict) -> None:
    """Spin until the run's end (its ``run-end`` event, or 5 s without a message: the node is
    gone without it), then until 2 s without a message."""
    deadline = time.monotonic() + 3600
    while not state["ended"] and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.1)
        if state["last"] is not None and time.monotonic() - state["last"] > 5.0:
            break  # the node is gone without its run-end event
    while time.monotonic() - (state["last"] or 0.0) < 2.0:  # until 2 s without a message
        executor.spin_once(timeout_sec=0.05)


def wakeup_costs(n: int = 2000) -> dict:
    """CPU time (µs, the waiting thread's own) of one wake-up from a 1 ms timed wait, by the
    primitives the node's threads wait in: what each deadline costs the publishing thread
    beside its publishing."""
    import threading

    cond, event, lock = threading.Condition(), threading.Event(), threading.Lock()
    lock.acquire()

    def cond_wait():
        with cond:
            cond.wait(0.001)

    out = {}
    for name, wait in (
        ("threading.Condition.wait(0.001)", cond_wait),
        ("threading.Event.wait(0.001)", lambda: event.wait(0.001)),
        ("threading.Lock.acquire(timeout=0.001)", lambda: lock.acquire(timeout=0.001)),
        ("time.sleep(0.001)", lambda: time.sleep(0.001)),
    ):
        t0 = time.thread_time()
        for _ in range(n):
            wait()
        out[name] = (time.thread_time() - t0) / n * 1e6
    return out


def writer_costs(rounds: int = 5, steps: int = 2000) -> dict:
    """CPU µs a message of the recording's MCAP writer (:class:`~mps_ros.recording.mcap_writer.McapWriter`)
    and of the ``mcap`` library's ``Writer``, given the same messages (press-cycle at 1 kHz,
    every output, ``steps`` steps: what the recording process writes) into memory, zstd chunks
    of 512 KiB; the two interleaved, best of ``rounds``; and whether the files were the same."""
    import io

    from mcap.writer import CompressionType, Writer

    from ..recording.mcap_writer import ENCODING_CDR, PROFILE_ROS2, SCHEMA_ROS2MSG, McapWriter
    from ..run.twin import Twin
    from ..wire.topics import OUTPUTS

    tw = Twin("press-cycle", dt=1e-3, t_end=steps * 1e-3, outputs=OUTPUTS)
    msgs = []
    while not tw.done:
        tw.step()
        msgs.extend((key, data, tw.k * 1_000_000) for key, data in tw.state_payloads())
    ids = {key: n + 1 for n, key in enumerate(dict.fromkeys(k for k, _d, _t in msgs))}

    def write(w) -> tuple[float, bytes]:
        out = io.BytesIO()
        w = w(out)
        w.start(profile=PROFILE_ROS2, library="bench")
        sid = w.register_schema("s", SCHEMA_ROS2MSG, b"")
        for key in ids:
            w.register_channel(str(key), ENCODING_CDR, sid, {})
        seq = dict.fromkeys(ids.values(), 0)
        add = w.add_message
        t0 = time.process_time()
        for key, data, t_ns in msgs:
            cid = ids[key]
            seq[cid] += 1
            add(cid, log_time=t_ns, data=data, publish_time=t_ns, sequence=seq[cid])
        w.finish()
        return (time.process_time() - t0) / len(msgs) * 1e6, out.getvalue()

    def ours(out):
        return McapWriter(out, chunk_size=512 * 1024)

    def theirs(out):
        return Writer(out, chunk_size=512 * 1024, compression=CompressionType.ZSTD)

    best = {"mps": math.inf, "mcap": math.inf}
    same = True
    for _ in range(rounds):
        a, fa = write(ours)
        b, fb = write(theirs)
        best["mps"], best["mcap"] = min(best["mps"], a), min(best["mcap"], b)
        same = same and fa == fb
    return {
        "messages": len(msgs),
        "per_step": len(msgs) / steps,
        "mps_us": best["mps"],
        "mcap_us": best["mcap"],
        "same_bytes": same,
    }


def _lost_line(r: dict) -> str:
    if r.get("recording_error"):
        return f"  no messages by topic        {r['recording_error']}\n"
    lost = r.get("lost_by_topic")
    if not lost:
        return ""
    return "  published less received     " + ", ".join(f"{t} {n}" for t, n in lost.items()) + "\n"


def main(argv=None) -> int:
    a = _parser().parse_args(argv)
    if a.what == "soak" and not a.minutes * 60.0 >= 10.0:
        print(
            f"python -m mps_ros.bench soak: --minutes {a.minutes:g}: expected at least 10 s "
            "(1/6 min): the node's memory is read at 5 s and at the end",
            file=sys.stderr,
        )
        return 2
    if a.what == "probe":
        return probe()
    if a.what == "wakeup":
        for name, us in wakeup_costs().items():
            print(f"{name:38s} {us:5.1f} us of CPU a wake-up (1 ms waits, this thread's own time)")
        return 0
    if a.what == "writer":
        return _writer()
    if a.what == "floor":
        return publish_floor(a.recording)
    env = ros_env()
    os.environ.update(
        {k: env[k] for k in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_LOG_DIR", "RMW_IMPLEMENTATION")}
    )
    res = {
        "machine": f"{os.cpu_count()} cores, load average "
        f"{' '.join(f'{x:.2f}' for x in os.getloadavg())} at the start"
    }
    with tempfile.TemporaryDirectory(prefix="mps-bench-") as d:
        tmp = Path(d)
        if a.what in ("all", "realtime"):
            res["realtime_1kHz"] = _realtime_run(a, env, tmp)
        if a.what == "table":
            res["table"] = _table(a, env, tmp)
        if a.what == "soak":
            res["soak"] = _soak(a, env, tmp)
        if a.what in ("all", "afap"):
            res["afap"] = _afap_runs(a, env, tmp)
    print(res["machine"])
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=2))
    return 0


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m mps_ros.bench",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "what",
        nargs="?",
        default="all",
        choices=("all", "realtime", "afap", "table", "soak", "wakeup", "writer", "probe", "floor"),
    )
    p.add_argument("recording", nargs="?", help="floor: the recording whose messages are published")
    p.add_argument(
        "--minutes",
        type=float,
        default=10.0,
        help="length of the soak run (default 10): realtime, every output, a "
        "subscriber; RSS at 5 s and at the end, drift, messages lost",
    )
    p.add_argument("--steps", type=int, default=10_000, help="steps of the realtime run")
    p.add_argument("--afap-steps", type=int, default=5_000, help="steps of each AFAP run")
    p.add_argument("--json", help="write the figures to this file")
    p.add_argument(
        "--keep",
        metavar="DIR",
        type=Path,
        help="keep the realtime or soak run's logs (the node's, the subscriber's) and figures in DIR",
    )
    _node_arguments(p.add_argument_group("the node's settings"))
    _beside_arguments(p.add_argument_group("beside the node: the machine's load, the subscriber"))
    return p


def _node_arguments(p) -> None:
    """The benchmark's arguments that set the node's parameters."""
    p.add_argument(
        "--outputs", metavar="LIST", help="the realtime run's outputs, comma-separated (default: all)"
    )
    p.add_argument(
        "--publish-every",
        type=int,
        default=1,
        metavar="N",
        help="the realtime run publishes every N-th step (default 1)",
    )
    p.add_argument(
        "--priority",
        type=int,
        default=None,
        metavar="P",
        help="the node's realtime_priority (default: the node's; 0: normal "
        "scheduling; 1-99: its stepping process and publishing thread under "
        "SCHED_FIFO, where allowed)",
    )
    p.add_argument(
        "--lead",
        type=float,
        default=None,
        metavar="S",
        help="the node's lead: steps computed up to S wall seconds ahead of their "
        "deadlines (default: the node's, 0.1; 0: one step's period, none "
        "banked)",
    )
    p.add_argument(
        "--release-period",
        type=float,
        default=None,
        metavar="S",
        help="the node's release_period: the steps due go out together about once "
        "per S wall seconds, each at most S less one step's period late (default: "
        "the node's, 0: each step at its deadline, one wake-up a step)",
    )
    p.add_argument(
        "--release-slice",
        type=float,
        default=None,
        metavar="S",
        help="the node's release_slice: the publishing thread's scheduler slice "
        "(default: the node's, 0.0001; 0: none asked)",
    )
    p.add_argument(
        "--derivatives",
        choices=("central", "autodiff"),
        default=None,
        help="the node's derivatives (default: the scene's)",
    )
    p.add_argument(
        "--in-process",
        action="store_true",
        help="the node steps in its own process (stepping_process:=false) instead "
        "of a stepping process of its own",
    )
    p.add_argument(
        "--command-delay",
        type=float,
        default=None,
        metavar="S",
        help="the node's command_delay (default: the node's, 0.05 s)",
    )


def _beside_arguments(p) -> None:
    """The benchmark's arguments for what runs beside the node."""
    p.add_argument(
        "--neighbours",
        type=int,
        default=0,
        metavar="N",
        help="run N pure-Python busy loops beside the node for the whole realtime or soak run (default 0)",
    )
    p.add_argument(
        "--commands-every",
        type=float,
        default=None,
        metavar="S",
        help="realtime: the subscriber also sends engage, disengage, stop, start in "
        "turn on ~/mode, one every S wall seconds (the scene's own commands off)",
    )
    p.add_argument(
        "--flood",
        type=int,
        default=0,
        metavar="N",
        help="realtime: the subscriber sends N engage at once, 2 s into the run "
        "(the scene's own commands off)",
    )
    p.add_argument(
        "--events-executor",
        action="store_true",
        help="probe: spin rclpy's events executor (the realtime run's subscriber "
        "does unless MPS_BENCH_EXECUTOR=single)",
    )
    p.add_argument(
        "--deserialize",
        action="store_true",
        help="the subscriber deserializes every message into a Python object "
        "(default: it takes them serialized, as delivered)",
    )


def _writer() -> int:
    """``writer``: the recordings' MCAP writer against the mcap library's, side by side."""
    r = writer_costs()
    print(
        f"the recording's MCAP writer, {r['messages']} messages of press-cycle at 1 kHz "
        f"({r['per_step']:.0f} a step), zstd chunks of 512 KiB, best of 5, CPU:\n"
        f"  mps_ros.recording.mcap_writer.McapWriter   {r['mps_us']:5.2f} us a message\n"
        f"  the mcap library's Writer         {r['mcap_us']:5.2f} us a message "
        f"({r['mcap_us'] / r['mps_us']:.1f}x)\n"
        f"  the same bytes                    {'yes' if r['same_bytes'] else 'NO'}"
    )
    return 0 if r["same_bytes"] else 1


def _node_settings(a) -> tuple:
    """The realtime and soak runs' settings from the command line, in :func:`realtime`'s order
    after the steps, the environment and the folder."""
    return (
        a.deserialize,
        a.outputs,
        a.publish_every,
        a.priority,
        a.lead,
        a.release_period,
        a.derivatives,
        a.release_slice,
        a.neighbours,
        a.in_process,
    )


def _realtime_run(a, env, tmp: Path) -> dict:
    """``realtime``: the run and its figures, printed."""
    r = realtime(a.steps, env, tmp, *_node_settings(a), a.commands_every, a.command_delay, a.flood)
    if a.keep:
        keep_logs(tmp, a.keep, "realtime", r)
    _print_realtime(a, r)
    return r


def _print_realtime(a, r: dict) -> None:
    how = "deserializing" if a.deserialize else "taking them serialized"
    scheme = a.derivatives or "the scene's (autodiff)"
    print(
        f"realtime, 1 kHz, {a.steps} steps, recording on, outputs "
        f"{a.outputs or 'all'}, publishing every {a.publish_every}, one external "
        f"subscriber ({how}, rclpy's {PROBE_EXECUTOR} executor), "
        f"{'stepping in the node process' if a.in_process else 'a stepping process'}"
        f", {a.neighbours} busy neighbour process(es), "
        f"realtime_priority {'40 (default)' if a.priority is None else a.priority}, lead "
        f"{'0.1 (default)' if a.lead is None else a.lead} s, release_period "
        f"{'0 (default)' if a.release_period is None else a.release_period} s, "
        f"release_slice {'0.0001 (default)' if a.release_slice is None else a.release_slice}"
        f" s, derivatives {scheme}"
        + (f", an operator command every {a.commands_every:g} s" if a.commands_every else "")
        + (
            f", a flood of {a.flood} engage at once 2 s in (sent in {r.get('flood_s') or float('nan'):.3f} s)"
            if a.flood
            else ""
        )
        + (
            f", command_delay {'0.05 (default)' if a.command_delay is None else a.command_delay} s"
            if a.commands_every or a.flood
            else ""
        )
        + ":\n"
        f"  priority the node got       {r['priority'] or 'normal (SCHED_OTHER)'}"
        f"{' (SCHED_FIFO)' if r['priority'] else ''}\n"
        f"  achieved real-time factor   {r['rtf']:.3f}\n"
        f"  step compute p50 / p99      {r['step_p50_ms']:.3f} / "
        f"{r['step_p99_ms']:.3f} ms\n"
        f"  publish p50 / p99           {r['publish_p50_ms']:.3f} / "
        f"{r['publish_p99_ms']:.3f} ms\n"
        f"  latency p50 / p99           {r.get('latency_p50_ms', float('nan')):.3f} / "
        f"{r.get('latency_p99_ms', float('nan')):.3f} ms (publication after the "
        f"step's deadline)\n"
        f"  deadline misses             {r['misses_per_1e4']:.0f} per 10^4 steps\n"
        + (
            f"  commands                    {r['commands_applied']} applied, "
            f"{r['commands_refused']} refused\n"
            if a.commands_every or a.flood
            else ""
        )
        + f"  subscriber received         {r['subscriber_msgs_per_s']:.0f} messages/s "
        f"({r['subscriber_received']} of {r['messages']} published)\n"
        + _lost_line(r)
        + f"  the subscriber's CPU        {100 * r['subscriber_cpu_share']:.0f} % of one core\n"
        f"  stepping thread CPU         {r['step_thread_cpu_us']:.0f} us a step "
        f"({r['step_thread_cpu_us'] / 10:.1f} % of the 1 ms period)\n"
        f"  publishing thread's slice   {r['release_slice_ms']:.3g} ms as granted "
        f"(0: the system's own)\n"
        f"  node process CPU            {r['process_cpu_us']:.0f} us a step over "
        f"the run's steps (the node's own count: every thread of its "
        f"{r['node_processes']} process(es); not the recording process)"
        + (
            f": stepping process {r['stepping_process_cpu_us']:.0f} us, ROS process "
            f"{r['ros_process_cpu_us']:.0f} us\n"
            f"{'':30s}stepping process {r['stepping_process_cpu_us'] / r['loop_us']:.2f}× "
            f"the same steps' work in a plain loop here ({r['loop_us']:.0f} us a step: stepped, "
            f"messages made, checkpoint; no ROS, no waiting)\n"
            f"{'':30s}ROS process {r['ros_process_cpu_us'] / r['ros_floor_us']:.2f}× "
            f"the floor here ({r['ros_floor_us']:.0f} us a step: rclpy publishing the same "
            f"serialized messages to the same subscriber in a bare loop)"
            if r["stepping_process_cpu_us"] == r["stepping_process_cpu_us"]
            else ""
        )
        + "\n"
        f"                              {r['process_cpu_us'] / r['loop_us']:.2f}× the "
        f"same steps' work in a plain loop here (the whole node)\n"
        f"                              {r['cpu_per_step_us']:.0f} us a step from "
        f"outside ({100 * r['cpu_share']:.0f} % of one core, /proc from 0.2 s after "
        f"the start to the run's end); the recording process "
        f"{100 * r['recorder_cpu_share']:.0f} %\n"
        f"  the node's threads (/proc; CPU a step, context switches a step: "
        f"voluntary, involuntary):\n"
        + "".join(
            f"    {t['thread']:<22s}{t['cpu_us']:6.0f} us  {t['voluntary']:5.2f}  {t['involuntary']:5.2f}\n"
            for t in r["threads"]
        ).rstrip("\n"),
        flush=True,
    )


def _table(a, env, tmp: Path) -> list:
    """``table``: the node as fast as possible by outputs."""
    rows = []
    from ..wire.topics import OUTPUTS

    no_markers = ",".join(o for o in OUTPUTS if o != "markers")
    for label, outs, rec in (
        ("joint_states, clock", "joint_states,clock", False),
        ("every output but markers, recording", no_markers, True),
        ("every output, no recording", None, False),
        ("every output, recording", None, True),
    ):
        r = afap(rec, env, tmp, a.afap_steps, outs)
        rows.append(dict(r, outputs=label))
    print(
        f"the node as fast as possible, no subscriber, {a.afap_steps} steps of "
        f"press-cycle at 1 kHz:\n"
        f"  | outputs | step p50 | publish p50 | real-time factor |\n"
        f"  |---|---|---|---|"
    )
    for r in rows:
        print(
            f"  | {r['outputs']} | {r['step_p50_ms']:.3f} ms | "
            f"{r['publish_p50_ms']:.3f} ms | {r['rtf']:.2f} |",
            flush=True,
        )
    return rows


def _soak(a, env, tmp: Path) -> dict:
    """``soak``: the long realtime run."""
    steps = int(round(a.minutes * 60_000))
    r = realtime(steps, env, tmp, *_node_settings(a))
    if a.keep:
        keep_logs(tmp, a.keep, "soak", r)
    print(
        f"soak: realtime, 1 kHz, {steps} steps ({a.minutes:g} min), "
        f"{a.neighbours} busy neighbour(s), priority {r['priority']}, recording on, "
        f"every output, one external subscriber:\n"
        f"  node RSS                    {r['rss_start_mb']:.1f} MB at 5 s, "
        f"{r['rss_end_mb']:.1f} MB at the end "
        f"({r['rss_end_mb'] - r['rss_start_mb']:+.1f} MB)\n"
        f"  simulated vs wall drift     {r['drift_ms']:.2f} ms (wall behind simulated: "
        f"the lowest offset of the subscriber's /clock over the last 5 s against the "
        f"first 5 s; first message against last "
        f"{r.get('drift_end_to_end_ms', float('nan')):.2f} ms)\n"
        f"  messages                    {r['messages']} published, "
        f"{r['subscriber_received']} received "
        f"({r['messages'] - r['subscriber_received']} lost)\n"
        + _lost_line(r)
        + f"  real-time factor            {r['rtf']:.4f}, deadline misses "
        f"{r['misses_per_1e4']:.1f} per 10^4 steps, latency p99 "
        f"{r.get('latency_p99_ms', float('nan')):.2f} ms\n"
        f"  CPU                         stepping thread {r['step_thread_cpu_us']:.0f} "
        f"us a step, node process {r['process_cpu_us']:.0f} us a step (its own "
        f"count over the run's steps; {100 * r['cpu_share']:.0f} % of one core from "
        f"outside), recording process {100 * r['recorder_cpu_share']:.0f} %",
        flush=True,
    )
    return r


def _afap_runs(a, env, tmp: Path) -> dict:
    """``afap``: the node as fast as possible with and without recording, and mps record."""
    on = afap(True, env, tmp, a.afap_steps)
    off = afap(False, env, tmp, a.afap_steps)
    one = afap(True, env, tmp, a.afap_steps, in_process=True)
    rec = record_only(tmp, a.afap_steps)
    plain = loop_cost(min(a.afap_steps, 3000))
    print(
        f"as fast as possible, 1 kHz steps, {a.afap_steps} steps, no subscriber:\n"
        f"  node, recording on          real-time factor {on['rtf']:.2f}\n"
        f"  node, recording off         real-time factor {off['rtf']:.2f}\n"
        f"  node, recording on, stepping in the node's process (stepping_process:=false)\n"
        f"                              real-time factor {one['rtf']:.2f}\n"
        f"  mps record (no ROS)         real-time factor {rec['rtf']:.2f}\n"
        f"  the plain loop of the same steps: {plain:.0f} us a step, "
        f"{1e3 / plain:.2f}x real time by itself",
        flush=True,
    )
    return {
        "recording_on": on,
        "recording_off": off,
        "recording_on_in_process": one,
        "mps_record": rec,
        "plain_loop_us": plain,
    }


if __name__ == "__main__":
    sys.exit(main())
