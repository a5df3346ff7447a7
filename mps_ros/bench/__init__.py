"""The node's benchmarks (``python -m mps_ros.bench``): not part of the runtime, nothing there
imports them. The command line (:mod:`.cli`), the runs (:mod:`.suite`), the subscriber
(:mod:`.probe`), the processes read from ``/proc`` (:mod:`.processes`), costs measured without
ROS (:mod:`.costs`)."""

# the package's public modules; importing the package imports none of them (no rclpy, no engine
# before a module asks for it): ``from mps_ros.bench import *`` imports them all
__all__ = ["cli", "costs", "probe", "processes", "suite"]
