"""mps_ros: the press twin's ROS 2 face and its recordings.

* :mod:`mps_ros.topics`: names (node, topics, types, frames, joints, wrenches), defined once;
* :mod:`mps_ros.twin`: the run (steps, messages, commands, pacing, diagnostics), no ROS;
* :mod:`mps_ros.cdr`: CDR encoders of the per-step messages (the bytes published and recorded);
* :mod:`mps_ros.recording`: MCAP recordings (``mps record``, the node's recorder, ``recover``),
  no ROS: mcap, mcap-ros2-support and rosbags;
* :mod:`mps_ros.node`: the ROS 2 node ``press_twin`` (rclpy; ``mps node``);
* :mod:`mps_ros.operator`: a small operator client sending mode commands (``mps operator``);
* :mod:`mps_ros.demo`: node + operator on the default scene (``mps demo``, ``make run``);
* :mod:`mps_ros.bench`: the node's benchmarks (``python -m mps_ros.bench``);
* :mod:`mps_ros.cli`: those subcommands of ``mps``.

Only :mod:`~mps_ros.node`, :mod:`~mps_ros.operator` and the benchmark's subscriber import rclpy
(install the ``ros`` extra); importing this package never does.
"""
