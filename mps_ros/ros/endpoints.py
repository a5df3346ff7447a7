"""The node's ROS endpoints: the message classes by type name (:data:`MSG_CLASSES`), the sink
that publishes a run's messages (:class:`RosSink`), the publishers, subscription and services
(:class:`Endpoints`) and the commands that come through them (:class:`Commands`)."""

from __future__ import annotations

import threading
import time
from collections.abc import Sequence

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import WrenchStamped
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.lifecycle import LifecycleNode
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from mps_core.scene.settings import COMMANDS as COMMAND_WORDS

from ..run.commands import Command, shown
from ..run.sinks import Message, Sink
from ..wire.json_text import to_json
from ..wire.topics import LATCHED, MODE, TOPICS, resolve

MSG_CLASSES = {
    "rosgraph_msgs/msg/Clock": Clock,
    "sensor_msgs/msg/JointState": JointState,
    "visualization_msgs/msg/MarkerArray": MarkerArray,
    "geometry_msgs/msg/WrenchStamped": WrenchStamped,
    "std_msgs/msg/String": String,
    "diagnostic_msgs/msg/DiagnosticArray": DiagnosticArray,
}
try:  # in a full ROS install; not among the wheels from PyPI
    from tf2_msgs.msg import TFMessage

    MSG_CLASSES["tf2_msgs/msg/TFMessage"] = TFMessage
except ImportError:
    pass


class RosSink(Sink):
    """A :class:`~mps_ros.run.runner.Runner` sink that publishes each message's CDR bytes on its
    topic: the very bytes the recorder writes. In realtime pacing the runner calls it from its
    releasing thread, at each step's deadline, beside the steps computed ahead."""

    #: released at the steps' deadlines (the recorder is fed after, off that path)
    live = True

    def __init__(self, publishers: dict):
        self.pubs = publishers  # key -> publisher
        self._raw: dict = {}  # key -> the publisher's own publish_raw, or False

    def _publisher(self, key):
        """The publisher's own ``publish_raw`` for ``key`` (what ``Publisher.publish`` calls
        for bytes, without its checks: the run's publishers outlive its releases); False
        where the key is not published (recorded only), kept so."""
        f = self._raw.get(key)
        if f is None:
            p = self.pubs.get(key)
            f = self._raw[key] = (
                False if p is None else getattr(getattr(p, "handle", None), "publish_raw", None) or p.publish
            )
        return f

    def emit_all(self, msgs: Sequence[Message]) -> int:
        """A released step's messages, ``(key, data, t_ns, received)`` each, in order (the
        commands as received are not published again); how many were to go out (a key
        with no publisher, recorded only, is not counted). Each goes straight to its
        publisher's ``publish_raw`` (what ``Publisher.publish`` calls for bytes, without its
        checks: the run's publishers live until the releasing thread has ended)."""
        raw = self._raw
        n = 0
        for key, data, _t, received in msgs:
            if received:
                continue
            f = raw.get(key)
            if f is None:
                f = self._publisher(key)
            if not f:
                continue
            n += 1
            try:
                f(data)
            except Exception:  # a publisher destroyed at shutdown: nothing to send to
                pass
        return n


class Endpoints:
    """The node's ROS side, made at configure and kept for every run (a reset's too): a
    publisher a topic of the twin's outputs (latched where the topic is), the sink that
    publishes a run's messages on them, the ``~/mode`` subscription and the command services
    (:meth:`listen`), and each topic's name as resolved."""

    def __init__(self, node: LifecycleNode, outputs, qos_depth: int):
        qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST,
            depth=qos_depth,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.VOLATILE,
        )
        outputs = set(outputs)
        latched = QoSProfile(
            history=HistoryPolicy.KEEP_LAST,
            depth=1,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
        )
        self.pubs: dict[str, Publisher] = {}
        self.names: dict[str, str] = {}
        #: topics recorded but not published: their type cannot be imported here
        self.unpublished: list[str] = []
        for t in TOPICS:
            if t.output and t.output not in outputs:
                continue
            if t.msgtype not in MSG_CLASSES:
                self.unpublished.append(t.key)
                self.names[t.key] = resolve(t.key, node.get_name(), node.get_namespace())
                continue
            # no QoS event handlers (rclpy's default: two a publisher, each one more entity
            # that the executor goes through for every command it takes; a subscriber that
            # asks for an incompatible QoS is told so by its own node)
            pub = node.create_publisher(
                MSG_CLASSES[t.msgtype],
                t.key,
                latched if t.key in LATCHED else qos,
                event_callbacks=PublisherEventCallbacks(use_default_callbacks=False),
            )
            self.pubs[t.key] = pub
            self.names[t.key] = pub.topic_name
        self.sink = RosSink(self.pubs)

    def listen(self, node: LifecycleNode, commands: Commands) -> None:
        """The ``~/mode`` subscription and the command services, answered by ``commands``."""
        # every command is kept until the run loop answers it (a flood is refused, one answer
        # each); what a sender's middleware loses on the way is counted (message-lost events)
        mode_qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
        self.mode_sub = node.create_subscription(
            String,
            MODE.key,
            commands.on_mode,
            mode_qos,
            event_callbacks=SubscriptionEventCallbacks(message_lost=commands.on_lost),
        )
        self.names[MODE.key] = self.mode_sub.topic_name
        self.trigger_services = [
            node.create_service(Trigger, f"~/{w}", commands.service(w)) for w in COMMAND_WORDS
        ]
        self.step_service = node.create_service(Trigger, "~/step", commands.on_step)
        self.reset_service = node.create_service(Trigger, "~/reset", commands.on_reset)

    def drain(self, timeout: float = 1.0) -> None:
        """Give the subscribers a bounded time to acknowledge what was published (the writers
        learn of acknowledgements at their heartbeats: this mostly waits out ``timeout``)."""
        end = time.monotonic() + timeout
        for pub in self.pubs.values():
            left = end - time.monotonic()
            if left <= 0:
                break
            try:
                pub.wait_for_all_acked(rclpy.duration.Duration(seconds=left))
            except Exception:
                pass


