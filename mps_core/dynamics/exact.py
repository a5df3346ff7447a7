"""The ``autodiff`` derivative scheme of the engine (:mod:`mps_core.dynamics.engine`): exact
derivatives.

One position call on second-order jets (:mod:`mps_core.derivatives.jet`) gives the analogs and,
along q̇, the velocity terms directly. Where the chart has ``flat`` positions and n ≤ 2 an exact
kernel (:mod:`mps_core.codegen.exact_kernels`) does the same on floats, and a fused function
(:mod:`mps_core.codegen.fused_kernels`) the whole evaluation with the effects traced in; a new
engine's first evaluation in a view takes the pair the last engine of the same tables and
effects used there.
"""

from __future__ import annotations

import math

import numpy as np

from ..caches import Memo
from ..codegen.exact_kernels import exact_kernel
from ..codegen.fused_kernels import ForceLawBranch
from ..codegen.kernels import as_matrix, solve_given_h
from ..derivatives.jet import Jet, ScalarJet, seed
from ..derivatives.tracing import BranchChanged
from ..errors import ChartDomainError
from .kinematics import Evaluation, Kinematics

__all__ = ["ExactScheme", "other_that_holds"]


def other_that_holds(others: list, first, call):
    """(fn, call(fn)) for the first of ``others`` whose guards hold here (it and ``first``
    change places in the list), or (None, None)."""
    for k, other in enumerate(others):
        try:
            out = call(other)
        except (BranchChanged, ArithmeticError, ValueError):
            continue
        others[k] = first
        return other, out
    return None, None


#: per (chart view, the engine's tables, the effects' fingerprint): the (exact kernel, fused
#: function) an engine last used there, for another engine's first evaluation in that view
#: (the charts a run changes to, in a fresh simulation of a scene run before)
_FIRST = Memo("dynamics.exact.first", 512)


