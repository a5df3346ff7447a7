"""The ``tracking`` status: whether the press still moves as the tracker's model says.

A :class:`TrackingMonitor` watches a :class:`~mps_core.track.tracker.Tracker` measurement by
measurement and gives one :class:`Status` (``OK``, ``WARN`` or ``ERROR``, one line saying what
and since when). Five tests, each on what the tracker already computes:

- **the innovations** (``WARN``): the mean normalised innovation squared (NIS) of the last
  ``window`` measurements taken, a χ² variable of ``window`` degrees of freedom divided by
  ``window`` where the filter is consistent, against its upper ``confidence`` bound: WARN above
  it. Only the upper side is a test: a healthy run's mean NIS is about 0.3 to 0.6 (the filter is
  pessimistic: docs/tracking.md), under the lower bound by design, and innovations smaller than
  expected are no departure of the machine.
- **the track** (``ERROR``): ``lost_after`` measurements running rejected as beyond the gate
  (``outlier``), beyond a physically possible crank jump (``jump``) or with no configuration
  (``model``): the press moves where the model cannot follow; found again once
  ``recover_after`` measurements running are taken.
- **the load torque** (``ERROR``, latch closed): the estimated load torque on the crank against
  its own estimate one revolution before at the same crank angle (``torque_bins`` bins a turn):
  what the model misses on the drive side (the masses, the friction, the motor off its
  catalogue) repeats each revolution; a slipping drive, a broken spring, a new friction does
  not. ERROR where the difference is ``torque_z`` of its 1-σ (both estimates') or more for
  ``torque_hold`` measurements running. The crank alone cannot tell these causes apart: the line
  names the torque, not the cause.
- **the process force** (``ERROR``): the work the punch has done so far in the stroke under way
  against the last healthy stroke's: ERROR where it exceeds ``work_factor`` times that by three
  of its 1-σ (a double blank, a harder or thicker part). The first stroke has no reference:
  it is not tested.
- **the part** (``WARN``): a whole revolution closed whose work is under the last healthy
  stroke's divided by ``work_factor`` by three of its 1-σ: no part blanked (a part missing from
  the die, a much thinner one). A process event, not a departure of the machine: WARN, until a
  stroke blanks again.

The status is the worst of the tests; its line is the earliest failing test's at that level.
:attr:`TrackingMonitor.events` keeps each change of the status.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .measurements import Measurement, MeasurementError
from .strokes import StrokeEstimate

if TYPE_CHECKING:
    from .tracker import Estimate, Tracker

__all__ = ["LEVELS", "DiagnosticSettings", "Status", "TrackingMonitor", "chi2_quantile"]


def chi2_quantile(p: float, dof: float | Sequence[float] | np.ndarray) -> np.ndarray:
    """Return the ``p``-quantile of χ² with ``dof`` degrees of freedom (a number or an array).

    ``scipy.stats.chi2.ppf``'s numbers, 2·P⁻¹(dof/2, p) by ``scipy.special.gammaincinv`` as
    scipy.stats computes them, without importing scipy.stats (half a second or more; scipy.special
    a sixth of that)."""
    from scipy.special import gammaincinv

    return 2.0 * gammaincinv(0.5 * np.asarray(dof, dtype=float), p)


#: the status levels, least to most severe (diagnostic_msgs/DiagnosticStatus's OK, WARN, ERROR)
LEVELS = ("OK", "WARN", "ERROR")
#: the rejections that say the model no longer follows the press (not bad data)
LOST_REASONS = ("outlier", "jump", "model")


@dataclass(frozen=True)
class DiagnosticSettings:
    """The tests' sizes and limits (see the module's doc)."""

    window: int = 100
    confidence: float = 0.95
    lost_after: int = 5
    recover_after: int = 50
    torque_bins: int = 72
    torque_z: float = 6.0
    torque_hold: int = 3
    work_factor: float = 1.5

    def __post_init__(self) -> None:
        for name, low in (
            ("window", 10),
            ("lost_after", 1),
            ("recover_after", 1),
            ("torque_bins", 4),
            ("torque_hold", 1),
        ):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= low):
                raise MeasurementError(f"diagnostics.{name}", v, f"an integer >= {low}")
        if not (isinstance(self.confidence, float) and 0.5 < self.confidence < 1.0):
            raise MeasurementError("diagnostics.confidence", self.confidence, "a probability in (0.5, 1)")
        for name in ("torque_z", "work_factor"):
            v = getattr(self, name)
            if not (isinstance(v, float | int) and v > 1.0 and math.isfinite(v)):
                raise MeasurementError(f"diagnostics.{name}", v, "a number > 1")


@dataclass(frozen=True)
class Status:
    """The tracking status at time ``t``.

    Its level (:data:`LEVELS`), what it says, and since when (s) it has said it.
    """

    t: float
    level: str
    message: str
    since: float

    def line(self) -> str:
        """Return the status as one line."""
        return f"tracking {self.level} since t = {self.since:.4f} s: {self.message}"


@dataclass
class _Finding:
    """One test's present verdict: its level, message, and since when it has failed."""

    level: str = "OK"
    message: str = ""
    since: float = math.nan


