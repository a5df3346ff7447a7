"""The ROS 2 node ``press_twin``: loads a scene, steps mps_core, publishes and records.

    mps node [SCENE] [--ros-args -p NAME:=VALUE ... --params-file FILE.yaml]

Topics, types, frames and signs: :mod:`mps_ros.wire.topics` (and the README). The run itself (steps,
pacing, commands, diagnostics) is :class:`mps_ros.run.runner.Runner`, the same one ``mps record``
uses; this module adds the ROS side: parameters, publishers, the ``~/mode`` subscription and the
``~/engage``, ``~/disengage``, ``~/stop``, ``~/start`` services (std_srvs/Trigger), the
recorder, signals. ROS callbacks run in a background executor thread and only queue commands;
the run loop applies them at the next step boundary and answers on ``~/mode/status`` (and to
the service caller).

Parameters (read-only; ``--ros-args -p`` or a YAML file, see ``config/press_twin.yaml``): the
table :data:`mps_ros.ros.parameters.PARAMETERS` (docs/ros.md lists it; ``ros2 param describe``
gives each one's description and range).
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
from pathlib import Path

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import WrenchStamped
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from mps_core import MpsError
from mps_core.scene.settings import COMMANDS as COMMAND_WORDS

from ..run.commands import Command, Gate, Inbox, shown
from ..run.runner import Runner
from ..run.twin import Twin, to_json
from ..wire.diagnostics import hardware_id
from ..wire.topics import BY_KEY, LATCHED, MODE, NODE_NAME, TOPICS, offered_qos, resolve
from .environment import env_defaults
from .parameters import ParameterError, declare, read

DEFAULT_SCENE = "press-cycle"

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


class RosSink:
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

    def emit(self, key, data, t_ns):
        p = self.pubs.get(key)
        if p is not None:
            try:
                p.publish(data)
            except Exception:  # a publisher destroyed at shutdown: nothing to send to
                pass

    def emit_all(self, msgs) -> int:
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

    def tick(self, deadline: float | None = None):
        pass


class NameTaken(RuntimeError):
    """Another node of this node's name and namespace is running in the same ROS domain."""


#: wall seconds after its creation within which a node expects to have discovered the others
#: on its machine (Fast DDS on loopback: well under one)
DISCOVERY_S = 2.5


class RunConfig:
    """A run's settings from the node's parameters (read and checked): the twin, the runner's
    pacing, whether the twin steps in a process of its own, and the runner (or the stepping
    process) that steps it. The same for every run of the node (a reset's too)."""

    def __init__(self, p: dict, name: str):
        self.p = p
        #: the node's fully qualified name, without its leading slash (its diagnostics' name)
        self.name = name

    def twin(self) -> Twin:
        """The scene's twin, new (:class:`ParameterError` where the scene cannot be loaded)."""
        p = self.p
        try:
            return Twin(p["scene"], **self._twin_settings())
        except (MpsError, OSError, ValueError) as exc:
            raise ParameterError(f"scene {p['scene']!r}: {exc}") from None

    def _twin_settings(self) -> dict:
        p = self.p
        return dict(
            dt=p["dt"] or None,
            t_end=p["t_end"] or None,
            outputs=p["outputs"],
            scene_commands=p["scene_commands"],
            markers_hz=p["markers_hz"],
            markers_scale=p["markers_scale"],
            derivatives=p["derivatives"] or None,
        )

    def splits(self, twin: Twin) -> bool:
        """Whether ``twin`` steps in a process of its own (:mod:`mps_ros.run.stepping`): asked for
        (``stepping_process``), in realtime pacing or where the twin can come back to a step."""
        p = self.p
        return p["stepping_process"] and (p["pacing"] == "realtime" or twin.rewindable)

    def pacing(self) -> dict:
        """The runner's settings from the parameters, the same in the node's process and in a
        stepping process of its own."""
        p = self.p
        return dict(
            real_time_factor=p["real_time_factor"],
            lead=p["lead"],
            command_delay=p["command_delay"],
            release_period=p["release_period"],
            release_slice=p["release_slice"],
            freeze_gc=True,
            publish_every=p["publish_every"],
            diagnostics_period=p["diagnostics_period"],
            name=self.name,
        )

    def gate(self) -> Gate:
        return Gate(self.p["command_burst"], self.p["command_rate"])

    def runner(self, twin: Twin, sink, inbox: Inbox, log) -> Runner:
        """The runner that steps ``twin`` in this process, publishing through ``sink``."""
        p = self.p
        return Runner(
            twin,
            sinks=[sink],
            pacing=p["pacing"],
            inbox=inbox,
            gate=self.gate(),
            log=log,
            **self.pacing(),
        )

    def stepping_process(self, twin: Twin, sink, log):
        """The stepping process that steps the scene of ``twin`` (not started), its releases
        published through ``sink``."""
        from ..run.releasing import SteppingProcess

        p = self.p
        spec = {
            "scene": p["scene"],
            "twin": dict(self._twin_settings(), outputs=list(p["outputs"])),
            "runner": self.pacing(),
            "grid": [twin.t0, twin.t_end, twin.n],
            "hardware_id": hardware_id(twin.scene.name),
            "afap": p["pacing"] != "realtime",
        }
        return SteppingProcess(spec, sink, log, self.gate(), _priority(p))


