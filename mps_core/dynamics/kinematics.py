"""What an evaluation gives: the kinematics of a state (positions, velocity analogs, angular
analogs, by name) and the evaluation itself (A, h, Q, q̈); an effect's loads as generalized
forces by virtual work."""

from __future__ import annotations

import numpy as np

from ..codegen.kernels import as_matrix
from ..model.mechanism import ChartView

__all__ = ["Evaluation", "Kinematics", "virtual_work"]


class Kinematics:
    """Positions, velocity analogs and velocities at one configuration, by name.

    Points are the mechanism's points and the centres of mass ``G_<body>``. Two views of the same
    numbers, each built from the other on first use:

    * arrays, for vector code: ``X`` (NP, 2) positions, ``J`` (NP, 2, n) velocity analogs, ``W``
      (nbody, n) angular analogs (zero rows: translating bodies);
    * floats, for the effects' scalar code (numpy's per-call cost would exceed the arithmetic):
      :meth:`xy`, :meth:`jac`, :meth:`vxy`, :meth:`omega`, :meth:`rate`.

    ``pose`` (the positions as ``{point: (x, y)}``) is built on first use and kept.
    """

    __slots__ = (
        "t",
        "q",
        "qd",
        "names",
        "bodies",
        "n",
        "_X",
        "_J",
        "_W",
        "_xl",
        "_jl",
        "_wl",
        "_vl",
        "_pose",
        "_side",
        "_conv",
    )

    def __init__(
        self,
        t,
        q,
        qd,
        names,
        X=None,
        J=None,
        W=None,
        bodies=None,
        *,
        lists=None,
        side=None,
        conv=None,
        v=None,
    ):
        self.t = t
        self._side = side  # (angular analogs at q ± Δe_k, 1/2Δ_k) from a kernel
        # from an exact kernel: θ̈ at q̈ = 0 of every body, then each centre of mass's (ẍ, ÿ)
        # at q̈ = 0
        self._conv = conv
        self.q = q
        self.qd = qd
        self.names = names  # {point name: row}
        self.bodies = bodies  # {body name: row}
        self._X, self._J, self._W = X, J, W
        self._pose = None
        self._vl = v  # q̇ as floats, where the caller has them
        if lists is not None:
            # xl: 2·NP floats (x, y by row); jl: per row, x then y, n floats each; wl: per body
            self._xl, self._jl, self._wl = lists
            self.n = len(self._wl) // len(bodies)
        else:
            self._xl = self._jl = self._wl = None
            self.n = J.shape[-1]

    # -- arrays ---------------------------------------------------------------------------
    @property
    def X(self) -> np.ndarray:
        if self._X is None:
            self._X = np.array(self._xl).reshape(-1, 2)
        return self._X

    @property
    def J(self) -> np.ndarray:
        if self._J is None:
            self._J = np.array(self._jl).reshape(-1, 2, self.n)
        return self._J

    @property
    def W(self) -> np.ndarray:
        if self._W is None:
            self._W = np.array(self._wl).reshape(-1, self.n)
        return self._W

    # -- floats ---------------------------------------------------------------------------
    def _lists(self):
        if self._xl is None:
            self._xl = self._X.reshape(-1).tolist()
            self._jl = self._J.reshape(-1).tolist()
            self._wl = self._W.reshape(-1).tolist()
        return self._xl, self._jl, self._wl

    def _v(self):
        v = self._vl
        if v is None:
            v = self._vl = [float(x) for x in self.qd]
        return v

    def xy(self, point: str) -> tuple[float, float]:
        """Position (x, y) of a point, floats."""
        xl = self._xl if self._xl is not None else self._lists()[0]
        r = 2 * self.names[point]
        return xl[r], xl[r + 1]

    def jac(self, point: str) -> tuple[list, list]:
        """Velocity analogs of a point: (∂x/∂q, ∂y/∂q), n floats each."""
        jl = self._jl if self._jl is not None else self._lists()[1]
        n = self.n
        r = 2 * n * self.names[point]
        return jl[r : r + n], jl[r + n : r + 2 * n]

    def vxy(self, point: str) -> tuple[float, float]:
        """Velocity (ẋ, ẏ) of a point, floats."""
        jx, jy = self.jac(point)
        v = self._vl if self._vl is not None else self._v()
        if self.n == 1:
            return jx[0] * v[0], jy[0] * v[0]
        if self.n == 2:
            return jx[0] * v[0] + jx[1] * v[1], jy[0] * v[0] + jy[1] * v[1]
        return sum(a * b for a, b in zip(jx, v)), sum(a * b for a, b in zip(jy, v))

    def omega(self, body: str) -> list:
        """Angular analog ∂θ/∂q of a body, n floats (zeros for a translating body)."""
        wl = self._wl if self._wl is not None else self._lists()[2]
        n = self.n
        r = n * self.bodies[body]
        return wl[r : r + n]

    def rate(self, body: str) -> float:
        """Angular velocity of a body, float."""
        wl = self._wl if self._wl is not None else self._lists()[2]
        v = self._vl if self._vl is not None else self._v()
        n = self.n
        r = n * self.bodies[body]
        if n == 1:
            return wl[r] * v[0]
        if n == 2:
            return wl[r] * v[0] + wl[r + 1] * v[1]
        w = wl[r : r + n]
        return sum(a * b for a, b in zip(w, v))

    def weighted_analogs(self, forces) -> list:
        """Σ (f_x ∂x_P/∂q + f_y ∂y_P/∂q) over ``forces``, a sequence of (point, f_x, f_y): the
        generalized force of constant forces at points, n floats."""
        jl = self._jl if self._jl is not None else self._lists()[1]
        n, names = self.n, self.names
        if n == 1:
            s = 0.0
            for p, fx, fy in forces:
                r = 2 * names[p]
                s += fx * jl[r] + fy * jl[r + 1]
            return [s]
        if n == 2:
            s0 = s1 = 0.0
            for p, fx, fy in forces:
                r = 4 * names[p]
                s0 += fx * jl[r] + fy * jl[r + 2]
                s1 += fx * jl[r + 1] + fy * jl[r + 3]
            return [s0, s1]
        Q = [0.0] * n
        for p, fx, fy in forces:
            r = 2 * n * names[p]
            for i in range(n):
                Q[i] += fx * jl[r + i] + fy * jl[r + n + i]
        return Q

    def angular_convective(self, body: str) -> float | None:
        """θ̈ of a body at q̈ = 0, Σ_jk ∂²θ/∂q_j∂q_k q̇_j q̇_k, in the scheme's own accuracy:
        exact from an exact kernel, by central differences of the angular analogs from a
        central one; None where this state has no such data."""
        if self._conv is not None:
            return self._conv[self.bodies[body]]
        if self._side is None:
            return None
        wb, inv2d = self._side
        n = self.n
        r = n * self.bodies[body]
        v = self._v()
        out = 0.0
        for k in range(n):
            wp, wm = wb[2 * k], wb[2 * k + 1]
            s = 0.0
            for i in range(n):
                s += (wp[r + i] - wm[r + i]) * v[i]
            out += s * inv2d[k] * v[k]
        return out

    # -- arrays by name (vector code) -------------------------------------------------------
    def position(self, point: str) -> np.ndarray:
        return self.X[self.names[point]]

    def analog(self, point: str) -> np.ndarray:
        return self.J[self.names[point]]

    def velocity(self, point: str) -> np.ndarray:
        return self.J[self.names[point]] @ self.qd

    def angular_analog(self, body: str) -> np.ndarray:
        return self.W[self.bodies[body]]

    @property
    def pose(self) -> dict:
        p = self._pose
        if p is None:
            xl = self._xl if self._xl is not None else self._lists()[0]
            p = self._pose = {k: (xl[2 * i], xl[2 * i + 1]) for k, i in self.names.items()}
        return p