class Commands:
    """The commands from outside, the callbacks of the ``~/mode`` subscription and the
    services (the executor's thread: they only queue; the run loop applies a command at the
    next step boundary and answers): ``~/mode`` (answered at once where the run has ended),
    ``~/engage``... (their answer awaited), ``~/step`` (one step while the node is paused) and
    ``~/reset`` (this run ended and a new one begun: :attr:`reset_wanted`, and the run loop
    sets :attr:`run_started` once the new run has begun, or will not)."""

    def __init__(self, node):
        self.node = node
        self.reset_wanted = False
        self.run_started = threading.Event()  # the run after a reset has begun

    def on_lost(self, info) -> None:
        node = self.node
        n = int(info.total_count_change)
        if node.runner is not None:
            node.runner.commands_lost += n
        node.get_logger().warning(
            f"{n} command(s) lost on the way to {node.endpoints.names[MODE.key]} ({info.total_count} in all)"
        )

    def on_mode(self, msg: String):
        node = self.node
        if node.closed:
            # answered all the same (not recorded: the recording is finished)
            node.get_logger().warning(f"refused command {msg.data[:40]!r}: the run has ended")
            ack = {
                "t": node.twin.t,
                "command": shown(msg.data, 64),
                "accepted": False,
                "reason": "the run has ended",
                "source": "topic",
                "structure": node.twin.sim.structure,
            }
            pub = node.endpoints.pubs.get("~/mode/status")
            if pub is not None:
                try:
                    pub.publish(String(data=to_json(ack)))
                except Exception:  # destroyed at shutdown
                    pass
            return
        node.inbox.put(Command(msg.data, "topic"))

    def on_reset(self, request, response):
        """``~/reset``: this run ends (its recording finished) and a new one begins at the
        scene's start, recorded to a new file (paused where the node is inactive)."""
        node = self.node
        if not node.activated.is_set() or node.runner is None:
            response.success, response.message = False, "refused: the run has not started"
            return response
        runs = node.runs
        self.run_started.clear()
        self.reset_wanted = True
        node.runner.resume()
        node.runner.request_stop("reset")
        if not self.run_started.wait(120.0) or node.runs == runs:
            response.success, response.message = False, "no new run: the node is ending"
            return response
        where = f"recording to {node.recorder.path}" if node.recorder is not None else "not recording"
        response.success = True
        response.message = f"reset: a new run from t = {node.twin.t0:g} s, {where}"
        return response

    def on_step(self, request, response):
        """``~/step``: one step while the node is deactivated (paused)."""
        node = self.node
        done = threading.Event()
        box = {}

        def reply(t):
            box["t"] = t
            done.set()

        why = (
            node.runner.step_paused(reply)
            if node.activated.is_set()
            else ("the run has not started: ~/step takes a step while it is deactivated")
        )
        if why is not None:
            response.success, response.message = False, f"refused: {why}"
        elif not done.wait(10.0):
            response.success, response.message = False, "no answer: the step did not come"
        else:
            response.success, response.message = True, f"stepped to t = {box['t']:.6f} s"
        return response

    def service(self, word: str):
        """The callback of the service ``~/WORD``: the command queued, its answer awaited."""
        node = self.node

        def callback(request, response):
            if node.closed:
                response.success, response.message = False, "refused: the run has ended"
                return response
            done = threading.Event()
            box = {}

            def reply(ack):
                box["ack"] = ack
                done.set()

            node.inbox.put(Command(word, "service", reply))
            if not done.wait(10.0):
                response.success, response.message = False, "no answer: the run is not stepping"
                return response
            ack = box["ack"]
            response.success = bool(ack["accepted"])
            response.message = (
                f"{word} applied at t = {ack['t']:.6f} s" if ack["accepted"] else f"refused: {ack['reason']}"
            )
            return response

        return callback
