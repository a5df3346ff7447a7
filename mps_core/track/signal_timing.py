"""Find when a late mode signal's command took effect: a search over its latency.

A press's mode signal (``engage``, ``disengage``) may come after its command took effect: a
``std_msgs/String`` has no stamp, so its time is when it came, and the controller's cycle, the
network and the executor add to it. Applied at that time, the model engages late while the
press already moves as engaged, and a few milliseconds of that lose the track
(docs/tracking.md, Late mode signals).

With a ``signal_latency`` L the tracker keeps, for its last 1.5·L of measurements (and back
to the window of a signal not yet searched), each one's log-likelihood and a checkpoint of its
state every ``CHECKPOINT_EVERY`` stamps. A signal stamped t is applied at t, as without the
search; once the estimate is L past t (or at the first measurement rejected since), its command
is tried at the middle of each gap between the measurements that meets [t − L, t], then at the
quarters of the best gap: from the last checkpoint before the gap, the measurements taken again.
The hypothesis whose measurements since t − L are the likeliest is kept: the one applied at t
unless another beats it by ``EVIDENCE`` (a likelihood ratio chance gives one time in twenty).
A measurement's log-likelihood is −½·(NIS + log S/R), the NIS capped at the gate, a rejection
before any innovation −gate: never positive, so a hypothesis is dropped as soon as its sum falls
below the one to beat. The estimates already given stay as they were; the tracker's state,
counts, innovations and strokes are the kept hypothesis's
(:attr:`~mps_core.track.tracker.Tracker.replaced_from` says from where).
"""

from __future__ import annotations

import time
from collections import deque
from itertools import accumulate, islice
from typing import Any, NamedTuple, Protocol

from .measurements import Measurement, ModeSignal

__all__ = ["CHECKPOINT_EVERY", "EVIDENCE", "Found", "SignalTiming"]

#: the gaps between stamps a checkpoint is kept for: the states between are taken again from the
#: one before, in a search; a checkpoint copies some 7 µs of state, and while it is held the steps
#: after it are slower too, about as much with one every fourth stamp as with one at each
#: (docs/tracking.md, Late mode signals)
CHECKPOINT_EVERY = 4
#: the last signals searched that :attr:`SignalTiming.found` keeps (a press followed for days)
FOUND_KEPT = 1000
#: how much likelier (log) a command earlier than its signal must make the measurements than
#: the signal on time: half χ²(1)'s 95 % quantile
EVIDENCE = 0.5 * 3.841


class Found(NamedTuple):
    """Where a mode signal's command was put: ``shift`` s before its stamp.

    ``searched``: found by the search (False: kept where it was applied, nothing measured to
    search with: none since its window opened, or a later signal came first); ``tried``: the
    hypotheses the search tried; ``cpu``: the search's CPU (s, the thread's), which holds up
    the measurement that closes it.
    """

    signal: ModeSignal
    shift: float
    searched: bool
    tried: int = 0
    cpu: float = 0.0


class Searched(Protocol):
    """What the search needs of a tracker (:class:`~mps_core.track.tracker.Tracker`)."""

    sim: Any
    #: the log-likelihood of the last measurement taken
    score: float

    def checkpoint(self) -> tuple: ...
    def restore(self, cp: tuple) -> None: ...
    def log_lengths(self) -> tuple[int, int]: ...
    def logs_since(self, lengths: tuple[int, int]) -> tuple[list, list]: ...
    def set_logs(self, lengths: tuple[int, int], logs: tuple[list, list]) -> None: ...
    def apply_command(self, command: str, t: float) -> None: ...
    def take(self, m: Measurement) -> bool: ...


class _Taken(NamedTuple):
    """A measurement taken: the tracker's time, logs and checkpoint before it, its score, whether taken.

    The checkpoint is kept every ``CHECKPOINT_EVERY`` gaps between stamps (None between, and
    where the tracker's time is the measurement's stamp already: no gap to try a command in).
    """

    m: Measurement
    t_before: float
    logs: tuple[int, int]
    before: tuple | None
    score: float
    taken: bool


