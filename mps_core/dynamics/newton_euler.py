"""The Newton–Euler system of the moving bodies (:mod:`.reactions` narrates it): their exact
kinematics at (q, q̇) from jets (:func:`body_motion`), the joints that carry load in a
structure, ``E u = b`` with one column an unknown and its least-squares solve with the whole
system's balance exact (:class:`System`), the effects' known loads on it
(:func:`external_loads`) and what the frame receives through the joints (:func:`frame_share`).
The reactions (:mod:`.reactions`) and an impact's impulses (:mod:`.impulses`) solve it."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from ..derivatives.jet import Jet
from ..model.mechanism import FRAME, ChartView, Joint, Mechanism
from .engine import Kinematics


# -- exact kinematics from jets -------------------------------------------------------------
def _parts(c, n: int):
    """(value, gradient (n,), first, second directional derivative) of a jet or a constant."""
    if isinstance(c, Jet):
        return (float(c.val), np.asarray(c.grad, dtype=float).reshape(n), float(c.d1), float(c.d2))
    return float(c), np.zeros(n), 0.0, 0.0


@dataclass
class BodyMotion:
    """Exact kinematics of the moving bodies at (q, q̇): everything but q̈.

    ``X``/``J``/``D1``/``D2``: positions, analogs ∂r/∂q, velocities and convective accelerations
    of the points and centres of mass ``G_<body>`` (rows by ``names``); ``W`` (nbody, n): angular
    analogs, ``theta2`` (nbody,): convective angular accelerations (zero for bodies that only
    translate).
    """

    names: dict
    X: np.ndarray
    J: np.ndarray
    D1: np.ndarray
    D2: np.ndarray
    W: np.ndarray
    theta2: np.ndarray
    bodies: dict

    def com_rows(self, mechanism: Mechanism) -> np.ndarray:
        return np.array([self.names[f"G_{b.name}"] for b in mechanism.bodies], dtype=int)

    def kinematics(self, t: float, q, qd) -> Kinematics:
        """The engine's :class:`Kinematics` with exact analogs (for effects' loads)."""
        return Kinematics(
            t, np.asarray(q, float), np.asarray(qd, float), self.names, self.X, self.J, self.W, self.bodies
        )


def body_motion(mechanism: Mechanism, view: ChartView, q, qd) -> BodyMotion:
    """Exact positions, analogs and convective accelerations from one jet evaluation."""
    q = np.asarray(q, dtype=float)
    qd = np.asarray(qd, dtype=float)
    n = view.n
    pose = dict(view.pose_jets(q, qd))
    for b in mechanism.bodies:
        pose[f"G_{b.name}"] = b.com_of(pose)
    names = {p: k for k, p in enumerate(list(mechanism.points) + [f"G_{b.name}" for b in mechanism.bodies])}
    NP = len(names)
    X = np.zeros((NP, 2))
    J = np.zeros((NP, 2, n))
    D1 = np.zeros((NP, 2))
    D2 = np.zeros((NP, 2))
    for name, row in names.items():
        for k, c in enumerate(pose[name]):
            X[row, k], J[row, k], D1[row, k], D2[row, k] = _parts(c, n)
    nb = len(mechanism.bodies)
    W = np.zeros((nb, n))
    theta2 = np.zeros(nb)
    for k, b in enumerate(mechanism.bodies):
        if b.toward is None:  # translates only
            continue
        o, t = names[b.origin], names[b.toward]
        r, rj = X[t] - X[o], J[t] - J[o]
        r1, r2v = D1[t] - D1[o], D2[t] - D2[o]
        rr = float(r @ r)
        W[k] = (r[0] * rj[1] - r[1] * rj[0]) / rr
        w1 = (r[0] * r1[1] - r[1] * r1[0]) / rr
        theta2[k] = (r[0] * r2v[1] - r[1] * r2v[0]) / rr - 2.0 * w1 * float(r @ r1) / rr
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(J))):
        raise ValueError(f"reactions: no finite kinematics in chart {view.name} at q = {q.tolist()}")
    return BodyMotion(names, X, J, D1, D2, W, theta2, {b.name: k for k, b in enumerate(mechanism.bodies)})


# -- the system -----------------------------------------------------------------------------
def active_joints(mechanism: Mechanism, frozen: Iterable[str]) -> list[Joint]:
    """The joints that carry load in a structure with these frozen coordinates."""
    frozen = set(frozen)
    joints = mechanism.joints
    return [j for j in joints if j.requires is None or j.requires in frozen]


def length_scale(mechanism: Mechanism) -> float:
    """L (m) dividing the moment rows in the least squares: mean length of the rotating links."""
    lengths = [b.length for b in mechanism.bodies if b.rotates and b.length > 0]
    return float(np.mean(lengths)) if lengths else 1.0


class System:
    """E u = b: 3 rows a moving body (Fx, Fy, M about its centre of mass), one column an unknown."""

    def __init__(self, mechanism: Mechanism, motion: BodyMotion, joints: Sequence[Joint], drive: str | None):
        self.mechanism = mechanism
        self.motion = motion
        self.body_row = {b.name: 3 * k for k, b in enumerate(mechanism.bodies)}
        self.G = motion.X[motion.com_rows(mechanism)]
        self.origin = motion.X[motion.names["O"]] if "O" in motion.names else np.zeros(2)
        cols: list[tuple[Joint | None, str, str]] = []
        for j in joints:
            for comp, col in zip(j.components, j.columns):
                cols.append((j, comp, col))
        if drive is not None:
            if drive not in self.body_row:
                raise ValueError(
                    f"reactions: drive = {drive!r}: expected a moving body, one of "
                    + ", ".join(self.body_row)
                )
            cols.append((None, "m", "M_drive"))
        self.cols = cols
        self.drive = drive
        nrow = 3 * len(mechanism.bodies)
        E = np.zeros((nrow, len(cols)))
        for c, (joint, comp, _col) in enumerate(cols):
            if joint is None:  # the drive: its body receives +M, the frame −M
                assert drive is not None  # (its column is there only with a drive)
                E[self.body_row[drive] + 2, c] += 1.0
                continue
            for body, sign in ((joint.receiver, 1.0), (joint.giver, -1.0)):
                if body == FRAME:
                    continue
                self._add(E[:, c], body, comp, joint.point, sign)
        self.E = E
        # whole-system balance (Σ force x, Σ force y, Σ moment about O) as rows on the residual
        C = np.zeros((3, nrow))
        for k in range(len(mechanism.bodies)):
            r0 = 3 * k
            g = self.G[k] - self.origin
            C[0, r0] = 1.0
            C[1, r0 + 1] = 1.0
            C[2, r0] = -g[1]
            C[2, r0 + 1] = g[0]
            C[2, r0 + 2] = 1.0
        self.C = C

    def _add(self, col: np.ndarray, body: str, comp: str, point: str | None, sign: float):
        r0 = self.body_row.get(body)
        if r0 is None:
            raise ValueError(f"reactions: joint body {body!r} is not a body of the mechanism")
        if comp == "m":
            col[r0 + 2] += sign
            return
        d = self.motion.X[self.motion.names[point]] - self.G[r0 // 3]
        if comp == "x":
            col[r0] += sign
            col[r0 + 2] += -sign * d[1]
        else:
            col[r0 + 1] += sign
            col[r0 + 2] += sign * d[0]

    def solve(self, b: np.ndarray, scale: float):
        """Least squares in newtons (moment rows / scale) with the whole-system balance exact."""
        E, C = self.E, self.C
        s = np.ones(len(b))
        s[2::3] = 1.0 / scale
        K = C @ E
        U, sv, Vt = np.linalg.svd(K)
        tol = max(K.shape) * np.finfo(float).eps * (sv[0] if sv.size else 0.0)
        rk = int(np.sum(sv > tol))
        d = C @ b
        up = Vt[:rk].T @ ((U[:, :rk].T @ d) / sv[:rk])
        N = Vt[rk:].T
        u = up
        rz = 0
        if N.shape[1]:
            M = s[:, None] * (E @ N)
            z, _res, rz, _sv = np.linalg.lstsq(M, s * (b - E @ up), rcond=None)
            u = up + N @ z
        return u, b - E @ u, rk + int(rz)


def external_loads(mechanism, effects, t, kin, motion: BodyMotion, G: np.ndarray):
    """Known loads: per body (Fx, Fy, M about G), their sums about O, the frame's own entries,
    and the motor torque."""
    nb = len(mechanism.bodies)
    index = motion.bodies
    ext = np.zeros((nb, 3))
    frame_F = np.zeros(2)
    frame_M = 0.0
    ext_M_O = 0.0
    m_motor = 0.0
    for e in effects:
        ld = e.loads(t, kin)
        for body, point, fx, fy in ld.forces:
            k = index.get(body)
            if k is None:
                raise ValueError(
                    f"effect {e.name!r}: force on {body!r}, expected a moving body "
                    f"({', '.join(index)}); the frame's share belongs in Loads.frame"
                )
            p = _point(motion, point, e.name)
            ext[k, 0] += fx
            ext[k, 1] += fy
            ext[k, 2] += (p[0] - G[k, 0]) * fy - (p[1] - G[k, 1]) * fx
            ext_M_O += p[0] * fy - p[1] * fx
        for body, m in ld.torques:
            k = index.get(body)
            if k is None:
                raise ValueError(
                    f"effect {e.name!r}: torque on {body!r}, expected a moving body ({', '.join(index)})"
                )
            ext[k, 2] += m
            ext_M_O += m
            if getattr(e, "kind", "") == "motor":
                m_motor += m
        for entry in ld.frame:
            if len(entry) == 4:
                _, point, fx, fy = entry
                p = _point(motion, point, e.name)
                frame_F += (fx, fy)
                frame_M += p[0] * fy - p[1] * fx
            elif len(entry) == 2:
                frame_M += entry[1]
            else:
                raise ValueError(
                    f"effect {e.name!r}: frame entry {entry!r}: expected "
                    "('frame', point, Fx, Fy) or ('frame', M)"
                )
    return ext, ext_M_O, frame_F, frame_M, m_motor


def _point(motion: BodyMotion, point, effect: str) -> np.ndarray:
    """A load's point relative to O: a mechanism point's name, ``G_<body>``, or (x, y) in m."""
    o = motion.X[motion.names["O"]] if "O" in motion.names else np.zeros(2)
    if isinstance(point, str):
        row = motion.names.get(point)
        if row is None:
            raise ValueError(
                f"effect {effect!r}: point {point!r}: expected one of "
                + ", ".join(motion.names)
                + " or coordinates (x, y) in m"
            )
        return motion.X[row] - o
    p = np.asarray(point, dtype=float)
    if p.shape != (2,):
        raise ValueError(f"effect {effect!r}: point {point!r}: expected a name or (x, y) in m")
    return p - o


def frame_share(sysm, u, motion, values) -> tuple[np.ndarray, float, float]:
    """Put each solved unknown into ``values`` and sum what the frame receives through the
    joints: (force, moment about the system's origin, drive torque solved as an unknown)."""
    R_F = np.zeros(2)
    R_M = 0.0
    drive = 0.0
    o = sysm.origin
    for (j, comp, col), val in zip(sysm.cols, u):
        if j is None:
            drive += val
            continue
        values[col] = float(val)
        sign = 1.0 if j.receiver == FRAME else (-1.0 if j.giver == FRAME else 0.0)
        if sign == 0.0:
            continue
        if comp == "m":
            R_M += sign * val
            continue
        f = np.array([val, 0.0] if comp == "x" else [0.0, val]) * sign
        p = motion.X[motion.names[j.point]] - o
        R_F += f
        R_M += p[0] * f[1] - p[1] * f[0]
    return R_F, R_M, drive
