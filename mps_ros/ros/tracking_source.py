"""Subscribe a node to a press's measurements (parameter ``track``) and hand each to its tracking run.

The source is a ``sensor_msgs/JointState`` topic, as ros2_control's joint_state_broadcaster
publishes a real press's encoders: the crank angle in radians (the joint named ``crank``, or the
only position of a message naming no joint), optionally the slider's position (joint ``slider``,
m), stamped with the measurement's time; read by :mod:`mps_ros.wire.measured`, as ``mps track
--recording`` reads a recording of it. ``track_mode`` names an ``std_msgs/String`` topic of mode
signals (``engage``, ``disengage``). Each measurement is taken as it comes
(:meth:`~mps_ros.run.tracking.TrackingRun.measurement`) by a thread of its own (a mode signal by
the executor), its bytes recorded as received; the subscriptions are made when the run starts
(after the node has waited for its peers), so a press's emulator that waits for its subscriber starts with it.
"""

from __future__ import annotations

import math
import struct
import threading
import time
from typing import Any

from rclpy.callback_groups import CallbackGroup
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from mps_core.track import Encoder, TorqueSensor
from mps_core.track.recording_input import Tuning

from ..recording.replay import joint_state_readings
from ..run.tracking import TrackingRun
from ..wire.measured import crank_and_slider, crank_torque, stamp_seconds
from ..wire.track_topics import RECEIVED_JOINTS, RECEIVED_MODE, TRACKING_TOPICS
from .endpoints import MSG_CLASSES

__all__ = ["TrackingSource", "add_endpoints", "tracking_run"]


def add_endpoints(node: Any) -> None:
    """Add the tracking topics' publishers to the node's endpoints, the inputs' names for the recording."""
    ep = node.endpoints
    st = node.settings
    qos = QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=st.qos_depth,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )
    outputs = set(st.outputs)
    for t in TRACKING_TOPICS:
        if t.output and t.output not in outputs:
            continue
        pub = node.create_publisher(
            MSG_CLASSES[t.msgtype],
            t.key,
            qos,
            event_callbacks=PublisherEventCallbacks(use_default_callbacks=False),
        )
        ep.pubs[t.key] = pub
        ep.names[t.key] = pub.topic_name
    ep.names[RECEIVED_JOINTS.key] = _topic(node, "track", st.track)
    if st.track_mode:
        ep.names[RECEIVED_MODE.key] = _topic(node, "track_mode", st.track_mode)


def _topic(node: Any, parameter: str, name: str) -> str:
    """Return the full name of the topic a parameter names (:class:`ParameterError` where it is none)."""
    from .parameters import ParameterError

    try:
        return str(node.resolve_topic_name(name))
    except Exception as exc:  # rclpy's InvalidTopicNameException and its kin
        raise ParameterError(
            f"parameter {parameter}: {name!r}: expected a ROS topic name such as /press/joint_states ({exc})"
        ) from None


def tracking_tuning(st: Any) -> Tuning:
    """Return the sensors' noise and the tracker's thresholds of the node's settings ``st``.

    Recorded in the node's recording (its ``mps`` metadata), so that ``mps track --recording``
    follows the press with them again.
    """
    return Tuning(
        encoder=Encoder(bits=st.track_encoder_bits, noise_counts=st.track_encoder_noise),
        torque=TorqueSensor(relative=st.track_torque_noise),
        timeout=st.track_timeout,
        max_jump_deg=st.track_max_jump,
        signal_latency=st.track_signal_latency if st.track_mode else 0.0,
    )


def tracking_run(node: Any) -> TrackingRun:
    """Return the node's tracking run, publishing through its endpoints' sink, its source attached.

    The run follows the twin's scene; its source subscribes as the run starts.
    """
    from ..run.sinks import Fanout

    st = node.settings
    tuning = tracking_tuning(st)
    run = TrackingRun(
        node.twin.scene,
        Fanout([node.endpoints.sink]),
        name=node.get_fully_qualified_name().lstrip("/"),
        outputs=st.outputs,
        settings=tuning.settings(),
        encoder=tuning.encoder,
        torque_sensor=tuning.torque,
        sigma_every=st.track_sigma_every,
        max_behind=st.track_max_behind,
        timeout=st.track_timeout,
        diagnostics_period=st.diagnostics_period,
        markers_hz=st.markers_hz,
        markers_scale=st.markers_scale,
        clock=time.time,  # the middleware's timestamps are on the system clock
        log=node._log,
        freeze_gc=True,
        fit_elsewhere=True,
    )
    source = TrackingSource(node, run)
    run.on_start = source.subscribe
    return run


