"""DOP853 on floats: Dormand and Prince's explicit Runge–Kutta pair of order 8(5,3), scipy's
``DOP853`` written out for the few coordinates of a linkage.

The method is scipy's, step for step: its tableau (``scipy.integrate._ivp.dop853_coefficients``),
its initial step (Hairer, Nørsett and Wanner's algorithm as scipy's ``select_initial_step``),
its error norm (the fifth- and third-order estimates combined), its step-size control (safety
0.9, factors between 0.2 and 10, no growth right after a rejection) and its seventh-order dense
output with three more stages per step where asked for. What differs is where the time goes:
with two coordinates a stage is a dozen multiply-adds, and scipy's numpy calls per stage (and
the state's concatenation into one array for its right-hand side) cost more than the
arithmetic. Here a step's twelve stages are one generated straight-line function on floats
(zero coefficients left out), and the stages ask for q̈ alone (``accel``).

Two differences from scipy, both in the work and neither in the accepted steps:

* the last stage's right-hand side (first same as last) is evaluated once an attempt's error
  is accepted, not for every attempt: the error estimate does not use it, so a rejected attempt
  costs eleven evaluations, not twelve (where it lies outside the chart's domain it rejects the
  attempt, as in scipy's solver);
* a stage outside the chart's domain (:class:`~mps_core.errors.ChartDomainError`) rejects the
  attempt like a too large error: the step is shrunk by 4 and tried again, up to 12 times,
  as :class:`~mps_core.solvers.adaptive.AdaptiveSolver` does around scipy's solver.

The state is y = (q, q̇); internal steps run ahead of the reported time as scipy's do: after
:meth:`step_to` the solver reports the state at ``t_target`` from the dense output and has
evaluated the equations there, while its next internal step starts where the last one ended.
"""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np

from ..caches import Memo
from ..errors import ChartDomainError, NumericalError
from .base import Advance, Solver, check_tolerances


def _scipy_tableau():
    """scipy's ``scipy.integrate._ivp.dop853_coefficients``, read from its file without
    importing ``scipy.integrate`` (whose package imports scipy's optimizers, special functions
    and sparse algebra: about a third of a second of every process's start), or imported
    where it already is or the file is not where scipy keeps it."""
    name = "scipy.integrate._ivp.dop853_coefficients"
    if name not in sys.modules:
        spec = importlib.util.find_spec("scipy")
        for root in (spec.submodule_search_locations or []) if spec is not None else []:
            path = Path(root) / "integrate" / "_ivp" / "dop853_coefficients.py"
            if path.is_file():
                at = importlib.util.spec_from_file_location("_mps_dop853_coefficients", path)
                if at is not None and at.loader is not None:
                    module = importlib.util.module_from_spec(at)
                    at.loader.exec_module(module)
                    return module
    return importlib.import_module(name)


_coef = _scipy_tableau()

SAFETY = 0.9
MIN_FACTOR = 0.2
MAX_FACTOR = 10.0
#: the error estimate's order is 7: steps scale as error^(−1/8)
ERROR_EXPONENT = -1.0 / 8.0
#: stage count of a step (without the last, first-same-as-last stage)
STAGES = _coef.N_STAGES
DOMAIN_TRIES = 12

_A = _coef.A
_B = _coef.B
_C = _coef.C
_E3 = _coef.E3
_E5 = _coef.E5
_D = _coef.D


def _terms(coefs, k_name, i) -> str:
    """Σ_j c_j·k_j[i] over the nonzero c_j, as code."""
    out = [f"{float(c)!r} * {k_name(j, i)}" for j, c in enumerate(coefs) if c != 0.0]
    return " + ".join(out) if out else "0.0"


