"""The garbage collector's passes, made between a run's deadlines instead of inside them.

Python collects its young objects when their count passes a threshold, wherever that happens:
in the middle of a measurement's estimate, say, which then waits for the pass. A run that has
idle time between its deadlines turns the automatic passes off (:func:`hold`) and makes the
passes that are due itself (:func:`collect_due`) once its deadline's work is done, by the same
thresholds as the interpreter's; :func:`release` gives the passes back to the interpreter. The
objects made before the run (its model, its code) are frozen out of every pass already
(``gc.freeze``). The CPU is the same: it is spent where no deadline waits for it.
"""

from __future__ import annotations

import gc

__all__ = ["collect_due", "hold", "release"]


def hold() -> bool:
    """Turn the interpreter's own passes off; return whether they were on (for :func:`release`)."""
    was = gc.isenabled()
    gc.disable()
    return was


def release(was: bool) -> None:
    """Give the passes back to the interpreter where :func:`hold` found them on."""
    if was:
        gc.enable()


def collect_due() -> int:
    """Make the pass that is due, if any; return its generation (-1: none was due).

    As the interpreter would have: the oldest generation whose count has passed its threshold
    (a young generation's pass counts in the next one's)."""
    c0, c1, c2 = gc.get_count()
    t0, t1, t2 = gc.get_threshold()
    if t0 <= 0 or c0 <= t0:
        return -1
    generation = 0
    if c1 + 1 > t1:
        generation = 1
        if c2 + 1 > t2:
            generation = 2
    gc.collect(generation)
    return generation
