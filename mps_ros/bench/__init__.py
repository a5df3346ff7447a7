"""The node's benchmarks (``python -m mps_ros.bench``): not part of the runtime, nothing there
imports them. The command line (:mod:`.cli`), the runs (:mod:`.suite`), the subscriber
(:mod:`.probe`), the processes read from ``/proc`` (:mod:`.processes`), costs measured without
ROS (:mod:`.costs`)."""