class PressTwin(LifecycleNode):
    """The node, a managed one (``rclpy.lifecycle``). Construct (its parameters declared and
    checked), configure (:meth:`configure`: the scene, the publishers, the kernels, the
    stepping process, the recording), activate (the run may start: :meth:`run` blocks until it
    ends or is stopped), deactivate and activate again (pause and go on), cleanup or shutdown
    (the run ends, its recording finished). Its parts: the run's settings (:class:`RunConfig`),
    the publishers, subscription and services (:class:`Endpoints`) and the commands that come
    through them (:class:`Commands`)."""

    def __init__(self, default_scene: str | None = None, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        self._created = time.monotonic()
        self._recording_reserved = False
        declare(self, default_scene or DEFAULT_SCENE)
        self.p = read(self)
        #: the run's settings from the parameters (every run of the node alike)
        self.config = RunConfig(self.p, self.get_fully_qualified_name().lstrip("/"))
        self.twin = self.runner = self.recorder = self.recording_sink = None
        #: the publishers, the command subscription and services (made at configure)
        self.endpoints: Endpoints | None = None
        #: the commands from outside (the callbacks of the subscription and services)
        self.commands = Commands(self)
        self.closed = False
        self.priority_got = 0
        self.split = False
        #: why configure failed (the node then ends)
        self.configure_error: Exception | None = None
        #: the run may start (the first activate); the node is to end (cleanup, shutdown)
        self.activated = threading.Event()
        self.ending = threading.Event()
        self.inactive = False  # deactivated (paused)
        self.runs = 0  # runs begun (a reset begins another)

    # -- the lifecycle (its transitions' callbacks: the executor's thread, or autostart's) --
    def on_configure(self, state) -> TransitionCallbackReturn:
        if self.runner is not None:  # configured once: a node runs one run
            return TransitionCallbackReturn.SUCCESS
        try:
            self.configure()
        except (ParameterError, MpsError, OSError) as exc:
            self.configure_error = exc
            if not self.p["autostart"]:  # autostart: the node's last line says it
                self.get_logger().error(f"configure failed: {exc}")
            self.ending.set()
            return TransitionCallbackReturn.FAILURE
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state) -> TransitionCallbackReturn:
        self.inactive = False
        if not self.activated.is_set():
            self.activated.set()
        else:
            self.runner.resume()
            self.get_logger().info("activated: the run goes on")
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        why = self.runner.pause() if self.activated.is_set() else None
        if why is not None:
            self.get_logger().error(f"cannot pause: {why}")
            return TransitionCallbackReturn.FAILURE
        self.inactive = True
        self.get_logger().info(
            "deactivated: paused (simulated time holds; a command is applied where it holds)"
        )
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, state) -> TransitionCallbackReturn:
        self._end("cleanup")
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state) -> TransitionCallbackReturn:
        self._end("shutdown")
        return TransitionCallbackReturn.SUCCESS

    def _end(self, reason: str) -> None:
        self.ending.set()
        if self.runner is not None:
            self.runner.resume()
            self.runner.request_stop(reason)

    def configure(self) -> None:
        """The scene, the publishers, the command subscription and services, the run
        (:meth:`new_run`)."""
        self.twin = self.config.twin()
        self.endpoints = Endpoints(self, self.twin.outputs, self.p["qos_depth"])
        self.inbox = Inbox()  # before the subscription that fills it
        self.endpoints.listen(self, self.commands)
        self.new_run(self.twin)

    def new_run(self, twin: Twin | None = None) -> None:
        """A run of the scene from its start: the twin (``twin``, or a new one), the runner (or
        the stepping process, started and its kernels built), the recording opened (after a
        reset, a new file beside the last: :func:`next_recording`). Paused from its start
        where the node is inactive."""
        self.runs += 1
        if twin is None:
            self.twin = self.config.twin()
        self.closed = False
        #: the twin steps in a process of its own (:mod:`mps_ros.run.stepping`); this process
        #: publishes what it releases and forwards the commands (as fast as possible, where
        #: the twin can come back to a step: a command's boundary is the last step released)
        self.split = self.config.splits(self.twin)
        if self.split:
            self.runner = self.config.stepping_process(self.twin, self.endpoints.sink, self._log)
            self.inbox = self.runner.inbox
        else:
            self.runner = self.config.runner(self.twin, self.endpoints.sink, self.inbox, self._log)
        rec = self.open_recording()
        if rec is not None:
            self.get_logger().info(f"recording to {rec.path}")
        # the kernels built (and the stepping process started) before the run may start
        self.runner.prepare()
        if self.inactive:
            self.runner.pause()

    # -- the runner's log (any of its threads) ------------------------------------------------
    def _log(self, level: str, text: str):
        lg = self.get_logger()
        # one call site a severity: rclpy's logger insists
        if level == "warn":
            lg.warning(text)
        elif level == "error":
            lg.error(text)
        else:
            lg.info(text)

    # -- the run ----------------------------------------------------------------------------
    def _wait_for_peers(self, stop: threading.Event) -> None:
        n_sub, n_cmd = self.p["wait_for_subscribers"], self.p["wait_for_commanders"]
        if not (n_sub or n_cmd):
            return
        deadline = time.monotonic() + self.p["wait_timeout"]
        while not stop.is_set():
            subs = min(pub.get_subscription_count() for pub in self.endpoints.pubs.values())
            cmds = self.count_publishers(self.endpoints.names[MODE.key])
            if subs >= n_sub and cmds >= n_cmd:
                return
            if time.monotonic() > deadline:
                self.get_logger().warning(
                    f"starting without all peers after {self.p['wait_timeout']:g} s "
                    f"(subscribers {subs}/{n_sub}, commanders {cmds}/{n_cmd})"
                )
                return
            time.sleep(0.01)

    def open_recording(self):
        from ..recording.background import BackgroundRecorder
        from ..recording.recorder import new_recording
        from ..run.record import run_metadata
        from ..run.sinks import RecordingSink

        path = self.p["recording"]
        self.recorder = self.recording_sink = None
        if path.lower() in ("", "none", "off", "false"):
            return None
        if path == "auto":
            path = new_recording(self.twin.scene.name)
        elif self.runs > 1:  # after a reset: a new file (or bag) beside the first
            path, self._recording_reserved = next_recording(path), False
        else:
            path, self._recording_reserved = claim_recording(path)
        meta = run_metadata(
            self.twin, "mps node", self.p["pacing"], self.p["real_time_factor"], self.p["publish_every"]
        )
        meta["node"] = self.get_fully_qualified_name()
        meta["ros_domain_id"] = os.environ.get("ROS_DOMAIN_ID", "0")
        meta["rmw_implementation"] = os.environ.get("RMW_IMPLEMENTATION", "")
        meta["fastdds_profiles_file"] = os.environ.get("FASTRTPS_DEFAULT_PROFILES_FILE", "")
        self.recorder = BackgroundRecorder(
            path,
            scene_name=self.twin.scene.name,
            scene_text=self.twin.scene.text,
            metadata=meta,
            flush_period=self.p["recording_flush_period"],
            compression=self.p["recording_compression"],
            max_bytes=int(self.p["recording_max_mb"] * 1e6),
            max_s=self.p["recording_max_s"],
        )
        self.recording_sink = RecordingSink(
            self.recorder,
            names=dict(self.endpoints.names),
            qos=offered_qos(self.p["qos_depth"]),
            log=self._log,
        )
        self.runner.sinks.append(self.recording_sink)
        return self.recorder

    def run(self, stop: threading.Event) -> dict:
        tw = self.twin
        names, unpublished = self.endpoints.names, self.endpoints.unpublished
        self.get_logger().info(
            f"scene {tw.scene.name}: {tw.n} steps of {tw.dt:.6g} s to t = {tw.t_end:g} s, "
            f"{self.p['pacing']}"
            + (f" x{self.p['real_time_factor']:g}" if self.p["pacing"] == "realtime" else "")
            + f", outputs {', '.join(tw.outputs)}"
            + ("" if self.p["scene_commands"] else f", scene commands off (listening on {names[MODE.key]})")
        )
        if unpublished:
            types = sorted({BY_KEY[k].msgtype.split("/")[0] for k in unpublished})
            self.get_logger().warning(
                f"{', '.join(names[k] for k in unpublished)}: recorded, not "
                f"published ({', '.join(types)} cannot be imported here; a full ROS install "
                "has it)"
            )
        # the kernels built and the channels registered while the peers are awaited
        self.runner.prepare()
        self._refuse_a_second_of_my_name(self._created + DISCOVERY_S, stop)
        self._wait_for_peers(stop)
        stop.wait(self.p["start_delay"])
        if stop.is_set():
            self.runner.request_stop("signal")
        if not self.split:
            self._set_priority()
        self.get_logger().info("stepping starts")
        return self.runner.run()

    def _refuse_a_second_of_my_name(self, until: float, stop: threading.Event) -> None:
        """:class:`NameTaken` where another node of this node's name and namespace runs in
        its domain (its topics, services and /clock would mix with this one's), looked for in
        the graph until ``until`` (monotonic s: the discovery's time), a stop, or one seen. A
        node that ended without a word (SIGKILL) before this one started is never in this
        one's graph: a participant learns of the others from themselves."""
        me = (self.get_name(), self.get_namespace())
        while not stop.is_set():
            if sum(1 for n in self.get_node_names_and_namespaces() if tuple(n) == me) > 1:
                raise NameTaken(
                    f"a node {self.get_fully_qualified_name()} is already running in ROS "
                    f"domain {os.environ.get('ROS_DOMAIN_ID', '0')}; give this one another "
                    "name or namespace (--ros-args -r __node:=NAME or -r __ns:=/NAMESPACE), or "
                    "another ROS_DOMAIN_ID"
                )
            if time.monotonic() >= until:
                return
            stop.wait(0.02)

    def _set_priority(self) -> None:
        """``realtime_priority`` > 0: the stepping thread runs under SCHED_FIFO at that priority
        (it sleeps between steps; the machine's real-time throttling still bounds it), so a
        step is not kept waiting by ordinary processes. Where the system does not allow it (no
        CAP_SYS_NICE, no such policy) the run goes on at normal priority, with a warning."""
        prio = _priority(self.p)
        if not prio:
            return
        from ..run.stepping import HOW_TO_ALLOW, ask_fifo

        why = ask_fifo(prio)
        if why is not None:
            self.get_logger().warning(
                f"realtime_priority {prio}: SCHED_FIFO refused here "
                f"({why}); stepping at normal priority; {HOW_TO_ALLOW}"
            )
            return
        self.priority_got = prio
        self.get_logger().info(f"stepping and publishing threads: SCHED_FIFO, priority {prio}")


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
        self.pubs: dict[str, object] = {}
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

    def __init__(self, node: PressTwin):
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


