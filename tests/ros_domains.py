"""A ROS domain for a test session's processes: one whose first participant's ports are free on
this machine (Fast DDS: unicast metatraffic port of participant 0 = 7400 + 250·d + 10)."""

from __future__ import annotations

import socket


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
