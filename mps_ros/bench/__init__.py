"""The node's benchmarks (``python -m mps_ros.bench``): not part of the runtime, nothing there
imports them (:mod:`.suite`)."""
