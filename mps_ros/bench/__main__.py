"""``python -m mps_ros.bench``: the node's benchmarks (:func:`.suite.main`)."""

import sys

from .suite import main

sys.exit(main())
