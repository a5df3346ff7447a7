"""The partial-system engine: from closed-form positions to generalized accelerations.

For a chart with free coordinates q = (q1 … qn) the engine builds, at each evaluation,

* the velocity analogs v*_P,i = ∂r_P/∂q_i of every point and centre of mass, and the angular
  analogs ω*_b,i of every rotating body (seed (5)–(16));
* the mass matrix A_ij = Σ_b m_b v*_G,i·v*_G,j + J_b ω*_b,i ω*_b,j (seed (21)–(25));
* the velocity terms h_i = Σ_jk (A_ij,k − ½ A_jk,i) q̇_j q̇_k (seed (30)–(35), for any n);
* the generalized forces Q_i = Σ F·v*_P,i + Σ M·ω*_b,i of the scene's effects (seed (26)–(29));

and solves A q̈ = Q − h (never inverting A).

Two derivative schemes:

``central``
    The seed's: central differences with a virtual displacement Δ (radians for angles; for a
    length coordinate Δ times the chart's length scale). Analogs at q and at q ± Δe_k from one
    vectorised position call on the stencil {q, q ± Δe_i, q ± 2Δe_i, q ± Δe_i ± Δe_j}
    (1 + 4n + 2n(n−1) points: 13 for n = 2, 5 for n = 1); A_ij,k by central differences of A.
    Error O(Δ²).
``autodiff``
    Exact derivatives (to round-off) from one position call on second-order jets
    (:mod:`mps_core.derivatives.jet`): the Jacobians give A, and the second directional derivative along q̇
    gives the velocity terms directly, h = Σ_b m_b J_Gᵀ (J̇_G q̇) + J_b ω*_b θ̈_b|q̈=0, which equals
    Σ_jk (A_ij,k − ½A_jk,i) q̇_j q̇_k identically.

How an evaluation is organised (it is the inner loop of every run, so it is written to make few
numpy calls: for n ≤ 2 numpy's per-call overhead, not arithmetic, is the cost):

* everything that depends only on the mechanism is built once per engine
  (:mod:`mps_core.dynamics.maps`): the centres of mass and the rotating bodies' link vectors
  are linear in the points' coordinates, so one matrix ``M`` maps the points' coordinates to
  all named points, centres of mass and link vectors;
* everything that depends on the chart view is built once per view (a :class:`_Plan`): the
  stencil's displacements and one matrix ``K`` whose columns select the base points of the
  stencil and take the central differences there;
* so an evaluation is: one position call on the stencil, ``Z = M @ (P @ K)`` (positions at the
  base points and every analog at every base point, in one pass), the angular analogs from the
  link vectors, the mass matrices at the base points as one batched product, and, for n ≤ 2,
  the velocity terms and the solve in closed form on floats. The numbers are the seed's
  formulas; only the order of floating-point operations differs from a literal transcription.

For a chart that also gives its positions on floats (``Chart.flat``) and has at most two free
coordinates, ``central`` runs the same computation as a scalar kernel (:mod:`mps_core.codegen.kernels`):
straight-line float code generated from these tables once per view, two to four times faster
than the arrays at this size; ``autodiff`` runs as an exact kernel (:mod:`mps_core.codegen.exact_kernels`):
the ``flat`` function traced once (:mod:`mps_core.derivatives.tracing`) and differentiated in forward mode
into float code: an evaluation costs a quarter of the jets' (and less than central
differences'). ``kernels=False`` keeps the array code and the jets (the same numbers to
round-off; tests compare them).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, Protocol, cast

import numpy as np

from ..codegen.fused_kernels import reuse_or_make
from ..codegen.kernels import central_kernel
from ..derivatives import SCHEMES
from ..derivatives.stencil import stencil
from ..derivatives.tracing import BranchChanged
from ..errors import ChartDomainError, NumericalError, config_in_degrees
from ..model.mechanism import ChartView, Mechanism
from .central import CentralScheme
from .exact import ExactScheme, other_that_holds
from .forces import EffectForces
from .kinematics import Evaluation, Kinematics, virtual_work
from .maps import MechanismMaps


class Accelerator(Protocol):
    """``accel(t, q, q̇) -> q̈`` on lists of floats (:meth:`PartialSystems.accelerator`), with
    ``direct()``: the fused function where it holds now, else None; ``count(k)``: count ``k``
    calls of that function made without ``accel``."""

    direct: Callable[[], Callable[..., Any] | None]
    count: Callable[[int], None]

    def __call__(self, t: float, ql: list, vl: list) -> list: ...


class _Plan:
    """What an evaluation in one chart view reuses (see the module's docstring)."""

    __slots__ = (
        "n",
        "S",
        "B",
        "odT",
        "K",
        "inv2d",
        "d",
        "scale",
        "kernel",
        "traced",
        "inline",
        "exact",
        "exact_traced",
        "exact_others",
        "branch_tries",
        "fused",
        "fused_at",
        "fused_tries",
        "fused_others",
        "tail",
        "tail_at",
        "tail_tries",
        "tail_others",
    )

    def __init__(self, view: ChartView, delta: float, central: bool = True):
        n = view.n
        self.n = n
        self.kernel = None  # central differences, calling the position function
        #: central differences from the traced position function (``kernel`` its fallback);
        #: ``traced``: built, or found impossible
        self.traced = False
        self.inline = None
        #: exact derivatives (:mod:`mps_core.codegen.exact_kernels`); ``exact_traced`` as ``traced``
        self.exact = None
        self.exact_traced = False
        #: the kernels of the position function's other branches met (``exact`` is the
        #: last one that held); ``branch_tries``: how often a branch had none of its own (the
        #: jets answer there; a few times a view at most)
        self.exact_others: list[Callable[..., Any]] = []
        self.branch_tries = 0
        #: q̈ alone with the effects traced in (:mod:`mps_core.codegen.fused_kernels`), made for the
        #: effects' and controls' state ``fused_at`` (:attr:`version`); ``fused_others``:
        #: up to six made at other states for the same (other branches of a force law);
        #: ``fused_tries``: how often a failed guard had one made (a few times a view at most)
        self.fused = None
        self.fused_at = -1
        self.fused_tries = 0
        self.fused_others: list[Callable[..., Any]] = []
        #: central differences: the effects and the solve after the central kernel, traced
        #: (:func:`~mps_core.codegen.fused_kernels.central_tail`), kept as ``fused`` is
        self.tail = None
        self.tail_at = -1
        self.tail_tries = 0
        self.tail_others: list[Callable[..., Any]] = []
        if not central:  # exact derivatives: no stencil
            self.S = self.B = self.odT = self.K = self.inv2d = self.d = self.scale = None
            return
        offsets, plus, minus = stencil(n)
        d = delta * np.asarray(view.scales, dtype=float)
        S, B = len(offsets), plus.shape[0]
        self.n, self.S, self.B, self.d = n, S, B, d
        self.odT = np.ascontiguousarray((offsets * d).T)  # (n, S)
        inv2d = 1.0 / (2.0 * d)
        self.inv2d = inv2d.tolist()
        # columns: B base positions, B·n analogs (base-major), one row sum (finiteness check)
        # the differences are taken exactly (±1) and scaled by 1/2Δ_i afterwards: the same
        # round-off as (r(q + Δe_i) − r(q − Δe_i)) / 2Δ_i
        K = np.zeros((S, B + B * n + 1))
        K[np.arange(B), np.arange(B)] = 1.0
        for b in range(B):
            for i in range(n):
                K[plus[b, i], B + b * n + i] += 1.0
                K[minus[b, i], B + b * n + i] -= 1.0
        K[:, -1] = 1.0
        self.K = K
        self.scale = np.tile(inv2d, B)[:, None]  # (B·n, 1)


class PartialSystems:
    """The engine: evaluates q̈ for a mechanism, its scene's effects and a derivative scheme.

    Counts its work in ``counts``: ``evaluations`` (right-hand sides), ``position_calls``
    (vectorised calls of a chart's position function) and ``position_points`` (configurations
    evaluated: the stencil size for ``central``, one jet for ``autodiff``).
    """

    def __init__(
        self,
        mechanism: Mechanism,
        effects=(),
        scheme: str = "central",
        delta: float = math.radians(0.1),
        kernels: bool = True,
    ):
        if scheme not in SCHEMES:
            raise ValueError(f"derivative scheme {scheme!r}: expected one of {', '.join(SCHEMES)}")
        if not (delta > 0.0 and math.isfinite(delta)):
            raise ValueError(f"virtual displacement delta = {delta!r}: expected a positive number")
        self.mechanism = mechanism
        #: the effects' generalized forces (:mod:`mps_core.dynamics.forces`)
        self.forces = EffectForces(mechanism, effects)
        #: the effects (bound to the mechanism); a change of the list moves :attr:`version`
        self.effects = self.forces.effects
        #: the state of the effects and the controls they read, as this engine's generated
        #: code folded them in: moved by any assignment to them (no other engine's)
        self.version = self.forces.version
        self.scheme = scheme
        self.delta = float(delta)
        #: central differences on charts with ``flat`` positions and n <= 2 run as scalar
        #: kernels (:mod:`mps_core.codegen.kernels`); False keeps the array code everywhere
        self.kernels = bool(kernels)
        self.counts = {"evaluations": 0, "position_calls": 0, "position_points": 0}
        #: what every evaluation reuses of the mechanism (its maps and their frozen tables)
        self.maps = MechanismMaps(mechanism)
        #: what the generated code reads of the mechanism (:mod:`mps_core.codegen.emitter`)
        self.tables = self.maps.tables
        self._plans: dict = {}
        #: the views' ``accel`` and ``fun`` (:meth:`accelerator`, :meth:`evaluator`), made once
        #: each: they read the plans as they are called
        self._functions: dict = {}
        #: the two derivative schemes' evaluations (:mod:`~mps_core.dynamics.central`,
        #: :mod:`~mps_core.dynamics.exact`), the scheme's one used
        self.central, self.exact = CentralScheme(self), ExactScheme(self)
        self._evaluate = self.central.evaluate if scheme == "central" else self.exact.evaluate

    def _plan(self, view) -> _Plan:
        plan = self._plans.get(view)
        if plan is None:
            if len(self._plans) > 256:
                self._plans.clear()
            plan = self._plans[view] = _Plan(view, self.delta, self.scheme == "central")
            if self.scheme == "central" and self.kernels:
                plan.kernel = central_kernel(self, view, plan)
        return plan

    # -- public ---------------------------------------------------------------------------
    def evaluate(self, view: ChartView, t: float, q, qd) -> Evaluation:
        q = np.asarray(q, dtype=float)
        qd = np.asarray(qd, dtype=float)
        plan = self._plans.get(view)
        if plan is not None and plan.inline is not None:
            e = self.central.kernel_evaluate(view, t, q, qd, plan)  # a traced central kernel
        elif plan is not None and plan.exact is not None and self.kernels:
            try:
                e = self.exact.kernel_evaluate(view, t, q, qd, plan)  # an exact kernel
            except BranchChanged:
                e = self.exact.jets_evaluate(view, t, q, qd)
        else:
            e = self._evaluate(view, t, q, qd)
        self.counts["evaluations"] += 1
        return e

    def accelerations(self, view: ChartView, t: float, ql: list, vl: list) -> list:
        """q̈ alone, n floats, at (t, q, q̇) given as lists of floats: the ``qdd`` that
        :meth:`evaluate` gives there, by the same operations, without making the evaluation
        (a solver's inner stages, whose evaluations are not kept). Counted as an evaluation.

        With exact derivatives this is one generated function from (t, q, q̇) to q̈ with the
        scene's effects traced in (:mod:`mps_core.codegen.fused_kernels`), where the view has one."""
        plan = self._plans.get(view)
        if plan is not None and plan.exact is not None and self.kernels:
            fused = plan.fused
            if plan.fused_at != self.version[0]:
                fused = self._fuse(view, plan, t, ql, vl)
            if fused is not None:
                try:
                    out = fused(t, *ql, *vl)
                except (BranchChanged, ArithmeticError, ValueError):
                    out = self._fused_miss(view, plan, t, ql, vl)
                if out is not None:
                    counts = self.counts
                    counts["evaluations"] += 1
                    counts["position_calls"] += 1
                    counts["position_points"] += 1
                    return out
        out = self._solve_on_floats(view, t, ql, vl)
        if out is None:
            return self.evaluate(view, t, np.array(ql, float), np.array(vl, float)).qdd.tolist()
        return out[3]

    def _function(self, kind: str, view: ChartView, make: Callable) -> Any:
        """Return the view's function of ``kind``, made by ``make(view)`` the first time."""
        key = (kind, view)
        fn = self._functions.get(key)
        if fn is None:
            if len(self._functions) > 512:
                self._functions.clear()
            fn = self._functions[key] = make(view)
        return fn

    def accelerator(self, view: ChartView) -> Accelerator:
        """``accel(t, q, q̇)``: :meth:`accelerations` in ``view``, the fused function called
        without the lookups where it holds (a solver's stages); made once a view."""
        return self._function("accel", view, self._make_accelerator)

    def _make_accelerator(self, view: ChartView) -> Accelerator:
        """Make :meth:`accelerator`'s function for ``view``."""
        accelerations = PartialSystems.accelerations
        engine = self
        counts = self.counts
        plans = self._plans
        version = self.version

        def accel(t, ql, vl):
            plan = plans.get(view)
            if plan is not None:
                fused = plan.fused
                if fused is not None and plan.fused_at == version[0]:
                    try:
                        out = fused(t, *ql, *vl)
                    except (BranchChanged, ArithmeticError, ValueError):
                        out = None
                    if out is not None:
                        counts["evaluations"] += 1
                        counts["position_calls"] += 1
                        counts["position_points"] += 1
                        return out
            return accelerations(engine, view, t, ql, vl)

        def direct():
            """The fused function itself where it holds now (a generated solver step calls it
            with the coordinates as arguments, ``accel`` where it raises or gives None), else
            None."""
            plan = plans.get(view)
            if (
                plan is not None
                and plan.fused is not None
                and plan.fused_at == version[0]
                and "accelerations" not in engine.__dict__
            ):
                return plan.fused
            return None

        def count(k: int) -> None:
            """Count ``k`` calls of the function :func:`direct` gave."""
            counts["evaluations"] += k
            counts["position_calls"] += k
            counts["position_points"] += k

        out = cast(Accelerator, accel)
        out.direct, out.count = direct, count
        return out

    def evaluator(self, view: ChartView):
        """``fun(t, q, q̇) -> Evaluation``: :meth:`evaluate` in ``view``, the fused evaluation
        called without the lookups where it holds (a solver's kept evaluations); made once a
        view. An ``evaluate`` set on the engine object (a spy, a budget) is called instead."""
        return self._function("fun", view, self._make_evaluator)

    def _make_evaluator(self, view: ChartView):
        """Make :meth:`evaluator`'s function for ``view``."""
        evaluate = PartialSystems.evaluate
        engine = self
        counts, plans, version = self.counts, self._plans, self.version
        names, bodies = self.maps.names, self.maps.body_index
        ndarray, array = np.ndarray, np.array

        def fun(t, q, qd):
            patched = engine.__dict__.get("evaluate")
            if patched is not None:
                return patched(view, t, q, qd)
            plan = plans.get(view)
            if plan is not None and q.__class__ is ndarray and qd.__class__ is ndarray:
                fused = plan.fused
                if fused is not None and plan.fused_at == version[0] and engine.kernels:
                    ql, vl = q.tolist(), qd.tolist()
                    try:
                        out = fused.full(t, *ql, *vl)
                    except (BranchChanged, ArithmeticError, ValueError):
                        out = None
                    if out is not None:
                        xl, jl, wl, A, h, conv, Q, Qnc, qdd = out
                        counts["evaluations"] += 1
                        counts["position_calls"] += 1
                        counts["position_points"] += 1
                        kin = Kinematics(t, q, qd, names, bodies=bodies, lists=(xl, jl, wl), conv=conv, v=vl)
                        return Evaluation(view, t, q, qd, array(qdd), A, h, Q, kin, Qnc)
            return evaluate(engine, view, t, q, qd)

        return fun

    def _fused_miss(self, view, plan, t, ql, vl):
        """q̈ by another of the view's fused functions where the first one's guards fail here
        (that one comes first from now on), or by one made here (a few per view at most);
        None for the general path."""
        other, out = other_that_holds(plan.fused_others, plan.fused, lambda f: f(t, *ql, *vl))
        if other is not None:
            plan.fused = other
            return out
        if plan.fused_tries >= 32:
            return None
        plan.fused_tries += 1
        first = plan.fused
        made = self._fuse(view, plan, t, ql, vl)
        if made is None or (first is not None and made.source == first.source):
            plan.fused = first
            return None
        plan.fused_others = ([first] + plan.fused_others)[:6]
        try:
            return made(t, *ql, *vl)
        except (BranchChanged, ArithmeticError, ValueError):
            return None

    def fingerprint(self):
        """:meth:`~mps_core.dynamics.forces.EffectForces.fingerprint`."""
        return self.forces.fingerprint()

    def _fuse(self, view, plan, t, ql, vl):
        """Make the view's fused function at (t, q, q̇) (None where it cannot be made)."""
        if plan.fused_at != self.version[0]:
            plan.fused_others = []  # made for other parameters or controls
        try:
            fused = reuse_or_make(self, view, plan.exact, t, ql, vl, Kinematics, virtual_work)
        except (ArithmeticError, ValueError, BranchChanged):
            fused = None
        plan.fused = fused
        plan.fused_at = self.version[0]
        return fused

    def equations(self, view: ChartView, t: float, ql: list, vl: list) -> tuple:
        """(A as rows, h, Q), lists of floats, at (t, q, q̇) given as lists of floats: the
        numbers :meth:`evaluate` gives there (its arrays' ``tolist()``), without making the
        evaluation where a kernel computes them. Counted as an evaluation."""
        out = self._solve_on_floats(view, t, ql, vl)
        if out is None:
            e = self.evaluate(view, t, np.array(ql, float), np.array(vl, float))
            return e.A.tolist(), e.h.tolist(), e.Q.tolist()
        A, h, Q, _qdd = out
        if isinstance(A, list):  # rows already (the jets)
            return A, h, Q
        if view.n == 1:
            return [[A]], h, Q
        a00, a01, a11 = A
        return [[a00, a01], [a01, a11]], h, Q

    def _solve_on_floats(self, view, t, ql, vl):
        """(A, h, Q, q̈) at (t, q, q̇) given as floats, by the view's kernel (A packed as the
        kernels give it), or by the jets where an exact kernel's branch changed (A as rows);
        None where the view has no kernel (yet). Counts the evaluation it makes."""
        plan = self._plans.get(view)
        if plan is None:
            return None
        if plan.inline is not None:
            out = self.central.kernel_solve(view, t, ql, vl, ql, vl, plan)
        elif plan.exact is not None and self.kernels:
            try:
                out = self.exact.kernel_solve(view, t, ql, vl, ql, vl, plan)
            except BranchChanged:  # another branch here: the jets
                e = self.exact.jets_evaluate(view, t, np.array(ql, float), np.array(vl, float))
                self.counts["evaluations"] += 1
                return e.A.tolist(), e.h.tolist(), e.Q.tolist(), e.qdd.tolist()
        else:
            return None
        self.counts["evaluations"] += 1
        return out[1], out[2], out[3], out[5]

    def generalized_forces(self, t: float, kin: Kinematics) -> np.ndarray:
        """Q = Σ over the effects of the virtual work of their loads (an array)."""
        return np.array(self.force_list(t, kin), dtype=float)

    def force_list(self, t: float, kin: Kinematics) -> list:
        """Q as n floats (:meth:`~mps_core.dynamics.forces.EffectForces.generalized`)."""
        return self.forces.generalized(t, kin)[0]

    def effect_paths(self) -> list:
        """:meth:`~mps_core.dynamics.forces.EffectForces.paths`."""
        return self.forces.paths()

    def potential_energy(self, kin: Kinematics) -> float:
        return self.forces.potential_energy(kin)

    def kinematics(self, view: ChartView, t: float, q, qd) -> Kinematics:
        """Positions and analogs alone (no forces, no solve), in the engine's scheme."""
        q = np.asarray(q, dtype=float)
        qd = np.asarray(qd, dtype=float)
        if self.scheme == "central":
            return self.central.kinematics(view, t, q, qd)[0]
        return self.exact.kinematics(view, t, q, qd)[0]

    def state_kinematics(self, view: ChartView, t: float, ql: list, vl: list) -> Kinematics:
        """Positions and analogs at (t, q, q̇) given as floats, by the view's kernel where it
        has one (one kernel call, no forces, no solve; the numbers :meth:`evaluate` reads
        there), else by :meth:`kinematics`. For functions of the state read between
        evaluations (the driver's switching functions); not counted as an evaluation."""
        plan = self._plans.get(view)
        if plan is not None and self.kernels:
            counts = self.counts
            maps = self.maps
            try:
                if plan.inline is not None:
                    counts["position_calls"] += 1
                    counts["position_points"] += plan.S
                    xl, jl, wl, _A, _h, wb = plan.inline(*ql, *vl)
                    return Kinematics(
                        t,
                        np.array(ql, float),
                        np.array(vl, float),
                        maps.names,
                        bodies=maps.body_index,
                        lists=(xl, jl, wl),
                        side=(wb, plan.inv2d),
                        v=list(vl),
                    )
                if plan.exact is not None:
                    counts["position_calls"] += 1
                    counts["position_points"] += 1
                    xl, jl, wl, _A, _h, conv = plan.exact(*ql, *vl)
                    return Kinematics(
                        t,
                        np.array(ql, float),
                        np.array(vl, float),
                        maps.names,
                        bodies=maps.body_index,
                        lists=(xl, jl, wl),
                        conv=conv,
                        v=list(vl),
                    )
            except BranchChanged:
                pass  # another branch here: the general path
            except (ValueError, ZeroDivisionError, OverflowError):
                raise ChartDomainError(view.name, "no real configuration at this point") from None
        return self.kinematics(view, t, ql, vl)

    def _finish(self, view, t, q, qd, A, h, Q, kin):
        try:
            qdd = np.linalg.solve(A, Q - h)
        except np.linalg.LinAlgError:
            qdd = np.full(view.n, np.nan)
        if not np.all(np.isfinite(qdd)):
            self._no_solution(view, t, q, A)
        return Evaluation(view, t, q, qd, qdd, A, h, Q, kin)

    def _no_solution(self, view, t, q, A):
        raise NumericalError(
            f"the equations of motion have no finite solution in chart {view.name} "
            f"(mass matrix {np.asarray(A).tolist()})",
            t,
            self._config(view, q),
        )

    def _config(self, view, q):
        return config_in_degrees({c.name: float(v) for c, v in zip(view.coordinates, q)})
