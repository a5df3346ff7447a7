"""Foxglove: the WebSocket endpoint (:mod:`.endpoint`) that the node's recording process serves
(:mod:`.live`) and that ``mps serve`` plays a recording through (:mod:`.serve`). No rclpy: the
node's side of the commands is :mod:`mps_ros.ros.foxglove_link`."""

# the package's public modules; importing the package imports none of them
__all__ = ["endpoint", "live", "serve"]
