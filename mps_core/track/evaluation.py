"""How well a tracker follows a truth: errors, per-stroke figures, consistency.

The measures of the anchors (Sanjurjo, Naya, Cuadrado et al.; Pastorino et al.): errors as a
fraction of the largest true value, the normalised estimation error squared (NEES, of (φ, φ̇) and,
in the work window, of (φ, φ̇, F_p)) and the normalised innovation squared (NIS) against their
95 % χ² bounds, and how often the estimate's 1-σ covers the truth. Per stroke: the peak process
force, the work the punch did (−∫F·ẋ_C dt, on the downstroke) and the peak foundation force,
each against the truth's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .diagnostics import chi2_quantile
from .strokes import stroke_index
from .tracker import Tracker, foundation_magnitude
from .truth import TruthRun

__all__ = ["Followed", "follow", "truth_strokes"]


@dataclass
class Followed:
    """A tracker's estimates over a truth run, sample by sample, and what they add up to."""

    t: list[float] = field(default_factory=list)
    nees: list[float] = field(default_factory=list)
    nees_dof: list[int] = field(default_factory=list)
    covered: list[bool] = field(default_factory=list)
    foundation_error: list[float] = field(default_factory=list)
    foundation_true: list[float] = field(default_factory=list)
    cpu: list[float] = field(default_factory=list)

    def nees_inside(self) -> float:
        """Return the fraction of NEES values inside their 95 % χ² bound (upper)."""
        if not self.nees:
            return math.nan
        bounds = chi2_quantile(0.95, self.nees_dof)
        return float(np.mean(np.asarray(self.nees) <= bounds))

    def coverage(self) -> float:
        """Return the fraction of (φ, φ̇, F_p) errors inside the estimate's 1-σ."""
        return float(np.mean(self.covered)) if self.covered else math.nan

    def foundation_rms_fraction(self) -> float:
        """Return the foundation force's RMS error as a fraction of its true peak."""
        if not self.foundation_error:
            return math.nan
        err = np.asarray(self.foundation_error)
        return float(np.sqrt(np.mean(err**2)) / np.max(np.abs(self.foundation_true)))


def nis_inside(tracker: Tracker) -> float:
    """Return the fraction of the tracker's NIS values inside the 95 % χ² bound of one dof."""
    if not tracker.innovations:
        return math.nan
    nis = np.array([v for _t, _k, v in tracker.innovations])
    return float(np.mean(nis <= chi2_quantile(0.95, 1)))


def follow(tracker: Tracker, truth: TruthRun, *, loads: bool = True, cpu_clock: object = None) -> Followed:
    """Run ``tracker`` over the truth's mode signals and measurements; compare as it goes."""
    import time

    clock = time.process_time if cpu_clock is None else cpu_clock
    out = Followed()
    modes = sorted(truth.modes, key=lambda s: s.t)
    for m in truth.measurements:
        while modes and modes[0].t <= m.t:
            tracker.mode(modes.pop(0))
        c0 = clock()  # type: ignore[operator]
        taken = tracker.update(m)
        smoothed = tracker.smoothed_loads() if loads else None
        tracker.observe_stroke(None if smoothed is None else smoothed[1])
        out.cpu.append(clock() - c0)  # type: ignore[operator]
        if not taken or m.kind != "crank_angle":
            continue
        _compare(tracker, truth, smoothed, out)
    return out


def _compare(tracker: Tracker, truth: TruthRun, smoothed: tuple[float, dict] | None, out: Followed) -> None:
    """Add the present estimate's normalised error, coverage and foundation error to ``out``."""
    est = tracker.estimate()
    tv = truth.at(est.t)
    window = tracker.in_window
    err = np.array([est.phi - tv["phi"], est.phi_dot - tv["phi_dot"], est.force - tv["force"]])
    P = tracker.physical_covariance()
    d = 3 if window else 2
    e, C = err[:d], P[:d, :d]
    try:
        out.nees.append(float(e @ np.linalg.solve(C, e)))
        out.nees_dof.append(d)
    except np.linalg.LinAlgError:
        pass
    sd = np.sqrt(np.maximum(np.diag(C), 0.0))
    out.covered.extend(bool(abs(a) <= s) for a, s in zip(e, sd))
    out.t.append(est.t)
    if smoothed is not None:
        t_loads, rx = smoothed
        f_est, _ = foundation_magnitude(rx)
        at = truth.at(t_loads)
        f_true = math.hypot(at["foundation_x"], at["foundation_y"])
        out.foundation_error.append(f_est - f_true)
        out.foundation_true.append(f_true)


def truth_strokes(truth: TruthRun, phi_tdc: float = 0.0) -> dict[int, dict[str, float]]:
    """Return the truth's per-stroke figures: stroke → peak force, work, peak foundation."""
    out: dict[int, dict[str, float]] = {}
    k = np.array([stroke_index(p, phi_tdc) for p in truth.phi])
    f_found = np.hypot(truth.foundation_x, truth.foundation_y)
    dx = np.diff(truth.x_C)
    f_mid = 0.5 * (truth.force[1:] + truth.force[:-1])
    dw = -f_mid * dx
    # the force averaged over each step between two encoder stamps (what a force constant over
    # each step can show at best), by the trapezoid rule on the fine grid
    stamps = np.array(sorted({m.t for m in truth.measurements if m.kind == "crank_angle"}))
    impulse = np.concatenate([[0.0], np.cumsum(f_mid * np.diff(truth.t))])
    at = np.interp(stamps, truth.t, impulse)
    averages = np.diff(at) / np.diff(stamps)
    middle = 0.5 * (stamps[1:] + stamps[:-1])
    k_mid = np.array([stroke_index(p, phi_tdc) for p in np.interp(middle, truth.t, truth.phi)])
    for s in np.unique(k[truth.locked]):
        rows = (k == s) & truth.locked
        steps = rows[1:] & rows[:-1]
        in_stroke = averages[k_mid == s]
        out[int(s)] = {
            "peak_step_average_N": float(in_stroke.max()) if len(in_stroke) else math.nan,
            "peak_force_N": float(truth.force[rows].max()),
            "work_J": float(dw[steps].sum()),
            "peak_foundation_N": float(f_found[rows].max()),
            "complete": float(not rows[-1]),
        }
    return out