class _TakenApart(CallbackGroup):
    """A callback group the executor never runs: its subscription is taken by a thread of its own."""

    def can_execute(self, entity: Any) -> bool:
        """Return False: the executor leaves the entity alone (not even in its wait set)."""
        return False

    def beginning_execution(self, entity: Any) -> bool:
        """Return False: never run by the executor."""
        return False

    def ending_execution(self, entity: Any) -> None:
        """Do nothing."""


class TrackingSource:
    """The subscriptions to a press's measurements and mode signals, each message handed to ``run``.

    The measurements are taken by a thread of their own, on a wait set that holds their
    subscription alone, every message waiting taken at each wake: the executor's round (a
    wait set of all the node's entities built again for each message: its services, its
    parameters', its lifecycle's) would cost more than the estimate at 1 kHz. The mode
    signals, a few a stroke, go through the executor.
    """

    #: the longest wait on the measurements before the thread looks whether the run stops (s)
    POLL = 0.05

    def __init__(self, node: Any, run: TrackingRun) -> None:
        self.node = node
        self.run = run
        self.subs: list = []
        self._reader: threading.Thread | None = None

    def subscribe(self) -> None:
        """Subscribe to the measurements (and the mode signals), their bytes as received."""
        st = self.node.settings
        # every measurement kept until taken (keep all, reliable): one dropped by a full
        # history would be a gap the tracker must bridge
        qos = QoSProfile(
            history=HistoryPolicy.KEEP_ALL,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.VOLATILE,
        )
        measurements = self.node.create_subscription(
            JointState, st.track, self.on_measurement, qos, raw=True, callback_group=_TakenApart()
        )
        self.subs.append(measurements)
        if st.track_mode:
            self.subs.append(
                self.node.create_subscription(String, st.track_mode, self.on_mode, qos, raw=True)
            )
        self._reader = threading.Thread(
            target=self._take_measurements, args=(measurements,), name="track-input", daemon=True
        )
        self._reader.start()
        self.run.on_end = self.stop
        self.node._log(
            "info", f"tracking {self.subs[0].topic_name}" + (f" and {st.track_mode}" if st.track_mode else "")
        )

    def stop(self) -> None:
        """Stop taking measurements (the thread ends within :attr:`POLL`)."""
        if self._reader is not None:
            self._reader.join()
            self._reader = None

    def _take_measurements(self, sub: Any) -> None:
        """Wait for measurements and take each as it comes, until the run stops."""
        context = self.node.context
        wait_set = _rclpy.WaitSet(1, 0, 0, 0, 0, 0, context.handle)
        timeout = int(self.POLL * 1e9)
        stopping = self.run.stopping
        try:
            while not stopping.is_set() and context.ok():
                with sub.handle:
                    wait_set.clear_entities()
                    wait_set.add_subscription(sub.handle)
                    wait_set.wait(timeout)
                    while not stopping.is_set():
                        taken = sub.handle.take_message(sub.msg_type, True)
                        if taken is None:
                            break
                        self.on_measurement(*taken)
        except Exception as exc:  # the middleware gone under it (a shutdown), or a bug: said, the run ended
            if not stopping.is_set() and context.ok():
                self.node._log("error", f"tracking: the measurements can no longer be taken: {exc!r}")
                self.run.request_stop("the measurements' thread failed")

    def on_measurement(self, data: bytes, info: dict) -> None:
        """Take one JointState's bytes: stamp, crank angle, slider position, motor torque."""
        arrival, sent = _times(info)
        raw = bytes(data)
        try:  # read as mps track --recording reads it (4 µs, rclpy's deserialisation 16)
            sec, nanosec, names, positions, efforts = joint_state_readings(raw)
        except (ValueError, struct.error):
            self.run.measurement(math.nan, None, None, raw, arrival, sent)  # counted as malformed
            return
        angle, slider = crank_and_slider(names, positions)
        torque = crank_torque(names, efforts)
        self.run.measurement(stamp_seconds(sec, nanosec), angle, slider, raw, arrival, sent, torque)

    def on_mode(self, data: bytes, info: dict) -> None:
        """Take one mode signal's bytes."""
        _arrival, sent = _times(info)
        msg = deserialize_message(data, String)
        self.run.mode(msg.data, bytes(data), sent)


def _times(info: dict) -> tuple[float, float]:
    """Return when a message arrived here and when its publisher sent it (s, the system clock).

    The middleware's timestamps (DDS reception and source), so a message that waited in the
    executor's queue counts that wait; the system clock's now where the middleware gives none.
    """
    now = time.time()
    received = info.get("received_timestamp") or 0
    source = info.get("source_timestamp") or 0
    arrival = received * 1e-9 if received else now
    return arrival, (source * 1e-9 if source else arrival)