class TrackingMonitor:
    """Watch a tracker measurement by measurement and give its ``tracking`` status."""

    def __init__(self, settings: DiagnosticSettings | None = None) -> None:
        self.settings = settings or DiagnosticSettings()
        s = self.settings
        #: the upper bound of the window's mean NIS (a χ²(window)/window quantile)
        self.nis_bound = float(chi2_quantile(0.5 + 0.5 * s.confidence, s.window)) / s.window
        self._nis: deque[float] = deque(maxlen=s.window)
        self._seen = 0
        self._rejected = 0
        self._running = 0
        self._accepted = 0
        self._taken = 0
        self._findings = {name: _Finding() for name in ("innovations", "track", "torque", "work", "part")}
        # the load torque a revolution back: bin -> (revolution, torque, variance)
        self._torque_ref: dict[int, tuple[int, float, float]] = {}
        self._torque_over = 0
        self._structure = ""
        self._work_ref: float | None = None
        self._work_ref_sigma = 0.0
        self._strokes = 0
        self._stroke_flagged = False
        #: the status now
        self.status = Status(0.0, "OK", "no measurement yet", 0.0)
        #: every change of the status, in order
        self.events: list[Status] = []

    def observe(self, tracker: Tracker, m: Measurement, estimate: Estimate | None = None) -> Status:
        """Take the tracker's state after it was given ``m``; return the status.

        ``estimate``: the tracker's present estimate, where the caller has it.
        """
        t = m.t
        self._innovations(tracker, t)
        self._track(tracker, t)
        est = estimate or tracker.estimate()
        self._torque(tracker, est.structure, est.phi, est.torque, est.torque_sigma, t)
        self._work(tracker, est.work, est.work_sigma, t)
        status = self._combine(t)
        stroke = tracker.strokes.current
        if stroke is not None and LEVELS.index(status.level) > LEVELS.index(stroke.tracking):
            stroke.tracking = status.level  # the stroke under way says the worst of its statuses
        return status

    # -- the tests --------------------------------------------------------------------------
    def _innovations(self, tracker: Tracker, t: float) -> None:
        """Run the windowed NIS test (WARN above its upper bound)."""
        replaced = tracker.take_replaced()
        if replaced is not None and replaced < self._seen:  # a late signal's: taken again
            for _ in range(min(self._seen - replaced, len(self._nis))):
                self._nis.pop()
            self._seen = replaced
        dropped = getattr(tracker, "innovations_dropped", 0)  # the log's first ones, dropped
        new = tracker.innovations[max(self._seen - dropped, 0) :]
        self._seen = dropped + len(tracker.innovations)
        w = self.settings.window
        self._nis.extend(v for _t, _k, v in new)
        f = self._findings["innovations"]
        if len(self._nis) < w:
            self._set(f, "OK", f"filling the window: {len(self._nis)} of {w} innovations", t)
            return
        mean = sum(self._nis) / w
        said = f"mean NIS {mean:.2f} over the last {w} measurements (upper bound {self.nis_bound:.2f})"
        if mean > self.nis_bound:
            self._set(f, "WARN", "innovations beyond their chi-squared bound: " + said, t)
        else:
            self._set(f, "OK", said, t)

    def _track(self, tracker: Tracker, t: float) -> None:
        """Run the lost-track test: measurements running rejected as the model's misses.

        A lost track is found again once ``recover_after`` measurements running are taken.
        """
        s = self.settings
        rejected = sum(tracker.rejected[r] for r in LOST_REASONS)
        if rejected > self._rejected:
            self._running += rejected - self._rejected
            self._taken = 0
        elif tracker.accepted > self._accepted:
            self._taken += 1
            if self._running < s.lost_after or self._taken >= s.recover_after:
                self._running = 0
        self._rejected, self._accepted = rejected, tracker.accepted
        f = self._findings["track"]
        if self._running >= s.lost_after:
            why = ", ".join(f"{r} {tracker.rejected[r]}" for r in LOST_REASONS if tracker.rejected[r])
            self._set(
                f,
                "ERROR",
                f"track lost: {self._running} measurements running rejected ({why} in all): the press "
                "moves where the model cannot follow (a force far from the model's: a broken spring, "
                "a jam, a slip)",
                t,
            )
        else:
            self._set(f, "OK", "", t)

    def _torque(
        self, tracker: Tracker, structure: str, phi: float, torque: float, sd: float, t: float
    ) -> None:
        """Compare the load torque with its own estimate a revolution back at the same crank angle."""
        s = self.settings
        f = self._findings["torque"]
        if structure != self._structure:  # another structure: the reference starts again
            self._structure = structure
            self._torque_ref.clear()
            self._torque_over = 0
        if structure != "locked" or self._running:
            self._set(f, "OK", "", t)
            return
        turns = (phi - tracker.phi_tdc) / (2.0 * math.pi)
        rev = math.floor(turns)
        b = int((turns - rev) * s.torque_bins) % s.torque_bins
        ref = self._torque_ref.get(b)
        z = 0.0
        if ref is not None and ref[0] == rev - 1:
            z = (torque - ref[1]) / math.sqrt(max(sd * sd + ref[2], 1e-12))
        self._torque_over = self._torque_over + 1 if abs(z) >= s.torque_z else 0
        if self._torque_over >= s.torque_hold:
            assert ref is not None  # z is nonzero only with a reference
            self._set(
                f,
                "ERROR",
                f"load torque on the crank {torque - ref[1]:+.1f} N*m off its estimate a revolution "
                f"before at the same crank angle ({abs(z):.1f} sigma): a slipping drive, a broken "
                "spring or a new friction (the crank alone cannot tell which)",
                t,
            )
            return  # a departed torque is no reference for the next revolution
        if not self._torque_over:
            self._torque_ref[b] = (rev, torque, sd * sd)
        self._set(f, "OK", "", t)

    def _work(self, tracker: Tracker, work: float, sd: float, t: float) -> None:
        """Compare the stroke's work so far with the last healthy stroke's."""
        s = self.settings
        f = self._findings["work"]
        table = tracker.strokes
        new = table.closed - self._strokes  # strokes closed since: a healthy one is the reference
        for done in table.strokes[len(table.strokes) - new :] if new else ():
            self._part(tracker, done, t)
            if not self._stroke_flagged and self._whole(done, tracker):
                self._work_ref, self._work_ref_sigma = done.work, done.work_sigma
                self._set(f, "OK", "", t)
            self._stroke_flagged = False
        self._strokes = table.closed
        ref, current = self._work_ref, tracker.strokes.current
        if ref is None or current is None:
            return
        limit = s.work_factor * ref
        if work - limit > 3.0 * math.hypot(sd, s.work_factor * self._work_ref_sigma):
            self._stroke_flagged = True
            self._set(
                f,
                "ERROR",
                f"process force beyond the part's: stroke {current.index} has done {work:.1f} +- "
                f"{sd:.1f} J so far, the last healthy stroke {ref:.1f} J (more than {s.work_factor:g} "
                "times: a double blank, a harder or thicker part)",
                t,
            )

    def _part(self, tracker: Tracker, done: StrokeEstimate, t: float) -> None:
        """Judge a closed stroke's part: WARN where a whole revolution blanked none."""
        ref = self._work_ref
        f = self._findings["part"]
        if ref is None or not self._revolution(done, tracker):
            return
        k = self.settings.work_factor
        if done.work + 3.0 * math.hypot(done.work_sigma, self._work_ref_sigma / k) < ref / k:
            self._set(
                f,
                "WARN",
                f"no part blanked in stroke {done.index}: {done.work:.1f} +- {done.work_sigma:.1f} J, the "
                f"last healthy stroke {ref:.1f} J (less than 1/{k:g} of it: a part missing from the die, "
                "a much thinner one)",
                t,
            )
        else:
            self._set(f, "OK", "", t)

    @staticmethod
    def _revolution(stroke: StrokeEstimate, tracker: Tracker) -> bool:
        """Return whether a closed stroke is a whole revolution (not cut by a change of structure)."""
        rate = abs(tracker.estimate().phi_dot)
        turn = 2.0 * math.pi / rate if rate > 0.0 else math.inf
        return math.isfinite(stroke.work) and stroke.t_end - stroke.t_start >= 0.8 * turn

    @classmethod
    def _whole(cls, stroke: StrokeEstimate, tracker: Tracker) -> bool:
        """Return whether a closed stroke can be the reference for the work.

        A whole revolution (not cut by a change of structure) in which a part was blanked (its
        work three of its 1-sigma off zero).
        """
        return cls._revolution(stroke, tracker) and stroke.work > 3.0 * stroke.work_sigma

    # -- the status -----------------------------------------------------------------------
    @staticmethod
    def _set(f: _Finding, level: str, message: str, t: float) -> None:
        """Give a test its verdict; its ``since`` moves only where its level changes."""
        if level != f.level:
            f.since = t
        f.level, f.message = level, message

    def _combine(self, t: float) -> Status:
        """Return the worst of the tests' verdicts (the earliest at that level), noting a change."""
        worst = max(LEVELS.index(f.level) for f in self._findings.values())
        level = LEVELS[worst]
        if level == "OK":
            f = self._findings["innovations"]
            message, since = f.message, self.status.since if self.status.level == "OK" else t
        else:
            f = min((f for f in self._findings.values() if f.level == level), key=lambda f: f.since)
            message, since = f.message, f.since
        changed = level != self.status.level or (level != "OK" and since != self.status.since)
        self.status = Status(t, level, message, since)
        if changed or not self.events:
            self.events.append(self.status)
        return self.status