def _priority(p: dict) -> int:
    """The SCHED_FIFO priority the run asks for: ``realtime_priority`` in realtime pacing; none
    as fast as possible (no deadlines to keep: it never takes a core from the others)."""
    return p["realtime_priority"] if p["pacing"] == "realtime" else 0


def claim_recording(path) -> tuple[Path, bool]:
    """The recording path a user named, made this run's own: created empty where it is new;
    an empty file (one reserved for it, e.g. by ``mps demo``) is taken; anything else is
    :class:`~mps_core.files.outputs.OutputFileError` (a recording never replaces a file).
    Returns (the path, whether it was an empty file reserved for it)."""
    from mps_core.files.outputs import OutputFileError
    from mps_core.files.outputs import check_outputs as check_paths

    from ..recording.bag import is_bag
    from ..recording.recorder import reserve

    p = Path(path)
    if is_bag(p):  # a new directory
        check_paths({"parameter recording": p}, folders={"parameter recording"})
        try:
            p.mkdir()
        except FileExistsError:
            raise OutputFileError(p, "parameter recording", "exists; expected a new directory") from None
        return p, False
    if p.is_file() and p.stat().st_size == 0:
        return p, True
    exists = OutputFileError(
        p, "parameter recording", "exists; a recording never replaces a file: expected a new path"
    )
    if p.exists() and not p.is_dir():
        raise exists
    check_paths({"parameter recording": p})
    try:
        return reserve(p), False
    except FileExistsError:
        raise exists from None


