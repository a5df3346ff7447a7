"""The pipes to the node's child processes (the stepping process, the recording process): a
frame is one byte of kind (:class:`Frame`), the payload's length (u32), the payload.

What each kind carries is said where it is written: :mod:`mps_ros.run.stepping` (the stepping
process's frames, both ways) and :class:`~mps_ros.recording.background.BackgroundRecorder` (the
recording process's).
"""

from __future__ import annotations

import os
import select
import struct
import threading
from enum import Enum

from mps_core.child_process import read_whole

#: a frame's head: its kind, its payload's length
HEAD = struct.Struct("<cI")


class Frame(bytes, Enum):
    """A frame's kind, one byte, for both pipes (equal to the byte itself)."""

    #: to either child, first: its settings (JSON)
    SETTINGS = b"I"
    #: from the stepping process: the run's end (JSON); to the recording process: finish the file
    END = b"E"
    # -- to the stepping process
    GO = b"G"
    COMMAND = b"C"
    REFUSED = b"N"
    PAUSE = b"Z"
    RESUME = b"O"
    STEP = b"T"
    RELEASED = b"K"
    STOP = b"S"
    # -- from the stepping process
    READY = b"R"
    PRIORITY = b"P"
    MESSAGES = b"M"
    ANSWER = b"A"
    LOG = b"L"
    # -- to the recording process
    CHANNEL = b"H"
    BATCH = b"B"
    STEPS = b"W"
    FLUSH = b"F"


def _split(buf: bytearray) -> list[tuple[bytes, bytes]]:
    """Take the whole frames off the front of ``buf``: (kind, payload) each."""
    got = []
    pos = 0
    n_buf = len(buf)
    while n_buf - pos >= 5:
        kind, n = HEAD.unpack_from(buf, pos)
        if n_buf - pos - 5 < n:
            break
        got.append((kind, bytes(buf[pos + 5 : pos + 5 + n])))
        pos += 5 + n
    if pos:
        del buf[:pos]
    return got


class FrameWriter:
    """Frames to a file descriptor, one writer at a time (the threads of a process share it)."""

    def __init__(self, fd: int):
        self.fd = fd
        self._lock = threading.Lock()
        self.broken = False

    def frame(self, kind: bytes, payload: bytes) -> bool:
        """Write one frame (False: the other side is gone)."""
        return self.write(HEAD.pack(kind, len(payload)) + payload)

    def write(self, data: bytes) -> bool:
        """Write whole frames at once (False: the other side is gone)."""
        with self._lock:
            if self.broken:
                return False
            view = memoryview(data)
            try:
                while view:
                    view = view[os.write(self.fd, view) :]
            except OSError:  # the other side is gone
                self.broken = True
                return False
        return True


class FrameReader:
    """Whole frames from a file descriptor: :meth:`read` blocks until at least one has come
    (an empty list: the other side closed its end)."""

    def __init__(self, fd: int):
        self.fd = fd
        self._buf = bytearray()

    def read(self) -> list[tuple[bytes, bytes]]:
        """Return the whole frames come so far, waiting for one; [] at the end."""
        return read_whole(self.fd, self._buf, _split, 1 << 20)


class PolledFrameReader:
    """Whole frames from a file descriptor, waiting a while at most (:meth:`read`); ``eof``
    once the other side closed its end."""

    def __init__(self, fd: int):
        self.fd = fd
        self.buf = bytearray()
        self.eof = False  # the other end closed

    def read(self, timeout: float | None) -> list[tuple[bytes, bytes]]:
        """Return the whole frames read so far, waiting up to ``timeout`` for more."""
        buf = self.buf
        if not self.eof and select.select([self.fd], [], [], timeout)[0]:
            chunk = os.read(self.fd, 1 << 20)
            if chunk:
                buf.extend(chunk)
            else:
                self.eof = True
        return _split(buf)


__all__ = ["HEAD", "Frame", "FrameWriter", "FrameReader", "PolledFrameReader"]
