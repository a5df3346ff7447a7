"""mps_ros: the press twin's ROS 2 face and its recordings, in packages that import one way
(lowest first; ``tests/core/test_imports.py`` holds the order):

* :mod:`mps_ros.os_threads`: the process's threads and pipes (Linux scheduling), no ROS;
* :mod:`mps_ros.wire`: names (node, topics, types, frames, joints, wrenches), CDR, a step's
  messages, markers, frames, diagnostics, defined once;
* :mod:`mps_ros.recording`: MCAP recordings and bags written, recovered and read back, no rclpy
  (mcap, mcap-ros2-support and rosbags);
* :mod:`mps_ros.run`: the run (steps, messages, commands, pacing, sinks; ``mps record``), no
  rclpy;
* :mod:`mps_ros.ros`: the ROS 2 node ``press_twin``, its parameters, the operator client (the
  runtime's only rclpy importers);
* :mod:`mps_ros.view`: recordings and the running node in the Rerun viewer;
* :mod:`mps_ros.commands`: the subcommands of ``mps`` this side adds; :mod:`mps_ros.bench`: the
  node's benchmarks (``python -m mps_ros.bench``).

Importing this package, or any of its packages, never imports rclpy.
"""
