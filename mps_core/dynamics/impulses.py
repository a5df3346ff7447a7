"""A plastic impact: the velocity jump on a constraint (:func:`plastic_impact`, contract §5) and
the joints' impulses it takes (:func:`impulses`), from the Newton–Euler system of
:mod:`.newton_euler` with momentum jumps in place of m·a and J·α."""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from ..model.mechanism import ChartView, Mechanism
from .newton_euler import System, active_joints, body_motion, frame_share, length_scale
from .reaction_columns import JOINT_COLUMNS


def plastic_impact(A: np.ndarray, qd_minus, g) -> tuple[np.ndarray, float]:
    """Perfectly plastic impact on a constraint with gradient g (contract §5).

    Returns ``(q̇⁺, λ)`` with ``q̇⁺ = q̇⁻ − A⁻¹g·λ``, ``λ = (gᵀq̇⁻)/(gᵀA⁻¹g)``: the generalized
    impulse is −g·λ and gᵀq̇⁺ = 0.
    """
    qd_minus = np.asarray(qd_minus, dtype=float)
    g = np.asarray(g, dtype=float)
    Ainv_g = np.linalg.solve(A, g)
    lam = float(g @ qd_minus) / float(g @ Ainv_g)
    return qd_minus - Ainv_g * lam, lam


@dataclass
class Impulses:
    """Joint impulses (N·s, N·m·s for moments) of an impact, keyed like the reaction columns
    (``F_O_x`` is the impulse of F_O's x component, same receiving body and sign); the
    foundation's impulse as ``F_found_x``, ``F_found_y``, ``M_found_O``; ``momentum_jump``:
    per body (Δp_x, Δp_y, ΔL about its centre of mass); ``residual`` as :class:`Reactions`;
    ``energy_loss`` (J): the kinetic energy lost, T(q̇⁻) − T(q̇⁺). An impact is instantaneous:
    its duration is 0."""

    t: float
    values: dict
    momentum_jump: dict
    residual: np.ndarray
    unknowns: tuple
    rank: int
    energy_loss: float = math.nan

    def as_event(self, kind: str = "impulse", **extra) -> dict:
        ev = {
            "t": self.t,
            "kind": kind,
            "impulses_Ns": {
                k: v
                for k, v in self.values.items()
                if k in self.unknowns or k.startswith(("F_found", "M_found"))
            },
            "energy_loss_J": self.energy_loss,
            "duration_s": 0.0,
        }
        ev.update(extra)
        return ev


def impulses(
    mechanism: Mechanism,
    view: ChartView,
    q,
    qd_minus,
    qd_plus,
    *,
    closing: Iterable[str] = (),
    t: float = math.nan,
    scale: float | None = None,
) -> Impulses:
    """Per-joint impulses of a velocity jump q̇⁻ → q̇⁺ at configuration q (in ``view``).

    The Newton–Euler system of :func:`compute_reactions` with the bodies' momentum jumps
    ``m Δv_G`` and ``J Δω`` in place of m·a and J·α, and no finite forces (they give no impulse
    in an instant). ``closing`` names the coordinates the impact freezes (``"psi"`` for the
    latch, ``"x_C"`` for the top stop): their joints join the unknowns even though ``view``
    (the state before the impact) does not freeze them yet.
    """
    q = np.asarray(q, dtype=float)
    qd_minus = np.asarray(qd_minus, dtype=float)
    qd_plus = np.asarray(qd_plus, dtype=float)
    dqd = qd_plus - qd_minus
    motion = body_motion(mechanism, view, q, np.zeros_like(q))
    joints = active_joints(mechanism, set(view.frozen) | set(closing))
    sysm = System(mechanism, motion, joints, None)
    rows = motion.com_rows(mechanism)
    dv = motion.J[rows] @ dqd
    dw = motion.W @ dqd
    mass = np.array([b.mass for b in mechanism.bodies])
    inertia = np.array([b.inertia for b in mechanism.bodies])
    b = np.empty(3 * len(mass))
    b[0::3] = mass * dv[:, 0]
    b[1::3] = mass * dv[:, 1]
    b[2::3] = inertia * dw
    u, r, rank = sysm.solve(b, scale if scale is not None else length_scale(mechanism))
    values = {c: 0.0 for c in JOINT_COLUMNS}
    R_F, R_M, _ = frame_share(sysm, u, motion, values)
    values["F_found_x"], values["F_found_y"], values["M_found_O"] = (float(R_F[0]), float(R_F[1]), float(R_M))
    jumps = {
        bd.name: (float(mass[k] * dv[k, 0]), float(mass[k] * dv[k, 1]), float(inertia[k] * dw[k]))
        for k, bd in enumerate(mechanism.bodies)
    }
    JG = motion.J[rows]
    A = np.einsum("b,bki,bkj->ij", mass, JG, JG) + np.einsum("b,bi,bj->ij", inertia, motion.W, motion.W)
    loss = 0.5 * float(qd_minus @ A @ qd_minus - qd_plus @ A @ qd_plus)
    return Impulses(float(t), values, jumps, r, tuple(c for _, _, c in sysm.cols), rank, loss)
