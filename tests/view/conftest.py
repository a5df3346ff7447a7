"""Recordings for the replay and viewer tests, made once a session by ``mps record``'s own
function (the twin without ROS) and by the synthetic writer of :mod:`view_helpers`."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

pytest.importorskip("mcap")
pytest.importorskip("mcap_ros2")


@pytest.fixture(scope="session")
def recordings(tmp_path_factory):
    return tmp_path_factory.mktemp("recordings")


@pytest.fixture(scope="session")
def cycle_mcap(recordings):
    """press-cycle at 1 kHz to 0.6 s: engage, latch closes, working strokes, disengage, latch
    opens, the slider back on its stop (all the twin's topics)."""
    from mps_ros.run.record import record

    path, _, _ = record("press-cycle", recordings / "press-cycle.mcap", dt=1e-3, t_end=0.6)
    return Path(path)


@pytest.fixture(scope="session")
def working_mcap(recordings):
    """working (locked crank-slider) at its own settings but 2e-4 s steps, to 0.3 s: one full
    crank revolution for the load report."""
    from mps_ros.run.record import record

    path, _, _ = record("working", recordings / "working.mcap", dt=2e-4, t_end=0.3)
    return Path(path)


@pytest.fixture(scope="session")
def synthetic_10s(recordings):
    from view_helpers import synthetic_recording

    path = recordings / "synthetic-10s.mcap"
    cols = synthetic_recording(path, t_end=10.0, dt=1e-3)
    return path, cols