def _stage_lines(s: int, n: int, k) -> list:
    """Code for stage s: its state y + h·Σ a_sj·k_j, and its derivative (q̇ of that state, and
    q̈ there from ``accel``) as k_s."""
    N = 2 * n
    lines = [f"    z{i} = y{i} + ({_terms(_A[s, :s], k, i)}) * h" for i in range(N)]
    qs = ", ".join(f"z{i}" for i in range(n))
    vs = ", ".join(f"z{i}" for i in range(n, N))
    acc = ", ".join(k(s, n + i) for i in range(n))
    lines.append(f"    {acc}, = accel(t + {float(_C[s])!r} * h, [{qs}], [{vs}])")
    lines += [f"    {k(s, i)} = z{n + i}" for i in range(n)]
    return lines


def _step_source(n: int) -> str:
    """``attempt(accel, t, h, y…, f…)``: one attempted step from y with derivative f (2n floats
    each): ``(y_new, err5, err3, K)`` with K the stages' derivatives (12 lists)."""
    N = 2 * n
    ys = [f"y{i}" for i in range(N)]
    fs = [f"f{i}" for i in range(N)]

    def k(j, i):
        return f"k{j}_{i}"

    lines = [f"def attempt(accel, t, h, {', '.join(ys)}, {', '.join(fs)}):"]
    lines += [f"    {k(0, i)} = f{i}" for i in range(N)]
    for s in range(1, STAGES):
        lines += _stage_lines(s, n, k)
    ynew = ", ".join(f"y{i} + h * ({_terms(_B, k, i)})" for i in range(N))
    e5 = ", ".join(f"{_terms(_E5[:STAGES], k, i)}" for i in range(N))
    e3 = ", ".join(f"{_terms(_E3[:STAGES], k, i)}" for i in range(N))
    K = ", ".join("[" + ", ".join(k(j, i) for i in range(N)) + "]" for j in range(STAGES))
    lines.append(f"    return [{ynew}], [{e5}], [{e3}], [{K}]")
    return "\n".join(lines) + "\n"


def _dense_source(n: int) -> str:
    """``dense(accel, t, h, K, y…, f…, y_new…, f_new…)``: the last step's interpolant
    coefficients F (7 lists of 2n floats) from its stages K, with the three more stages the
    interpolant needs (scipy's ``_dense_output_impl``)."""
    N = 2 * n
    E = _coef.N_STAGES_EXTENDED

    def k(j, i):
        return f"k{j}_{i}"

    args = (
        [f"y{i}" for i in range(N)]
        + [f"f{i}" for i in range(N)]
        + [f"u{i}" for i in range(N)]
        + [f"g{i}" for i in range(N)]
    )
    lines = [f"def dense(accel, t, h, K, {', '.join(args)}):"]
    for j in range(STAGES):
        lines.append(f"    {', '.join(k(j, i) for i in range(N))} = K[{j}]")
    lines += [f"    {k(STAGES, i)} = g{i}" for i in range(N)]
    for s in range(STAGES + 1, E):
        lines += _stage_lines(s, n, k)
    lines += [f"    d{i} = u{i} - y{i}" for i in range(N)]
    rows = [
        "[" + ", ".join(f"d{i}" for i in range(N)) + "]",
        "[" + ", ".join(f"h * f{i} - d{i}" for i in range(N)) + "]",
        "[" + ", ".join(f"2 * d{i} - h * (g{i} + f{i})" for i in range(N)) + "]",
    ]
    for r in range(_D.shape[0]):
        rows.append("[" + ", ".join(f"h * ({_terms(_D[r], k, i)})" for i in range(N)) + "]")
    lines.append(f"    return [{', '.join(rows)}]")
    return "\n".join(lines) + "\n"


_CODE = Memo("solvers.dop853.code", 64)


def _generated(kind: str, n: int):
    """The generated ``attempt`` or ``dense`` function for n coordinates (made once)."""
    f = _CODE.get((kind, n))
    if f is None:
        src = (_step_source if kind == "attempt" else _dense_source)(n)
        ns: dict = {}
        exec(compile(src, f"<dop853 {kind}, n = {n}>", "exec"), ns)
        f = _CODE.keep((kind, n), ns[kind])
        f.source = src
    return f


