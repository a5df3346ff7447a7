"""ROS tests: every process stays on loopback, in a ROS domain of this test session's own, with
its logs in a temporary folder; every process a test starts is ended (its whole process group)
before the test returns, and the session checks that none is left."""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

import pytest


def pick_domain_id() -> int:
    """A ROS domain in 1..101 for this session (see ``ros_domains.session_base``), skipping 42
    and 43 (make's and the default test domain) and any domain whose first participant port is
    taken here (a session or a node already on it)."""
    from ros_domains import free_domain, session_base

    return free_domain(session_base())


DOMAIN_ID = pick_domain_id()
LOG_DIR = tempfile.mkdtemp(prefix="mps-ros-test-log-")
os.environ["ROS_DOMAIN_ID"] = str(DOMAIN_ID)
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ["ROS_LOG_DIR"] = LOG_DIR
os.environ["RMW_IMPLEMENTATION"] = "rmw_fastrtps_cpp"
os.environ.pop("ROS_LOCALHOST_ONLY", None)
os.environ.pop("ROS_STATIC_PEERS", None)

sys.path.insert(0, str(Path(__file__).parent))

# the rest of a ROS process's environment (the middleware's profile), as the node's sets it
from mps_ros.ros.environment import env_defaults  # noqa: E402

env_defaults()


def _children(pid: int) -> list[tuple[int, str]]:
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
        except OSError:
            continue
        rest = stat[stat.rfind(")") + 2 :].split()
        if len(rest) > 1 and rest[0] != "Z" and int(rest[1]) == pid:
            try:
                cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode()
            except OSError:
                cmd = "?"
            out.append((int(d.name), cmd))
    return out


@pytest.fixture(scope="session", autouse=True)
def no_process_left_behind():
    before = {p for p, _ in _children(os.getpid())}
    yield
    left = [(p, c) for p, c in _children(os.getpid()) if p not in before]
    assert not left, f"processes left behind by the ROS tests: {left}"


@pytest.fixture(scope="session")
def ros_domain():
    return DOMAIN_ID


@pytest.fixture(scope="session")
def ros():
    """rclpy, started in this (the test's) process for the session."""
    rclpy = pytest.importorskip("rclpy")
    from rclpy.signals import SignalHandlerOptions

    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    try:
        yield rclpy
    finally:
        rclpy.try_shutdown()


def pytest_sessionfinish(session, exitstatus):
    if exitstatus == 0:  # keep the ROS logs of a failed session for a look
        import shutil

        shutil.rmtree(LOG_DIR, ignore_errors=True)


def pytest_configure(config):
    # rosidl's parser (lark) imports modules Python 3.11 calls deprecated
    config.addinivalue_line("filterwarnings", "ignore:module 'sre_:DeprecationWarning")
