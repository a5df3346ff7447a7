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
    (:mod:`mps_core.jet`): the Jacobians give A, and the second directional derivative along q̇
    gives the velocity terms directly, h = Σ_b m_b J_Gᵀ (J̇_G q̇) + J_b ω*_b θ̈_b|q̈=0, which equals
    Σ_jk (A_ij,k − ½A_jk,i) q̇_j q̇_k identically.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .errors import ChartDomainError, NumericalError, config_in_degrees
from .jet import Jet, seed
from .mechanism import ChartView, Mechanism

SCHEMES = ("central", "autodiff")


@lru_cache(maxsize=None)
def stencil(n: int):
    """Offsets (in units of Δ) of the central-difference stencil for n coordinates.

    Returns ``(offsets, plus, minus)``: ``offsets`` is (S, n); for each base point
    b ∈ [q, q+Δe_1, q−Δe_1, …, q+Δe_n, q−Δe_n] and coordinate i, ``plus[b, i]`` and
    ``minus[b, i]`` index the stencil points b ± Δe_i.
    """
    eye = np.eye(n, dtype=int)
    pts = [tuple([0] * n)]
    for i in range(n):
        pts += [tuple(eye[i]), tuple(-eye[i])]
    for i in range(n):
        pts += [tuple(2 * eye[i]), tuple(-2 * eye[i])]
    for i in range(n):
        for j in range(i + 1, n):
            for si in (1, -1):
                for sj in (1, -1):
                    pts.append(tuple(si * eye[i] + sj * eye[j]))
    index = {p: k for k, p in enumerate(pts)}
    bases = [np.zeros(n, dtype=int)]
    for i in range(n):
        bases += [eye[i], -eye[i]]
    plus = np.array([[index[tuple(b + eye[i])] for i in range(n)] for b in bases])
    minus = np.array([[index[tuple(b - eye[i])] for i in range(n)] for b in bases])
    return np.array(pts, dtype=float), plus, minus


class Kinematics:
    """Positions, velocity analogs and velocities at one configuration, by name.

    Points are the mechanism's points and the centres of mass ``G_<body>``.
    """

    __slots__ = ("t", "q", "qd", "names", "X", "J", "W", "bodies", "_omega_index")

    def __init__(self, t, q, qd, names, X, J, W, bodies):
        self.t = t
        self.q = q
        self.qd = qd
        self.names = names          # {point name: row}
        self.X = X                  # (NP, 2) positions
        self.J = J                  # (NP, 2, n) velocity analogs
        self.W = W                  # (nbody, n) angular analogs (zero rows: translating bodies)
        self.bodies = bodies        # {body name: row}

    def position(self, point: str) -> np.ndarray:
        return self.X[self.names[point]]

    def analog(self, point: str) -> np.ndarray:
        return self.J[self.names[point]]

    def velocity(self, point: str) -> np.ndarray:
        return self.J[self.names[point]] @ self.qd

    def angular_analog(self, body: str) -> np.ndarray:
        return self.W[self.bodies[body]]

    def rate(self, body: str) -> float:
        return float(self.W[self.bodies[body]] @ self.qd)

    @property
    def pose(self) -> dict:
        return {k: (self.X[i, 0], self.X[i, 1]) for k, i in self.names.items()}


@dataclass
class Evaluation:
    """One evaluation of the equations of motion at (t, q, q̇) in a chart view."""

    view: ChartView
    t: float
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    A: np.ndarray
    h: np.ndarray
    Q: np.ndarray
    kin: Kinematics

    @property
    def kinetic_energy(self) -> float:
        return 0.5 * float(self.qd @ self.A @ self.qd)


