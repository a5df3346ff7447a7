"""A run's progress on a terminal: one line, rewritten in place, with the simulated time, the
rate (simulated seconds a wall second: × real time) and the time left, so that a long run
(a fine step, a stiff spring, many corrections) is seen going, or seen crawling, while it runs.

The line goes to a terminal only: where the stream is a file or a pipe (a test, a CI log, a
script reading the summary) nothing is written, and ``quiet`` turns it off on a terminal too.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO


class Progress:
    """``progress(t)`` as a run reaches simulated time ``t`` (cheap: the wall clock is read
    every ``check`` calls, the line rewritten at most every ``every`` wall seconds);
    :meth:`done` clears the line. ``label`` heads the line (e.g. the scene's name). The rate
    is the recent one (each interval's, smoothed), so that a slow start (kernels built on the
    first steps) or a slow stretch (impacts) does not weigh on the time left for long."""

    def __init__(
        self,
        t0: float,
        t_end: float,
        label: str = "",
        stream: TextIO | None = None,
        quiet: bool = False,
        every: float = 0.5,
        check: int = 32,
    ):
        self.stream = sys.stderr if stream is None else stream
        isatty = getattr(self.stream, "isatty", None)
        self.on = not quiet and isatty is not None and isatty()
        self.t0, self.t_end = float(t0), float(t_end)
        self.label = label
        self.every, self.check = float(every), max(1, int(check))
        self._calls = 0
        self._last: tuple[float, float] | None = None  # (wall, t) of the previous look
        self._next = 0.0
        self._rate: float | None = None
        self._width = 0

    def __call__(self, t: float) -> None:
        if not self.on:
            return
        self._calls += 1
        if self._calls % self.check:
            return
        now = time.monotonic()
        if now < self._next:
            return
        self._next = now + self.every
        if self._last is None:  # the first look: the rate is measured from here
            self._last = (now, t)
            return
        wall, sim = now - self._last[0], t - self._last[1]
        self._last = (now, t)
        if wall > 0:
            rate = sim / wall
            self._rate = rate if self._rate is None else 0.6 * self._rate + 0.4 * rate
        self._write(self.line(t, self._rate or 0.0))

    def line(self, t: float, rate: float) -> str:
        """The progress line at simulated time ``t``, going at ``rate`` simulated seconds a
        wall second."""
        done = t - self.t0
        total = self.t_end - self.t0
        left = (self.t_end - t) / rate if rate > 0 else float("inf")
        pct = 100.0 * done / total if total > 0 else 100.0
        eta = _duration(left) if left != float("inf") else "unknown"
        head = f"{self.label}: " if self.label else ""
        return f"{head}t = {t:.4g} of {self.t_end:.4g} s ({pct:.0f} %), {rate:.3g}x real time, {eta} left"

    def _write(self, text: str) -> None:
        pad = max(0, self._width - len(text))
        self._width = len(text)
        try:
            self.stream.write("\r" + text + " " * pad)
            self.stream.flush()
        except (OSError, ValueError):
            self.on = False

    def done(self) -> None:
        """Clear the line (the summary that follows starts at the line's beginning)."""
        if self.on and self._width:
            self._write("")
            try:
                self.stream.write("\r")
                self.stream.flush()
            except (OSError, ValueError):
                pass
        self._width = 0


def _duration(seconds: float) -> str:
    s = int(round(seconds))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {s // 60 % 60:02d} min"


__all__ = ["Progress"]
