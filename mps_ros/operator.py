"""A small operator client for ``press_twin``: watches ``/clock`` and, when the simulated time
reaches a scheduled command, sends it on ``/press_twin/mode`` (std_msgs/String), as a person at
the press's panel would; prints the node's answers (``~/mode/status``) and ends with the run
(the node's ``run-end`` event), or when the node is gone.

    mps operator [SCENE] [--at T:WORD ...] [--node /press_twin]

A command goes out on the first ``/clock`` at or after its time; the node applies it at the next
step boundary after it arrives, so it takes effect a step or so after the scheduled time, and
the node's answer says exactly when.
"""

from __future__ import annotations

import json
import signal
import sys
import time

from .node import env_defaults

env_defaults()

import rclpy  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from std_msgs.msg import String  # noqa: E402


def schedule_of(args) -> list[tuple[float, str]]:
    if args.at:
        out = []
        for item in args.at:
            t, _, word = item.partition(":")
            try:
                out.append((float(t), word.strip()))
            except ValueError:
                raise SystemExit(f"mps operator: --at {item!r}: expected T:WORD, e.g. 0.008:engage") from None
        return sorted(out)
    from mps_core import load_scene

    return sorted((float(t), w) for t, w in load_scene(args.scene).commands)


def say(text: str) -> None:
    print(f"operator: {text}", flush=True)


class Operator(Node):
    def __init__(self, node: str, schedule):
        super().__init__("press_operator")
        node = "/" + node.strip("/")
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.pub = self.create_publisher(String, f"{node}/mode", qos)
        # the latest clock only (ROS's clock QoS): never behind, never slowing anyone down
        self.create_subscription(
            Clock,
            "/clock",
            self._on_clock,
            QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.BEST_EFFORT),
        )
        self.create_subscription(
            String,
            f"{node}/mode/status",
            self._on_status,
            QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE),
        )
        self.create_subscription(
            String,
            f"{node}/events",
            self._on_event,
            QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE),
        )
        self.todo = list(schedule)
        self.t = None
        self.sent: list[tuple[float, float, str]] = []  # (scheduled, clock when sent, word)
        self.acks: list[dict] = []
        self.ended = False
        self.last_clock_wall = None

    def _on_clock(self, msg):
        self.t = msg.clock.sec + msg.clock.nanosec * 1e-9
        self.last_clock_wall = time.monotonic()
        self.send_due()

    def send_due(self):
        while self.todo and self.t is not None and self.t >= self.todo[0][0]:
            if self.pub.get_subscription_count() == 0:
                return  # the node does not hear us yet: next clock
            t_s, word = self.todo.pop(0)
            self.pub.publish(String(data=word))
            self.sent.append((t_s, self.t, word))
            say(f"t = {self.t:.4f} s: sent {word!r} (scheduled at {t_s:g} s)")

    def _on_status(self, msg):
        try:
            ack = json.loads(msg.data)
        except ValueError:
            return
        self.acks.append(ack)
        if ack.get("accepted"):
            say(f"{ack['command']!r} applied at t = {ack['t']:.4f} s (structure {ack.get('structure')})")
        else:
            say(f"{ack['command']!r} refused at t = {ack['t']:.4f} s: {ack.get('reason')}")

    def _on_event(self, msg):
        try:
            ev = json.loads(msg.data)
        except ValueError:
            return
        if ev.get("kind") == "run-end":
            self.ended = True
            say(f"the run ended at t = {ev['t']:.4f} s ({ev.get('reason')})")


def run_operator(args) -> int:
    schedule = schedule_of(args)
    stop = {"flag": False}

    def on_signal(signum, _frame):
        stop["flag"] = True

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    rclpy.init(args=["press_operator"], signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    op = Operator(args.node, schedule)
    say(
        "will send "
        + (", ".join(f"{w!r} at t = {t:g} s" for t, w in schedule) or "nothing")
        + f" on {op.pub.topic_name}"
    )
    start = time.monotonic()
    code = 0
    try:
        while not stop["flag"] and not op.ended:
            rclpy.spin_once(op, timeout_sec=0.05)
            now = time.monotonic()
            if now - start > args.timeout:
                say(f"giving up after {args.timeout:g} s")
                code = 1
                break
            if (
                op.last_clock_wall is not None
                and now - op.last_clock_wall > 5.0
                and op.count_publishers("/clock") == 0
            ):
                say("the node is gone")
                break
        # answers to the last commands may still be on their way
        end = time.monotonic() + 1.0
        while len(op.acks) < len(op.sent) and time.monotonic() < end:
            rclpy.spin_once(op, timeout_sec=0.05)
        refused = [a for a in op.acks if not a.get("accepted")]
        if op.todo:
            say("not sent (the run ended first): " + ", ".join(w for _, w in op.todo))
        if refused or len(op.acks) < len(op.sent) or op.todo:
            code = code or 1
        return code
    finally:
        op.destroy_node()
        rclpy.try_shutdown()
        for s, h in old.items():
            signal.signal(s, h)


if __name__ == "__main__":
    import argparse

    p = argparse.ArgumentParser()
    p.add_argument("scene", nargs="?", default="press-cycle")
    p.add_argument("--at", action="append")
    p.add_argument("--node", default="/press_twin")
    p.add_argument("--timeout", type=float, default=120.0)
    sys.exit(run_operator(p.parse_args()))
