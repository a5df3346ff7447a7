"""The fixed-step solvers' stability limit for the stiff effects (a spring, an elastic stop).

An explicit fixed-step method is stable for q̈ = −ω²q only while ω·Δt stays under its limit
(:data:`~mps_core.solvers.FIXED_STEP_LIMITS`). The stiff effects (:class:`~mps_core.model.effects.base.Stiff`)
give their generalized stiffness K at a state; the largest ω² of K v = ω² A v is estimated from
above by trace(A⁻¹K). A step beyond 0.9 × the limit is subdivided into equal parts within
half the limit, or refused with :class:`StabilityError` (``solver.stiff = "error"``).

Where every stiff effect also bounds its ω² over all states
(:class:`~mps_core.model.effects.base.StiffnessBounded`), steps up to half of 0.9 × the limit
for the sum of the bounds (:attr:`StepStability.always`) are kept whole at once, without the
per-step estimate.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ..errors import SimulationError
from ..model.effects.base import Stiff, StiffnessBounded, has_hook
from ..solvers import FIXED_STEP_LIMITS

__all__ = ["StabilityError", "StepStability"]


class StabilityError(SimulationError):
    """A fixed step exceeds the solver's stability limit for a stiff effect."""


class StepStability:
    """The stability limit of a run's fixed steps: ``effects`` (the stiff ones are kept),
    ``mechanism`` (the effects' bounds), ``settings`` (the solver's name and ``stiff``)."""

    def __init__(self, effects, mechanism, settings):
        self.stiff = [e for e in effects if has_hook(e, Stiff)]
        self.mechanism = mechanism
        self.settings = settings
        #: steps up to this are stable in any state (:meth:`always_stable`, computed once)
        self.always = self.always_stable()

    def always_stable(self) -> float:
        """A step up to which :meth:`stable_step` keeps every step whole, in any state: half of
        0.9 × the stability limit for ω² = the sum of the stiff effects' bounds
        (``stiffness_bound``: ω²_max of their summed K is at most the sum of theirs); 0 where one
        has no bound. Half, so that the round-off of the per-step estimate (a few ulps, more
        on a badly conditioned A) can never reach the bound's factor of 4 in ω²."""
        name = self.settings.name
        if not self.stiff or name not in FIXED_STEP_LIMITS:
            return math.inf
        w2 = 0.0
        for s in self.stiff:
            b = s.stiffness_bound(self.mechanism) if has_hook(s, StiffnessBounded) else None
            if b is None or not (b >= 0.0) or math.isinf(b):
                return 0.0
            w2 += b
        if w2 == 0.0:
            return math.inf
        limit = FIXED_STEP_LIMITS[name][0] * (2.0 * math.pi / math.sqrt(w2))
        return 0.5 * 0.9 * limit

    def omega2(self, e) -> float | None:
        """The stiff effects' ω²_max at evaluation ``e``, estimated from above by trace(A⁻¹K)
        (A SPD, K PSD: at most n times too large, and no eigensolver); None where their K is
        zero."""
        K = None
        for s in self.stiff:
            k = s.stiffness(e.kin)
            if k is not None:
                K = k if K is None else [[a + b for a, b in zip(r, s_)] for r, s_ in zip(K, k)]
        if K is None or not any(any(r) for r in K):
            return None
        n = len(K)
        if n == 1:
            return K[0][0] / float(e.A[0, 0] if isinstance(e._A, np.ndarray) else e._A)
        if n == 2:
            (a00, a01), (a10, a11) = e.A.tolist()
            det = a00 * a11 - a01 * a10
            return (a11 * K[0][0] - a01 * K[1][0] - a10 * K[0][1] + a00 * K[1][1]) / det
        return float(np.trace(np.linalg.solve(e.A, np.array(K))))

    def stable_step(self, dt: float, e, config: Callable) -> float:
        """The largest step not beyond the solver's stability limit for the stiff effects, from
        the evaluation ``e`` at the step's start (``config(e)``: the state, for an error).

        Steps up to :attr:`always` are returned at once: the per-step estimate below would
        keep them whole too."""
        if dt <= self.always:
            return dt
        name = self.settings.name
        if not self.stiff or name not in FIXED_STEP_LIMITS:
            return dt
        w2 = self.omega2(e)
        if w2 is None or w2 <= 0.0:
            return dt
        t_min = 2.0 * math.pi / math.sqrt(w2)
        limit = FIXED_STEP_LIMITS[name][0] * t_min
        if dt <= 0.9 * limit:
            return dt
        if self.settings.stiff == "error":
            which = ", ".join(s.name for s in self.stiff)
            raise StabilityError(
                f"step {dt:.3g} s exceeds the {name} method's stability limit {limit:.3g} s "
                f"({FIXED_STEP_LIMITS[name][1]} of the shortest "
                f"period T_min = {t_min:.3g} s, from {which}); use dt <= {0.9 * limit:.3g} s "
                "or solver.stiff = 'subdivide'",
                e.t,
                config(e),
            )
        m = math.ceil(dt / (0.5 * limit))
        return dt / m
