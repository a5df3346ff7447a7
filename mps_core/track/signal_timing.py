"""Find when a late mode signal's command took effect: a search over its latency.

A press's mode signal (``engage``, ``disengage``) may come after its command took effect: a
``std_msgs/String`` has no stamp, so its time is when it came, and the controller's cycle, the
network and the executor add to it. Applied at that time, the model engages late while the
press already moves as engaged, and a few milliseconds of that lose the track
(docs/tracking.md, Late mode signals).

With a ``signal_latency`` L the tracker keeps its state before each of its last measurements (a
checkpoint, for the last 1.5·L and back to the window of a signal not yet searched) and each
one's log-likelihood. A signal stamped t is applied at t, as without the search; once the
estimate is L past t (or at the first measurement rejected since), its command is tried in each
gap between the measurements that meets [t − L, t] (at the middle of what of the gap lies
within it), the measurements from there taken again, and the hypothesis whose measurements
since t − L are the likeliest is kept: the one applied at t unless another beats it by
``EVIDENCE`` (a likelihood ratio chance gives one time in twenty). A measurement's
log-likelihood is −½·(NIS + log S/R), the NIS capped at the gate, a rejection before any
innovation −gate: never positive, so a hypothesis is dropped as soon as its sum falls below the
one to beat. The estimates already given stay as they were; the tracker's state, counts,
innovations and strokes are the kept hypothesis's
(:attr:`~mps_core.track.tracker.Tracker.replaced_from` says from where).
"""

from __future__ import annotations

from collections import deque
from typing import Any, NamedTuple, Protocol

from .measurements import Measurement, ModeSignal

__all__ = ["EVIDENCE", "SignalTiming"]

#: how much likelier (log) a command earlier than its signal must make the measurements than
#: the signal on time: half χ²(1)'s 95 % quantile
EVIDENCE = 0.5 * 3.841


class Searched(Protocol):
    """What the search needs of a tracker (:class:`~mps_core.track.tracker.Tracker`)."""

    sim: Any
    #: the log-likelihood of the last measurement taken
    score: float

    def checkpoint(self) -> tuple: ...
    def restore(self, cp: tuple) -> None: ...
    def logs_since(self, cp: tuple) -> tuple[list, list]: ...
    def set_logs(self, cp: tuple, logs: tuple[list, list]) -> None: ...
    def apply_command(self, command: str, t: float) -> None: ...
    def take(self, m: Measurement) -> bool: ...


