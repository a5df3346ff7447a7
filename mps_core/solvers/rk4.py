"""The classic fourth-order Runge–Kutta method on y = (q, q̇).

Stages k1 (the evaluation at the step's start, carried over from the previous step), k2, k3, k4;
then an evaluation at the accepted state (the next k1): 4 evaluations a step. Global error O(Δt⁴).
Dense output: cubic Hermite of (q, q̇) and of (q̇, q̈) at the step's ends.
"""

from __future__ import annotations

from .base import CubicHermite, Solver


class RK4(Solver):
    name = "rk4"
    order = 4
    evaluations_per_step = 4

    def step_to(self, t_target, interrupt=None):
        t0, q0, v0 = self.t, self.q, self.qd
        h = t_target - t0
        a1 = self.current.qdd
        v2 = v0 + 0.5 * h * a1
        a2 = self._call(t0 + 0.5 * h, q0 + 0.5 * h * v0, v2).qdd
        v3 = v0 + 0.5 * h * a2
        a3 = self._call(t0 + 0.5 * h, q0 + 0.5 * h * v2, v3).qdd
        v4 = v0 + h * a3
        a4 = self._call(t_target, q0 + h * v3, v4).qdd
        q1 = q0 + (h / 6.0) * (v0 + 2.0 * v2 + 2.0 * v3 + v4)
        v1 = v0 + (h / 6.0) * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        e = self._call(t_target, q1, v1)
        self._dense = CubicHermite(t0, t_target, q0, v0, a1, q1, v1, e.qdd)
        self.t, self.q, self.qd, self.current = t_target, q1, v1, e
        self.nsteps += 1
