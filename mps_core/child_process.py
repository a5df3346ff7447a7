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
from typing import Any

__all__ = ["MessageReader", "die_with_parent", "write_message"]

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


class MessageReader:
    """Whole messages from ``fd``: :meth:`read` waits for at least one ([] at the end)."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self._buf = bytearray()

    def read(self) -> list[Any]:
        """Return the messages come so far, waiting for one; [] once the other end closed."""
        buf = self._buf
        while True:
            got = []
            pos = 0
            while len(buf) - pos >= 4:
                (n,) = _LENGTH.unpack_from(buf, pos)
                if len(buf) - pos - 4 < n:
                    break
                got.append(pickle.loads(bytes(buf[pos + 4 : pos + 4 + n])))
                pos += 4 + n
            del buf[:pos]
            if got:
                return got
            try:
                chunk = os.read(self.fd, 1 << 16)
            except InterruptedError:
                continue
            if not chunk:
                return []
            buf.extend(chunk)


def die_with_parent() -> None:
    """Have SIGTERM sent to this process when the process that started it dies (Linux)."""
    try:
        import ctypes
        import signal

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
