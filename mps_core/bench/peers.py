"""The peer: scipy's DOP853 on exact equations of motion derived with sympy.

A formulation written independently of the engine and of ``tests/reference``: redundant
coordinates z = (φ, ψ, x_C) (crank angle, rocker angle, slider position) with the rod's closure
``|B − A|² = l2²`` as one scalar constraint,

    A = l1 (cos φ, sin φ),  C = (x_C, 0),  B = C + l3 (cos ψ, sin ψ),

so that the rod's angle is not a coordinate at all. The equations come from d'Alembert's principle
projected on z (M z̈ + c(z, ż) = Q + Gᵀλ, G = ∂g/∂z, G z̈ = −Ġż), assembled and differentiated
symbolically (sympy), turned into one scalar function by ``lambdify`` (common subexpressions
eliminated) and solved at every right-hand side as the 4×4 index-1 system. It is regular wherever
the machine is (the gradient of the closure vanishes only where crank, rod and rocker all stand
across the guide), so it passes the (φ, ψ) chart's branch points.

Only what this formulation knows is supported: the free structure with gravity and the motor
(:func:`supports` says whether a scene qualifies). At a tight tolerance (rtol 1e-13) the same
model is the benchmarks' reference for such scenes.

sympy is needed here (``pip install 'mps[bench]'``); it is imported when a model is built.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.integrate import solve_ivp

__all__ = ["ExactPress", "PeerRun", "supports", "exact_model", "run_peer"]

_SUPPORTED_EFFECTS = {"gravity", "motor"}


def supports(scene) -> tuple[bool, str]:
    """(True, "") if the exact model covers the scene, else (False, why not)."""
    if scene.structure != "free":
        return False, f"structure {scene.structure!r} (the exact model is the free mechanism)"
    extra = sorted({e.kind for e in scene.effects} - _SUPPORTED_EFFECTS)
    if extra:
        return False, "effects " + ", ".join(extra) + " (the exact model has gravity and motor)"
    if getattr(scene, "commands", None):
        return False, "commands (the exact model has no events)"
    return True, ""


@dataclass(frozen=True)
class _Params:
    """Everything the equations depend on, hashable (one derivation per parameter set)."""

    l1: float
    l2: float
    l3: float
    bodies: tuple  # (name, mass, inertia, origin, toward, com_along, com_across, length)
    g: tuple  # (gx, gy)


def _params(scene) -> _Params:
    mech = scene.mechanism()
    g: tuple[float, ...] = (0.0, 0.0)
    for e in scene.effects:
        if e.kind == "gravity":
            g = tuple(float(x) for x in e.params["g"])
    bodies = tuple(
        (b.name, b.mass, b.inertia, b.origin, b.toward, b.com[0], b.com[1], b.length) for b in mech.bodies
    )
    geo = scene.geometry
    return _Params(geo.l1, geo.l2, geo.l3, bodies, g)


class ExactPress:
    """The exact model of one scene: :meth:`accelerations` and :meth:`rhs` on y = (z, ż)."""

    def __init__(self, scene):
        ok, why = supports(scene)
        if not ok:
            raise ValueError(f"scene {scene.name!r}: the exact model does not cover {why}")
        self.scene = scene
        self.params = _params(scene)
        t0 = time.process_time()
        self._f = _derive(self.params)
        self.derive_cpu = time.process_time() - t0
        self.motor = None
        for e in scene.effects:
            if e.kind == "motor":
                self.motor = scene.build_effects(scene.mechanism())[
                    [x.kind for x in scene.effects].index("motor")
                ]
        self.sigma = scene.assembly
        p = self.params
        self.atol_scale = np.array([1.0, 1.0, p.l1, 1.0, 1.0, p.l1])

    # -- state --------------------------------------------------------------------------
    def initial_state(self) -> np.ndarray:
        """y0 = (φ, ψ, x_C, φ̇, ψ̇, ẋ_C) from the scene's (φ, ψ, φ̇, ψ̇) on its assembly."""
        p, i = self.params, self.scene.initial
        phi, psi, phid, psid = i["phi"], i["psi"], i["phi_dot"], i.get("psi_dot", 0.0)
        s = p.l3 * math.sin(psi) - p.l1 * math.sin(phi)
        xb = p.l1 * math.cos(phi) + self.sigma * math.sqrt(p.l2 * p.l2 - s * s)
        xc = xb - p.l3 * math.cos(psi)
        g = self._f(phi, psi, xc, phid, psid, 0.0)[9:12]
        xcd = -(g[0] * phid + g[1] * psid) / g[2]
        return np.array([phi, psi, xc, phid, psid, xcd])

    # -- dynamics -----------------------------------------------------------------------
    def accelerations(self, y) -> np.ndarray:
        """(φ̈, ψ̈, ẍ_C) at y = (z, ż)."""
        m00, m01, m02, m11, m12, m22, f0, f1, f2, g0, g1, g2, gam = self._f(*y)
        if self.motor is not None:
            f0 += self.motor.torque(y[3])
        K = np.array([[m00, m01, m02, -g0], [m01, m11, m12, -g1], [m02, m12, m22, -g2], [g0, g1, g2, 0.0]])
        return np.linalg.solve(K, np.array([f0, f1, f2, -gam]))[:3]

    def rhs(self, t, y):
        a = self.accelerations(y)
        return np.array([y[3], y[4], y[5], a[0], a[1], a[2]])

    def closure(self, y) -> float:
        """|B − A| − l2 (m): the constraint's drift."""
        p = self.params
        phi, psi, xc = y[0], y[1], y[2]
        bx, by = xc + p.l3 * np.cos(psi), p.l3 * np.sin(psi)
        return np.hypot(bx - p.l1 * np.cos(phi), by - p.l1 * np.sin(phi)) - p.l2