def _rms(x) -> float:
    return math.sqrt(sum(v * v for v in x) / len(x))


class DOP853(Solver):
    """Adaptive DOP853 on floats (see the module's docstring); ``rtol``, ``atol`` as
    :class:`~mps_core.solvers.adaptive.AdaptiveSolver`'s (``atol`` scaled by the chart's
    coordinate scales for q and q̇)."""

    name = "dop853"
    order = None
    adaptive = True

    @classmethod
    def create(
        cls,
        fun,
        t0,
        q0,
        qd0,
        current=None,
        *,
        rtol=1e-9,
        atol=1e-12,
        scales=None,
        first_step=None,
        accel=None,
        **_,
    ):
        return cls(
            fun, t0, q0, qd0, current, rtol=rtol, atol=atol, scales=scales, first_step=first_step, accel=accel
        )

    def __init__(
        self,
        fun,
        t0,
        q0,
        qd0,
        current=None,
        rtol=1e-9,
        atol=1e-12,
        scales=None,
        max_step=math.inf,
        first_step=None,
        accel=None,
    ):
        check_tolerances(rtol, atol)
        super().__init__(fun, t0, q0, qd0, current, accel)
        n = self.q.size
        sc = [1.0] * n if scales is None else [float(s) for s in scales]
        self._n = n
        self.rtol = float(rtol)
        self._atol = [atol * s for s in sc] * 2
        self.max_step = float(max_step)
        self._attempt_fn = _generated("attempt", n)
        self._dense_fn = _generated("dense", n)
        # the internal state: (t, y, f) at the end of the last internal step
        self._t = self.t
        self._y = self.q.tolist() + self.qd.tolist()
        self._f = self.qd.tolist() + self.current.qdd.tolist()
        self._last = None  # (t_old, y_old, f_old, K, h) of the last internal step
        self._sol = None  # its interpolant, built once
        if first_step is not None and 0 < first_step < math.inf:
            self.h_abs = float(first_step)
        else:
            self.h_abs = self._initial_step()

    @property
    def step_size(self):
        """The size of the last internal step (None before the first): a good ``first_step``
        for a solver that carries on from here (after a change of chart)."""
        return None if self._last is None else abs(self._last[4])

    def _initial_step(self) -> float:
        """scipy's ``select_initial_step`` for an error estimate of order 7 (one evaluation)."""
        y0, f0, n = self._y, self._f, self._n
        scale = [a + abs(y) * self.rtol for a, y in zip(self._atol, y0)]
        d0 = _rms([y / s for y, s in zip(y0, scale)])
        d1 = _rms([f / s for f, s in zip(f0, scale)])
        h0 = 1e-6 if d0 < 1e-5 or d1 < 1e-5 else 0.01 * d0 / d1
        y1 = [y + h0 * f for y, f in zip(y0, f0)]
        a1 = self._accel_counted(self._t + h0, y1[:n], y1[n:])
        f1 = y1[n:] + a1
        d2 = _rms([(b - a) / s for a, b, s in zip(f0, f1, scale)]) / h0
        if d1 <= 1e-15 and d2 <= 1e-15:
            h1 = max(1e-6, h0 * 1e-3)
        else:
            h1 = (0.01 / max(d1, d2)) ** (1.0 / 8.0)
        return min(100.0 * h0, h1, self.max_step)

    def _attempt(self, t, h):
        return self._attempt_fn(self._accel_counted, t, h, *self._y, *self._f)

    def _error_norm(self, y, y_new, e5, e3, h_abs) -> float:
        """scipy's DOP853 error norm: the fifth-order estimate, damped by the third-order one."""
        rtol = self.rtol
        s5 = s3 = 0.0
        for a, b, c, d, e in zip(self._atol, y, y_new, e5, e3):
            sc = a + max(abs(b), abs(c)) * rtol
            s5 += (d / sc) ** 2
            s3 += (e / sc) ** 2
        if s5 == 0.0 and s3 == 0.0:
            return 0.0
        return h_abs * s5 / math.sqrt((s5 + 0.01 * s3) * len(y))

    def _advance(self) -> None:
        """One accepted internal step (scipy's ``_step_impl``)."""
        t, y, n = self._t, self._y, self._n
        min_step = 10.0 * abs(math.nextafter(t, math.inf) - t)
        h_abs = min(self.h_abs, self.max_step)
        if h_abs < min_step:
            h_abs = min_step
        rejected = False
        domain_failures = 0
        while True:
            if h_abs < min_step:
                raise NumericalError("dop853 failed: the step size fell below the spacing of the numbers", t)
            t_new = t + h_abs
            h = t_new - t
            h_abs = abs(h)
            try:
                y_new, e5, e3, K = self._attempt(t, h)
                err = self._error_norm(y, y_new, e5, e3, h_abs)
                if err < 1.0:
                    # the last stage (the next step's first): outside the domain, it rejects
                    # the step as scipy's solver, which evaluates it in every attempt, does
                    a_new = self._accel_counted(t_new, y_new[:n], y_new[n:])
            except ChartDomainError:
                domain_failures += 1
                if domain_failures == DOMAIN_TRIES:
                    raise
                # a fresh start with the step shrunk by 4
                self.h_abs *= 0.25
                h_abs = max(min(self.h_abs, self.max_step), min_step)
                rejected = False
                continue
            if err < 1.0:
                factor = MAX_FACTOR if err == 0.0 else min(MAX_FACTOR, SAFETY * err**ERROR_EXPONENT)
                if rejected:
                    factor = min(1.0, factor)
                h_abs *= factor
                break
            h_abs *= max(MIN_FACTOR, SAFETY * err**ERROR_EXPONENT)
            rejected = True
        self._last = (t, y, self._f, K, h)
        self._t, self._y, self._f = t_new, y_new, y_new[n:] + a_new
        self.h_abs = h_abs
        self._sol = None

    def _interpolant(self):
        """The last internal step's seventh-order interpolant of y (three more stages)."""
        if self._sol is None:
            t_old, y_old, f_old, K, h = self._last
            F = self._dense_fn(self._accel_counted, t_old, h, K, *y_old, *f_old, *self._y, *self._f)
            self._sol = _DenseOutput(t_old, h, y_old, F, self._n)
        return self._sol

    def _advance_to(self, t_target, interrupt):
        n = self._n
        steps = 0
        while self._t < t_target:
            # every internal step's end before t_target is offered to ``interrupt`` before the
            # next step is taken: also the end of a step that began before this call (the
            # last report lay inside it), so that what happens between the last report and
            # that end is found on that step's interpolant, not on the next one's
            if interrupt is not None and self._t > self.t:
                q, qd = np.array(self._y[:n]), np.array(self._y[n:])
                if interrupt(self._t, q, qd):
                    return Advance(self._t, q, qd, self._interpolant(), None, steps)
            self._advance()
            steps += 1
        sol = self._interpolant()
        q, qd = sol(t_target)
        return Advance(t_target, q, qd, sol, None, steps)


class _DenseOutput:
    """(q, q̇) at t in the step, as arrays: scipy's ``Dop853DenseOutput`` on floats."""

    __slots__ = ("t_old", "h", "y_old", "F", "n")

    def __init__(self, t_old, h, y_old, F, n):
        self.t_old, self.h, self.y_old, self.F, self.n = t_old, h, y_old, F, n

    def __call__(self, t):
        x = (t - self.t_old) / self.h
        x1 = 1 - x
        y = [0.0] * len(self.y_old)
        for i, f in enumerate(reversed(self.F)):
            w = x if i % 2 == 0 else x1
            y = [(a + b) * w for a, b in zip(y, f)]
        y = [a + b for a, b in zip(y, self.y_old)]
        n = self.n
        return np.array(y[:n]), np.array(y[n:])
