"""A press's measurement message read as a tracker takes it: one reading, for the node and ``mps track``.

A press's encoders come as a ``sensor_msgs/JointState`` (ros2_control's joint_state_broadcaster):
the crank angle in radians is the position of the joint named :data:`CRANK`, or the only
position of a message that names no joint; the slider's position (m) is the joint
:data:`SLIDER`'s, where it has one; the motor's torque on the crank (N·m, from its current) is
the crank's effort, where the message has one (a NaN effort: none). The measurement's time is
the header's stamp, in seconds as ``sec + nanosec·10⁻⁹``, and a time a recording keeps in
nanoseconds (a mode signal's log time) is read the same way (:func:`ns_seconds`). The node following a press
(:mod:`mps_ros.ros.tracking_source`, the message from rclpy) and ``mps track`` over a recording
(:mod:`mps_ros.recording.track_input`, the message from its CDR bytes) both read it here, so the
tracker gets the same numbers from either.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from mps_core.track.measurements import Measurement, TorqueSensor

__all__ = [
    "CRANK",
    "SLIDER",
    "crank_and_slider",
    "crank_torque",
    "measurements",
    "ns_seconds",
    "stamp_seconds",
]

#: the joint whose position is the crank angle (rad)
CRANK = "crank"
#: the joint whose position is the slider's (m, along the guide, up)
SLIDER = "slider"


def stamp_seconds(sec: int, nanosec: int) -> float:
    """Return a ``builtin_interfaces/Time`` in seconds, as the tracker takes a measurement's stamp."""
    return sec + nanosec * 1e-9


def ns_seconds(t_ns: int) -> float:
    """Return a time in nanoseconds in seconds, read as a stamp of the same time (:func:`stamp_seconds`)."""
    sec, nanosec = divmod(int(t_ns), 1_000_000_000)
    return stamp_seconds(sec, nanosec)


def crank_and_slider(names: Sequence[str], positions: Sequence[float]) -> tuple[float | None, float | None]:
    """Return the crank angle and the slider's position of a JointState's names and positions.

    None for one the message does not carry: the crank is the joint :data:`CRANK`'s position, or
    the only position of a message without names; the slider the joint :data:`SLIDER`'s.
    """
    names = list(names)
    angle = slider = None
    if CRANK in names and names.index(CRANK) < len(positions):
        angle = float(positions[names.index(CRANK)])
    elif len(positions) == 1 and not names:
        angle = float(positions[0])
    if SLIDER in names and names.index(SLIDER) < len(positions):
        slider = float(positions[names.index(SLIDER)])
    return angle, slider


def crank_torque(names: Sequence[str], efforts: Sequence[float]) -> float | None:
    """Return the motor's torque on the crank of a JointState's names and efforts.

    The joint :data:`CRANK`'s effort, or the only effort of a message without names; None where
    it carries none (or NaN: a message with efforts for some joints only).
    """
    names = list(names)
    torque = None
    if CRANK in names and names.index(CRANK) < len(efforts):
        torque = float(efforts[names.index(CRANK)])
    elif len(efforts) == 1 and not names:
        torque = float(efforts[0])
    return None if torque is None or math.isnan(torque) else torque


def measurements(
    t: float,
    angle: float,
    slider: float | None,
    torque: float | None,
    angle_variance: float,
    slider_variance: float,
    torque_sensor: TorqueSensor,
) -> list[Measurement]:
    """Return one message's readings at stamp ``t`` as the tracker takes them, in its order.

    The crank angle, then the slider's position and the motor's torque where the message has
    them, each with its variance (the torque's from ``torque_sensor``).
    """
    out = [Measurement(t, "crank_angle", float(angle), angle_variance)]
    if slider is not None:
        out.append(Measurement(t, "slider_position", float(slider), slider_variance))
    if torque is not None:
        out.append(Measurement(t, "motor_torque", float(torque), torque_sensor.variance(torque)))
    return out
