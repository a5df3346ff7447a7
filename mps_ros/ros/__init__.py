"""ROS 2: the lifecycle node ``press_twin``, its parameters and the operator client.

The only runtime package that imports rclpy: the node and its process (:mod:`.node`), its
publishers, subscription and services (:mod:`.endpoints`), a run's settings (:mod:`.config`),
its recording paths (:mod:`.recording_files`), its parameters (:mod:`.parameters`), the ROS
environment set where a process starts (:mod:`.environment`), the operator sending mode
commands (:mod:`.operator`). Importing this package does not import rclpy; its modules do.
"""

# the package's public modules; importing the package imports none of them (no rclpy, no engine
# before a module asks for it): ``from mps_ros.ros import *`` imports them all
__all__ = ["config", "endpoints", "environment", "node", "operator", "parameters", "recording_files"]
