"""The classic fourth-order Runge–Kutta method on y = (q, q̇).

Stages k1 (the evaluation at the step's start, carried over from the previous step), k2, k3, k4
(q̈ alone: ``accel``); then an evaluation at the accepted state (the next k1): 4 evaluations a
step. Global error O(Δt⁴).
Dense output: cubic Hermite of (q, q̇) and of (q̇, q̈) at the step's ends.
"""

from __future__ import annotations

import math

from .base import GeneratedStep, stage_lines


class RK4(GeneratedStep):
    name = "rk4"
    order = 4
    #: stable on the imaginary axis for ω·Δt ≤ 2√2
    stability_limit, stability_text = 2.0 * math.sqrt(2.0) / (2.0 * math.pi), "2√2/2π"
    evaluations_per_step = 4
    inner_stages = 3

    @staticmethod
    def step_source(n: int, direct: bool = False) -> str:
        """One step on floats for n coordinates, the operations of ``y₁ = y₀ + h/6 (k1 + 2k2
        + 2k3 + k4)`` in their order (numpy's per-call cost would dominate at n = 1 or 2)."""
        r = range(n)
        q = [f"q{i}" for i in r]
        v = [f"v{i}" for i in r]
        a = [f"a{i}" for i in r]
        L = [
            f"def step({'f, ' if direct else ''}accel, t0, t1, h, {', '.join(q + v + a)}):",
            "    hh = 0.5 * h",
            "    h6 = h / 6.0",
        ]
        if direct:
            L.append("    m = 0")

        def stage(k, t, vs, step, qs_from):
            L.extend(f"    v{k}_{i} = v{i} + {step} * {vs[i]}" for i in r)
            L.extend(
                stage_lines(
                    t,
                    [f"q{i} + {step} * {qs_from[i]}" for i in r],
                    [f"v{k}_{i}" for i in r],
                    [f"a{k}_{i}" for i in r],
                    direct,
                )
            )

        stage(2, "t0 + hh", a, "hh", v)
        stage(3, "t0 + hh", [f"a2_{i}" for i in r], "hh", [f"v2_{i}" for i in r])
        stage(4, "t1", [f"a3_{i}" for i in r], "h", [f"v3_{i}" for i in r])
        q1 = [f"q{i} + h6 * (v{i} + 2.0 * v2_{i} + 2.0 * v3_{i} + v4_{i})" for i in r]
        v1 = [f"v{i} + h6 * (a{i} + 2.0 * a2_{i} + 2.0 * a3_{i} + a4_{i})" for i in r]
        L.append(f"    return [{', '.join(q1)}], [{', '.join(v1)}]{', m' if direct else ''}")
        return "\n".join(L) + "\n"
