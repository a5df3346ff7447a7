"""The tracking twin's topics beside the twin's own (:mod:`mps_ros.wire.topics`), defined once.

A tracked run (``mps track --out FILE.mcap``) records what the twin records, estimated, and
beside it: what the press's sensors measured, on topics of their own under ``/press``, each
estimated topic's 1-σ on the topic's name with ``/sigma`` (same type: a WrenchStamped of 1-σ
values beside each estimated wrench), the process force and the load torque (the unknown inputs)
and the per-stroke table. A node following a press (``track``) publishes the same, estimated,
with the process force at each measurement's stamp beside the smoother's, and records the
measurements and mode signals as they came in, under the topic names it subscribed to
(:data:`RECEIVED_JOINTS`, :data:`RECEIVED_MODE`). Standard interfaces only.
"""

from __future__ import annotations

from .topics import BY_KEY, FOUNDATION, NODE_NAME, WRENCHES, Topic

__all__ = [
    "LOAD_TORQUE",
    "MEASURED_JOINTS",
    "MEASURED_MODE",
    "PROCESS_FORCE",
    "PROCESS_FORCE_NOW",
    "PROCESS_FRAME",
    "RECEIVED_JOINTS",
    "RECEIVED_MODE",
    "TRACKING_BY_KEY",
    "TRACKING_TOPICS",
    "msgtype",
    "SIGMA",
    "STROKES",
    "TRACKING_STATUS",
    "TRACK_TOPICS",
    "sigma",
]

#: the suffix of an estimated topic's 1-σ (the same type, each number its 1-σ)
SIGMA = "/sigma"

MEASURED_JOINTS = Topic(
    "/press/joint_states",
    "sensor_msgs/msg/JointState",
    "",
    "what the press's sensors read at each stamp: the crank's angle (its encoder count's centre, "
    "rad), rate (rad/s) and the motor's torque as its effort (N*m), the slider's position (m); "
    "NaN where a sensor has no sample at that stamp",
)
MEASURED_MODE = Topic("/press/mode", "std_msgs/msg/String", "", "the press's mode signals: engage, disengage")
PROCESS_FORCE = Topic(
    "~/process_force",
    "geometry_msgs/msg/WrenchStamped",
    "",
    "the estimated process force on the slider at C (force.x, along the guide, up; frame "
    "press_C): the fixed-lag smoother's, stamped with the middle of the step it acted over",
)
LOAD_TORQUE = Topic(
    "~/load_torque",
    "geometry_msgs/msg/WrenchStamped",
    "",
    "the estimated load torque the crank receives besides the model's (torque.z, N*m; frame press)",
)
STROKES = Topic(
    "~/strokes",
    "std_msgs/msg/String",
    "",
    "one JSON object a stroke at its end: peak process force, work, peak foundation force, each "
    "with its 1-sigma",
)
#: the tracked runs' topics (their 1-σ topics aside)
TRACK_TOPICS = (MEASURED_JOINTS, MEASURED_MODE, PROCESS_FORCE, LOAD_TORQUE, STROKES)

#: the name of the tracking status on /diagnostics
TRACKING_STATUS = f"{NODE_NAME}: tracking"


def sigma(key: str) -> str:
    """Return the key of the topic that carries the 1-σ of topic ``key``."""
    return key + SIGMA


WRENCH = "geometry_msgs/msg/WrenchStamped"

#: the frame of the process force: parallel to the press frame, at the slider's joint C
PROCESS_FRAME = "press_C"

#: the crank encoder (and slider scale) as received, recorded under the subscribed topic's name
RECEIVED_JOINTS = Topic(
    "~/track/measured",
    "sensor_msgs/msg/JointState",
    "",
    "the press's measurements as received (parameter track): recorded, not published again",
)
#: the press's mode signals as received (parameter track_mode)
RECEIVED_MODE = Topic(
    "~/track/measured_mode",
    "std_msgs/msg/String",
    "",
    "the press's mode signals as received (parameter track_mode): recorded, not published again",
)
#: the process force at each measurement's stamp
PROCESS_FORCE_NOW = Topic(
    "~/process_force/now",
    WRENCH,
    "",
    "the estimated process force the slider receives along the guide (force.x, N, up), at the "
    "measurement's stamp (frame press_C)",
)
TRACKING_TOPICS: tuple[Topic, ...] = (
    *(Topic(sigma(w.key), WRENCH, "reactions", f"1-σ of {w.key}'s components") for w in WRENCHES),
    Topic(sigma(FOUNDATION.key), WRENCH, "foundation", f"1-σ of {FOUNDATION.key}'s components"),
    PROCESS_FORCE_NOW,
    Topic(sigma(PROCESS_FORCE_NOW.key), WRENCH, "", "1-σ of the process force now"),
    PROCESS_FORCE,
    Topic(sigma(PROCESS_FORCE.key), WRENCH, "", "1-σ of the smoothed process force"),
    STROKES,
)

TRACKING_BY_KEY = {t.key: t for t in (*TRACKING_TOPICS, RECEIVED_JOINTS, RECEIVED_MODE)}


def msgtype(key: str) -> str:
    """Return the message type of a topic key, the simulator's or a tracking node's."""
    t = BY_KEY.get(key) or TRACKING_BY_KEY.get(key)
    if t is None:
        raise KeyError(f"topic key {key!r}: expected one of the node's topics")
    return t.msgtype
