"""Recordings: MCAP files and rosbag2 bags written, recovered and read back, no rclpy.

The byte writer (:mod:`.mcap_writer`), the recorder and its writing process
(:mod:`.recorder`), bags and their ``metadata.yaml`` (:mod:`.bag`, :mod:`.bag_metadata`), and a
recording read back as columns (:mod:`.replay`). Needs mcap, mcap-ros2-support and rosbags only.
"""

# the package's public modules; importing the package imports none of them (no rclpy, no engine
# before a module asks for it): ``from mps_ros.recording import *`` imports them all
__all__ = ["background", "bag", "bag_metadata", "mcap_writer", "recorder", "recover", "replay"]
