"""A sixth-order Runge–Kutta method at fixed steps: Butcher's seven-stage tableau.

Butcher's method of order six in seven stages (the fewest a sixth-order explicit method can
have; J. C. Butcher, *Numerical Methods for Ordinary Differential Equations*, 3rd ed., §325),
with rational coefficients and nodes 0, 1/3, 2/3, 1/3, 1/2, 1/2, 1, on y = (q, q̇):

* stage 1 is the evaluation at the step's start (carried over from the previous step);
* stages 2–7 ask for q̈ alone (``accel``), in one generated straight-line function on floats
  for the chart's n coordinates (zero coefficients left out);
* the evaluation at the new state is the next step's first stage: 7 evaluations a step.

Global error O(Δt⁶): between RK4 (4 evaluations, O(Δt⁴)) and RK8 (12, O(Δt⁸)) where a fixed
step is wanted. Dense output: the quintic Hermite polynomial of (q, q̇, q̈) at the step's ends
for q, its derivative for q̇ (no evaluation more; O(Δt⁶) and O(Δt⁵) inside the step).

Stability: on the imaginary axis the method is stable for ω·Δt up to :data:`IMAGINARY_LIMIT`,
computed from the tableau as RK8's is (:func:`~mps_core.solvers.rk8.imaginary_limit`).
"""

from __future__ import annotations

import math
from fractions import Fraction as _F

import numpy as np

from .base import CubicHermite, GeneratedStep
from .rk8 import tableau_step_source

STAGES = 7
_ROWS: tuple[list[int | _F], ...] = (
    [],
    [_F(1, 3)],
    [0, _F(2, 3)],
    [_F(1, 12), _F(1, 3), _F(-1, 12)],
    [_F(-1, 16), _F(9, 8), _F(-3, 16), _F(-3, 8)],
    [0, _F(9, 8), _F(-3, 8), _F(-3, 4), _F(1, 2)],
    [_F(9, 44), _F(-9, 11), _F(63, 44), _F(18, 11), 0, _F(-16, 11)],
)
_WEIGHTS: tuple[int | _F, ...] = (_F(11, 120), 0, _F(27, 40), _F(27, 40), _F(-4, 15), _F(-4, 15), _F(11, 120))

#: the tableau as exact fractions: A (strictly lower), b, c = row sums of A
A_EXACT = [[_F(x) for x in row] + [_F(0)] * (STAGES - len(row)) for row in _ROWS]
B_EXACT = [_F(x) for x in _WEIGHTS]
C_EXACT = [sum(row, _F(0)) for row in A_EXACT]

_A = np.array([[float(x) for x in row] for row in A_EXACT])
_B = np.array([float(x) for x in B_EXACT])
_C = np.array([float(x) for x in C_EXACT])

#: ``imaginary_limit(_A, _B)``, written out as RK8's is
IMAGINARY_LIMIT = 0.0793


class QuinticHermite(CubicHermite):
    """q by the quintic Hermite polynomial of (q, q̇, q̈) at both ends of a step, q̇ by its
    derivative (the same data as :class:`~mps_core.solvers.base.CubicHermite`)."""

    def __call__(self, t):
        q0, qd0, qdd0, q1, qd1, qdd1 = self._ends()
        h = self.h
        s = (t - self.t0) / h
        s2 = s * s
        s3 = s2 * s
        # the basis on [0, 1] and its derivative in s
        h0 = 1.0 - 10.0 * s3 + 15.0 * s3 * s - 6.0 * s3 * s2
        h1 = s - 6.0 * s3 + 8.0 * s3 * s - 3.0 * s3 * s2
        h2 = 0.5 * s2 - 1.5 * s3 + 1.5 * s3 * s - 0.5 * s3 * s2
        h3 = 10.0 * s3 - 15.0 * s3 * s + 6.0 * s3 * s2
        h4 = -4.0 * s3 + 7.0 * s3 * s - 3.0 * s3 * s2
        h5 = 0.5 * s3 - s3 * s + 0.5 * s3 * s2
        d0 = -30.0 * s2 + 60.0 * s3 - 30.0 * s2 * s2
        d1 = 1.0 - 18.0 * s2 + 32.0 * s3 - 15.0 * s2 * s2
        d2 = s - 4.5 * s2 + 6.0 * s3 - 2.5 * s2 * s2
        d3 = -d0
        d4 = -12.0 * s2 + 28.0 * s3 - 15.0 * s2 * s2
        d5 = 1.5 * s2 - 4.0 * s3 + 2.5 * s2 * s2
        hh = h * h
        c1, c2, c4, c5 = h1 * h, h2 * hh, h4 * h, h5 * hh
        q = [
            h0 * x0 + c1 * v0 + c2 * a0 + h3 * x1 + c4 * v1 + c5 * a1
            for x0, v0, a0, x1, v1, a1 in zip(q0, qd0, qdd0, q1, qd1, qdd1)
        ]
        qd = [
            (d0 * x0 + d3 * x1) / h + d1 * v0 + d4 * v1 + h * (d2 * a0 + d5 * a1)
            for x0, v0, a0, x1, v1, a1 in zip(q0, qd0, qdd0, q1, qd1, qdd1)
        ]
        return np.array(q), np.array(qd)


class RK6(GeneratedStep):
    name = "rk6"
    stability_limit = IMAGINARY_LIMIT / (2.0 * math.pi)
    stability_text = f"{IMAGINARY_LIMIT:.3g}/2π"
    order = 6
    evaluations_per_step = STAGES
    inner_stages = STAGES - 1
    #: the dense output: q̈ at the ends is known, so the quintic costs no evaluation
    interpolant = QuinticHermite

    @staticmethod
    def step_source(n: int, direct: bool = False) -> str:
        """One step on floats for n coordinates: the tableau's stages (zero coefficients left
        out) and its weights."""
        return tableau_step_source(_A, _B, _C, n, direct, t1_at_one=True)
