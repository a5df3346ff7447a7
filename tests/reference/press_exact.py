"""Exact reference models of the crank press mechanism, for tests only.

Three independent formulations of the same planar mechanism are provided:

1. ``lagrange_phi_psi`` / ``integrate_phi_psi``: equations of motion in the
   minimal coordinates ``q = (phi, psi)`` (assembly branch sigma = +1 by
   default, sigma = -1 available),
   derived symbolically from T and V with Lagrange's equations of the second
   kind.  The chart is singular where the rod AB is perpendicular to the
   guide (``l2**2 - (l3 sin psi - l1 sin phi)**2 = 0``), so it is only valid
   before the motion reaches that configuration.

2. ``redundant_model`` / ``integrate_redundant``: equations of motion in the
   redundant coordinates ``z = (phi, theta2, psi, x_C)`` with the two
   loop-closure constraints, solved at every right-hand-side evaluation as
   the index-1 augmented system ``[M G^T; G 0][z''; mu] = [F; -G' z']``.
   This formulation is regular through the singular configuration of
   the (phi, psi) chart.

3. ``crank_slider_locked`` / ``integrate_locked``: classical one-degree-of-
   freedom crank-slider obtained by locking the rocker at ``psi = 0``.

Frame: origin O at the crank bearing, x along the slider guide (up), y across.
SI units throughout.  Gravity is a vector ``(g_x, g_y)``; the default is
``(-9.81, 0.0)`` m/s^2.

Geometry:
    A = l1 (cos phi, sin phi)
    B = C + l3 (cos psi, sin psi),  C = (x_C, 0),  |B - A| = l2
    theta2 = angle of the vector A->B measured from x.

Mass properties (centres of mass): crank at A, rod at B, rocker at C,
slider at C.  The rocker rotates with psi, the rod with theta2, the crank
with phi; the slider does not rotate.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cache

import numpy as np
import sympy as sp
from scipy.integrate import solve_ivp

__all__ = [
    "PressParams",
    "DEFAULT_PARAMS",
    "GRAVITY",
    "PHI0",
    "PSI0",
    "PHI_DOT0",
    "PSI_DOT0",
    "PAPER_STATE0",
    "motor_constants",
    "motor_torque",
    "closure_sqrt_arg",
    "Trajectory",
    "PhiPsiModel",
    "RedundantModel",
    "LockedModel",
    "lagrange_phi_psi",
    "redundant_model",
    "crank_slider_locked",
    "redundant_state_from_minimal",
    "integrate_phi_psi",
    "integrate_redundant",
    "integrate_locked",
    "chart_breakdown_times",
]


# ---------------------------------------------------------------------------
# Parameters
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class PressParams:
    """Geometry, mass properties and motor data of the press (SI units)."""

    l1: float = 0.015
    l2: float = 0.040
    l3: float = 0.030
    m1: float = 4.6
    J1: float = 0.034
    m2: float = 20.0
    J2: float = 0.036
    m3: float = 18.0
    J3: float = 0.0441
    m4: float = 100.0
    # Asynchronous motor (Kloss characteristic) and reduction gear.
    motor_power: float = 1500.0  # W
    omega_sync: float = 50.0 * math.pi  # rad/s (1500 rpm)
    slip_rated: float = 0.058
    kloss_lambda: float = 2.2  # M_k / M_n
    crank_speed_rated: float = 43.5  # rad/s, crank speed at rated slip
    efficiency: float = 1.0


DEFAULT_PARAMS = PressParams()
GRAVITY = (-9.81, 0.0)

# Initial state of the "paper" scene.
PHI0 = math.radians(-64.1)
PSI0 = math.radians(-46.34)
PHI_DOT0 = 43.5
PSI_DOT0 = 0.0
PAPER_STATE0 = (PHI0, PSI0, PHI_DOT0, PSI_DOT0)


def motor_constants(params: PressParams = DEFAULT_PARAMS) -> dict:
    """Return the derived motor constants.

    Keys: ``M_n`` (rated motor torque), ``M_k`` (breakdown torque),
    ``s_k`` (breakdown slip), ``u`` (reduction ratio, motor speed / crank
    speed), ``omega_sync`` and ``efficiency``.
    """
    p = params
    M_n = p.motor_power / (p.omega_sync * (1.0 - p.slip_rated))
    M_k = p.kloss_lambda * M_n
    s_k = p.slip_rated * (p.kloss_lambda + math.sqrt(p.kloss_lambda**2 - 1.0))
    u = p.omega_sync * (1.0 - p.slip_rated) / p.crank_speed_rated
    return {
        "M_n": M_n,
        "M_k": M_k,
        "s_k": s_k,
        "u": u,
        "omega_sync": p.omega_sync,
        "efficiency": p.efficiency,
    }


def motor_torque(phi_dot, params: PressParams = DEFAULT_PARAMS):
    """Torque on the crank (positive in the +phi sense), Kloss formula.

    ``s = 1 - u*phi_dot/omega_sync``, ``M = 2 M_k s s_k / (s^2 + s_k^2)``,
    crank torque ``= efficiency * u * M``.  Accepts scalars or arrays.
    """
    c = motor_constants(params)
    s = 1.0 - c["u"] * np.asarray(phi_dot, dtype=float) / c["omega_sync"]
    M = 2.0 * c["M_k"] * s * c["s_k"] / (s * s + c["s_k"] ** 2)
    out = c["efficiency"] * c["u"] * M
    return float(out) if np.ndim(out) == 0 else out


def closure_sqrt_arg(phi, psi, params: PressParams = DEFAULT_PARAMS):
    """Radicand ``l2^2 - (l3 sin psi - l1 sin phi)^2`` of the (phi, psi) chart."""
    p = params
    s = p.l3 * np.sin(psi) - p.l1 * np.sin(phi)
    return p.l2**2 - s * s


def _gravity_tuple(gravity) -> tuple[float, float]:
    if gravity is None:
        return (0.0, 0.0)
    g = tuple(float(v) for v in gravity)
    if len(g) != 2:
        raise ValueError("gravity must be a 2-vector (g_x, g_y)")
    return g


# ---------------------------------------------------------------------------
# Result container
# ---------------------------------------------------------------------------


@dataclass
class Trajectory:
    """Sampled solution.  All arrays have the shape of ``t``.

    Fields not produced by a given formulation are ``None``.
    """

    t: np.ndarray
    phi: np.ndarray
    psi: np.ndarray
    phi_dot: np.ndarray
    psi_dot: np.ndarray
    phi_ddot: np.ndarray
    psi_ddot: np.ndarray
    x_C: np.ndarray | None = None
    x_C_dot: np.ndarray | None = None
    x_C_ddot: np.ndarray | None = None
    theta2: np.ndarray | None = None
    theta2_dot: np.ndarray | None = None
    T: np.ndarray | None = None
    V: np.ndarray | None = None
    # Constraint residuals (redundant formulation): Euclidean norms of
    # g(z) [m] and G(z) z' [m/s] at every sample.
    constraint_pos: np.ndarray | None = None
    constraint_vel: np.ndarray | None = None
    nfev: int = 0
    # Dense interpolant of the state vector (scipy OdeSolution).
    dense: object | None = field(default=None, repr=False)
    # Time at which a terminal event stopped the integration, if any.
    t_event: float | None = None

    @property
    def E(self) -> np.ndarray | None:
        """Total mechanical energy ``T + V`` (``None`` if not available)."""
        if self.T is None or self.V is None:
            return None
        return self.T + self.V


# ---------------------------------------------------------------------------
# Lambdify helpers
# ---------------------------------------------------------------------------


def _lambdify_math(args, exprs) -> Callable:
    """Scalar fast path: returns a callable producing a list of floats."""
    return sp.lambdify(args, list(exprs), modules="math", cse=True)


def _lambdify_numpy(args, exprs, shape) -> Callable:
    """Vectorised evaluation; output shape ``shape + broadcast(inputs)``."""
    f = sp.lambdify(args, list(exprs), modules="numpy", cse=True)

    def wrapped(*vals):
        vals = [np.asarray(v, dtype=float) for v in vals]
        bshape = np.broadcast_shapes(*(v.shape for v in vals)) if vals else ()
        out = f(*vals)
        out = [np.broadcast_to(np.asarray(o, dtype=float), bshape) for o in out]
        arr = np.stack(out, axis=0).reshape(tuple(shape) + bshape)
        return arr

    return wrapped


# ---------------------------------------------------------------------------
# 1. Minimal coordinates (phi, psi), assembly branch sigma
# ---------------------------------------------------------------------------


class PhiPsiModel:
    """Lagrange equations in ``q = (phi, psi)`` on assembly branch ``sigma``.

    ``sigma = +1`` (default, the paper configuration) has
    ``x_B - x_A = +sqrt(l2^2 - (l3 sin psi - l1 sin phi)^2)``; ``sigma = -1``
    is the other branch, reached after the rod passes the perpendicular to
    the guide.

    Equation of motion: ``M(q) q'' = h(q, q', g) + Q_motor``, where ``h``
    collects the velocity terms and the gravity generalised forces, and
    ``Q_motor = (motor_torque(phi'), 0)``.

    Vectorised methods accept scalars or broadcastable arrays ``phi, psi``;
    matrix results have the matrix indices first (e.g. shape (2, 2, N)).
    """

    def __init__(self, params: PressParams = DEFAULT_PARAMS, sigma: int = 1):
        if sigma not in (1, -1):
            raise ValueError("sigma must be +1 or -1")
        self.params = p = params
        self.sigma = sigma
        phi, psi, phid, psid, gx, gy = sp.symbols("phi psi phid psid gx gy", real=True)
        q = [phi, psi]
        qd = [phid, psid]
        l1, l2, l3 = (sp.Float(p.l1), sp.Float(p.l2), sp.Float(p.l3))
        S = l3 * sp.sin(psi) - l1 * sp.sin(phi)
        R = sp.sqrt(l2**2 - S**2)
        xA, yA = l1 * sp.cos(phi), l1 * sp.sin(phi)
        xB, yB = l1 * sp.cos(phi) + sigma * R, l3 * sp.sin(psi)
        xC, yC = xB - l3 * sp.cos(psi), sp.Integer(0)
        # sin(theta2) = S/l2, cos(theta2) = sigma*R/l2.
        th2 = sp.asin(S / l2) if sigma == 1 else sp.pi - sp.asin(S / l2)

        rA = sp.Matrix([xA, yA])
        rB = sp.Matrix([xB, yB])
        rC = sp.Matrix([xC, yC])
        JA, JB, JC = rA.jacobian(q), rB.jacobian(q), rC.jacobian(q)
        dth2 = sp.Matrix([th2]).jacobian(q)
        qdv = sp.Matrix(qd)
        vA, vB, vC = JA * qdv, JB * qdv, JC * qdv
        w2 = (dth2 * qdv)[0]

        m1, m2, m3, m4 = (sp.Float(v) for v in (p.m1, p.m2, p.m3, p.m4))
        J1, J2, J3 = (sp.Float(v) for v in (p.J1, p.J2, p.J3))
        half = sp.Rational(1, 2)
        T = (
            half * m1 * vA.dot(vA)
            + half * J1 * phid**2
            + half * m2 * vB.dot(vB)
            + half * J2 * w2**2
            + half * m3 * vC.dot(vC)
            + half * J3 * psid**2
            + half * m4 * vC.dot(vC)
        )
        V = -(gx * (m1 * xA + m2 * xB + (m3 + m4) * xC) + gy * (m1 * yA + m2 * yB + (m3 + m4) * yC))
        L = T - V
        # Lagrange II: d/dt(dL/dq') - dL/dq = Q
        #   => (d2L/dq'dq') q'' = Q + dL/dq - (d2L/dq'dq) q'
        p_mom = [sp.diff(L, v) for v in qd]
        Mmat = [[sp.diff(p_mom[i], qd[j]) for j in range(2)] for i in range(2)]
        h = [sp.diff(L, q[i]) - sum(sp.diff(p_mom[i], q[j]) * qd[j] for j in range(2)) for i in range(2)]

        self._sym = dict(T=T, V=V, M=Mmat, h=h, th2=th2, rA=rA, rB=rB, rC=rC)
        args_state = (phi, psi, phid, psid, gx, gy)
        self._rhs_math = _lambdify_math(args_state, [Mmat[0][0], Mmat[0][1], Mmat[1][1], h[0], h[1]])
        args_q = (phi, psi)
        self._M_np = _lambdify_numpy(args_q, [Mmat[i][j] for i in range(2) for j in range(2)], (2, 2))
        self._JA_np = _lambdify_numpy(args_q, list(JA), (2, 2))
        self._JB_np = _lambdify_numpy(args_q, list(JB), (2, 2))
        self._JC_np = _lambdify_numpy(args_q, list(JC), (2, 2))
        self._dth2_np = _lambdify_numpy(args_q, list(dth2), (2,))
        self._pos_np = _lambdify_numpy(args_q, [xA, yA, xB, yB, xC, yC, th2], (7,))
        self._T_np = _lambdify_numpy((phi, psi, phid, psid), [T], ())
        self._V_np = _lambdify_numpy((phi, psi, gx, gy), [V], ())

    # -- kinematics ---------------------------------------------------------
    def positions(self, phi, psi) -> dict:
        """Positions of A, B, C (each shape (2, ...)) and theta2."""
        a = self._pos_np(phi, psi)
        return {"A": a[0:2], "B": a[2:4], "C": a[4:6], "theta2": a[6]}

    def jacobian_A(self, phi, psi) -> np.ndarray:
        """``d r_A / d(phi, psi)``: rows (x, y), columns (phi, psi)."""
        return self._JA_np(phi, psi)

    def jacobian_B(self, phi, psi) -> np.ndarray:
        """``d r_B / d(phi, psi)``: rows (x, y), columns (phi, psi)."""
        return self._JB_np(phi, psi)

    def jacobian_C(self, phi, psi) -> np.ndarray:
        """``d r_C / d(phi, psi)``: rows (x, y), columns (phi, psi)."""
        return self._JC_np(phi, psi)

    def jacobian(self, point: str, phi, psi) -> np.ndarray:
        """Jacobian of point ``'A'``, ``'B'`` or ``'C'``."""
        return {"A": self._JA_np, "B": self._JB_np, "C": self._JC_np}[point](phi, psi)

    def theta2_grad(self, phi, psi) -> np.ndarray:
        """``d theta2 / d(phi, psi)``, shape (2, ...)."""
        return self._dth2_np(phi, psi)

    def mass_matrix(self, phi, psi) -> np.ndarray:
        """Generalised mass matrix ``M(phi, psi)``, shape (2, 2, ...)."""
        return self._M_np(phi, psi)

    # -- energies -----------------------------------------------------------
    def kinetic_energy(self, phi, psi, phi_dot, psi_dot):
        return self._T_np(phi, psi, phi_dot, psi_dot)

    def potential_energy(self, phi, psi, gravity=GRAVITY):
        gx, gy = _gravity_tuple(gravity)
        return self._V_np(phi, psi, gx, gy)

    # -- dynamics -----------------------------------------------------------
    def qdd(self, t, q, qd, motor: bool = True, gravity=GRAVITY) -> np.ndarray:
        """Generalised accelerations ``(phi'', psi'')`` at one state."""
        gx, gy = _gravity_tuple(gravity)
        m00, m01, m11, h0, h1 = self._rhs_math(float(q[0]), float(q[1]), float(qd[0]), float(qd[1]), gx, gy)
        if motor:
            h0 += motor_torque(float(qd[0]), self.params)
        return np.linalg.solve(np.array([[m00, m01], [m01, m11]]), np.array([h0, h1]))


@cache
def _phi_psi_cached(params: PressParams, sigma: int) -> PhiPsiModel:
    return PhiPsiModel(params, sigma)


def lagrange_phi_psi(params: PressParams = DEFAULT_PARAMS, sigma: int = 1) -> PhiPsiModel:
    """Derive (once per parameter set and branch) and return the (phi, psi) model."""
    return _phi_psi_cached(params, int(sigma))


def integrate_phi_psi(
    t_end: float,
    t_eval,
    motor: bool = True,
    rtol: float = 1e-12,
    atol: float = 1e-12,
    *,
    gravity=GRAVITY,
    state0: Sequence[float] | None = None,
    params: PressParams = DEFAULT_PARAMS,
    min_cos_theta2: float = 1e-3,
    sigma: int = 1,
    t0: float = 0.0,
) -> Trajectory:
    """Integrate the (phi, psi) equations with DOP853 from ``state0``.

    ``state0 = (phi0, psi0, phi_dot0, psi_dot0)``, default the paper state,
    at time ``t0`` (default 0), on assembly branch ``sigma``.
    Integration stops (terminal event) when
    ``cos(theta2)`` falls to ``min_cos_theta2``, i.e. just before the chart
    becomes singular; a ``ValueError`` is raised if ``t_eval`` reaches
    beyond that time.
    """
    model = lagrange_phi_psi(params, sigma)
    y0 = np.array(PAPER_STATE0 if state0 is None else state0, dtype=float)
    t_eval = np.asarray(t_eval, dtype=float)
    p = params

    def rhs(t, y):
        a = model.qdd(t, y[:2], y[2:], motor=motor, gravity=gravity)
        return np.array([y[2], y[3], a[0], a[1]])

    def chart_edge(t, y):
        return closure_sqrt_arg(y[0], y[1], p) - (p.l2 * min_cos_theta2) ** 2

    chart_edge.terminal = True
    chart_edge.direction = -1

    sol = solve_ivp(
        rhs,
        (float(t0), float(t_end)),
        y0,
        method="DOP853",
        rtol=rtol,
        atol=atol,
        dense_output=True,
        events=chart_edge,
    )
    if not sol.success:
        raise RuntimeError(f"(phi, psi) integration failed: {sol.message}")
    t_ev = None
    if sol.status == 1:
        t_ev = float(sol.t_events[0][0])
        if t_eval.size and t_eval.max() > t_ev:
            raise ValueError(
                f"(phi, psi) chart reaches its singular configuration at "
                f"t = {t_ev:.9g} s (cos theta2 = {min_cos_theta2}); "
                f"t_eval extends to {t_eval.max():.9g} s"
            )
    Y = sol.sol(t_eval)
    acc = np.array(
        [model.qdd(t, Y[:2, k], Y[2:, k], motor=motor, gravity=gravity) for k, t in enumerate(t_eval)]
    ).T.reshape(2, -1)
    pos = model.positions(Y[0], Y[1])
    JC = model.jacobian_C(Y[0], Y[1])
    dth = model.theta2_grad(Y[0], Y[1])
    T = model.kinetic_energy(Y[0], Y[1], Y[2], Y[3])
    V = model.potential_energy(Y[0], Y[1], gravity)
    return Trajectory(
        t=t_eval,
        phi=Y[0],
        psi=Y[1],
        phi_dot=Y[2],
        psi_dot=Y[3],
        phi_ddot=acc[0],
        psi_ddot=acc[1],
        x_C=pos["C"][0],
        x_C_dot=JC[0, 0] * Y[2] + JC[0, 1] * Y[3],
        theta2=pos["theta2"],
        theta2_dot=dth[0] * Y[2] + dth[1] * Y[3],
        T=T,
        V=V,
        nfev=sol.nfev,
        dense=sol.sol,
        t_event=t_ev,
    )


# ---------------------------------------------------------------------------
# 2. Redundant coordinates z = (phi, theta2, psi, x_C) with closure
# ---------------------------------------------------------------------------


class RedundantModel:
    """Constrained Lagrange equations in ``z = (phi, theta2, psi, x_C)``.

    Kinematics: ``A = l1 e(phi)``, ``B = A + l2 e(theta2)``, ``C = (x_C, 0)``,
    ``e(a) = (cos a, sin a)``.  Closure ``g(z) = B - C - l3 e(psi) = 0``.

    Index-1 form solved at each evaluation::

        [ M  G^T ] [ z'' ]   [ F(z, z') + Q_motor ]
        [ G   0  ] [ mu  ] = [ -G'(z, z') z'      ]

    with ``F = dL/dz - (d2L/dz' dz) z'`` (velocity terms of M and gravity).
    """

    def __init__(self, params: PressParams = DEFAULT_PARAMS):
        self.params = p = params
        phi, th, psi, xc = sp.symbols("phi theta2 psi x_C", real=True)
        phid, thd, psid, xcd = sp.symbols("phid theta2d psid x_Cd", real=True)
        gx, gy = sp.symbols("gx gy", real=True)
        z = [phi, th, psi, xc]
        zd = [phid, thd, psid, xcd]
        l1, l2, l3 = (sp.Float(p.l1), sp.Float(p.l2), sp.Float(p.l3))
        m1, m2, m3, m4 = (sp.Float(v) for v in (p.m1, p.m2, p.m3, p.m4))
        J1, J2, J3 = (sp.Float(v) for v in (p.J1, p.J2, p.J3))
        xA, yA = l1 * sp.cos(phi), l1 * sp.sin(phi)
        xB, yB = xA + l2 * sp.cos(th), yA + l2 * sp.sin(th)
        xC, yC = xc, sp.Integer(0)
        zdv = sp.Matrix(zd)
        vA = sp.Matrix([xA, yA]).jacobian(z) * zdv
        vB = sp.Matrix([xB, yB]).jacobian(z) * zdv
        vC = sp.Matrix([xC, yC]).jacobian(z) * zdv
        half = sp.Rational(1, 2)
        T = (
            half * m1 * vA.dot(vA)
            + half * J1 * phid**2
            + half * m2 * vB.dot(vB)
            + half * J2 * thd**2
            + half * m3 * vC.dot(vC)
            + half * J3 * psid**2
            + half * m4 * vC.dot(vC)
        )
        V = -(gx * (m1 * xA + m2 * xB + (m3 + m4) * xC) + gy * (m1 * yA + m2 * yB + (m3 + m4) * yC))
        L = T - V
        p_mom = [sp.diff(L, v) for v in zd]
        Mmat = sp.Matrix(4, 4, lambda i, j: sp.diff(p_mom[i], zd[j]))
        F = [sp.diff(L, z[i]) - sum(sp.diff(p_mom[i], z[j]) * zd[j] for j in range(4)) for i in range(4)]
        gvec = sp.Matrix([xB - xc - l3 * sp.cos(psi), yB - l3 * sp.sin(psi)])
        G = gvec.jacobian(z)
        Gzd = G * zdv
        gamma = Gzd.jacobian(z) * zdv  # G'(z, z') z'

        self._sym = dict(T=T, V=V, M=Mmat, F=F, g=gvec, G=G, gamma=gamma)
        args = (*z, *zd, gx, gy)
        self._rhs_math = _lambdify_math(args, [*list(Mmat), *F, *list(G), *list(gamma)])
        self._g_np = _lambdify_numpy(tuple(z), list(gvec), (2,))
        self._G_np = _lambdify_numpy(tuple(z), list(G), (2, 4))
        self._M_np = _lambdify_numpy(tuple(z), list(Mmat), (4, 4))
        self._T_np = _lambdify_numpy((*z, *zd), [T], ())
        self._V_np = _lambdify_numpy((*z, gx, gy), [V], ())

    def accelerations(self, z, zd, motor: bool = True, gravity=GRAVITY):
        """Return ``(z'', mu)`` for one state (``mu``: constraint multipliers)."""
        gx, gy = _gravity_tuple(gravity)
        vals = self._rhs_math(*(float(v) for v in z), *(float(v) for v in zd), gx, gy)
        M = np.asarray(vals[0:16]).reshape(4, 4)
        F = np.asarray(vals[16:20])
        G = np.asarray(vals[20:28]).reshape(2, 4)
        gam = np.asarray(vals[28:30])
        if motor:
            F[0] += motor_torque(float(zd[0]), self.params)
        K = np.zeros((6, 6))
        K[:4, :4] = M
        K[:4, 4:] = G.T
        K[4:, :4] = G
        sol = np.linalg.solve(K, np.concatenate([F, -gam]))
        return sol[:4], sol[4:]

    def constraint(self, z) -> np.ndarray:
        """Closure residual ``g(z)`` [m], shape (2, ...)."""
        z = np.asarray(z, dtype=float)
        return self._g_np(*z)

    def constraint_jacobian(self, z) -> np.ndarray:
        """``G(z) = dg/dz``, shape (2, 4, ...)."""
        z = np.asarray(z, dtype=float)
        return self._G_np(*z)

    def mass_matrix(self, z) -> np.ndarray:
        """Mass matrix ``M(z)``, shape (4, 4, ...)."""
        z = np.asarray(z, dtype=float)
        return self._M_np(*z)

    def kinetic_energy(self, z, zd):
        z = np.asarray(z, dtype=float)
        zd = np.asarray(zd, dtype=float)
        return self._T_np(*z, *zd)

    def potential_energy(self, z, gravity=GRAVITY):
        gx, gy = _gravity_tuple(gravity)
        z = np.asarray(z, dtype=float)
        return self._V_np(*z, gx, gy)


@cache
def _redundant_cached(params: PressParams) -> RedundantModel:
    return RedundantModel(params)


def redundant_model(params: PressParams = DEFAULT_PARAMS) -> RedundantModel:
    """Derive (once per parameter set) and return the redundant model."""
    return _redundant_cached(params)


def redundant_state_from_minimal(
    phi: float,
    psi: float,
    phi_dot: float,
    psi_dot: float,
    sigma: int = 1,
    params: PressParams = DEFAULT_PARAMS,
) -> np.ndarray:
    """Consistent redundant state ``(z, z')`` (length 8) from ``(phi, psi)``.

    ``theta2`` and ``x_C`` follow from the closure on branch ``sigma``;
    their rates from ``G(z) z' = 0``.
    """
    p = params
    S = p.l3 * math.sin(psi) - p.l1 * math.sin(phi)
    rad = p.l2**2 - S * S
    if rad < 0.0:
        raise ValueError("(phi, psi) is not an assembly configuration")
    R = sigma * math.sqrt(rad)
    th = math.atan2(S, R)
    xB = p.l1 * math.cos(phi) + R
    xc = xB - p.l3 * math.cos(psi)
    c2 = math.cos(th)
    if abs(c2) < 1e-14:
        raise ValueError("theta2 rate undefined: rod perpendicular to the guide")
    thd = (p.l3 * math.cos(psi) * psi_dot - p.l1 * math.cos(phi) * phi_dot) / (p.l2 * c2)
    xcd = -p.l1 * math.sin(phi) * phi_dot - p.l2 * math.sin(th) * thd + p.l3 * math.sin(psi) * psi_dot
    return np.array([phi, th, psi, xc, phi_dot, thd, psi_dot, xcd], dtype=float)


def _atol_vector(atol: float, params: PressParams) -> np.ndarray:
    """Per-component absolute tolerances for the state (z, z').

    Angles and angular rates get ``atol`` (rad, rad/s); the translation
    ``x_C`` and its rate get ``atol * l1`` (m, m/s), i.e. the displacement of
    the crank pin for an angle error ``atol``.
    """
    s = np.array([1.0, 1.0, 1.0, params.l1])
    return float(atol) * np.concatenate([s, s])


def integrate_redundant(
    t_end: float,
    t_eval,
    motor: bool = True,
    gravity=GRAVITY,
    state0: Sequence[float] | None = None,
    rtol: float = 1e-12,
    atol: float = 1e-12,
    *,
    sigma: int = 1,
    params: PressParams = DEFAULT_PARAMS,
) -> Trajectory:
    """Integrate the redundant-coordinate equations with DOP853.

    ``state0 = (phi0, psi0, phi_dot0, psi_dot0)`` at ``t = 0`` (default the
    paper state); ``theta2``, ``x_C`` and their rates are made consistent
    with the closure on branch ``sigma``.  No constraint stabilisation is
    applied; the residuals are returned in ``constraint_pos`` /
    ``constraint_vel``.
    """
    model = redundant_model(params)
    s0 = PAPER_STATE0 if state0 is None else tuple(state0)
    y0 = redundant_state_from_minimal(*s0, sigma=sigma, params=params)
    t_eval = np.asarray(t_eval, dtype=float)

    def rhs(t, y):
        zdd, _ = model.accelerations(y[:4], y[4:], motor=motor, gravity=gravity)
        return np.concatenate([y[4:], zdd])

    sol = solve_ivp(
        rhs,
        (0.0, float(t_end)),
        y0,
        method="DOP853",
        rtol=rtol,
        atol=_atol_vector(atol, params),
        dense_output=True,
    )
    if not sol.success:
        raise RuntimeError(f"redundant integration failed: {sol.message}")
    Y = sol.sol(t_eval).reshape(8, -1)
    acc = np.array(
        [model.accelerations(Y[:4, k], Y[4:, k], motor=motor, gravity=gravity)[0] for k in range(Y.shape[1])]
    ).T.reshape(4, -1)
    gpos = model.constraint(Y[:4])
    G = model.constraint_jacobian(Y[:4])
    gvel = np.einsum("ijk,jk->ik", G, Y[4:])
    T = model.kinetic_energy(Y[:4], Y[4:])
    V = model.potential_energy(Y[:4], gravity)
    shape = t_eval.shape
    return Trajectory(
        t=t_eval,
        phi=Y[0].reshape(shape),
        psi=Y[2].reshape(shape),
        phi_dot=Y[4].reshape(shape),
        psi_dot=Y[6].reshape(shape),
        phi_ddot=acc[0].reshape(shape),
        psi_ddot=acc[2].reshape(shape),
        x_C=Y[3].reshape(shape),
        x_C_dot=Y[7].reshape(shape),
        x_C_ddot=acc[3].reshape(shape),
        theta2=Y[1].reshape(shape),
        theta2_dot=Y[5].reshape(shape),
        T=np.asarray(T).reshape(shape),
        V=np.asarray(V).reshape(shape),
        constraint_pos=np.linalg.norm(gpos, axis=0).reshape(shape),
        constraint_vel=np.linalg.norm(gvel, axis=0).reshape(shape),
        nfev=sol.nfev,
        dense=sol.sol,
    )


def chart_breakdown_times(
    traj: Trajectory, params: PressParams = DEFAULT_PARAMS, n_scan: int = 20001
) -> np.ndarray:
    """Times where the (phi, psi) chart radicand vanishes along ``traj``.

    ``traj`` must come from ``integrate_redundant``.  On the closure,
    ``l2^2 - (l3 sin psi - l1 sin phi)^2 = (l2 cos theta2)^2``, and the
    signed quantity ``x_B - x_A = l2 cos theta2`` changes sign where the
    motion passes from branch sigma = +1 to sigma = -1 (or back).  Returns
    the sign-change times, refined by bisection on the dense output.
    """
    from scipy.optimize import brentq

    if traj.dense is None:
        raise ValueError("trajectory has no dense output")
    t0, t1 = float(traj.t[0]), float(traj.t[-1])
    ts = np.linspace(t0, t1, n_scan)

    def c2(t):
        return float(np.cos(traj.dense(t)[1]))

    vals = np.cos(traj.dense(ts)[1])
    roots = []
    for k in range(n_scan - 1):
        if vals[k] == 0.0:
            roots.append(ts[k])
        elif vals[k] * vals[k + 1] < 0.0:
            roots.append(brentq(c2, ts[k], ts[k + 1], xtol=1e-15, rtol=1e-15, maxiter=200))
    return np.asarray(roots, dtype=float)


# ---------------------------------------------------------------------------
# 3. Crank-slider with the rocker locked at psi = 0
# ---------------------------------------------------------------------------


class LockedModel:
    """One-degree-of-freedom crank-slider (rocker locked at ``psi = 0``).

    ``x_B = l1 cos phi + sqrt(l2^2 - l1^2 sin^2 phi)``, ``y_B = 0``,
    ``x_C = x_B - l3``; ``theta2 = asin(-l1 sin phi / l2)`` (rod A->B,
    ``cos theta2 > 0`` since ``l2 > l1``).  Rod centre of mass at B; the
    rocker (centre of mass at C, not rotating) and the slider translate with
    ``x_C``.

    Reduced inertia ``J(phi) = sum m |d r_G/d phi|^2 + J1 + J2 theta2'^2``;
    equation of motion ``phi'' = (Q(phi, phi') - J'(phi) phi'^2 / 2) / J(phi)``
    with ``Q = -dV/dphi + motor torque``.  All methods are vectorised.
    """

    def __init__(self, params: PressParams = DEFAULT_PARAMS):
        self.params = p = params
        phi, phid, gx, gy = sp.symbols("phi phid gx gy", real=True)
        l1, l2, l3 = (sp.Float(p.l1), sp.Float(p.l2), sp.Float(p.l3))
        m1, m2, m3, m4 = (sp.Float(v) for v in (p.m1, p.m2, p.m3, p.m4))
        J1, J2 = sp.Float(p.J1), sp.Float(p.J2)
        xA, yA = l1 * sp.cos(phi), l1 * sp.sin(phi)
        xB = l1 * sp.cos(phi) + sp.sqrt(l2**2 - l1**2 * sp.sin(phi) ** 2)
        xC = xB - l3
        th2 = sp.asin(-l1 * sp.sin(phi) / l2)
        dxC = sp.diff(xC, phi)
        ddxC = sp.diff(dxC, phi)
        dth2 = sp.diff(th2, phi)
        Jred = (
            m1 * (sp.diff(xA, phi) ** 2 + sp.diff(yA, phi) ** 2)
            + J1
            + m2 * sp.diff(xB, phi) ** 2
            + J2 * dth2**2
            + (m3 + m4) * dxC**2
        )
        dJ = sp.diff(Jred, phi)
        V = -(gx * (m1 * xA + m2 * xB + (m3 + m4) * xC) + gy * (m1 * yA))
        Qg = -sp.diff(V, phi)
        self._sym = dict(xC=xC, th2=th2, J=Jred, dJ=dJ, V=V, Qg=Qg)
        self._f_xC = _lambdify_numpy((phi,), [xC], ())
        self._f_dxC = _lambdify_numpy((phi,), [dxC], ())
        self._f_ddxC = _lambdify_numpy((phi,), [ddxC], ())
        self._f_th2 = _lambdify_numpy((phi,), [th2], ())
        self._f_dth2 = _lambdify_numpy((phi,), [dth2], ())
        self._f_J = _lambdify_numpy((phi,), [Jred], ())
        self._f_dJ = _lambdify_numpy((phi,), [dJ], ())
        self._f_V = _lambdify_numpy((phi, gx, gy), [V], ())
        self._f_Qg = _lambdify_numpy((phi, gx, gy), [Qg], ())
        self._rhs_math = _lambdify_math((phi, gx, gy), [Jred, dJ, Qg])

    def x_C(self, phi):
        return self._f_xC(phi)

    def x_C_d1(self, phi):
        """``d x_C / d phi``."""
        return self._f_dxC(phi)

    def x_C_d2(self, phi):
        """``d^2 x_C / d phi^2``."""
        return self._f_ddxC(phi)

    def theta2(self, phi):
        return self._f_th2(phi)

    def theta2_d1(self, phi):
        """``d theta2 / d phi``."""
        return self._f_dth2(phi)

    def J(self, phi):
        """Reduced moment of inertia ``J(phi)`` [kg m^2]."""
        return self._f_J(phi)

    def dJ(self, phi):
        """``dJ/dphi``."""
        return self._f_dJ(phi)

    def potential_energy(self, phi, gravity=GRAVITY):
        gx, gy = _gravity_tuple(gravity)
        return self._f_V(phi, gx, gy)

    def gravity_torque(self, phi, gravity=GRAVITY):
        """Generalised gravity force ``-dV/dphi`` [N m]."""
        gx, gy = _gravity_tuple(gravity)
        return self._f_Qg(phi, gx, gy)

    def kinetic_energy(self, phi, phi_dot):
        return 0.5 * self.J(phi) * np.asarray(phi_dot, dtype=float) ** 2

    def phi_ddot(self, phi: float, phi_dot: float, motor: bool = True, gravity=GRAVITY) -> float:
        gx, gy = _gravity_tuple(gravity)
        J, dJ, Qg = self._rhs_math(float(phi), gx, gy)
        Q = Qg + (motor_torque(float(phi_dot), self.params) if motor else 0.0)
        return (Q - 0.5 * dJ * phi_dot * phi_dot) / J


@cache
def _locked_cached(params: PressParams) -> LockedModel:
    return LockedModel(params)


def crank_slider_locked(params: PressParams = DEFAULT_PARAMS) -> LockedModel:
    """Derive (once per parameter set) and return the locked crank-slider."""
    return _locked_cached(params)


def integrate_locked(
    t_end: float,
    t_eval,
    phi0: float,
    phi_dot0: float,
    motor: bool = True,
    gravity=GRAVITY,
    rtol: float = 1e-12,
    atol: float = 1e-12,
    *,
    params: PressParams = DEFAULT_PARAMS,
) -> Trajectory:
    """Integrate the locked crank-slider with DOP853 from ``(phi0, phi_dot0)``.

    ``psi``, ``psi_dot`` and ``psi_ddot`` of the result are zero arrays.
    """
    model = crank_slider_locked(params)
    t_eval = np.asarray(t_eval, dtype=float)

    def rhs(t, y):
        return np.array([y[1], model.phi_ddot(y[0], y[1], motor=motor, gravity=gravity)])

    sol = solve_ivp(
        rhs,
        (0.0, float(t_end)),
        np.array([phi0, phi_dot0], dtype=float),
        method="DOP853",
        rtol=rtol,
        atol=atol,
        dense_output=True,
    )
    if not sol.success:
        raise RuntimeError(f"locked integration failed: {sol.message}")
    Y = sol.sol(t_eval).reshape(2, -1)
    phi, phid = Y[0].reshape(t_eval.shape), Y[1].reshape(t_eval.shape)
    phidd = np.array(
        [model.phi_ddot(a, b, motor=motor, gravity=gravity) for a, b in zip(Y[0], Y[1])]
    ).reshape(t_eval.shape)
    zeros = np.zeros_like(phi)
    d1 = model.x_C_d1(phi)
    d2 = model.x_C_d2(phi)
    return Trajectory(
        t=t_eval,
        phi=phi,
        psi=zeros,
        phi_dot=phid,
        psi_dot=zeros.copy(),
        phi_ddot=phidd,
        psi_ddot=zeros.copy(),
        x_C=model.x_C(phi),
        x_C_dot=d1 * phid,
        x_C_ddot=d2 * phid**2 + d1 * phidd,
        theta2=model.theta2(phi),
        theta2_dot=model.theta2_d1(phi) * phid,
        T=model.kinetic_energy(phi, phid),
        V=model.potential_energy(phi, gravity),
        nfev=sol.nfev,
        dense=sol.sol,
    )
