"""ROS 2: the lifecycle node ``press_twin``, its parameters and the operator client.

The only runtime package that imports rclpy: the node and its endpoints (:mod:`.node`), its
parameters (:mod:`.parameters`), the operator sending mode commands (:mod:`.operator`).
Importing this package does not import rclpy; its modules do.
"""