class Evaluation:
    """One evaluation of the equations of motion at (t, q, q̇) in a chart view.

    ``A``, ``h`` and ``Q`` are arrays; an evaluation from a scalar kernel keeps them as floats
    and makes the arrays on first use."""

    __slots__ = ("view", "t", "q", "qd", "qdd", "kin", "_A", "_h", "_Q", "Q_nc")

    def __init__(self, view: ChartView, t: float, q, qd, qdd, A, h, Q, kin: Kinematics, Q_nc=None):
        self.view, self.t, self.q, self.qd, self.qdd, self.kin = view, t, q, qd, qdd, kin
        self._A, self._h, self._Q = A, h, Q
        #: the non-conservative effects' share of Q (n floats; None where not kept): their
        #: power is Q_nc·q̇
        self.Q_nc = Q_nc

    @property
    def A(self) -> np.ndarray:
        A = self._A
        if not isinstance(A, np.ndarray):
            A = self._A = as_matrix(A, self.view.n)
        return A

    @property
    def h(self) -> np.ndarray:
        if not isinstance(self._h, np.ndarray):
            self._h = np.array(self._h, dtype=float)
        return self._h

    @property
    def Q(self) -> np.ndarray:
        if not isinstance(self._Q, np.ndarray):
            self._Q = np.array(self._Q, dtype=float)
        return self._Q

    @property
    def kinetic_energy(self) -> float:
        A, v = self._A, self.qd
        if isinstance(A, np.ndarray):
            return 0.5 * float(v @ A @ v)
        if self.view.n == 1:
            v0 = float(v[0])
            return 0.5 * A * v0 * v0
        a00, a01, a11 = A
        v0, v1 = float(v[0]), float(v[1])
        return 0.5 * (a00 * v0 * v0 + 2.0 * a01 * v0 * v1 + a11 * v1 * v1)


def virtual_work(ld, kin) -> list | None:
    """Σ F·v*_P + Σ M·ω*_b of an effect's loads, n floats (None for no loads)."""
    if not ld.forces and not ld.torques:
        return None
    n = kin.n
    Q = [0.0] * n
    for _body, point, fx, fy in ld.forces:
        jx, jy = kin.jac(point)
        for i in range(n):
            Q[i] += fx * jx[i] + fy * jy[i]
    for body, m in ld.torques:
        w = kin.omega(body)
        for i in range(n):
            Q[i] += m * w[i]
    return Q
