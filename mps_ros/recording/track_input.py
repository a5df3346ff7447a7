"""A press's measurements and mode signals out of a recording: ``mps track --recording``.

The entry points ``mcap`` and ``bag`` of the group ``mps.track_readers``, which
:mod:`mps_core.track.recording_input` calls. The file (an MCAP file, or a bag directory of them,
as the node writes) is read by the twin's own reader (:func:`~mps_ros.recording.replay.read_topics`:
mcap's stream reader, the CDR walked here), the topics asked for kept in the file's order. Each
``sensor_msgs/JointState`` is read as the node following a press reads it
(:mod:`mps_ros.wire.measured`): the crank angle and the slider's position at the header's stamp,
one :class:`~mps_core.track.Measurement` each (the crank first); each ``std_msgs/String`` is a
mode signal at its log time. A topic missing, of another type or encoding, a message that
cannot be decoded or has no crank angle, a mode signal not ``engage`` or ``disengage``: a
:class:`~mps_core.track.MeasurementError` naming the field, its value and what was expected.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import TYPE_CHECKING

from mps_core.track.measurements import MODE_COMMANDS, Measurement, MeasurementError, ModeSignal, TorqueSensor
from mps_core.track.recording_input import RecordedInputs, Tuning

from ..wire.measured import CRANK, crank_and_slider, crank_torque, measurements, ns_seconds, stamp_seconds
from .mcap_writer import ENCODING_CDR
from .replay import META_SOFTWARE, TopicMessages, joint_state_readings, read_topics, string_data

if TYPE_CHECKING:
    from mps_core.track.recording_input import RecordedTopics

__all__ = ["read"]

JOINT_STATE = "sensor_msgs/msg/JointState"
STRING = "std_msgs/msg/String"


def read(path: Path, topics: RecordedTopics) -> RecordedInputs:
    """Return the measurements and mode signals of the recording ``path``, in its order.

    With the tuning it records (its ``mps`` metadata): the variances of its measurements are
    that tuning's.
    """
    wanted = [("--joints-topic", topics.joints, JOINT_STATE, True)]
    if topics.mode and (topics.mode != topics.joints or topics.mode_required):
        wanted.append(("--mode-topic", topics.mode, STRING, topics.mode_required))
    got = read_topics(path, {topic for _f, topic, _t, _r in wanted})
    present = _check_topics(got, wanted)
    tuning = Tuning.of(got.metadata.get(META_SOFTWARE, {}), str(path))
    variances = tuning.variances()
    out = RecordedInputs(tuning=tuning)
    k = 0  # the measurement messages so far
    for topic, _type, t_ns, data in got.messages:
        if topic == topics.joints:
            out += _measurements(path, topic, k, t_ns, data, variances, tuning.torque)
            k += 1
        elif topic in present:
            out.append(_mode(path, topic, t_ns, data))
    return out


def _check_topics(got: TopicMessages, wanted: list[tuple[str, str, str, bool]]) -> set[str]:
    """Return the wanted topics recorded.

    Raise :class:`MeasurementError` where one is missing (and required), of another type or
    encoding.
    """
    have = ", ".join(f"{t} ({ty}, {n})" for t, ty, _e, n in sorted(got.channels)) or "no channels"
    present = set()
    for field, topic, msgtype, required in wanted:
        chans = [c for c in got.channels if c[0] == topic and c[3]]
        if not chans:
            if not required:
                continue  # the default mode topic, not recorded: no mode signals
            raise MeasurementError(
                f"{got.path}: {field}",
                topic,
                f"a topic of the recording with {msgtype} messages (it has: {have})",
            )
        for _t, ty, enc, _n in chans:
            if ty != msgtype:
                raise MeasurementError(f"{got.path}: {topic}: type", ty, msgtype)
            if enc != ENCODING_CDR:
                raise MeasurementError(f"{got.path}: {topic}: message encoding", enc, ENCODING_CDR)
        present.add(topic)
    return present


def _measurements(
    path: Path, topic: str, k: int, t_ns: int, data: bytes, variances: dict[str, float], torque: TorqueSensor
) -> list[Measurement]:
    """Return the crank angle (the slider's position, the motor's torque) of the ``k``-th JointState."""
    where = f"{path}: {topic}: message {k} (log time {t_ns} ns)"
    try:
        sec, nanosec, names, positions, efforts = joint_state_readings(data)
    except (ValueError, struct.error) as exc:
        raise MeasurementError(
            f"{where}: the message", f"{len(data)} bytes", f"a CDR {JOINT_STATE} ({exc})"
        ) from None
    angle, slider = crank_and_slider(names, positions)
    if angle is None:
        raise MeasurementError(
            f"{where}: name, position",
            (names, positions),
            f"a crank angle: the position of a joint named {CRANK!r}, or a single position without names",
        )
    return measurements(
        stamp_seconds(sec, nanosec),
        angle,
        slider,
        crank_torque(names, efforts),
        variances["crank_angle"],
        variances["slider_position"],
        torque,
    )


def _mode(path: Path, topic: str, t_ns: int, data: bytes) -> ModeSignal:
    """Return the mode signal of a String message, at its log time."""
    where = f"{path}: {topic}: message at log time {t_ns} ns"
    try:
        command = string_data(data).strip()
    except (ValueError, struct.error) as exc:
        raise MeasurementError(
            f"{where}: the message", f"{len(data)} bytes", f"a CDR {STRING} ({exc})"
        ) from None
    if command not in MODE_COMMANDS:
        raise MeasurementError(f"{where}: data", command, "one of " + ", ".join(MODE_COMMANDS))
    return ModeSignal(ns_seconds(t_ns), command)
