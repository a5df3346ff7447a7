"""The contract every integrator keeps (scipy's ``OdeSolver`` is the model).

A solver advances a second-order system ``q̈ = f(t, q, q̇)``:

* it is built from ``fun(t, q, q̇) -> Evaluation`` (any object with a ``qdd`` array) and an initial
  state, and evaluates ``fun`` there once unless the caller passes that evaluation as ``current``;
* :meth:`Solver.step_to` advances to ``t_target``. Fixed-step solvers take exactly one step of
  ``t_target − t``; adaptive ones take as many internal steps as their tolerances ask and may stop
  early where ``interrupt(t, q, q̇)`` returns True after an internal step;
* a step is all or nothing: if ``fun`` raises, the exception propagates and ``t``, ``q``, ``q̇``,
  ``current`` are those of the step's start;
* after a step ``current`` is the evaluation at the new state (the next step's start and the
  accelerations reported for it), and :meth:`dense_output` interpolates (q, q̇) inside the step;
* ``nfev`` counts the calls of ``fun`` and ``accel``, ``nsteps`` the steps;
* :meth:`state` and :meth:`set_state` keep and bring back everything a step changes, so that
  a driver can take steps ahead and come back (a solver that cannot says so with
  ``rewindable = False``);
* ``accel(t, q, q̇) -> q̈``, on lists of floats, may be given beside ``fun``: the same q̈ as
  ``fun(t, q, q̇).qdd`` without the evaluation, for the stages whose evaluation is not kept.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from ..caches import Memo
from ..derivatives.tracing import BranchChanged


def check_tolerances(rtol: float, atol: float) -> None:
    """An adaptive method's tolerances: 0 < rtol < 1, atol > 0 (ValueError naming both)."""
    if not (0 < rtol < 1) or not (atol > 0):
        raise ValueError(f"tolerances rtol = {rtol!r}, atol = {atol!r}: expected 0 < rtol < 1, atol > 0")


class Advance(NamedTuple):
    """What a method's :meth:`Solver._advance_to` hands the base's :meth:`Solver.step_to`: the
    new state, its dense output (None: made when asked for, from ``dense_from``), what the
    dense output is made from, and the steps taken (internal steps of an adaptive method)."""

    t: float
    q: np.ndarray
    qd: np.ndarray
    dense: Any = None
    dense_from: Any = None
    steps: int = 1


