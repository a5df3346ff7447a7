"""The Rerun view: a recording drawn and plotted (:mod:`.offline`), or the running node followed
live (:mod:`.live`)."""

# the package's public modules; importing the package imports none of them (no rclpy, no engine
# before a module asks for it): ``from mps_ros.view import *`` imports them all
__all__ = ["live", "offline"]
