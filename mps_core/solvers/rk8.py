"""An eighth-order Runge–Kutta method at fixed steps: DOP853's tableau without its error control.

Dormand and Prince's eighth-order solution (the ``B`` weights of
``scipy.integrate._ivp.dop853_coefficients``) taken at the step it is given, on y = (q, q̇):

* stage 1 is the evaluation at the step's start (carried over from the previous step);
* stages 2–12 ask for q̈ alone (``accel``), in one generated straight-line function on floats
  for the chart's n coordinates (zero coefficients left out);
* the evaluation at the new state is the next step's first stage: 12 evaluations a step.

Global error O(Δt⁸): where a fixed step is wanted (a live twin, a recording at a fixed rate)
it reaches in one step what RK4 needs several for. Dense output: DOP853's seventh-order
interpolant, three more evaluations a step where it is asked for (event location, and outputs
inside a step longer than their interval: ``[solver] step_s``).

Stability: on the imaginary axis (an undamped oscillation of angular frequency ω) the method is
stable for ω·Δt up to :data:`IMAGINARY_LIMIT`, computed from the tableau
(:func:`imaginary_limit`); the driver's check of the stiff effects uses it as RK4's 2√2.
"""

from __future__ import annotations

import math

import numpy as np

from .base import GeneratedStep, stage_lines
from .dop853 import _coef, _DenseOutput
from .dop853 import _generated as _dop853_code

STAGES = _coef.N_STAGES
_A = np.asarray(_coef.A[:STAGES, :STAGES], dtype=float)
_B = np.asarray(_coef.B, dtype=float)
_C = np.asarray(_coef.C[:STAGES], dtype=float)


def imaginary_limit(A, b, growth: float = 1e-12, step: float = 1e-4, top: float = 20.0) -> float:
    """The largest y such that |R(iy')| ≤ 1 + ``growth`` for all 0 < y' ≤ y, with R the
    stability function of the explicit tableau (A, b): R(z) = 1 + z bᵀ(I − zA)⁻¹ 1 (scanned
    in steps of ``step`` up to ``top``)."""
    A = np.asarray(A, dtype=float)
    b = np.asarray(b, dtype=float)
    s = len(b)
    ys = np.arange(1, int(top / step) + 1) * step
    ones = np.ones(s)
    # explicit A is nilpotent: (I − zA)⁻¹ 1 = Σ_k (zA)^k 1, k < s
    powers = [ones]
    for _ in range(s - 1):
        powers.append(A @ powers[-1])
    z = 1j * ys
    acc = np.zeros_like(z)
    zk = np.ones_like(z)
    for p in powers:
        acc = acc + zk * (b @ p)
        zk = zk * z
    R = 1.0 + z * acc
    bad = np.nonzero(np.abs(R) > 1.0 + growth)[0]
    return float(ys[bad[0] - 1]) if len(bad) and bad[0] > 0 else (0.0 if len(bad) else top)


#: ``imaginary_limit(_A, _B)``, written out: the scan takes 10 to 25 ms of every process's start
#: (``tests/core/solvers/test_solvers.py`` scans it again)
IMAGINARY_LIMIT = 5.9603


def _term(coefs, name) -> str:
    out = [f"{float(c)!r} * {name(j)}" for j, c in enumerate(coefs) if c != 0.0]
    return " + ".join(out) if out else "0.0"


def tableau_step_source(
    A, b, c, n: int, direct: bool = False, stages: bool = False, t1_at_one: bool = False
) -> str:
    """The code of one step of the explicit tableau (A, b, c) on y = (q, q̇) for n coordinates
    (see :meth:`~mps_core.solvers.base.GeneratedStep.step_source`): stage 1 the step's start,
    the others by :func:`~mps_core.solvers.base.stage_lines`, zero coefficients left out;
    ``stages``: the stages' (q̇, q̈) returned too; ``t1_at_one``: a stage at c = 1 reads ``t1``."""
    r = range(n)
    s_count = len(b)
    args = [f"q{i}" for i in r] + [f"v{i}" for i in r] + [f"a{i}" for i in r]
    L = [f"def step({'f, ' if direct else ''}accel, t0, t1, h, {', '.join(args)}):"]
    if direct:
        L.append("    m = 0")
    V = {0: [f"v{i}" for i in r]}  # stage 1: the step's start
    a = {0: [f"a{i}" for i in r]}
    for s in range(1, s_count):
        row = A[s, :s]
        qs = [f"q{i} + h * ({_term(row, lambda j, i=i: V[j][i])})" for i in r]
        vs = [f"v{i} + h * ({_term(row, lambda j, i=i: a[j][i])})" for i in r]
        V[s] = [f"V{s}_{i}" for i in r]
        a[s] = [f"a{s}_{i}" for i in r]
        L.extend(f"    V{s}_{i} = {vs[i]}" for i in r)
        t = "t1" if t1_at_one and c[s] == 1.0 else f"t0 + {float(c[s])!r} * h"
        L.extend(stage_lines(t, qs, V[s], a[s], direct))
    q1 = [f"q{i} + h * ({_term(b, lambda j, i=i: V[j][i])})" for i in r]
    v1 = [f"v{i} + h * ({_term(b, lambda j, i=i: a[j][i])})" for i in r]
    K = ""
    if stages:
        K = ", [" + ", ".join("[" + ", ".join(V[s] + a[s]) + "]" for s in range(s_count)) + "]"
    L.append(f"    return [{', '.join(q1)}], [{', '.join(v1)}]{K}{', m' if direct else ''}")
    return "\n".join(L) + "\n"


class RK8(GeneratedStep):
    name = "rk8"
    stability_limit = IMAGINARY_LIMIT / (2.0 * math.pi)
    stability_text = f"{IMAGINARY_LIMIT:.4g}/2π"
    order = 8
    evaluations_per_step = STAGES
    inner_stages = STAGES - 1
    returns_stages = True

    @staticmethod
    def step_source(n: int, direct: bool = False) -> str:
        """One step on floats for n coordinates: the tableau's stages (zero coefficients left
        out) and the eighth-order weights."""
        return tableau_step_source(_A, _B, _C, n, direct, stages=True)

    def dense_output(self):
        """DOP853's seventh-order interpolant of the last step, from its stages and three more
        (scipy's ``Dop853DenseOutput``), made when asked for: outputs inside a step keep the
        method's accuracy."""
        if self._dense is None:
            last = self.__dict__.get("_dense_from")
            if last is None:
                raise RuntimeError("no step taken yet")
            t0, q0, v0, a0, stages = last
            n = q0.size
            y_old = q0.tolist() + v0.tolist()
            f_old = v0.tolist() + a0.tolist()
            y_new = self.q.tolist() + self.qd.tolist()
            f_new = self.qd.tolist() + self.current.qdd.tolist()
            h = self.t - t0
            F = _dop853_code("dense", n)(self._accel_counted, t0, h, stages, *y_old, *f_old, *y_new, *f_new)
            self._dense = _DenseOutput(t0, h, y_old, F, n)
        return self._dense
