"""The benchmark's subscriber (``python -m mps_ros.bench probe``, :func:`probe`): every topic
taken (reliable) and counted, the operator's commands sent meanwhile."""

from __future__ import annotations

import json
import math
import sys
import time

from ..ros.environment import env_defaults

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
