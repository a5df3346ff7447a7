"""Shared fixtures. Every process a test starts stays on loopback with its own ROS domain, and
keeps generated code in a folder of the session's own (never the user's cache)."""

from __future__ import annotations

import atexit
import os
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("ROS_DOMAIN_ID", "43")
# the disk cache of generated code (mps_core.codegen.disk_cache): one folder a test process,
# which the processes it starts share, removed at its end
os.environ["MPS_CACHE_DIR"] = tempfile.mkdtemp(prefix="mps-test-cache-")

sys.path.insert(0, str(Path(__file__).parent))

from reference import press_exact as pe

atexit.register(shutil.rmtree, os.environ["MPS_CACHE_DIR"], True)


@pytest.fixture(scope="session")
def paper_reference():
    """The paper scene's exact motion to 0.1 s (passes the (phi, psi) branch point), 5e-5 grid."""
    t = np.linspace(0.0, 0.1, 2001)
    return pe.integrate_redundant(0.1, t, motor=True)


@pytest.fixture(scope="session")
def paper_reference_005():
    t = np.linspace(0.0, 0.05, 401)
    return pe.integrate_redundant(0.05, t, motor=True)
