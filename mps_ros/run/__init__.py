"""The run: the twin stepped, its messages made, commands applied, paced, no rclpy.

The twin (:mod:`.twin`) and its :class:`~.runner.Runner` (:mod:`.runner`; its commands
:mod:`.commands`, its measurements :mod:`.metrics`), the run paced in this process
(:mod:`.paced`) or stepped in a process of its own (:mod:`.stepping`, the child's loop;
:mod:`.releasing`, the node's side). ``mps record`` and the node run the same runner.
"""