@lru_cache(maxsize=8)
def _derive(p: _Params):
    try:
        import sympy as sp
    except ImportError:
        raise RuntimeError("the exact model needs sympy: pip install -e '.[bench]'") from None

    phi, psi, xc = sp.symbols("phi psi x_C", real=True)
    phid, psid, xcd = sp.symbols("phid psid x_Cd", real=True)
    z, zd = sp.Matrix([phi, psi, xc]), sp.Matrix([phid, psid, xcd])
    l1, l2, l3 = sp.Float(p.l1), sp.Float(p.l2), sp.Float(p.l3)
    pts = {
        "O": sp.Matrix([0, 0]),
        "A": sp.Matrix([l1 * sp.cos(phi), l1 * sp.sin(phi)]),
        "C": sp.Matrix([xc, 0]),
    }
    pts["B"] = pts["C"] + sp.Matrix([l3 * sp.cos(psi), l3 * sp.sin(psi)])
    gx, gy = sp.Float(p.g[0]), sp.Float(p.g[1])
    n = 3
    M = sp.zeros(n, n)
    c = sp.zeros(n, 1)
    Qg = sp.zeros(n, 1)

    def convective(r):
        """(J, J̇ż) of a vector r(z): the velocity's Jacobian and the acceleration at z̈ = 0."""
        J = r.jacobian(z)
        return J, (J * zd).jacobian(z) * zd

    for _name, m, inertia, origin, toward, a, b, length in p.bodies:
        m, inertia = sp.Float(m), sp.Float(inertia)
        po = pts[origin]
        if toward is None:
            G = po + sp.Matrix([a, b])
        else:
            r = pts[toward] - po
            al, be = sp.Float(a / length), sp.Float(b / length)
            G = po + al * r + be * sp.Matrix([-r[1], r[0]])
            # the body's angle θ = atan2(r_y, r_x): ∂θ/∂z and the convective θ̈
            r2 = r[0] ** 2 + r[1] ** 2
            Jr = r.jacobian(z)
            Jth = (r[0] * Jr[1, :] - r[1] * Jr[0, :]) / r2
            thd = (Jth * zd)[0]
            th2 = (sp.Matrix([thd]).jacobian(z) * zd)[0]
            if inertia != 0:
                M += inertia * Jth.T * Jth
                c += inertia * Jth.T * th2
        JG, aG = convective(G)
        M += m * JG.T * JG
        c += m * JG.T * aG
        Qg += m * JG.T * sp.Matrix([gx, gy])
    F = Qg - c
    rab = pts["B"] - pts["A"]
    g = sp.Matrix([rab[0] ** 2 + rab[1] ** 2 - l2**2])
    G = g.jacobian(z)
    gam = ((G * zd).jacobian(z) * zd)[0]
    out = [M[0, 0], M[0, 1], M[0, 2], M[1, 1], M[1, 2], M[2, 2], F[0], F[1], F[2], G[0], G[1], G[2], gam]
    return sp.lambdify((phi, psi, xc, phid, psid, xcd), out, modules="math", cse=True)


def exact_model(scene) -> ExactPress:
    """The exact model of a scene (the symbolic derivation is kept per parameter set)."""
    return ExactPress(scene)


@dataclass
class PeerRun:
    """A run of the peer: the trajectory on a grid, its cost and its work."""

    t: np.ndarray
    phi: np.ndarray
    phi_dot: np.ndarray
    phi_ddot: np.ndarray
    cpu: float  # seconds of CPU for the integration and φ̈ at the outputs (derivation
    #                     excluded)
    nfev: int  # right-hand sides
    closure: float  # max | |B − A| − l2 | on the grid (m)
    dense: object = None


def run_peer(
    scene,
    t_end: float,
    t_eval,
    rtol: float,
    atol: float | None = None,
    dense: bool = False,
    model: ExactPress | None = None,
) -> PeerRun:
    """Integrate the exact model with DOP853 to ``t_end``; φ, φ̇, φ̈ at ``t_eval``.

    ``atol`` (default rtol·1e-3) is in radians for the angles and their rates, scaled by l1 for
    x_C and its rate."""
    model = model or exact_model(scene)
    atol = rtol * 1e-3 if atol is None else atol
    y0 = model.initial_state()
    t_eval = np.asarray(t_eval, float)
    c0 = time.process_time()
    sol = solve_ivp(
        model.rhs,
        (0.0, float(t_end)),
        y0,
        method="DOP853",
        rtol=rtol,
        atol=atol * model.atol_scale,
        t_eval=t_eval,
        dense_output=dense,
    )
    if not sol.success:
        raise RuntimeError(f"peer integration failed: {sol.message}")
    Y = sol.y
    # φ̈ at the outputs is part of what a run reports (ours evaluate the equations there)
    acc = np.array([model.accelerations(Y[:, k])[0] for k in range(Y.shape[1])])
    cpu = time.process_time() - c0
    return PeerRun(
        sol.t,
        Y[0],
        Y[3],
        acc,
        cpu,
        int(sol.nfev),
        float(np.abs(model.closure(Y)).max()),
        sol.sol if dense else None,
    )
