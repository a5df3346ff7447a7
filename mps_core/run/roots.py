"""A root of a scalar function in a bracket: Brent's method on floats.

An event's time is the root of its function inside the step that crossed it
(:mod:`mps_core.run.events`). Brent's method (Brent, *Algorithms for Minimization without
Derivatives*, 1973, ch. 4) keeps a bracket [b, c] with f(b)·f(c) ≤ 0 and |f(b)| ≤ |f(c)|, and
tries inverse quadratic interpolation through the last three points (the secant where two of
them coincide); a trial step is taken only where it lands well inside the bracket and shrinks
faster than the step before last, else the bracket is bisected. It needs at most about the
square of bisection's evaluations and usually a handful.

Written here rather than taken from ``scipy.optimize``, whose package costs a quarter to a third
of a second to import: every process that meets an event would pay it, a run's first event on the
clock. The tolerance is scipy's ``brentq``'s: the root is within ``xtol + rtol·|x|`` of the one
returned.
"""

from __future__ import annotations

import math
from collections.abc import Callable

__all__ = ["brent_root"]


def brent_root(
    f: Callable[[float], float], a: float, b: float, xtol: float, rtol: float, maxiter: int = 200
) -> float:
    """Return x in [a, b] within ``xtol + rtol·|x|`` of a root of ``f``.

    f(a) and f(b) of opposite signs (or one of them zero); ValueError where they have the same
    sign or ``f`` gives a value that is not finite, RuntimeError where ``maxiter`` evaluations
    beyond the ends do not reach the tolerance."""
    fa, fb = _finite(f, a), _finite(f, b)
    if fa == 0.0:
        return a
    if fb == 0.0:
        return b
    if (fa > 0.0) == (fb > 0.0):
        raise ValueError(f"f({a!r}) = {fa!r} and f({b!r}) = {fb!r}: expected values of opposite signs")
    # b: the best estimate; c: the other end of the bracket; a: the estimate before b
    c, fc = a, fa
    d = e = b - a  # the last step and the one before it
    for _ in range(maxiter):
        if (fb > 0.0) == (fc > 0.0):  # the root is between a and b: the bracket is [b, a]
            c, fc = a, fa
            d = e = b - a
        if abs(fc) < abs(fb):  # b the end nearer the root by |f|
            a, fa = b, fb
            b, fb = c, fc
            c, fc = a, fa
        tol = 0.5 * (xtol + rtol * abs(b))
        m = 0.5 * (c - b)  # bisection's step
        if fb == 0.0 or abs(m) <= tol:
            return b
        if abs(e) >= tol and abs(fa) > abs(fb):
            s = fb / fa
            if a == c:  # two points: the secant
                p = 2.0 * m * s
                q = 1.0 - s
            else:  # three: inverse quadratic interpolation
                r, u = fa / fc, fb / fc
                p = s * (2.0 * m * r * (r - u) - (b - a) * (u - 1.0))
                q = (r - 1.0) * (u - 1.0) * (s - 1.0)
            if p > 0.0:
                q = -q
            else:
                p = -p
            # the trial step p/q: inside three quarters of the bracket and less than half the
            # step before last, else bisection
            if 2.0 * p < min(3.0 * m * q - abs(tol * q), abs(e * q)):
                e, d = d, p / q
            else:
                d = e = m
        else:
            d = e = m
        a, fa = b, fb
        b += d if abs(d) > tol else (tol if m > 0.0 else -tol)
        fb = _finite(f, b)
    raise RuntimeError(f"no root found to {xtol!r} + {rtol!r}·|x| in {maxiter} evaluations (last x = {b!r})")


def _finite(f: Callable[[float], float], x: float) -> float:
    """Return f(x), a ValueError where it is not a finite number."""
    v = f(x)
    if not math.isfinite(v):
        raise ValueError(f"f({x!r}) = {v!r}: expected a finite value")
    return v