class _Taken(NamedTuple):
    """A measurement taken: the tracker's time and checkpoint before it, its score, whether taken.

    The checkpoint is None where the tracker's time is the measurement's stamp already (no gap
    to try a command in).
    """

    m: Measurement
    t_before: float
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
        #: signals stamped ahead of the estimate (applied at their stamp once a measurement reaches it)
        self._due: list[ModeSignal] = []
        #: signals applied (signal, the time applied at), searched once the estimate is ``latency`` past
        self._applied: list[tuple[ModeSignal, float]] = []
        #: each signal searched (on the tracker's clock) and how long before its stamp its
        #: command was found to take effect (s), in order
        self.found: list[tuple[ModeSignal, float]] = []
        #: the hypotheses tried, in all
        self.tried = 0

    @property
    def shifts(self) -> list[float]:
        """Return how long before its stamp each signal's command was found (s), in order."""
        return [shift for _signal, shift in self.found]

    def signal(self, tracker: Searched, signal: ModeSignal) -> None:
        """Take a signal (on the tracker's clock): applied at its stamp (now where the estimate is past it).

        A signal before it not yet searched is searched now, with what has come.
        """
        for earlier in self._due:
            tracker.apply_command(earlier.command, earlier.t)
            self.found.append((earlier, 0.0))
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
        keep = (
            m.t - 1.5 * self.latency
        )  # a signal stamped a little behind the estimate still finds its window
        if self._applied:
            keep = min(keep, self._applied[0][0].t - self.latency)
        while history and history[0].m.t < keep:
            history.popleft()
        t_before = tracker.sim.t
        before = tracker.checkpoint() if m.t > t_before else None
        while self._due and self._due[0].t <= m.t:
            signal = self._due.pop(0)
            self._applied.append((signal, signal.t))
            tracker.apply_command(signal.command, signal.t)
        taken = tracker.take(m)
        history.append(_Taken(m, t_before, before, tracker.score, taken))
        if not taken and self._applied:
            self._resolve(tracker, *self._applied.pop(0))
            taken = self._history[-1].taken
        return taken

    def _resolve(self, tracker: Searched, signal: ModeSignal, applied: float) -> None:
        """Keep the signal's command where the measurements since its window opened say it was.

        Tried in each gap between the measurements that meets [stamp − latency, stamp], against
        where it was applied (the present run).
        """
        t_s, command = signal.t, signal.command
        t_open = t_s - self.latency
        history = list(self._history)
        # the window opens at the first measurement after t_open with a gap before it (those
        # before it are every hypothesis's alike)
        first = next(
            (i for i, h in enumerate(history) if h.m.t > t_open and h.before is not None), len(history)
        )
        window = history[first:]
        if not window:
            self.found.append((signal, t_s - applied))
            return
        present = tracker.checkpoint()
        opened = window[0].before
        assert opened is not None
        main = tracker.logs_since(opened)  # the present run's, since the window opened
        # the signal on time is the hypothesis to beat, by a likelihood ratio that chance gives
        # one time in twenty (χ²(1) 95 %): near its stamp the measurements say little, and a
        # command moved by noise is off where it was not
        best = (sum(h.score for h in window) + EVIDENCE, applied, present, history, main)

        def attempt(j: int, tau: float, prefix: float) -> bool:
            """Try the command at tau in the gap before window[j]; return whether it is the best."""
            nonlocal best
            h = window[j]
            assert h.before is not None
            tracker.restore(h.before)
            tracker.apply_command(command, tau)
            again: list[_Taken] = []
            total = prefix
            for later in window[j:]:
                _take(tracker, later.m, again)
                total += again[-1].score
                if total <= best[0]:  # no score is positive: it cannot win
                    break
            self.tried += 1
            if total <= best[0]:
                return False
            (n_i, n_s), (o_i, o_s) = h.before[1], opened[1]
            innovations, strokes = tracker.logs_since(h.before)
            logs = (main[0][: n_i - o_i] + innovations, main[1][: n_s - o_s] + strokes)
            best = (total, tau, tracker.checkpoint(), history[: first + j] + again, logs)
            return True

        prefix, won = 0.0, None
        for j, h in enumerate(window):
            if h.before is not None and h.t_before < t_s:
                lo, hi = max(h.t_before, t_open), min(h.m.t, t_s)
                if attempt(j, 0.5 * (lo + hi), prefix):
                    won = (j, lo, hi, prefix)
            prefix += h.score
        if won is not None:  # the gap's quarters: a command a quarter of a sample off moves an impact
            j, lo, hi, prefix = won
            for tau in (0.75 * lo + 0.25 * hi, 0.25 * lo + 0.75 * hi):
                attempt(j, tau, prefix)
        _total, tau, state, kept, logs = best
        tracker.restore(state)
        tracker.set_logs(opened, logs)
        self._history = deque(kept)
        self.found.append((signal, t_s - tau))


def _take(tracker: Searched, m: Measurement, into: deque[_Taken] | list[_Taken]) -> bool:
    """Take ``m`` into the tracker, its checkpoint before it and its score kept in ``into``."""
    t_before = tracker.sim.t
    before = tracker.checkpoint() if m.t > t_before else None
    taken = tracker.take(m)
    into.append(_Taken(m, t_before, before, tracker.score, taken))
    return taken
