"""The ROS environment of a process, set once where the process starts (before rclpy starts):
loopback-only discovery, a temporary log folder, Fast DDS with :data:`FASTDDS_PROFILE`'s
timers, each unless the environment says otherwise; and a crash in native code said where it
happened. No rclpy here: importing it sets nothing.
"""

from __future__ import annotations

import faulthandler
import os
import tempfile

#: the Fast DDS timers: a participant's announcements, and the reliable writers' (the QoS comes
#: from the code)
FASTDDS_PROFILE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "fastdds_profile.xml")


def env_defaults() -> None:
    """Set the ROS defaults that the environment leaves unset (call before rclpy starts), and
    have a fatal signal print every thread's stack here and in the processes started from here."""
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ.setdefault("ROS_LOG_DIR", os.path.join(tempfile.gettempdir(), "mps-ros-log"))
    os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    os.environ.setdefault("FASTRTPS_DEFAULT_PROFILES_FILE", FASTDDS_PROFILE)
    # a fatal signal (a crash in the middleware's or rclpy's native code) prints every thread's
    # Python stack, this process's and its children's (the node's stepping and recording
    # processes, which inherit the variable)
    if not faulthandler.is_enabled():
        try:
            faulthandler.enable(all_threads=True)
        except (AttributeError, ValueError, OSError):  # a stderr without a file (captured)
            pass
    os.environ.setdefault("PYTHONFAULTHANDLER", "1")


__all__ = ["FASTDDS_PROFILE", "env_defaults"]
