"""The subcommands of ``mps`` that the ROS side adds: node, record, recover, operator, demo
(:mod:`.cli`, :mod:`.demo`) and view (:mod:`.view`)."""
