"""The per-stroke table: each working stroke's peak process force, its work and the peak load
on the foundation, each with its standard deviation.

The peak force and the foundation's peak are the stroke's cut fitted whole where it was
(:mod:`~mps_core.track.cut_fit`: the part's force curve, its contact and breakthrough depth
with it; the foundation's largest over the fitted run), else the filter's largest; the
filter's are kept beside them.

A stroke runs from one top dead centre of the locked crank-slider to the next: stroke ``k`` is
where ``floor((φ − φ_TDC)/2π) = k`` with the latch closed (φ_TDC = 0 for the press: the rocker
locked at ψ = 0 puts O, A, B, C on the guide's axis there). The work is the filter's integrated
state (the work the punch does on the part, −∫F_p·ẋ_C dt, whose variance the filter carries
with its correlations), read at the stroke's end; the peaks are the largest estimates over the
stroke, with the 1-σ of the estimate where the peak is. Each stroke says the worst tracking status
of its measurements (``tracking``): where it is ERROR the press departed from the model during
the stroke (a slipping clutch, a broken spring), and its figures are not the press's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .cut_fit import CutFit

__all__ = ["StrokeEstimate", "StrokeTable", "stroke_index"]


def stroke_index(phi: float, phi_tdc: float = 0.0) -> int:
    """Return the index of the stroke the crank angle ``phi`` (rad, unwrapped) lies in."""
    return math.floor((phi - phi_tdc) / (2.0 * math.pi))


@dataclass
class StrokeEstimate:
    """One stroke's figures (SI units), each with its 1-σ."""

    index: int
    t_start: float
    t_end: float = math.nan
    peak_force: float = -math.inf
    peak_force_sigma: float = math.nan
    t_peak_force: float = math.nan
    work: float = math.nan
    work_sigma: float = math.nan
    peak_foundation: float = -math.inf
    peak_foundation_sigma: float = math.nan
    #: the largest of the filter's smoothed force, and of its foundation load, with their 1-σ
    filter_peak_force: float = -math.inf
    filter_peak_force_sigma: float = math.nan
    filter_peak_foundation: float = -math.inf
    filter_peak_foundation_sigma: float = math.nan
    #: the cut fitted whole (None where it was not)
    fit: CutFit | None = None
    #: whether its cut's fit is being made elsewhere and has not come back
    fit_pending: bool = False
    #: the worst tracking status while it ran (OK, WARN, ERROR: :mod:`~mps_core.track.diagnostics`
    #: says it at each measurement): a stroke's figures under a fault are no press's
    tracking: str = "OK"

    def row(self) -> dict[str, float | str]:
        """Return the stroke as a table's row (column name → value)."""
        fit = self.fit
        return {
            "stroke": float(self.index),
            "t_start": self.t_start,
            "t_end": self.t_end,
            "peak_force_N": self.peak_force,
            "peak_force_sigma_N": self.peak_force_sigma,
            "t_peak_force": self.t_peak_force,
            "work_J": self.work,
            "work_sigma_J": self.work_sigma,
            "peak_foundation_N": self.peak_foundation,
            "peak_foundation_sigma_N": self.peak_foundation_sigma,
            "filter_peak_force_N": self.filter_peak_force,
            "filter_peak_force_sigma_N": self.filter_peak_force_sigma,
            "filter_peak_foundation_N": self.filter_peak_foundation,
            "filter_peak_foundation_sigma_N": self.filter_peak_foundation_sigma,
            "contact_m": math.nan if fit is None else fit.contact,
            "contact_sigma_m": math.nan if fit is None else fit.contact_sigma,
            "breakthrough_depth_m": math.nan if fit is None else fit.depth,
            "breakthrough_depth_sigma_m": math.nan if fit is None else fit.depth_sigma,
            "fit_chi2_dof": math.nan if fit is None else fit.chi2 / max(fit.dof, 1),
            "tracking": self.tracking,
        }


class StrokeTable:
    """Collect the per-stroke figures from a tracker's estimates as they come."""

    def __init__(self) -> None:
        #: the finished strokes, in order
        self.strokes: list[StrokeEstimate] = []
        #: the stroke under way (None outside the working structure)
        self.current: StrokeEstimate | None = None
        #: strokes finished since the start (those taken off :attr:`strokes` too)
        self.closed = 0

    def state(self) -> tuple:
        """Return the count closed and the stroke under way, for :meth:`set_state`.

        The list of strokes is its owner's to keep (a tracker's checkpoint keeps its length).
        """
        return self.closed, None if self.current is None else dict(vars(self.current))

    def set_state(self, state: tuple) -> None:
        """Come back to a :meth:`state`."""
        self.closed, current = state
        self.current = None
        if current is not None:
            self.current = StrokeEstimate.__new__(StrokeEstimate)
            vars(self.current).update(current)

    def begin(self, index: int, t: float) -> None:
        """Start stroke ``index`` at time ``t``."""
        self.current = StrokeEstimate(index, t)

    def observe(
        self,
        t: float,
        force: float,
        force_sigma: float,
        foundation: float | None = None,
        foundation_sigma: float = math.nan,
    ) -> None:
        """Take one estimate of the process force (and of the foundation load's magnitude)."""
        s = self.current
        if s is None:
            return
        if force > s.filter_peak_force:
            s.filter_peak_force, s.filter_peak_force_sigma = force, force_sigma
            if s.fit is None:
                s.peak_force, s.peak_force_sigma, s.t_peak_force = force, force_sigma, t
        if foundation is not None and foundation > s.filter_peak_foundation:
            s.filter_peak_foundation, s.filter_peak_foundation_sigma = foundation, foundation_sigma
            if s.fit is None:
                s.peak_foundation, s.peak_foundation_sigma = foundation, foundation_sigma

    def _find(self, index: int) -> StrokeEstimate | None:
        """Return the stroke ``index``: the one under way or one finished (None: neither)."""
        if self.current is not None and self.current.index == index:
            return self.current
        for s in reversed(self.strokes):
            if s.index == index:
                return s
        return None

    def pending(self, index: int) -> None:
        """Mark stroke ``index``'s cut as being fitted elsewhere."""
        s = self._find(index)
        if s is not None:
            s.fit_pending = True

    def unfitted(self, index: int) -> None:
        """Stroke ``index``'s cut was not fitted: it keeps the filter's peak."""
        s = self._find(index)
        if s is not None:
            s.fit_pending = False

    def fitted(self, index: int, fit: CutFit, t_peak: float) -> None:
        """Take stroke ``index``'s cut fitted whole: its peak (at ``t_peak``) the stroke's."""
        s = self._find(index)
        if s is None:
            return
        s.fit, s.fit_pending = fit, False
        s.peak_force, s.peak_force_sigma, s.t_peak_force = fit.peak_force, fit.peak_force_sigma, t_peak
        if math.isfinite(fit.peak_foundation):
            s.peak_foundation, s.peak_foundation_sigma = fit.peak_foundation, fit.peak_foundation_sigma

    def close(self, t: float, work: float, work_sigma: float) -> StrokeEstimate | None:
        """End the stroke under way at ``t`` with its work; return it (None if none was)."""
        s = self.current
        self.current = None
        if s is None:
            return None
        s.t_end, s.work, s.work_sigma = t, work, work_sigma
        self.strokes.append(s)
        self.closed += 1
        return s
