"""The classic fourth-order Runge–Kutta method on y = (q, q̇).

Stages k1 (the evaluation at the step's start, carried over from the previous step), k2, k3, k4
(q̈ alone: ``accel``); then an evaluation at the accepted state (the next k1): 4 evaluations a
step. Global error O(Δt⁴).
Dense output: cubic Hermite of (q, q̇) and of (q̇, q̈) at the step's ends.
"""

from __future__ import annotations

import numpy as np

from .base import CubicHermite, Solver


class RK4(Solver):
    name = "rk4"
    order = 4
    evaluations_per_step = 4

    def step_to(self, t_target, interrupt=None):
        # elementwise on floats (n is 1 or 2: numpy's per-call cost would dominate); the same
        # operations in the same order as y₁ = y₀ + h/6 (k1 + 2k2 + 2k3 + k4) on arrays
        t0, q0, v0 = self.t, self.q, self.qd
        h = t_target - t0
        hh, h6 = 0.5 * h, h / 6.0
        ql, v0l = q0.tolist(), v0.tolist()
        a1 = self.current.qdd.tolist()
        v2 = [v + hh * a for v, a in zip(v0l, a1)]
        accel = self._accel_counted
        a2 = accel(t0 + hh, [q + hh * v for q, v in zip(ql, v0l)], v2)
        v3 = [v + hh * a for v, a in zip(v0l, a2)]
        a3 = accel(t0 + hh, [q + hh * v for q, v in zip(ql, v2)], v3)
        v4 = [v + h * a for v, a in zip(v0l, a3)]
        a4 = accel(t_target, [q + h * v for q, v in zip(ql, v3)], v4)
        q1 = np.array([q + h6 * (a + 2.0 * b + 2.0 * c + d)
                       for q, a, b, c, d in zip(ql, v0l, v2, v3, v4)])
        v1 = np.array([v + h6 * (a + 2.0 * b + 2.0 * c + d)
                       for v, a, b, c, d in zip(v0l, a1, a2, a3, a4)])
        e = self._call(t_target, q1, v1)
        self._dense = CubicHermite(t0, t_target, q0, v0, self.current.qdd, q1, v1, e.qdd)
        self.t, self.q, self.qd, self.current = t_target, q1, v1, e
        self.nsteps += 1