class SignalTiming:
    """Find when each late mode signal's command took effect (maximum likelihood over its window)."""

    def __init__(self, latency: float) -> None:
        #: how late a signal may come after its command took effect (s); and how long after
        #: its stamp its measurements are gathered before the search
        self.latency = float(latency)
        self._history: deque[_Taken] = deque()
        self._gaps = 0  # the gaps between stamps so far (a checkpoint every CHECKPOINT_EVERY)
        #: signals stamped ahead of the estimate (applied at their stamp once a measurement reaches it)
        self._due: list[ModeSignal] = []
        #: signals applied (signal, the time applied at), searched once the estimate is ``latency`` past
        self._applied: list[tuple[ModeSignal, float]] = []
        #: each signal resolved (on the tracker's clock), how long before its stamp its command
        #: was put (s) and whether it was searched for, in order
        self.found: deque[Found] = deque(maxlen=FOUND_KEPT)
        #: the signals resolved, in all (:attr:`found` keeps the last ``FOUND_KEPT``)
        self.searched = 0
        #: the hypotheses tried, in all
        self.tried = 0

    def _found(
        self, signal: ModeSignal, shift: float, searched: bool, tried: int = 0, cpu: float = 0.0
    ) -> None:
        """Record a signal resolved and where its command was put."""
        self.found.append(Found(signal, shift, searched, tried, cpu))
        self.searched += 1

    @property
    def shifts(self) -> list[float]:
        """Return how long before its stamp each signal's command was put (s), in order."""
        return [f.shift for f in self.found]

    def signal(self, tracker: Searched, signal: ModeSignal) -> None:
        """Take a signal (on the tracker's clock): applied at its stamp (now where the estimate is past it).

        A signal before it not yet searched is searched now, with what has come.
        """
        for earlier in self._due:
            tracker.apply_command(earlier.command, earlier.t)
            self._found(earlier, 0.0, False)
        self._due.clear()
        while self._applied:
            self._resolve(tracker, *self._applied.pop(0))
        if signal.t > tracker.sim.t:
            self._due.append(signal)
            return
        self._applied.append((signal, tracker.sim.t))
        tracker.apply_command(signal.command, signal.t)

    def take(self, tracker: Searched, m: Measurement) -> bool:
        """Take a measurement (on the tracker's clock); return whether it was taken.

        The signals whose search it closes are searched first; those it reaches are applied
        (after the checkpoint before it). A measurement rejected after a signal was applied
        closes its search at once (the command is off where it was applied).
        """
        while self._applied and m.t > self._applied[0][0].t + self.latency:
            self._resolve(tracker, *self._applied.pop(0))
        history = self._history
        # kept back far enough that a signal stamped a little behind the estimate finds its window
        keep = m.t - 1.5 * self.latency
        if self._applied:
            keep = min(keep, self._applied[0][0].t - self.latency)
        while len(history) > 1 and history[0].m.t < keep:
            # a checkpoint is kept while it is the last one at or before keep (where the window's
            # measurements are taken again from)
            later = next((h for h in islice(history, 1, None) if h.before is not None), None)
            if history[0].before is not None and (later is None or later.m.t > keep):
                break
            history.popleft()
        t_before = tracker.sim.t
        logs = tracker.log_lengths()
        gap = m.t > t_before
        if gap:
            self._gaps += 1
        before = tracker.checkpoint() if gap and self._gaps % CHECKPOINT_EVERY == 0 else None
        while self._due and self._due[0].t <= m.t:
            signal = self._due.pop(0)
            self._applied.append((signal, signal.t))
            tracker.apply_command(signal.command, signal.t)
        taken = tracker.take(m)
        history.append(_Taken(m, t_before, logs, before, tracker.score, taken))
        if not taken and self._applied:
            self._resolve(tracker, *self._applied.pop(0))
            taken = self._history[-1].taken
        return taken

    def _resolve(self, tracker: Searched, signal: ModeSignal, applied: float) -> None:
        """Keep the signal's command where the measurements since its window opened say it was.

        Tried in each gap between the measurements that meets [stamp − latency, stamp], against
        where it was applied (the present run), from the last checkpoint before the gap.
        """
        t_s, command = signal.t, signal.command
        t_open = t_s - self.latency
        cpu0, tried0 = time.thread_time(), self.tried
        history = list(self._history)
        first = next((i for i, h in enumerate(history) if h.m.t > t_open), len(history))
        if first == len(history):
            self._found(signal, t_s - applied, False)  # nothing measured since its window opened
            return
        window = history[first:]
        present = tracker.checkpoint()
        opened = window[0].logs
        main = tracker.logs_since(opened)  # the present run's, since the window opened
        # the signal on time is the hypothesis to beat, by a likelihood ratio that chance gives
        # one time in twenty (χ²(1) 95 %): near its stamp the measurements say little, and a
        # command moved by noise is off where it was not
        best = (sum(h.score for h in window) + EVIDENCE, applied, present, history, main)
        base = None  # the last entry with a checkpoint, at or before the one tried
        bases = []
        for i, h in enumerate(history):
            if h.before is not None:
                base = i
            bases.append(base)

        def attempt(j: int, tau: float, prefix: float) -> bool:
            """Try the command at tau in the gap before history[j]; return whether it is the best."""
            nonlocal best
            k = bases[j]
            if k is None:
                return False
            start = history[k].before
            assert start is not None
            # the logs whole again first (a hypothesis dropped early leaves them shorter than
            # a later checkpoint's, which a restore only cuts): the present run's up to it
            tracker.set_logs(opened, main)
            tracker.restore(start)
            again: list[_Taken] = []
            for i in range(k, j):  # as they were: no command before the gap
                _take(tracker, history[i], again)
            tracker.apply_command(command, tau)
            total = prefix
            for i in range(j, len(history)):
                _take(tracker, history[i], again)
                total += again[-1].score
                if total <= best[0]:  # no score is positive: it cannot win
                    break
            self.tried += 1
            if total <= best[0]:
                return False
            (n_i, n_s), (o_i, o_s) = history[j].logs, opened
            innovations, strokes = tracker.logs_since(history[j].logs)
            logs = (main[0][: n_i - o_i] + innovations, main[1][: n_s - o_s] + strokes)
            best = (total, tau, tracker.checkpoint(), history[:k] + again, logs)
            return True

        # the gaps nearest the stamp first: a command a little early (the commonest) is found
        # first, and the one to beat rises with it, so the gaps further back are dropped sooner;
        # the likeliest is the same in any order
        prefixes = list(accumulate((h.score for h in history[first:]), initial=0.0))
        won = None
        for j in reversed(range(first, len(history))):
            h = history[j]
            if h.t_before < t_s and h.m.t > h.t_before:
                lo, hi = max(h.t_before, t_open), min(h.m.t, t_s)
                if attempt(j, 0.5 * (lo + hi), prefixes[j - first]):
                    won = (j, lo, hi, prefixes[j - first])
        if won is not None:  # the gap's quarters: a command a quarter of a sample off moves an impact
            j, lo, hi, prefix = won
            for tau in (0.75 * lo + 0.25 * hi, 0.25 * lo + 0.75 * hi):
                attempt(j, tau, prefix)
        _total, tau, state, kept, logs = best
        tracker.restore(state)
        tracker.set_logs(opened, logs)
        self._history = deque(kept)
        self._found(signal, t_s - tau, True, self.tried - tried0, time.thread_time() - cpu0)


def _take(tracker: Searched, taken: _Taken, into: list[_Taken]) -> None:
    """Take ``taken``'s measurement into the tracker again, into ``into`` as it was.

    With a checkpoint before it where it had one.
    """
    m = taken.m
    t_before, logs = tracker.sim.t, tracker.log_lengths()
    before = tracker.checkpoint() if taken.before is not None else None
    ok = tracker.take(m)
    into.append(_Taken(m, t_before, logs, before, tracker.score, ok))
