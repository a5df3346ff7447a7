"""The ``central`` derivative scheme of the engine (:mod:`mps_core.dynamics.engine`): the seed's
central differences with a virtual displacement Δ.

One vectorised position call on the view's stencil gives the positions at q and the analogs at
q and at q ± Δe_k; the mass matrices at the base points in one batched product; A's derivatives,
the velocity terms and, for n ≤ 2, the solve in closed form on floats. Where the chart has
``flat`` positions and n ≤ 2 a scalar kernel (:mod:`mps_core.codegen.kernels`) does the same on
floats, and the effects and the solve after it run as one generated tail
(:func:`~mps_core.codegen.fused_kernels.central_tail`).
"""

from __future__ import annotations

import math

import numpy as np

from ..codegen.fused_kernels import reuse_or_make_tail
from ..codegen.kernels import as_matrix, central_kernel, solve_given_h
from ..derivatives.tracing import BranchChanged
from ..errors import ChartDomainError
from .exact import other_that_holds
from .kinematics import Evaluation, Kinematics, virtual_work

__all__ = ["CentralScheme"]


class CentralScheme:
    """The central-difference evaluation of an ``engine``'s views (its tables, plans, counts and
    effects)."""

    def __init__(self, engine):
        self.engine = engine

    def points_matrix(self, pose, cols):
        eng = self.engine
        P = np.empty((2 * eng.maps.npts, cols))
        for p, rx, ry in eng.maps.point_slots:
            x, y = pose[p]
            P[rx] = x
            P[ry] = y
        return P

    def kinematics(self, view, t, q, qd):
        """(kin, Zt, Wr, plan): kinematics at q; Zt (columns of K × pairs of M): positions at the
        base points, then every analog at every base point; Wr (B, n, nrot) the angular ones."""
        eng = self.engine
        maps = eng.maps
        plan = eng._plans.get(view) or eng._plan(view)
        n, B = plan.n, plan.B
        pose = view.positions(list(q[:, None] + plan.odT))
        counts = eng.counts
        counts["position_calls"] += 1
        counts["position_points"] += plan.S
        Zt = (self.points_matrix(pose, plan.S) @ plan.K).T @ maps.MT
        if not math.isfinite(Zt[-1, -2]):
            raise ChartDomainError(view.name, "a stencil point has no real configuration")
        Zt[B:-1] *= plan.scale
        NP, NP2 = maps.npoints, 2 * maps.npoints
        X = Zt[0, :NP2]
        if maps.offset is not None:
            X = X + maps.offset
        X = X.reshape(NP, 2)
        J = Zt[B : B + n, :NP2].T.reshape(NP, 2, n)
        nrot = maps.nrot
        if nrot:
            Zc = Zt[:-1].view(complex)  # pairs as x + iy
            Rc = Zc[:B, NP : NP + nrot]
            Wr = (Zc[B : B + B * n, NP : NP + nrot].reshape(B, n, nrot) / Rc[:, None, :]).imag
            W = Wr[0].T if maps.rot_all else maps.omega_rows(Wr[0], n)
        else:
            Wr = None
            W = np.zeros((len(maps.mass), n))
        kin = Kinematics(t, q, qd, maps.names, X, J, W, maps.body_index)
        return kin, Zt, Wr, plan

    def evaluate(self, view, t, q, qd):
        eng = self.engine
        maps = eng.maps
        plan = eng._plans.get(view) or eng._plan(view)
        if plan.kernel is not None:
            if not plan.traced:
                try:
                    plan.inline = central_kernel(eng, view, plan, q)
                    plan.traced = True
                except (ChartDomainError, ArithmeticError, ValueError):
                    pass  # q is outside the chart: the kernel says so; traced later
            return self.kernel_evaluate(view, t, q, qd, plan)
        kin, Zt, Wr, plan = self.kinematics(view, t, q, qd)
        n, B = plan.n, plan.B
        Ut = Zt[B : B + B * n, 2 * maps.npts : 2 * maps.npoints].reshape(B, n, -1)  # v*_G: (B, n, ·)
        if Wr is not None:
            Ut = np.concatenate((Ut, Wr), axis=2)
        Ab = (Ut * maps.weights) @ Ut.transpose(0, 2, 1)  # (B, n, n): A at the bases
        Q = eng.generalized_forces(t, kin)
        if n <= 2:
            return self.solve_small(view, t, q, qd, Ab, Q, kin, plan)
        A = Ab[0]
        dA = (Ab[1::2] - Ab[2::2]) * (1.0 / (2.0 * plan.d))[:, None, None]  # dA[k, i, j]
        h = (np.tensordot(qd, dA, 1) @ qd) - 0.5 * ((dA @ qd) @ qd)
        return eng._finish(view, t, q, qd, A, h, Q, kin)

    def kernel_evaluate(self, view, t, q, qd, plan):
        """The same evaluation on floats, by the view's scalar kernel."""
        vl = qd.tolist()
        kin, A, h, Q, Qnc, qdd = self.kernel_solve(view, t, q, qd, q.tolist(), vl, plan)
        return Evaluation(view, t, q, qd, np.array(qdd), A, h, Q, kin, Qnc)

    def kernel_solve(self, view, t, q, qd, ql, vl, plan):
        """(kin, A, h, Q, Q_nc, q̈) by the view's central kernel, all on floats; q, q̇ as given
        (arrays, or the float lists themselves where no evaluation is made)."""
        eng = self.engine
        counts = eng.counts
        counts["position_calls"] += 1
        counts["position_points"] += plan.S
        try:
            if plan.inline is not None:
                try:
                    xl, jl, wl, A, h, wb = plan.inline(*ql, *vl)
                except BranchChanged:
                    xl, jl, wl, A, h, wb = plan.kernel(*ql, *vl)
            else:
                xl, jl, wl, A, h, wb = plan.kernel(*ql, *vl)
        except (ValueError, ZeroDivisionError, OverflowError):
            raise ChartDomainError(view.name, "a stencil point has no real configuration") from None
        kin = Kinematics(
            t,
            q,
            qd,
            eng.maps.names,
            bodies=eng.maps.body_index,
            lists=(xl, jl, wl),
            side=(wb, plan.inv2d),
            v=vl,
        )
        tail = plan.tail
        if plan.tail_at != eng.version[0] and eng.kernels:
            tail = self.tail(view, plan, t, vl, (xl, jl, wl, A, h, wb))
        if tail is not None:
            # the effects and the solve in one generated call where its guards hold and q̈ is
            # finite; else the effects one by one below
            try:
                out = tail(t, *vl, xl, jl, wl, A, h)
            except (BranchChanged, ArithmeticError, ValueError):
                out = self.tail_miss(view, plan, t, vl, (xl, jl, wl, A, h, wb))
            if out is not None:
                Q, Qnc, qdd = out
                return kin, A, h, Q, Qnc, qdd
        Q, Qnc = eng.forces.generalized(t, kin)
        qdd = solve_given_h(A, h, Q)
        for x in qdd:
            if not math.isfinite(x):
                eng._no_solution(view, t, np.array(ql, float), as_matrix(A, plan.n))
        return kin, A, h, Q, Qnc, qdd

    def tail(self, view, plan, t, vl, parts):
        """Make the view's traced effects and solve after its central kernel at this state
        (None where it cannot be made), for the effects' present state."""
        eng = self.engine

        if plan.tail_at != eng.version[0]:
            plan.tail_others = []  # made for other parameters or controls
        try:
            tail = reuse_or_make_tail(eng, view, t, vl, parts, Kinematics, virtual_work)
        except (ArithmeticError, ValueError):
            tail = None
        plan.tail, plan.tail_at = tail, eng.version[0]
        return tail

    def tail_miss(self, view, plan, t, vl, parts):
        """(Q, Q_nc, q̈) by another of the view's traced tails where the first one's guards
        fail here (that one comes first from now on), or by one made here (a few per view at
        most); None for the effects one by one."""
        eng = self.engine
        xl, jl, wl, A, h, _wb = parts
        other, out = other_that_holds(plan.tail_others, plan.tail, lambda f: f(t, *vl, xl, jl, wl, A, h))
        if other is not None:
            plan.tail = other
            return out
        if plan.tail_tries >= 32:
            return None
        plan.tail_tries += 1

        try:
            made = reuse_or_make_tail(eng, view, t, vl, parts, Kinematics, virtual_work)
        except (ArithmeticError, ValueError):
            made = None
        if made is None:
            return None
        if plan.tail is not None:
            plan.tail_others.insert(0, plan.tail)
            del plan.tail_others[6:]
        plan.tail = made
        try:
            return made(t, *vl, xl, jl, wl, A, h)
        except (BranchChanged, ArithmeticError, ValueError):
            return None

    def solve_small(self, view, t, q, qd, Ab, Q, kin, plan):
        """n = 1 or 2: velocity terms by central differences of A, and the solve, on floats."""
        eng = self.engine
        AL = Ab.tolist()
        v = qd.tolist()
        Ql = Q.tolist()
        c = plan.inv2d
        if plan.n == 2:
            (a00, a01), (a10, a11) = AL[0]
            v0, v1 = v
            # dA[k] = (A(q + Δe_k) − A(q − Δe_k)) / 2Δ_k
            (p00, p01), (p10, p11) = AL[1]
            (m00, m01), (m10, m11) = AL[2]
            c0 = c[0]
            d000, d001, d010, d011 = ((p00 - m00) * c0, (p01 - m01) * c0, (p10 - m10) * c0, (p11 - m11) * c0)
            (p00, p01), (p10, p11) = AL[3]
            (m00, m01), (m10, m11) = AL[4]
            c1 = c[1]
            d100, d101, d110, d111 = ((p00 - m00) * c1, (p01 - m01) * c1, (p10 - m10) * c1, (p11 - m11) * c1)
            # h_i = Σ_jk dA[k][i][j] q̇_j q̇_k − ½ Σ_jk dA[i][j][k] q̇_j q̇_k
            h0 = (
                (d000 * v0 + d001 * v1) * v0
                + (d100 * v0 + d101 * v1) * v1
                - 0.5 * ((d000 * v0 + d001 * v1) * v0 + (d010 * v0 + d011 * v1) * v1)
            )
            h1 = (
                (d010 * v0 + d011 * v1) * v0
                + (d110 * v0 + d111 * v1) * v1
                - 0.5 * ((d100 * v0 + d101 * v1) * v0 + (d110 * v0 + d111 * v1) * v1)
            )
            r0, r1 = Ql[0] - h0, Ql[1] - h1
            det = a00 * a11 - a01 * a10
            try:
                qdd = [(r0 * a11 - a01 * r1) / det, (a00 * r1 - a10 * r0) / det]
            except ZeroDivisionError:
                qdd = [math.nan, math.nan]
            h = [h0, h1]
        else:
            a = AL[0][0][0]
            d = (AL[1][0][0] - AL[2][0][0]) * c[0]
            h0 = 0.5 * d * v[0] * v[0]
            try:
                qdd = [(Ql[0] - h0) / a]
            except ZeroDivisionError:
                qdd = [math.nan]
            h = [h0]
        for x in qdd:
            if not math.isfinite(x):
                eng._no_solution(view, t, q, Ab[0])
        return Evaluation(view, t, q, qd, np.array(qdd), Ab[0], np.array(h), Q, kin)
