"""The subcommands of ``mps`` that the ROS side adds: node, record, recover, operator, demo
(:mod:`.cli`, :mod:`.demo`), emulator (:mod:`.emulator`) and view (:mod:`.view`)."""

# the package's public modules; importing the package imports none of them (no rclpy, no engine
# before a module asks for it): ``from mps_ros.commands import *`` imports them all
__all__ = ["cli", "demo", "emulator", "view"]
