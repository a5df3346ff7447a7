"""Name the topics a tracking node adds: the measurements as received, the estimates' 1-σ, the process force.

A node following a press (``track``) publishes what it publishes as a simulator (the keys of
:mod:`mps_ros.wire.topics`), estimated, and beside them the keys here: a WrenchStamped of 1-σ
values beside each estimated wrench (``KEY/sigma``), the process force on the slider (present
and smoothed, each with its 1-σ), and records the measurements and mode signals as they came
in (under the topic names the node subscribed to). Pure Python, no rclpy.
"""

from __future__ import annotations

from . import track_topics
from .topics import BY_KEY, FOUNDATION, WRENCHES, Topic

__all__ = [
    "MEASURED",
    "MEASURED_MODE",
    "PROCESS_FORCE",
    "PROCESS_FORCE_SMOOTHED",
    "PROCESS_FRAME",
    "TRACKING_BY_KEY",
    "TRACKING_TOPICS",
    "msgtype",
    "sigma_key",
]

WRENCH = "geometry_msgs/msg/WrenchStamped"

#: the frame of the process force: parallel to the press frame, at the slider's joint C
PROCESS_FRAME = "press_C"

#: the crank encoder (and slider scale) as received, recorded under the subscribed topic's name
MEASURED = Topic(
    "~/track/measured",
    "sensor_msgs/msg/JointState",
    "",
    "the press's measurements as received (parameter track): recorded, not published again",
)
#: the press's mode signals as received (parameter track_mode)
MEASURED_MODE = Topic(
    "~/track/measured_mode",
    "std_msgs/msg/String",
    "",
    "the press's mode signals as received (parameter track_mode): recorded, not published again",
)
#: the process force at each measurement's stamp
PROCESS_FORCE = Topic(
    "~/process_force/now",
    WRENCH,
    "",
    "the estimated process force the slider receives along the guide (force.x, N, up), at the "
    "measurement's stamp (frame press_C)",
)
#: the fixed-lag smoother's process force: the tracked recording's (mps track --out) topic
PROCESS_FORCE_SMOOTHED = track_topics.PROCESS_FORCE


def sigma_key(key: str) -> str:
    """Return the key of the 1-σ wrench beside the estimated wrench ``key``."""
    return f"{key}/sigma"


TRACKING_TOPICS: tuple[Topic, ...] = (
    *(Topic(sigma_key(w.key), WRENCH, "reactions", f"1-σ of {w.key}'s components") for w in WRENCHES),
    Topic(sigma_key(FOUNDATION.key), WRENCH, "foundation", f"1-σ of {FOUNDATION.key}'s components"),
    PROCESS_FORCE,
    Topic(sigma_key(PROCESS_FORCE.key), WRENCH, "", "1-σ of the process force"),
    PROCESS_FORCE_SMOOTHED,
    Topic(sigma_key(PROCESS_FORCE_SMOOTHED.key), WRENCH, "", "1-σ of the smoothed process force"),
)

TRACKING_BY_KEY = {t.key: t for t in (*TRACKING_TOPICS, MEASURED, MEASURED_MODE)}


def msgtype(key: str) -> str:
    """Return the message type of a topic key, the simulator's or a tracking node's."""
    t = BY_KEY.get(key) or TRACKING_BY_KEY.get(key)
    if t is None:
        raise KeyError(f"topic key {key!r}: expected one of the node's topics")
    return t.msgtype