class Solver:
    """The contract (see the module's docstring). A method implements :meth:`_advance_to`;
    :meth:`step_to` is the template around it: the evaluation at the new state, then the
    bookkeeping, so that a step is all or nothing."""

    name = "solver"
    #: order of convergence of the global error in the step (None: adaptive, as asked)
    order: int | None = 0
    #: controls its error (takes the steps it chooses); the others take the steps given
    adaptive = False
    #: a fixed step's stability limit as a share of the shortest period of an oscillation
    #: q̈ = −ω²q (None: not a fixed-step method), and how an error message writes it
    stability_limit: float | None = None
    stability_text = ""
    #: calls of ``fun`` per fixed step (None for adaptive solvers)
    evaluations_per_step: int | None = None
    #: :meth:`state` and :meth:`set_state` bring a step's state back
    rewindable = True

    def __init__(self, fun: Callable, t0: float, q0, qd0, current=None, accel: Callable | None = None):
        self.fun = fun
        self.accel = accel if accel is not None else self._accel_by_fun
        self.t = float(t0)
        self.q = np.array(q0, dtype=float)
        self.qd = np.array(qd0, dtype=float)
        self.nfev = 0
        self.nsteps = 0
        self._dense = None
        self.current = current if current is not None else self._call(self.t, self.q, self.qd)

    @classmethod
    def create(
        cls,
        fun: Callable,
        t0: float,
        q0,
        qd0,
        current=None,
        *,
        iterations: int = 1,
        rtol: float = 1e-9,
        atol: float = 1e-12,
        scales=None,
        first_step=None,
        accel: Callable | None = None,
    ) -> Solver:
        """The solver from the run's settings, each taking those it has (a fixed-step method
        no tolerances, an adaptive one no corrector iterations)."""
        return cls(fun, t0, q0, qd0, current, accel=accel)

    def _call(self, t, q, qd):
        self.nfev += 1
        return self.fun(t, q, qd)

    def _accel_counted(self, t, ql, vl) -> list:
        self.nfev += 1
        return self.accel(t, ql, vl)

    def _accel_by_fun(self, t, ql, vl) -> list:
        return self.fun(t, np.array(ql, dtype=float), np.array(vl, dtype=float)).qdd.tolist()

    def step_to(self, t_target: float, interrupt: Callable | None = None) -> None:
        """Advance to ``t_target`` (an adaptive method: or to where ``interrupt`` stopped it):
        the method's :meth:`_advance_to`, the evaluation at the state it reached, then the new
        state, its dense output and the step count. Where the evaluation raises, nothing of the
        solver's state has changed (all or nothing)."""
        a = self._advance_to(t_target, interrupt)
        e = self._call(a.t, a.q, a.qd)
        self._dense, self._dense_from = a.dense, a.dense_from
        self.t, self.q, self.qd, self.current = a.t, a.q, a.qd, e
        self.nsteps += a.steps

    def _advance_to(self, t_target: float, interrupt: Callable | None) -> Advance:
        """The method's own work: from the present state toward ``t_target`` (see
        :class:`Advance`), without changing the solver's state (t, q, q̇, current, the dense
        output), which :meth:`step_to` sets from what it returns."""
        raise NotImplementedError

    def state(self) -> dict:
        """What a step changes, to come back to with :meth:`set_state`. A step gives its
        attributes new objects (it never changes an array or list in place), so their
        references are the state."""
        return dict(self.__dict__)

    def set_state(self, state: dict) -> None:
        self.__dict__.clear()
        self.__dict__.update(state)

    def dense_output(self) -> Callable[[float], tuple[np.ndarray, np.ndarray]]:
        """(q, q̇) at a time inside the last step."""
        if self._dense is None:
            raise RuntimeError("no step taken yet")
        return self._dense


_STEPS = Memo("solvers.base.steps", 64)


def _generated(cls, n: int, direct: bool):
    """A generated step of ``cls`` for n coordinates, compiled once."""
    fn = _STEPS.get((cls, n, direct))
    if fn is None:
        namespace: dict = {"_MISSES": misses()}
        exec(compile(cls.step_source(n, direct), f"<{cls.name} step, n = {n}>", "exec"), namespace)
        fn = _STEPS.keep((cls, n, direct), namespace["step"])
    return fn


class GeneratedStep(Solver):
    """A fixed-step method whose step is one generated function on floats (RK4, RK8).

    Subclasses give :meth:`step_source` (the step on floats for n coordinates) and
    :attr:`inner_stages`; a step runs it (its stages calling the fused function directly where
    ``accel`` offers one, :func:`stage_lines`, else ``accel``; counted in ``nfev``), then
    evaluates the new state (the kept evaluation, the next step's first stage). Dense output:
    cubic Hermite of the step's ends unless a subclass has a better one, made when asked for
    (an event, a cut, an output inside the step)."""

    #: the calls of ``accel`` a step makes (the stages but the first)
    inner_stages = 0
    #: the generated step also gives its stages' derivatives (kept for the interpolant)
    returns_stages = False
    #: the dense output's class, made from the step's ends: (t0, t1, q0, q̇0, q̈0, q1, q̇1, q̈1)
    interpolant: type[CubicHermite] | None = None

    @staticmethod
    def step_source(n: int, direct: bool) -> str:
        """The code of ``step(accel, t0, t1, h, q…, v…, a…) -> (q₁, v₁)`` for n coordinates
        (``(q₁, v₁, K)`` with :attr:`returns_stages`); ``direct``: ``step(f, accel, …)``, the
        stages calling the fused function ``f`` (:func:`stage_lines`), the misses last."""
        raise NotImplementedError

    def _advance(self, t0, t1, q, v, a):
        """(q₁, v₁, the stages or None): the generated step."""
        f = self._direct()
        if f is not None:
            out = _generated(type(self), len(q), True)(f, self.accel, t0, t1, t1 - t0, *q, *v, *a)
            self.accel.count(self.inner_stages - out[-1])
        else:
            out = _generated(type(self), len(q), False)(self.accel, t0, t1, t1 - t0, *q, *v, *a)
        self.nfev += self.inner_stages
        return out[0], out[1], out[2] if self.returns_stages else None

    def _advance_to(self, t_target, interrupt):
        t0, q0, v0, a0 = self.t, self.q, self.qd, self.current.qdd
        ql, vl, stages = self._advance(t0, t_target, q0.tolist(), v0.tolist(), a0.tolist())
        return Advance(t_target, np.array(ql), np.array(vl), None, (t0, q0, v0, a0, stages))

    def _direct(self):
        """The fused function to call from the generated stages, where ``accel`` has one that
        holds now (:meth:`~mps_core.dynamics.engine.PartialSystems.accelerator`), else None."""
        direct = getattr(self.accel, "direct", None)
        return direct() if direct is not None else None

    def dense_output(self):
        if self._dense is None:
            last = self.__dict__.get("_dense_from")
            if last is None:
                raise RuntimeError("no step taken yet")
            t0, q0, v0, a0, _stages = last
            self._dense = (self.interpolant or CubicHermite)(
                t0, self.t, q0, v0, a0, self.q, self.qd, self.current.qdd
            )
        return self._dense


