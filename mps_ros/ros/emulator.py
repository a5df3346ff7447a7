"""Publish what a press's sensors read, from a truth scene, at their stamps on the wall clock.

The ROS node ``press_emulator`` (``mps emulator SCENE``): the truth of SCENE
(:func:`mps_core.track.truth_scene`: masses, friction, part and motor off the nominal) is run
first (:func:`mps_core.track.run_truth`, faults injected at their times), then its sensors'
readings are published as a real press's would be: the crank encoder (17 bits, 1 kHz, stamp
jitter) as ``sensor_msgs/JointState`` (joint ``crank``, the count's centre in radians; with the
slider scale, joint ``slider`` in m; with the motor's torque, the crank's effort in N·m), stamped
with the measurement's time, each at that time after the start on the wall clock; the
controller's mode signals (``engage``, ``disengage``) as ``std_msgs/String`` before the first
measurement at or after their time. Glitches can be put
into the stream (``jump``: the crank read 20° off; ``duplicate``: a message sent twice;
``out-of-order``: a message stamped before the one sent before it) to see a follower reject
them. It starts once its measurements' topic has as many subscribers as asked.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import rclpy
from builtin_interfaces.msg import Time
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from mps_core.track import Measurement, ModeSignal

__all__ = ["GLITCHES", "Glitch", "Samples", "publish", "samples"]

#: what can be put wrong into the published stream
GLITCHES = ("jump", "duplicate", "out-of-order")
#: a glitch's crank jump (degrees): no press turns so between two samples
JUMP_DEG = 20.0


@dataclass(frozen=True)
class Glitch:
    """A glitch put into the stream at the first measurement at or after ``t`` (s)."""

    t: float
    kind: str


@dataclass(frozen=True)
class Samples:
    """One sampling instant: stamp (s), crank angle (rad), slider position (m), motor torque (N·m).

    The slider's and the torque are None where not measured.
    """

    t: float
    angle: float
    slider: float | None
    torque: float | None = None


def samples(measurements: list[Measurement]) -> list[Samples]:
    """Return the measurements grouped by their stamp (the encoder's and the scale's at one instant)."""
    out: list[Samples] = []
    by_t: dict[float, dict[str, float]] = {}
    for m in measurements:
        by_t.setdefault(m.t, {})[m.kind] = m.value
    for t in sorted(by_t):
        v = by_t[t]
        if "crank_angle" in v:
            out.append(Samples(t, v["crank_angle"], v.get("slider_position"), v.get("motor_torque")))
    return out


def _stamp(t: float) -> Time:
    """Return the ROS time of ``t`` (s), to the nanosecond."""
    ns = int(round(t * 1e9))
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def _joint_state(s: Samples, t: float | None = None, angle: float | None = None) -> JointState:
    """Return the JointState of one sampling instant (its stamp and angle replaced where given)."""
    msg = JointState()
    msg.header.stamp = _stamp(s.t if t is None else t)
    msg.header.frame_id = "press"
    msg.name = ["crank"] + (["slider"] if s.slider is not None else [])
    msg.position = [float(s.angle if angle is None else angle)] + (
        [float(s.slider)] if s.slider is not None else []
    )
    if s.torque is not None:  # the crank's; none for the slider
        msg.effort = [float(s.torque)] + ([math.nan] if s.slider is not None else [])
    return msg


def publish(
    stream: list[Samples],
    modes: list[ModeSignal],
    glitches: list[Glitch],
    *,
    topic: str,
    mode_topic: str,
    subscribers: int,
    wait: float,
    real_time_factor: float = 1.0,
    log: Callable[[str], None],
) -> int:
    """Publish ``stream`` and ``modes`` at their stamps on the wall clock; return the exit status.

    Waits up to ``wait`` seconds for ``subscribers`` subscribers on ``topic`` (1: nothing
    published is lost to a follower that is not there yet); 1 where they did not come.
    ``real_time_factor``: the press's seconds a wall second (the stamps are the press's).
    """
    node = rclpy.create_node("press_emulator")
    qos = QoSProfile(  # every reading delivered to a follower that keeps all (the node's source)
        history=HistoryPolicy.KEEP_ALL,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )
    pub = node.create_publisher(JointState, topic, qos)
    mode_pub = node.create_publisher(String, mode_topic, qos) if mode_topic else None
    try:
        deadline = time.monotonic() + wait
        while pub.get_subscription_count() < subscribers or (
            mode_pub is not None and modes and mode_pub.get_subscription_count() < subscribers
        ):
            if time.monotonic() > deadline:
                missing = [pub.topic_name] if pub.get_subscription_count() < subscribers else []
                if mode_pub is not None and mode_pub.get_subscription_count() < subscribers:
                    missing.append(
                        f"{mode_pub.topic_name} (a follower without mode signals: --mode-topic '')"
                    )
                log(f"emulator: no follower on {' and '.join(missing)} after {wait:g} s: published nothing")
                return 1
            time.sleep(0.01)
        pending = sorted(glitches, key=lambda g: g.t)
        todo = sorted(modes, key=lambda m: m.t)
        late: list[float] = []
        sent = 0
        start = time.monotonic()
        prev: Samples | None = None
        for s in stream:
            due = start + s.t / real_time_factor
            now = time.monotonic()
            if due > now:
                time.sleep(due - now)
            late.append(time.monotonic() - due)
            while todo and todo[0].t <= s.t:
                m = todo.pop(0)
                if mode_pub is not None:
                    mode_pub.publish(String(data=m.command))
            kind = pending.pop(0).kind if pending and pending[0].t <= s.t else None
            if kind == "jump":
                pub.publish(_joint_state(s, angle=s.angle + math.radians(JUMP_DEG)))
            elif kind == "out-of-order" and prev is not None:
                pub.publish(_joint_state(s))
                pub.publish(_joint_state(prev, t=0.5 * (prev.t + s.t)))  # older than the last sent
            else:
                pub.publish(_joint_state(s))
                if kind == "duplicate":
                    pub.publish(_joint_state(s))
            sent += 1
            prev = s
        pub.wait_for_all_acked(rclpy.duration.Duration(seconds=5.0))
        ms = np.array(late) * 1e3
        log(
            f"emulator: published {sent} measurements on {pub.topic_name} from t = "
            f"{stream[0].t if stream else 0:.6f} to {stream[-1].t if stream else 0:.6f} s"
            + (f", {len(modes)} mode signals on {mode_pub.topic_name}" if mode_pub is not None else "")
            + (f", glitches: {', '.join(f'{g.kind} at {g.t:g} s' for g in glitches)}" if glitches else "")
            + (
                f"; published after its time p50 {np.percentile(ms, 50):.3g} ms, p99 "
                f"{np.percentile(ms, 99):.3g} ms, max {ms.max():.3g} ms "
                f"(at t = {stream[int(ms.argmax())].t:.4f} s)"
                if len(ms)
                else ""
            )
        )
        return 0
    finally:
        node.destroy_node()
