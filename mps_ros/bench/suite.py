"""The benchmark's runs of the node: realtime with a subscriber beside it (:func:`realtime`),
as fast as possible (:func:`afap`), ``mps record`` alone (:func:`record_only`), and the floors
they are measured against (:func:`ros_floor`, :func:`publish_floor`, :func:`loop_cost`). The
command line is :mod:`.cli`."""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
import time
from pathlib import Path

from ..commands.demo import stop_group
from ..ros.environment import env_defaults
from .processes import Usage, neighbours


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
    foxglove: str = "",
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
    if foxglove:  # the node's Foxglove endpoint, one client of it (``slow``: one that lags)
        params.update(foxglove_port=_free_port(), wait_for_foxglove=1)
    busy = neighbours(n_neighbours)  # for the whole run, the plain loop's too
    try:
        return _realtime(
            steps, env, tmp, deserialize, outputs, params, derivatives, commands_every, flood, foxglove
        )
    finally:
        for b in busy:
            stop_group(b)


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _foxglove_client(env, port: int, slow: bool, log_path: Path) -> subprocess.Popen:
    """The benchmark's Foxglove client (:mod:`.foxglove_probe`), in a session of its own."""
    return subprocess.Popen(
        [sys.executable, "-m", "mps_ros.bench.foxglove_probe", f"ws://127.0.0.1:{port}"]
        + (["--slow"] if slow else []),
        env=env,
        stdout=subprocess.PIPE,
        stderr=open(log_path, "wb"),
        text=True,
        start_new_session=True,
    )


def _realtime(
    steps, env, tmp, deserialize, outputs, params, derivatives, commands_every=None, flood=0, foxglove=""
) -> dict:
    t_end = steps * 1e-3
    loop = loop_cost(steps, outputs, derivatives)  # the same steps as the run's
    if outputs:
        params["outputs"] = "[" + outputs + "]"
    node = _node(params, env, tmp / "rt.log")
    probe = _probe(env, tmp / "probe.log", deserialize, commands_every, flood)
    fox = None
    if foxglove:
        log = tmp / "rt.log"
        end = time.monotonic() + 120
        while time.monotonic() < end and "foxglove endpoint" not in log.read_text() and node.poll() is None:
            time.sleep(0.05)
        fox = _foxglove_client(env, params["foxglove_port"], foxglove == "slow", tmp / "foxglove.log")
    try:
        log = tmp / "rt.log"
        end = time.monotonic() + 60
        while time.monotonic() < end and "stepping starts" not in log.read_text():
            time.sleep(0.01)
        # from the run's start (its kernels already built), after its first lead is banked
        time.sleep(0.2)
        usage = Usage(node.pid, probe.pid)
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
        if fox is not None:
            fout, _ = fox.communicate(timeout=60)
            st["foxglove"] = json.loads(fout.strip().splitlines()[-1])
            st["foxglove"]["recorded"] = sum(recorded_counts(tmp / "rt.mcap").values())
        usage.figures(st)
        _subscriber_figures(st, got, tmp / "rt.mcap")
        st["misses_per_1e4"] = st["misses"] * 1e4 / steps
        st["threads"] = usage.threads()
        st["loop_us"] = loop
    finally:
        stop_group(node)
        stop_group(probe)
        if fox is not None:
            stop_group(fox)
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