class ExactScheme:
    """The exact-derivative evaluation of an ``engine``'s views (its tables, plans, counts and
    effects)."""

    def __init__(self, engine):
        self.engine = engine

    def kinematics(self, view, t, q, qd):
        """(kin, Zt, Wr, theta2) from one position call on jets: Zt's rows are the value, the
        n partial derivatives, d1 and d2 (along q̇) of every pair of M; Wr (n, nrot) the angular
        analogs, theta2 (nrot,) the angles' second rates at q̈ = 0."""
        eng = self.engine
        maps = eng.maps
        n = view.n
        pose = view.positions(seed(q, qd))
        eng.counts["position_calls"] += 1
        eng.counts["position_points"] += 1
        rows = []
        zero = [0.0] * (n + 2)
        for p in maps.point_names:
            for c in pose[p]:
                if c.__class__ is ScalarJet:
                    rows.append([c.val, *c.g, c.d1, c.d2])
                elif isinstance(c, Jet):
                    rows.append([float(c.val), *np.reshape(c.grad, n).tolist(), float(c.d1), float(c.d2)])
                else:
                    rows.append([float(c), *zero])
        Zt = np.array(rows).T @ maps.MT
        if not all(math.isfinite(x) for x in Zt[: 1 + n, -2].tolist()):
            raise ChartDomainError(view.name, "no real configuration at this point")
        NP, NP2 = maps.npoints, 2 * maps.npoints
        X = Zt[0, :NP2]
        if maps.offset is not None:
            X = X + maps.offset
        X = X.reshape(NP, 2)
        J = Zt[1 : 1 + n, :NP2].T.reshape(NP, 2, n)
        nrot = maps.nrot
        if nrot:
            Zc = Zt[:, :-2].view(complex)
            # (∂r, ṙ, r̈)/r: Im gives ω* and the angle's rate, Re the rate of ln |r|
            quo = Zc[1:, NP : NP + nrot] / Zc[0, NP : NP + nrot]
            Wr = quo[:n].imag
            w1, dot1 = quo[n].imag, quo[n].real
            theta2 = quo[n + 1].imag - 2.0 * w1 * dot1
            W = maps.omega_rows(Wr, n)
        else:
            Wr = theta2 = None
            W = np.zeros((len(maps.mass), n))
        kin = Kinematics(t, q, qd, maps.names, X, J, W, maps.body_index)
        return kin, Zt, Wr, theta2

    def evaluate(self, view, t, q, qd):
        eng = self.engine
        if eng.kernels:
            plan = eng._plans.get(view) or eng._plan(view)
            if not plan.exact_traced:
                e = self.first_evaluate(view, t, q, qd, plan)
                if e is not None:
                    return e
                try:
                    plan.exact = exact_kernel(eng, view, q)
                    plan.exact_traced = True
                except (ChartDomainError, ArithmeticError, ValueError):
                    pass  # q is outside the chart: the jets say so; built next time
            if plan.exact is not None:
                try:
                    e = self.kernel_evaluate(view, t, q, qd, plan)
                except BranchChanged:
                    pass  # the position function takes another branch here
                else:
                    self.remember_first(view, plan)
                    return e
        return self.jets_evaluate(view, t, q, qd)

    def jets_evaluate(self, view, t, q, qd):
        """The autodiff evaluation by the jets (no kernel, or the kernel's branch changed)."""
        eng = self.engine
        maps = eng.maps
        kin, Zt, Wr, theta2 = self.kinematics(view, t, q, qd)
        n = view.n
        G = Zt[:, 2 * maps.npts : 2 * maps.npoints]  # (n + 3, 2·nbody)
        if Wr is None:
            U, D = G[1 : 1 + n], G[2 + n]
        else:
            U = np.concatenate((G[1 : 1 + n], Wr), axis=1)
            D = np.concatenate((G[2 + n], theta2))
        Uw = U * maps.weights
        A = Uw @ U.T
        h = Uw @ D
        Q = eng.generalized_forces(t, kin)
        if n == 2:
            (a00, a01), (a10, a11) = A.tolist()
            r0, r1 = (Q - h).tolist()
            det = a00 * a11 - a01 * a10
            try:
                qdd = [(r0 * a11 - a01 * r1) / det, (a00 * r1 - a10 * r0) / det]
            except ZeroDivisionError:
                qdd = [math.nan, math.nan]
            for x in qdd:
                if not math.isfinite(x):
                    eng._no_solution(view, t, q, A)
            return Evaluation(view, t, q, qd, np.array(qdd), A, h, Q, kin)
        return eng._finish(view, t, q, qd, A, h, Q, kin)

    def first_evaluate(self, view, t, q, qd, plan):
        """A view's first exact evaluation in this engine by the (exact kernel, fused function)
        pair that an engine of the same tables and effects last used in this view, where the
        fused function holds here (one call: its guards are the kernel's and the laws'); the
        plan then has both, as the lookups would have given it. None: the lookups decide."""
        eng = self.engine
        fp = eng.fingerprint()
        if fp is None:
            return None
        key = (view, eng.tables.number, fp)
        pair = _FIRST.get(key)
        if pair is None:
            return None
        exact, fused = pair
        ql, vl = q.tolist(), qd.tolist()
        try:
            out = fused.full(t, *ql, *vl)
        except (BranchChanged, ArithmeticError, ValueError):
            return None
        if out is None:
            return None
        plan.exact, plan.exact_traced = exact, True
        plan.fused, plan.fused_at = fused, eng.version[0]
        plan.fused_others = []
        counts = eng.counts
        counts["position_calls"] += 1
        counts["position_points"] += 1
        xl, jl, wl, A, h, conv, Q, Qnc, qdd = out
        kin = Kinematics(
            t, q, qd, eng.maps.names, bodies=eng.maps.body_index, lists=(xl, jl, wl), conv=conv, v=vl
        )
        return Evaluation(view, t, q, qd, np.array(qdd), A, h, Q, kin, Qnc)

    def remember_first(self, view, plan):
        """Keep the view's (exact kernel, fused function) for the next engine's first
        evaluation there (:meth:`_first_evaluate`)."""
        eng = self.engine
        fp = eng.fingerprint()
        if fp is None or plan.exact is None or plan.fused is None:
            return
        _FIRST.keep((view, eng.tables.number, fp), (plan.exact, plan.fused))

    def other_branch(self, view, plan, ql) -> bool:
        """Make the view's exact kernel the one of the branch its position function takes at
        ``ql`` (one of the view's whose guards hold there, else one made before for the same
        position function, else traced there; six kept a view), its fused function to be
        made again; False where there is none (the jets answer)."""
        eng = self.engine
        zeros = [0.0] * view.n  # the guards are the positions' alone
        kernel, _ = other_that_holds(plan.exact_others, plan.exact, lambda k: k(*ql, *zeros))
        if kernel is None:
            if plan.branch_tries >= 16:
                return False
            try:
                kernel = exact_kernel(eng, view, ql)
            except (ChartDomainError, ArithmeticError, ValueError, BranchChanged):
                kernel = None
            if kernel is None or kernel is plan.exact:
                plan.branch_tries += 1
                return False
            plan.exact_others = ([plan.exact] + plan.exact_others)[:6]
        plan.exact = kernel
        plan.fused, plan.fused_others, plan.fused_at = None, [], -1
        return True

    def kernel_evaluate(self, view, t, q, qd, plan):
        """The autodiff evaluation on floats, by the view's exact kernel."""
        vl = qd.tolist()
        kin, A, h, Q, Qnc, qdd = self.kernel_solve(view, t, q, qd, q.tolist(), vl, plan)
        return Evaluation(view, t, q, qd, np.array(qdd), A, h, Q, kin, Qnc)

    def kernel_solve(self, view, t, q, qd, ql, vl, plan):
        """(kin, A, h, Q, Q_nc, q̈) by the view's exact kernel, all on floats (as
        :meth:`_kernel_solve`)."""
        eng = self.engine
        maps = eng.maps
        counts = eng.counts
        counts["position_calls"] += 1
        counts["position_points"] += 1
        fused = plan.fused
        if plan.fused_at != eng.version[0]:
            fused = eng._fuse(view, plan, t, ql, vl)
        if fused is not None:
            # the whole evaluation in one call (mps_core.codegen.fused_kernels), where its guards
            # hold and q̈ is finite; else the kernel and the effects one by one below
            try:
                out = fused.full(t, *ql, *vl)
            except ForceLawBranch:
                out = None  # the kinematics hold: the kernel below
            except BranchChanged:
                out = None  # the kinematics' branch: the kernel below
            except (ArithmeticError, ValueError):
                out = None  # the kernel below says what is wrong
            if out is not None:  # (None: q̈ not finite, the kernel below says so)
                xl, jl, wl, A, h, conv, Q, Qnc, qdd = out
                kin = Kinematics(
                    t, q, qd, maps.names, bodies=maps.body_index, lists=(xl, jl, wl), conv=conv, v=vl
                )
                return kin, A, h, Q, Qnc, qdd
        try:
            try:
                xl, jl, wl, A, h, conv = plan.exact(*ql, *vl)
            except BranchChanged:
                # the position function takes another branch here (a continuation chart's
                # sign, a root that touches zero): that branch's kernel, made once
                if not self.other_branch(view, plan, ql):
                    raise
                xl, jl, wl, A, h, conv = plan.exact(*ql, *vl)
        except (ValueError, ZeroDivisionError, OverflowError):
            raise ChartDomainError(view.name, "no real configuration at this point") from None
        kin = Kinematics(t, q, qd, maps.names, bodies=maps.body_index, lists=(xl, jl, wl), conv=conv, v=vl)
        Q, Qnc = eng.forces.generalized(t, kin)
        qdd = solve_given_h(A, h, Q)
        for x in qdd:
            if not math.isfinite(x):
                if not all(math.isfinite(x) for x in xl):
                    raise ChartDomainError(view.name, "no real configuration at this point")
                eng._no_solution(view, t, np.array(ql, float), as_matrix(A, plan.n))
        return kin, A, h, Q, Qnc, qdd