def next_recording(path) -> Path:
    """The recording of the run after a reset: beside ``path``, ``NAME-2.mcap``, ``-3``…
    (a bag: ``NAME-2``…), the first that is free, claimed at once."""
    from ..recording.recorder import reserve_free

    return reserve_free(Path(path), start=2)


def discard_recording(path: Path, reserved: bool) -> None:
    """A recording begun by a node that did not run: gone, but for what was there before it (an
    empty file or directory reserved for it stays, empty)."""
    if path.is_dir():  # a bag: its files
        for f in path.iterdir():
            f.unlink(missing_ok=True)
        if not reserved:
            path.rmdir()
    elif reserved:
        path.write_bytes(b"")
    else:
        path.unlink(missing_ok=True)


def _split_argv(argv):
    """(scene or None, ROS arguments) from a command line like ``[SCENE] [--ros-args ...]``."""
    argv = list(argv)
    if "--ros-args" in argv:
        i = argv.index("--ros-args")
        plain, ros = argv[:i], argv[i:]
    else:
        plain, ros = argv, []
    plain = [a for a in plain if a]
    if len(plain) > 1:
        raise SystemExit(f"press_twin: one scene at most, got {plain}")
    return (plain[0] if plain else None), ros


def _one_run(node: PressTwin, stop: threading.Event) -> tuple[int, bool]:
    """The node's run, from its start to its end, its recording finished and its last lines
    said: (the exit status, whether another run follows: a reset, its run begun)."""
    taken = None
    try:
        stats = node.run(stop)
        code = _status(node)
    except NameTaken as exc:
        taken = exc
    except MpsError as exc:
        node.get_logger().error(f"the simulation stopped: {exc}")
        stats = node.runner.stats()
        code = 2
    except OSError as exc:  # the stepping process could not start its run
        if not node.split:
            raise
        node.get_logger().error(f"the run could not start: {exc}")
        return 2, False
    finally:
        recording_error = _closed(node)
    if taken is not None:  # nothing ran: the recording begun is not one
        if node.recorder is not None:
            discard_recording(node.recorder.path, node._recording_reserved)
        print(f"press_twin: error: {taken}", file=sys.stderr, flush=True)
        return 2, False
    node.endpoints.drain()
    _say_run_end(node, stats)
    if node.recorder is not None:
        failure = node.recording_sink.failure or recording_error
        if failure is None:
            node.get_logger().info(
                f"recording finished: {node.recorder.path} ({node.recorder.messages} messages)"
            )
        else:
            node.get_logger().error(f"recording incomplete ({failure})")
            code = code or 1
    again = node.commands.reset_wanted and not (stop.is_set() or node.ending.is_set())
    if again:
        node.commands.reset_wanted = False
        try:
            node.new_run()
        except (ParameterError, MpsError, OSError) as exc:
            node.get_logger().error(f"reset: no new run: {exc}")
            again, code = False, 2
    node.commands.run_started.set()  # a reset waiting for its answer: the new run, or none
    return code, again


