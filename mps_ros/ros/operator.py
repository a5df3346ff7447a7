"""A small operator client for ``press_twin``: watches ``/clock`` and, when the simulated time
reaches a scheduled command, sends it on ``/press_twin/mode`` (std_msgs/String), as a person at
the press's panel would; prints the node's answers (``~/mode/status``) and ends with the run
(the node's ``run-end`` event), or when the node is gone.

    mps operator [SCENE] [--at T:WORD ...] [--node /press_twin] [--wait S] [--timeout S]

A command goes out on the first ``/clock`` at or after its time; the node applies it at the next
step boundary after it arrives, so it takes effect a step or so after the scheduled time, and
the node's answer says exactly when.

The schedule is checked before rclpy starts (``mps operator`` parses ``--at``, the scene is
loaded there): a bad word or time is one line and exit status 2. When it does not end with the
run, one line says why, what was sent and what was not: no node subscribed to the mode topic
within ``--wait`` seconds, ``--timeout`` reached, the node gone, or a signal. Exit status: 0
every command sent and applied; 1 one refused, unanswered or not sent, or no node; 2 bad input;
130 on SIGINT (Ctrl-C) and 143 on SIGTERM (128 + the signal's number), no traceback.
"""

from __future__ import annotations

import json
import signal
import time

import rclpy
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from std_msgs.msg import String


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


def outcome(why: str, sent, todo) -> str:
    """Say in one line why the operator ends, which words it sent and which it did not."""
    line = f"{why}: sent " + (", ".join(sent) or "nothing")
    return line + ("; not sent: " + ", ".join(todo) if todo else "")


def run_operator(args, schedule: list[tuple[float, str]], stop: dict) -> int:
    """Send ``schedule`` (time, word) to the node; its exit status (see the module's doc).

    ``stop["signum"]`` is set by the caller's SIGINT and SIGTERM handlers (installed before
    rclpy was imported); the run ends at the next look."""
    why: str | None  # why it ends
    if stop["signum"] is not None:  # before rclpy started: nothing to say to anyone
        why = f"stopped by {signal.Signals(stop['signum']).name} before it started"
        say(outcome(why, [], [w for _, w in schedule]))
        return 128 + stop["signum"]
    rclpy.init(args=["press_operator"], signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    op = Operator(args.node, schedule)
    topic = op.pub.topic_name
    say(
        "will send " + (", ".join(f"{w!r} at t = {t:g} s" for t, w in schedule) or "nothing") + f" on {topic}"
    )
    start = time.monotonic()
    heard = False  # a node has subscribed to the mode topic
    why = None  # why it ends, when not with the run
    code = 0
    try:
        while not op.ended:
            if stop["signum"] is not None:
                why = f"stopped by {signal.Signals(stop['signum']).name}"
                code = 128 + stop["signum"]
                break
            rclpy.spin_once(op, timeout_sec=0.05)
            now = time.monotonic()
            heard = heard or op.pub.get_subscription_count() > 0
            if not heard and now - start > args.wait:
                why, code = f"no node answered on {topic} in {args.wait:g} s", 1
                break
            if now - start > args.timeout:
                why, code = f"gave up after {args.timeout:g} s (--timeout)", 1
                break
            if (
                op.last_clock_wall is not None
                and now - op.last_clock_wall > 5.0
                and op.count_publishers("/clock") == 0
            ):
                why = "the node is gone"
                break
        if stop["signum"] is None:
            # answers to the last commands may still be on their way
            end = time.monotonic() + 1.0
            while len(op.acks) < len(op.sent) and time.monotonic() < end and stop["signum"] is None:
                rclpy.spin_once(op, timeout_sec=0.05)
        if why is not None:
            say(outcome(why, [w for _, _, w in op.sent], [w for _, w in op.todo]))
        elif op.todo:
            say("not sent (the run ended first): " + ", ".join(w for _, w in op.todo))
        refused = [a for a in op.acks if not a.get("accepted")]
        if refused or len(op.acks) < len(op.sent) or op.todo:
            code = code or 1
        return code
    finally:
        op.destroy_node()
        rclpy.try_shutdown()
