"""``python -m mps_ros.bench``: the node's benchmarks (:func:`.cli.main`)."""

import sys

from .cli import main

sys.exit(main())
