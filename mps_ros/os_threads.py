"""What the node asks of the operating system for its threads, where the system offers it:
a name that ``top -H`` and ``/proc`` show, and a short scheduler slice for the publishing
thread. Linux only (``prctl``, ``sched_getattr``/``sched_setattr``); elsewhere each call does
nothing and says so by its result.

**The slice.** Since Linux 6.12 the fair scheduler (EEVDF) lets a thread ask for a slice of
its own (``sched_attr.sched_runtime``, 0.1 to 100 ms; no privilege needed). A thread with a
short slice gets an earlier virtual deadline when it wakes, so a thread that it wakes itself
(the subscriber's listener, woken by each message the node publishes) preempts it less often.
The node's publishing thread asks for 0.1 ms; its nice value and policy stay as they were.
"""

from __future__ import annotations

import platform
import struct

#: struct sched_attr, SCHED_ATTR_SIZE_VER1: size, policy, flags, nice, priority, runtime,
#: deadline, period, util_min, util_max
_ATTR = struct.Struct("<IIQiIQQQII")
_SCHED_OTHER, _SCHED_BATCH = 0, 3
#: (sched_setattr, sched_getattr) by machine
_SYSCALLS = {"x86_64": (314, 315), "aarch64": (274, 275)}


def _libc():
    import ctypes

    return ctypes, ctypes.CDLL(None, use_errno=True)


def name_thread(name: str) -> bool:
    """Give the calling thread ``name`` (15 bytes at most) in the system's view."""
    try:
        ctypes, libc = _libc()
        return libc.prctl(15, ctypes.c_char_p(name.encode()[:15]), 0, 0, 0) == 0  # PR_SET_NAME
    except (OSError, AttributeError):
        return False


def _fair_attr():
    """(ctypes, libc, sched_setattr's number, the calling thread's sched_attr as a list) where
    the thread is under the fair scheduler (SCHED_OTHER or SCHED_BATCH) on a system and machine
    this module knows; else None."""
    calls = _SYSCALLS.get(platform.machine())
    if calls is None:
        return None
    try:
        ctypes, libc = _libc()
        buf = ctypes.create_string_buffer(_ATTR.size)
        if libc.syscall(calls[1], 0, buf, _ATTR.size, 0) != 0:
            return None
    except (OSError, AttributeError):
        return None
    attr = list(_ATTR.unpack(buf.raw))
    return (ctypes, libc, calls[0], attr) if attr[1] in (_SCHED_OTHER, _SCHED_BATCH) else None


def thread_slice() -> float | None:
    """The calling thread's scheduler slice (s) as the system reports it (its own where it
    asked for one), where it reports one; else None."""
    got = _fair_attr()
    return got[3][5] * 1e-9 if got is not None and got[3][5] else None


def short_slice(seconds: float = 1e-4) -> bool:
    """Ask for a scheduler slice of ``seconds`` for the calling thread, its policy and nice
    value kept. True where the system granted it (read back), False elsewhere: another system
    or machine, a kernel before 6.12 (it takes the call and ignores the slice), a thread under
    a realtime policy."""
    got = _fair_attr()
    if got is None:
        return False
    ctypes, libc, setattr_number, attr = got
    attr[0] = _ATTR.size
    attr[5] = int(round(seconds * 1e9))
    try:
        buf = ctypes.create_string_buffer(_ATTR.pack(*attr), _ATTR.size)
        if libc.syscall(setattr_number, 0, buf, 0) != 0:
            return False
    except (OSError, struct.error):
        return False
    now = thread_slice()
    return now is not None and abs(now - seconds) < 1e-9


def widen_pipe(fd: int, size: int = 1 << 20) -> None:
    """Give a pipe room for about a second of a 1 kHz run's messages (Linux; elsewhere the
    default stays), so that handing a batch over never waits for the other process to read."""
    import fcntl

    try:
        fcntl.fcntl(fd, getattr(fcntl, "F_SETPIPE_SZ", 1031), size)
    except OSError:
        pass


__all__ = ["name_thread", "short_slice", "thread_slice", "widen_pipe"]