class CubicHermite:
    """q by the cubic Hermite polynomial of (q, q̇) at both ends, q̇ by that of (q̇, q̈).

    Evaluated on floats (a few coordinates: numpy's per-call cost would be most of it), the
    same operations in the same order as on arrays; the ends are made lists on the first call
    (most steps are never asked)."""

    def __init__(self, t0, t1, q0, qd0, qdd0, q1, qd1, qdd1):
        self.t0, self.h = t0, t1 - t0
        self.data = (q0, qd0, qdd0, q1, qd1, qdd1)
        self._lists: tuple | None = None

    def _ends(self) -> tuple:
        """The ends' (q, q̇, q̈) as lists of floats, made once."""
        ends = self._lists
        if ends is None:
            ends = self._lists = tuple(np.asarray(x, dtype=float).tolist() for x in self.data)
        return ends

    def __call__(self, t):
        q0, qd0, qdd0, q1, qd1, qdd1 = self._ends()
        h = self.h
        s = (t - self.t0) / h
        h00 = (1 + 2 * s) * (1 - s) ** 2
        h10 = s * (1 - s) ** 2
        h01 = s * s * (3 - 2 * s)
        h11 = s * s * (s - 1)
        b, d = h10 * h, h11 * h
        q = [h00 * x0 + b * v0 + h01 * x1 + d * v1 for x0, v0, x1, v1 in zip(q0, qd0, q1, qd1)]
        qd = [h00 * v0 + b * a0 + h01 * v1 + d * a1 for v0, a0, v1, a1 in zip(qd0, qdd0, qd1, qdd1)]
        return np.array(q), np.array(qd)


#: what a fused function raises or gives where it does not hold (a generated step then asks
#: ``accel``, the general path): a failed guard, a domain error, and None (not finite) unpacked
_MISSES = (BranchChanged, ArithmeticError, ValueError, TypeError)


def misses() -> tuple:
    return _MISSES


def stage_lines(t: str, qs: list, vs: list, out: list, direct: bool) -> list:
    """Code of one solver stage asking for q̈ at (t, q, q̇) (expressions, computed in this
    order) into the names ``out``: by ``accel(t, [q…], [q̇…])``, or, ``direct``, by the fused
    function ``f(t, q…, q̇…)`` with ``accel`` where it misses (counted in ``m``)."""
    if not direct:
        return [f"    {', '.join(out)}, = accel({t}, [{', '.join(qs)}], [{', '.join(vs)}])"]
    n = len(out)
    L = [f"    _q{i} = {qs[i]}" for i in range(n)]
    L.append(f"    _t = {t}")
    L.append("    try:")
    L.append(f"        {', '.join(out)}, = f(_t, {', '.join(f'_q{i}' for i in range(n))}, {', '.join(vs)})")
    L.append("    except _MISSES:")
    L.append(
        f"        {', '.join(out)}, = accel(_t, [{', '.join(f'_q{i}' for i in range(n))}], [{', '.join(vs)}])"
    )
    L.append("        m += 1")
    return L