def _status(node: PressTwin) -> int:
    """The exit status of a run that ended without an exception: 2 where its simulation failed
    in the stepping process (which said why: its log line), 1 where the stepping process failed
    otherwise, else 0."""
    if node.split and node.runner.error_kind == "simulation":
        return 2
    if node.split and node.runner.error:
        node.get_logger().error(f"the run failed: {node.runner.error}")
        return 1
    return 0


def _closed(node: PressTwin) -> str | None:
    """The run closed, however it ended: commands refused from now on, its recording finished,
    its stepping process ended. Why the recording could not be finished (said when it
    happened: the sink's line), or None."""
    node.closed = True
    recording_error = None
    if node.recorder is not None:
        try:
            node.recorder.finish()
        except OSError as exc:
            recording_error = str(exc)
    if node.split:
        node.runner.close()
    return recording_error


def _say_run_end(node: PressTwin, stats: dict) -> None:
    """The run's last line: how it ended and its statistics (``mps bench`` reads it)."""
    why = node.runner.stop_reason or "end"
    node.get_logger().info(
        f"run {'ended' if why == 'end' else 'stopped (' + why + ')'} at t = "
        f"{stats.get('t', node.twin.t):.6g} s after {stats['steps']} steps: real-time factor "
        f"{stats['real_time_factor']:.3g}, step p50 {stats['step_time_p50_ms']:.3g} ms, "
        f"p99 {stats['step_time_p99_ms']:.3g} ms, publish p50 "
        f"{stats['publish_time_p50_ms']:.3g} ms, p99 {stats['publish_time_p99_ms']:.3g} ms, "
        + (
            f"latency p50 {stats['latency_p50_ms']:.3g} ms, p99 {stats['latency_p99_ms']:.3g} ms, "
            if "latency_p50_ms" in stats
            else ""
        )
        + f"{stats['deadline_misses']} deadline misses, {stats['messages']} messages, "
        f"stepping thread CPU {stats['step_thread_cpu_per_step_us']:.0f} us a step, "
        f"process CPU {stats['process_cpu_per_step_us']:.0f} us a step, "
        + (
            f"stepping process {stats['stepping_process_cpu_per_step_us']:.0f} us and ROS "
            f"process {stats['ros_process_cpu_per_step_us']:.0f} us of it, "
            if "ros_process_cpu_per_step_us" in stats
            else ""
        )
        + f"realtime priority {stats.get('realtime_priority', node.priority_got)}, "
        + (
            f"publishing thread's slice {stats['release_slice_ms']:.3g} ms, "
            if "release_slice_ms" in stats
            else ""
        )
        + f"{stats['commands_accepted']} commands applied, {stats['commands_refused']} refused, "
        f"{stats['commands_lost']} lost"
    )


