"""Names and wire: what the twin says and how it is encoded, defined once, no ROS.

The topics, types, frames, joints and wrenches (:mod:`.topics`), the CDR encoders of the
per-step messages (:mod:`.cdr`), a step's messages in publishing order (:mod:`.step_messages`),
the ``/tf`` frames and the markers (:mod:`.frames`, :mod:`.markers`, drawn from
:mod:`.drawing`), the ``/diagnostics`` statuses (:mod:`.diagnostics`), and the frames of the
pipes to the child processes (:mod:`.pipe`).
"""

# the package's public modules; importing the package imports none of them (no rclpy, no engine
# before a module asks for it): ``from mps_ros.wire import *`` imports them all
__all__ = ["cdr", "diagnostics", "drawing", "frames", "markers", "pipe", "step_messages", "topics"]
