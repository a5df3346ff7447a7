"""The seed's linear acceleration method, a predictor-corrector (seed (38)–(45)).

From the accelerations q̈_i at the step's start:

* predict with constant acceleration (38)–(39): q̇⁽¹⁾ = q̇_i + q̈_i Δt, q⁽¹⁾ = q_i + q̇_i Δt + q̈_i Δt²/2;
* evaluate q̈⁽²⁾_{i+1} there (40);
* correct with linearly varying acceleration (41)–(45):
  q̇_{i+1} = q̇_i + (q̈_i + q̈⁽²⁾_{i+1}) Δt/2, q_{i+1} = q_i + q̇_i Δt + (2q̈_i + q̈⁽²⁾_{i+1}) Δt²/6.

One correction is the seed's scheme; ``iterations = k`` re-evaluates at the corrected state and
corrects again, k corrections in all. The step ends with an evaluation at the accepted state (the
seed's step 1 of the next step), so a step costs ``1 + iterations`` evaluations. The dense output
is the step's cubic (43). Global error O(Δt²) (Newmark β = 1/6, γ = 1/2). With one correction,
as an explicit predictor-corrector, it is stable on q̈ = −ω²q for ω·Δt ≤ 2, i.e. Δt ≤ T_min/π ≈
0.318 T_min of the shortest period T_min (from its amplification matrix; the implicit linear
acceleration method's √3/π ≈ 0.551 T_min does not apply to it).
"""

from __future__ import annotations

import math

import numpy as np

from .base import Advance, Solver


class LinearAcceleration(Solver):
    name = "linear-acceleration"
    order = 2
    stability_limit, stability_text = 1.0 / math.pi, "1/π"

    @classmethod
    def create(cls, fun, t0, q0, qd0, current=None, *, iterations=1, accel=None, **_):
        return cls(fun, t0, q0, qd0, current, iterations=iterations, accel=accel)

    def __init__(self, fun, t0, q0, qd0, current=None, iterations: int = 1, accel=None):
        if int(iterations) != iterations or iterations < 1:
            raise ValueError(f"corrector iterations = {iterations!r}: expected an integer >= 1")
        self.iterations = int(iterations)
        self.evaluations_per_step = 1 + self.iterations
        super().__init__(fun, t0, q0, qd0, current, accel)

    def _advance_to(self, t_target, interrupt):
        # elementwise on floats (n is 1 or 2: numpy's per-call cost would dominate), written out
        # for n = 1 and 2; the same operations in the same order as the vector formulas above.
        # The predicted and all but the last corrected states need q̈ alone (``accel``); the
        # accepted state is evaluated (``fun``)
        t0, q0, qd0 = self.t, self.q, self.qd
        dt = t_target - t0
        a0 = self.current.qdd
        ql, vl, al = q0.tolist(), qd0.tolist(), a0.tolist()
        h2, h6, hh = 0.5 * dt * dt, dt * dt / 6.0, 0.5 * dt
        accel = self._accel_counted
        last = self.iterations - 1
        n = len(ql)
        if n == 1:
            (x,), (v,), (a,) = ql, vl, al
            a1 = accel(t_target, [x + v * dt + a * h2], [v + a * dt])
            for k in range(self.iterations):
                (b,) = a1
                qd1 = [v + (a + b) * hh]
                q1 = [x + v * dt + (2.0 * a + b) * h6]
                if k < last:
                    a1 = accel(t_target, q1, qd1)
        elif n == 2:
            (x, y), (v, w), (a, c) = ql, vl, al
            a1 = accel(t_target, [x + v * dt + a * h2, y + w * dt + c * h2], [v + a * dt, w + c * dt])
            for k in range(self.iterations):
                b, d = a1
                qd1 = [v + (a + b) * hh, w + (c + d) * hh]
                q1 = [x + v * dt + (2.0 * a + b) * h6, y + w * dt + (2.0 * c + d) * h6]
                if k < last:
                    a1 = accel(t_target, q1, qd1)
        else:
            a1 = accel(
                t_target,
                [x + v * dt + a * h2 for x, v, a in zip(ql, vl, al)],
                [v + a * dt for v, a in zip(vl, al)],
            )
            for k in range(self.iterations):
                qd1 = [v + (a + b) * hh for v, a, b in zip(vl, al, a1)]
                q1 = [x + v * dt + (2.0 * a + b) * h6 for x, v, a, b in zip(ql, vl, al, a1)]
                if k < last:
                    a1 = accel(t_target, q1, qd1)
        # the step's cubic is made when asked for (at events only): what it needs, (t0, Δt,
        # q0, q̇0, q̈0, q̈1)
        return Advance(t_target, np.array(q1), np.array(qd1), None, (t0, dt, q0, qd0, a0, a1))

    def dense_output(self):
        """The last step's cubic (43), made on the first call after the step."""
        last = self.__dict__.get("_dense_from")
        if self._dense is None and last is not None:
            self._dense = _LinearAccelerationCubic(*last)
        return super().dense_output()


class _LinearAccelerationCubic:
    """The step's cubic (43) and its derivative (42)."""

    __slots__ = ("t0", "dt", "q0", "qd0", "a0", "_a1", "_j")

    def __init__(self, t0, dt, q0, qd0, a0, a1):
        self.t0, self.dt = t0, dt
        self.q0, self.qd0, self.a0, self._a1 = q0, qd0, a0, a1
        self._j = None

    @property
    def j(self):
        """The step's constant jerk (q̈₁ − q̈₀)/Δt."""
        if self._j is None:
            self._j = (np.array(self._a1) - self.a0) / self.dt
        return self._j

    def __call__(self, t):
        tau = t - self.t0
        j = self.j
        q = self.q0 + self.qd0 * tau + self.a0 * (tau * tau / 2.0) + j * (tau**3 / 6.0)
        qd = self.qd0 + self.a0 * tau + j * (tau * tau / 2.0)
        return q, qd