def main(argv=None) -> int:
    """``mps node [SCENE] [--ros-args ...]`` (argv without the program name)."""
    env_defaults()
    # the stepping, publishing and executor threads share the interpreter: a thread that wants
    # it waits at most this long for another to let go (the default 5 ms is five steps)
    sys.setswitchinterval(0.0002)
    if argv is None:
        argv = sys.argv[1:]
    scene, ros = _split_argv(argv)
    stop = threading.Event()
    runner_box: dict = {}
    old = _stop_on_signals(stop, runner_box)
    rclpy.init(args=[NODE_NAME, *ros], signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = None
    executor = None
    thread = None
    try:
        try:
            node = PressTwin(scene)
        except ParameterError as exc:
            print(f"press_twin: error: {exc}", file=sys.stderr, flush=True)
            return 2
        runner_box["node"] = node
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        thread = _spin_in_background(node, executor)
        _start(node)
        while not (node.activated.is_set() or node.ending.is_set() or stop.is_set()):
            stop.wait(0.05)
        if not node.activated.is_set():  # never activated: what was begun is not a run
            return _never_ran(node)

        code = 0
        again = True
        while again:
            status, again = _one_run(node, stop)
            code = max(code, status)
        return code
    finally:
        if executor is not None:
            executor.shutdown(timeout_sec=1.0)
        if thread is not None:
            thread.join(timeout=2.0)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        for s, h in old.items():
            signal.signal(s, h)


def _stop_on_signals(stop: threading.Event, runner_box: dict) -> dict:
    """SIGINT and SIGTERM set ``stop`` and stop the run of the node in ``runner_box`` (once
    there is one); the handlers they had before, to put back."""

    def on_signal(signum, _frame):
        name = signal.Signals(signum).name
        stop.set()
        node = runner_box.get("node")
        if node is not None and node.runner is not None:
            node.runner.resume()
            node.runner.request_stop(name)

    return {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}


def _spin_in_background(node: PressTwin, executor: SingleThreadedExecutor) -> threading.Thread:
    """The executor spun in a thread of its own (the node's callbacks), started; a callback
    that fails ends the node's run."""

    def spin():
        try:
            executor.spin()
        except ExternalShutdownException:
            pass
        except Exception as exc:  # a callback failed: the run must not go on deaf
            if node.runner is None or node.runner.stop_reason is None:
                node.get_logger().error(f"executor stopped: {type(exc).__name__}: {exc}")
                node._end("error")

    thread = threading.Thread(target=spin, name="press_twin-executor", daemon=True)
    thread.start()
    return thread


def _start(node: PressTwin) -> None:
    """``autostart``: the node configured and activated at once; else it waits, unconfigured,
    for a lifecycle manager."""
    if node.p["autostart"]:
        node.trigger_configure()
        if node.configure_error is None:
            node.trigger_activate()
    else:
        node.get_logger().info(
            "autostart false: unconfigured, waiting for a lifecycle manager "
            f"({node.get_fully_qualified_name()}/change_state: configure, activate)"
        )


def _never_ran(node: PressTwin) -> int:
    """A node that ended before its run started (never activated): what was begun is undone
    (the stepping process ended, the recording discarded); its exit status."""
    if node.split:
        node.runner.close()
    if node.recorder is not None:
        with contextlib.suppress(OSError):
            node.recorder.finish()
        discard_recording(node.recorder.path, node._recording_reserved)
    if node.configure_error is not None:
        print(f"press_twin: error: {node.configure_error}", file=sys.stderr, flush=True)
        return 2
    node.get_logger().info("ended before its run started")
    return 0


if __name__ == "__main__":
    sys.exit(main())
