"""The tracking twin's topics beside the twin's own (:mod:`mps_ros.wire.topics`), defined once.

A tracked run (``mps track --out FILE.mcap``) records what the twin records, estimated, and
beside it: what the press's sensors measured, on topics of their own under ``/press``, each
estimated topic's 1-σ on the topic's name with ``/sigma`` (same type: a WrenchStamped of 1-σ
values beside each estimated wrench), the process force and the load torque (the unknown inputs)
and the per-stroke table. Standard interfaces only.
"""

from __future__ import annotations

from .topics import NODE_NAME, Topic

__all__ = [
    "LOAD_TORQUE",
    "MEASURED_JOINTS",
    "MEASURED_MODE",
    "PROCESS_FORCE",
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
