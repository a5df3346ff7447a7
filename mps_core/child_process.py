"""A child process of the core's own: its pipe's messages and its end with its parent.

A message is a pickle with its length before it (u32, little-endian), written whole
(:func:`write_message`) and read whole (:class:`MessageReader`). Pickles, because both ends
are this package, started by one another, on one machine. :func:`die_with_parent` has the
child ended when the process that started it dies (Linux; elsewhere it does nothing).
"""

from __future__ import annotations

import os
import pickle
import struct
from collections.abc import Callable
from typing import Any

__all__ = ["MessageReader", "die_with_parent", "read_whole", "write_message"]

_LENGTH = struct.Struct("<I")


def write_message(fd: int, obj: Any) -> bool:
    """Write ``obj`` whole to ``fd``; False where the other end is gone."""
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    view = memoryview(_LENGTH.pack(len(data)) + data)
    try:
        while view:
            view = view[os.write(fd, view) :]
    except OSError:
        return False
    return True


def read_whole(fd: int, buf: bytearray, split: Callable[[bytearray], list], size: int = 1 << 16) -> list:
    """Return the whole messages ``split`` takes off the front of ``buf``.

    ``fd`` is read into ``buf`` until there is one; [] once the other end closed.
    """
    while True:
        got = split(buf)
        if got:
            return got
        try:
            chunk = os.read(fd, size)
        except InterruptedError:
            continue
        if not chunk:
            return []
        buf.extend(chunk)


def _split(buf: bytearray) -> list[Any]:
    """Take the whole messages off the front of ``buf``, unpickled."""
    got = []
    pos = 0
    while len(buf) - pos >= 4:
        (n,) = _LENGTH.unpack_from(buf, pos)
        if len(buf) - pos - 4 < n:
            break
        got.append(pickle.loads(bytes(buf[pos + 4 : pos + 4 + n])))
        pos += 4 + n
    del buf[:pos]
    return got


class MessageReader:
    """Whole messages from ``fd``: :meth:`read` waits for at least one ([] at the end)."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self._buf = bytearray()

    def read(self) -> list[Any]:
        """Return the messages come so far, waiting for one; [] once the other end closed."""
        return read_whole(self.fd, self._buf, _split)


def die_with_parent() -> None:
    """Have SIGTERM sent to this process when the process that started it dies (Linux)."""
    try:
        import ctypes
        import signal

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
