"""What a run measures of itself: durations as histograms (:class:`Timings`), its clocks
(:class:`RunClocks`), and its counts (:class:`Measurements`).
"""

from __future__ import annotations

import math
import time

from ..wire import diagnostics


class Timings:
    """Durations (s) kept as a histogram of 1 % wide bins from 1 µs to 100 s: percentiles to
    1 % and the maximum, in memory that does not grow with the run's length."""

    _LO = 1e-6
    _PER = 1.0 / math.log(1.01)
    _BINS = int(math.log(1e8) * _PER) + 2

    def __init__(self):
        self.counts = [0] * self._BINS
        self.n = 0
        self.max = 0.0

    def add(self, x: float) -> None:
        self.n += 1
        if x > self.max:
            self.max = x
        i = int(math.log(x / self._LO) * self._PER) + 1 if x > self._LO else 0
        self.counts[i if i < self._BINS else self._BINS - 1] += 1

    def percentile(self, p: float) -> float:
        """The p-th percentile (the upper edge of its bin; 0 for no samples)."""
        if not self.n:
            return 0.0
        want = p / 100.0 * self.n
        acc = 0
        for i, c in enumerate(self.counts):
            acc += c
            if acc >= want and c:
                return min(self.max, self._LO * math.exp(i / self._PER))
        return self.max


class RunClocks:
    """A run's clocks, from :meth:`start` to :meth:`stop`: the wall clock
    (``time.perf_counter``; a paced run's schedule starts at ``wall_start``, moved on by its
    pauses), the process's CPU, and the CPU of the thread that steps."""

    def __init__(self):
        self.wall_start = 0.0
        self.wall_end = 0.0
        self.cpu_start = 0.0
        self.cpu_end: float | None = None
        self.thread_start = time.thread_time()
        self.thread_cpu: float | None = None

    def start(self) -> None:
        self.wall_start = time.perf_counter()
        self.cpu_start = time.process_time()
        self.thread_start = time.thread_time()

    def stop(self) -> None:
        self.wall_end = time.perf_counter()
        self.cpu_end = time.process_time()
        self.thread_cpu = time.thread_time() - self.thread_start

    def wall(self) -> float:
        """Wall seconds from the start to the stop (to now, before it)."""
        return (self.wall_end or time.perf_counter()) - self.wall_start

    def cpu(self) -> float:
        """The process's CPU seconds from the start to the stop (to now, before it)."""
        return (self.cpu_end if self.cpu_end is not None else time.process_time()) - self.cpu_start

    def thread(self) -> float:
        """The stepping thread's CPU seconds from the start to the stop (to now, before it)."""
        return self.thread_cpu if self.thread_cpu is not None else time.thread_time() - self.thread_start


class Measurements:
    """What a run measures of itself (:meth:`Runner.stats`, /diagnostics): the step times
    (compute: advance + messages), the publish times (a step's messages to the sinks) and, in
    realtime pacing, the latencies (publish done − deadline), as :class:`Timings`; the deadline
    misses, the messages and events sent, the steps recomputed (realtime: computed ahead,
    dropped for a command); ``release_slice``: the releasing thread's scheduler slice (s) as
    granted (realtime; None: the system's); ``window``: the counters the last /diagnostics
    saw."""

    def __init__(self):
        self.step_times = Timings()
        self.publish_times = Timings()
        self.latencies = Timings()
        self.misses = 0
        self.messages = 0
        self.events = 0
        self.steps_recomputed = 0
        self.release_slice: float | None = None
        self.window = diagnostics.Window()


__all__ = ["Timings", "RunClocks", "Measurements"]
