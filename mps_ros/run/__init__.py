"""The run: the twin stepped, its messages made, commands applied, paced, no rclpy.

The twin (:mod:`.twin`) and its :class:`~.runner.Runner` (:mod:`.runner`; its commands
:mod:`.commands`, its measurements :mod:`.metrics`, its sinks that are not ROS :mod:`.sinks`),
the run paced in this process (:mod:`.paced`) or stepped in a process of its own
(:mod:`.stepping`, the child's loop; :mod:`.releasing`, the node's side, with the steps
published (:mod:`.publication`), the commands at their boundaries (:mod:`.boundaries`) and the
child process (:mod:`.child`)). ``mps record`` (:mod:`.record`) and the node run the same runner.
"""

# the package's public modules; importing the package imports none of them (no rclpy, no engine
# before a module asks for it): ``from mps_ros.run import *`` imports them all
__all__ = [
    "boundaries",
    "child",
    "commands",
    "metrics",
    "paced",
    "publication",
    "record",
    "releasing",
    "runner",
    "sinks",
    "stepping",
    "twin",
]
