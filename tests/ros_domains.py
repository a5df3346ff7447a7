"""A ROS domain for a test session's processes: one whose first participant's ports are free on
this machine (Fast DDS: unicast metatraffic port of participant 0 = 7400 + 250·d + 10)."""

from __future__ import annotations

import os
import socket


def session_base() -> int:
    """Where this test session starts looking for a domain: from its pid, or, in a worker of
    pytest-xdist (``make test`` runs two), from the workers' common parent, 23 apart by worker,
    so that two workers started at once never pick the same domain."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    if worker.startswith("gw") and worker[2:].isdigit():
        return (os.getppid() + 23 * int(worker[2:])) % 101
    return os.getpid() % 101


def udp_port_free(port: int) -> bool:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.bind(("", port))
        return True
    except OSError:
        return False
    finally:
        s.close()


def free_domain(base: int, taken=(42, 43)) -> int:
    """The first domain in 1..101 from ``base`` on, not in ``taken``, whose ports are free."""
    for i in range(101):
        d = 1 + (base + i) % 101
        if d in taken:
            continue
        if all(udp_port_free(7400 + 250 * d + off) for off in (10, 11, 12)):
            return d
    return 1 + base % 101
