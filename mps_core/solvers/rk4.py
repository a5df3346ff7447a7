"""The classic fourth-order Runge–Kutta method on y = (q, q̇).

Stages k1 (the evaluation at the step's start, carried over from the previous step), k2, k3, k4
(q̈ alone: ``accel``); then an evaluation at the accepted state (the next k1): 4 evaluations a
step. Global error O(Δt⁴).
Dense output: cubic Hermite of (q, q̇) and of (q̇, q̈) at the step's ends.
"""

from __future__ import annotations

import numpy as np

from .base import CubicHermite, Solver


_STEPS: dict = {}


def _step_source(n: int) -> str:
    """``step(accel, t0, t1, h, q…, v…, a…) -> (q₁, v₁)``: one step of RK4 on floats for n
    coordinates, the operations of ``y₁ = y₀ + h/6 (k1 + 2k2 + 2k3 + k4)`` in their order."""
    r = range(n)
    q = [f"q{i}" for i in r]
    v = [f"v{i}" for i in r]
    a = [f"a{i}" for i in r]
    L = [f"def step(accel, t0, t1, h, {', '.join(q + v + a)}):",
         "    hh = 0.5 * h",
         "    h6 = h / 6.0"]

    def stage(k, t, vs, step, qs_from):
        L.extend(f"    v{k}_{i} = v{i} + {step} * {vs[i]}" for i in r)
        L.append(f"    {', '.join(f'a{k}_{i}' for i in r)}, = accel({t}, "
                 f"[{', '.join(f'q{i} + {step} * {qs_from[i]}' for i in r)}], "
                 f"[{', '.join(f'v{k}_{i}' for i in r)}])")

    stage(2, "t0 + hh", a, "hh", v)
    stage(3, "t0 + hh", [f"a2_{i}" for i in r], "hh", [f"v2_{i}" for i in r])
    stage(4, "t1", [f"a3_{i}" for i in r], "h", [f"v3_{i}" for i in r])
    L.append(f"    return [{', '.join(f'q{i} + h6 * (v{i} + 2.0 * v2_{i} + 2.0 * v3_{i} + v4_{i})' for i in r)}], "
             f"[{', '.join(f'v{i} + h6 * (a{i} + 2.0 * a2_{i} + 2.0 * a3_{i} + a4_{i})' for i in r)}]")
    return "\n".join(L) + "\n"


def _step(n: int):
    fn = _STEPS.get(n)
    if fn is None:
        namespace: dict = {}
        exec(compile(_step_source(n), f"<rk4 step, n = {n}>", "exec"), namespace)
        fn = _STEPS[n] = namespace["step"]
    return fn


class RK4(Solver):
    name = "rk4"
    order = 4
    evaluations_per_step = 4

    def step_to(self, t_target, interrupt=None):
        # one generated function on floats (n is 1 or 2: numpy's per-call cost would
        # dominate), the same operations in the same order as y₁ = y₀ + h/6 (k1 + 2k2 + 2k3 +
        # k4) on arrays; the three inner stages ask for q̈ alone
        t0, q0, v0 = self.t, self.q, self.qd
        h = t_target - t0
        step = self.__dict__.get("_step_fn")
        if step is None:
            step = self._step_fn = _step(q0.size)
        ql, vl = step(self.accel, t0, t_target, h, *q0.tolist(), *v0.tolist(),
                      *self.current.qdd.tolist())
        self.nfev += 3
        q1, v1 = np.array(ql), np.array(vl)
        e = self._call(t_target, q1, v1)
        self._dense = None          # made when asked for (an event, a cut)
        self._last = (t0, q0, v0, self.current.qdd)
        self.t, self.q, self.qd, self.current = t_target, q1, v1, e
        self.nsteps += 1

    def dense_output(self):
        if self._dense is None:
            last = self.__dict__.get("_last")
            if last is None:
                raise RuntimeError("no step taken yet")
            t0, q0, v0, a0 = last
            self._dense = CubicHermite(t0, self.t, q0, v0, a0, self.q, self.qd,
                                       self.current.qdd)
        return self._dense
