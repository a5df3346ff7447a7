"""scipy's adaptive solvers over the same right-hand side: Radau (the scenes' ``radau``), and
DOP853 (the scenes' ``dop853`` is the float version in :mod:`mps_core.solvers.dop853`, which
takes scipy's steps without its per-stage numpy calls; this one stays for comparison).

The scipy solver runs on y = (q, q̇) with its own step-size control (``rtol``, ``atol``).
:meth:`AdaptiveSolver.step_to` takes internal steps until ``t_target`` is passed, then reports the
state at ``t_target`` from scipy's dense output and evaluates the equations there (counted in
``nfev`` like every other call). Each internal step's end before ``t_target`` goes to
``interrupt(t, q, q̇)`` before the next step is taken, which may stop the solver there (an event
or a change of chart is due). ``atol`` applies to q and q̇ component by
component, scaled by the chart's coordinate scales where given.
"""

from __future__ import annotations

import numpy as np

from ..errors import ChartDomainError, NumericalError
from .base import Advance, Solver, check_tolerances

#: scipy's solver classes by method name (``scipy.integrate`` imported by the first solver
#: made: its package takes about a third of a second to import)
_METHODS = {"dop853": "DOP853", "radau": "Radau"}


class AdaptiveSolver(Solver):
    order = None
    adaptive = True
    #: scipy's solver object changes in place as it steps: no state to come back to
    rewindable = False

    def __init__(
        self,
        fun,
        t0,
        q0,
        qd0,
        current=None,
        method="dop853",
        rtol=1e-9,
        atol=1e-12,
        scales=None,
        t_bound=np.inf,
        max_step=np.inf,
        first_step=None,
    ):
        if method not in _METHODS:
            raise ValueError(f"adaptive method {method!r}: expected one of {', '.join(_METHODS)}")
        check_tolerances(rtol, atol)
        self.name = method
        super().__init__(fun, t0, q0, qd0, current)
        n = self.q.size
        sc = np.ones(n) if scales is None else np.asarray(scales, float)
        self._n = n
        self._last_eval = None
        y0 = np.concatenate((self.q, self.qd))
        # scipy evaluates the right-hand side at the initial state once more: it is `current`
        start = [self.t, y0, self.current]

        def f(t, y):
            if start[2] is not None:
                t_s, y_s, e_s = start
                start[2] = None
                if t == t_s and np.array_equal(y, y_s):
                    return np.concatenate((y[n:], e_s.qdd))
            e = self._call(t, y[:n], y[n:])
            self._last_eval = e
            return np.concatenate((y[n:], e.qdd))

        if first_step is not None and not (0 < first_step < np.inf):
            first_step = None
        import scipy.integrate

        self._scipy = getattr(scipy.integrate, _METHODS[method])(
            f,
            self.t,
            y0,
            t_bound,
            rtol=rtol,
            atol=atol * np.concatenate((sc, sc)),
            max_step=max_step,
            first_step=first_step,
        )
        self._sol = None  # the last internal step's interpolant, built once

    @property
    def step_size(self):
        """The size of the last internal step (None before the first): a good ``first_step``
        for a solver that carries on from here (after a change of chart)."""
        return self._scipy.step_size

    def _interpolant(self):
        s = self._scipy
        if self._sol is None or self._sol[0] != s.t:
            # DOP853's dense output costs three more evaluations: once per internal step
            self._sol = (s.t, s.dense_output())
        return self._sol[1]

    def state(self) -> dict:
        raise NotImplementedError(f"the {self.name} solver cannot be rewound")

    def _advance_to(self, t_target, interrupt):
        s, n = self._scipy, self._n
        steps = 0
        while s.t < t_target:
            # each internal step's end before t_target goes to ``interrupt`` before the next
            # step (also the end of a step that began before this call)
            if interrupt is not None and s.t > self.t and interrupt(s.t, s.y[:n], s.y[n:]):
                dense = self._wrap(self._interpolant())
                return Advance(s.t, s.y[:n].copy(), s.y[n:].copy(), dense, None, steps)
            if s.status != "running":
                raise NumericalError(f"{self.name} stopped: {s.status}", s.t)
            msg = self._step_within_domain()
            if s.status == "failed":
                raise NumericalError(f"{self.name} failed: {msg}", s.t)
            steps += 1
        sol = self._interpolant()
        y = sol(t_target)
        return Advance(t_target, y[:n].copy(), y[n:].copy(), self._wrap(sol), None, steps)

    def _step_within_domain(self, tries: int = 12):
        """One internal step; a stage outside the chart's domain rejects it like a too large
        error estimate: the step is shrunk by 4 and tried again (scipy's solver keeps its state
        when its right-hand side raises). After ``tries`` the domain error goes to the caller."""
        s = self._scipy
        for k in range(tries):
            try:
                return s.step()
            except ChartDomainError:
                if k + 1 == tries or s.h_abs is None:
                    raise
                s.h_abs *= 0.25
        return None

    def _wrap(self, sol):
        n = self._n

        def dense(t):
            y = sol(t)
            return y[:n], y[n:]

        return dense


class Radau(AdaptiveSolver):
    """scipy's Radau IIA (order 5, implicit): the scenes' ``radau``."""

    name = "radau"

    def __init__(self, fun, t0, q0, qd0, current=None, **settings):
        """:class:`AdaptiveSolver`'s settings by keyword (``rtol``, ``atol``, ``scales``,
        ``t_bound``, ``max_step``, ``first_step``), the method Radau."""
        super().__init__(fun, t0, q0, qd0, current, method="radau", **settings)

    @classmethod
    def create(
        cls, fun, t0, q0, qd0, current=None, *, rtol=1e-9, atol=1e-12, scales=None, first_step=None, **_
    ):
        return cls(fun, t0, q0, qd0, current, rtol=rtol, atol=atol, scales=scales, first_step=first_step)