class PartialSystems:
    """The engine: evaluates q̈ for a mechanism, its scene's effects and a derivative scheme.

    Counts its work in ``counts``: ``evaluations`` (right-hand sides), ``position_calls``
    (vectorised calls of a chart's position function) and ``position_points`` (configurations
    evaluated: the stencil size for ``central``, one jet for ``autodiff``).
    """

    def __init__(self, mechanism: Mechanism, effects=(), scheme: str = "central",
                 delta: float = math.radians(0.1)):
        if scheme not in SCHEMES:
            raise ValueError(f"derivative scheme {scheme!r}: expected one of {', '.join(SCHEMES)}")
        if not (delta > 0.0 and math.isfinite(delta)):
            raise ValueError(f"virtual displacement delta = {delta!r}: expected a positive number")
        self.mechanism = mechanism
        self.effects = list(effects)
        for e in self.effects:
            e.bind(mechanism)
        self.scheme = scheme
        self.delta = float(delta)
        self.counts = {"evaluations": 0, "position_calls": 0, "position_points": 0}
        bodies = mechanism.bodies
        self._point_names = list(mechanism.points)
        self._names = {p: k for k, p in enumerate(self._point_names)}
        for b in bodies:
            self._names[f"G_{b.name}"] = len(self._names)
        self._body_index = {b.name: k for k, b in enumerate(bodies)}
        self._mass = np.array([b.mass for b in bodies])
        self._inertia = np.array([b.inertia for b in bodies])
        self._rot = [k for k, b in enumerate(bodies) if b.rotates]
        self._rot_p = np.array([self._names[bodies[k].origin] for k in self._rot], dtype=int)
        self._rot_q = np.array([self._names[bodies[k].toward] for k in self._rot], dtype=int)
        self._com_rows = np.array([self._names[f"G_{b.name}"] for b in bodies], dtype=int)

    # -- public ---------------------------------------------------------------------------
    def evaluate(self, view: ChartView, t: float, q, qd) -> Evaluation:
        q = np.asarray(q, dtype=float)
        qd = np.asarray(qd, dtype=float)
        if self.scheme == "central":
            kin, A, h = self._central(view, t, q, qd)
        else:
            kin, A, h = self._autodiff(view, t, q, qd)
        Q = self.generalized_forces(t, kin)
        try:
            qdd = np.linalg.solve(A, Q - h)
        except np.linalg.LinAlgError:
            qdd = np.full(view.n, np.nan)
        if not np.all(np.isfinite(qdd)):
            raise NumericalError(
                f"the equations of motion have no finite solution in chart {view.name} "
                f"(mass matrix {A.tolist()})", t, self._config(view, q))
        self.counts["evaluations"] += 1
        return Evaluation(view, t, q, qd, qdd, A, h, Q, kin)

    def generalized_forces(self, t: float, kin: Kinematics) -> np.ndarray:
        Q = np.zeros(kin.J.shape[-1])
        for e in self.effects:
            ld = e.loads(t, kin)
            for _body, point, fx, fy in ld.forces:
                J = kin.J[kin.names[point]]
                Q += fx * J[0] + fy * J[1]
            for body, m in ld.torques:
                Q += m * kin.W[kin.bodies[body]]
        return Q

    def potential_energy(self, kin: Kinematics) -> float:
        return float(sum(e.potential(kin) for e in self.effects if e.conservative))

    def kinematics(self, view: ChartView, t: float, q, qd) -> Kinematics:
        """Positions and analogs alone (no forces, no solve), in the engine's scheme."""
        q = np.asarray(q, dtype=float)
        qd = np.asarray(qd, dtype=float)
        if self.scheme == "central":
            return self._central(view, t, q, qd, want_mass=False)[0]
        return self._autodiff(view, t, q, qd, want_mass=False)[0]

    # -- the schemes ----------------------------------------------------------------------
    def _stack(self, pose, shape):
        """(NP, 2, ...) array of the named points and the centres of mass."""
        rows = []
        for p in self._point_names:
            x, y = pose[p]
            rows.append((np.broadcast_to(x, shape), np.broadcast_to(y, shape)))
        for b in self.mechanism.bodies:
            gx, gy = b.com_of(pose)
            rows.append((np.broadcast_to(gx, shape), np.broadcast_to(gy, shape)))
        return np.array(rows, dtype=float)

    def _central(self, view, t, q, qd, want_mass=True):
        n = view.n
        offsets, plus, minus = stencil(n)
        d = self.delta * view.scales
        pts = q + offsets * d
        pose = view.positions([pts[:, i] for i in range(n)])
        self.counts["position_calls"] += 1
        self.counts["position_points"] += len(pts)
        X = self._stack(pose, (len(pts),))                      # (NP, 2, S)
        if not np.all(np.isfinite(X)):
            raise ChartDomainError(view.name, "a stencil point has no real configuration")
        V = (X[:, :, plus] - X[:, :, minus]) / (2.0 * d)        # (NP, 2, nbase, n)
        nbody = len(self._mass)
        W = np.zeros((nbody, plus.shape[0], n))
        if self._rot:
            base = np.array([0] + [k for i in range(n) for k in (1 + 2 * i, 2 + 2 * i)])
            R = X[self._rot_q][:, :, base] - X[self._rot_p][:, :, base]   # (nrot, 2, nbase)
            VR = V[self._rot_q] - V[self._rot_p]                          # (nrot, 2, nbase, n)
            r2 = R[:, 0] ** 2 + R[:, 1] ** 2
            W[self._rot] = (R[:, 0, :, None] * VR[:, 1] - R[:, 1, :, None] * VR[:, 0]) / r2[..., None]
        kin = Kinematics(t, q, qd, self._names, X[:, :, 0], V[:, :, 0, :], W[:, 0, :],
                         self._body_index)
        if not want_mass:
            return kin, None, None
        VG = V[self._com_rows]                                   # (nbody, 2, nbase, n)
        Ab = (np.einsum("b,bkci,bkcj->cij", self._mass, VG, VG)
              + np.einsum("b,bci,bcj->cij", self._inertia, W, W))
        A = Ab[0]
        dA = (Ab[1::2] - Ab[2::2]) / (2.0 * d)[:, None, None]  # dA[k, i, j] = A_ij,k
        h = (np.einsum("kij,j,k->i", dA, qd, qd) - 0.5 * np.einsum("ijk,j,k->i", dA, qd, qd))
        return kin, A, h

    def _autodiff(self, view, t, q, qd, want_mass=True):
        n = view.n
        jets = seed(q, qd)
        pose = view.positions(jets)
        self.counts["position_calls"] += 1
        self.counts["position_points"] += 1
        NP = len(self._names)
        X = np.empty((NP, 2))
        J = np.zeros((NP, 2, n))
        D1 = np.zeros((NP, 2))
        D2 = np.zeros((NP, 2))
        full = dict(pose)
        for b in self.mechanism.bodies:
            full[f"G_{b.name}"] = b.com_of(pose)
        for name, row in self._names.items():
            for k, c in enumerate(full[name]):
                if isinstance(c, Jet):
                    X[row, k] = c.val
                    J[row, k] = c.grad
                    D1[row, k] = c.d1
                    D2[row, k] = c.d2
                else:
                    X[row, k] = c
        if not np.all(np.isfinite(X)) or not np.all(np.isfinite(J)):
            raise ChartDomainError(view.name, "no real configuration at this point")
        nbody = len(self._mass)
        W = np.zeros((nbody, n))
        theta2 = np.zeros(nbody)
        if self._rot:
            R = X[self._rot_q] - X[self._rot_p]
            R1 = D1[self._rot_q] - D1[self._rot_p]
            R2 = D2[self._rot_q] - D2[self._rot_p]
            RJ = J[self._rot_q] - J[self._rot_p]
            r2 = R[:, 0] ** 2 + R[:, 1] ** 2
            W[self._rot] = (R[:, 0, None] * RJ[:, 1] - R[:, 1, None] * RJ[:, 0]) / r2[:, None]
            w1 = (R[:, 0] * R1[:, 1] - R[:, 1] * R1[:, 0]) / r2
            theta2[self._rot] = ((R[:, 0] * R2[:, 1] - R[:, 1] * R2[:, 0]) / r2
                                 - 2.0 * w1 * (R[:, 0] * R1[:, 0] + R[:, 1] * R1[:, 1]) / r2)
        kin = Kinematics(t, q, qd, self._names, X, J, W, self._body_index)
        if not want_mass:
            return kin, None, None
        JG = J[self._com_rows]
        A = (np.einsum("b,bki,bkj->ij", self._mass, JG, JG)
             + np.einsum("b,bi,bj->ij", self._inertia, W, W))
        h = (np.einsum("b,bki,bk->i", self._mass, JG, D2[self._com_rows])
             + np.einsum("b,bi,b->i", self._inertia, W, theta2))
        return kin, A, h

    def _config(self, view, q):
        return config_in_degrees({c.name: float(v) for c, v in zip(view.coordinates, q)})
