"""Friction in the joints and the guide: smoothed Coulomb plus viscous.

A joint between bodies i and j with relative rate ω = ω_j − ω_i receives
``M = −(M_c·tanh(ω/ω_s) + c·ω)`` on j and −M on i (the frame for the crank bearing O). The
guide gives the slider ``F = −(F_c·tanh(v/v_s) + c·v)`` along x, the frame −F. The Coulomb parts
are load-independent constants (a scene states them), smoothed over ω_s, v_s.
"""

from __future__ import annotations

from ...derivatives.tracing import tanh
from .base import Effect, Loads, along_x

#: joint: (body on one side or "frame", body on the other side)
JOINTS = {"O": ("frame", "crank"), "A": ("crank", "rod"), "B": ("rod", "rocker"), "C": ("rocker", "slider")}


class JointFriction(Effect):
    kind = "joint_friction"

    def __init__(
        self,
        coulomb: float,
        viscous: float,
        rate_smooth: float = 0.05,
        joints=("O", "A", "B", "C"),
        name=None,
    ):
        super().__init__(name)
        self.mc = float(coulomb)
        self.c = float(viscous)
        self.ws = float(rate_smooth)
        self.joints = tuple(joints)
        self.acts_on = tuple(sorted({b for j in self.joints for b in JOINTS[j]} - {"frame"}))

    def loads(self, t, kin) -> Loads:
        torques, frame = [], []
        for j in self.joints:
            a, b = JOINTS[j]
            w = kin.rate(b) - (0.0 if a == "frame" else kin.rate(a))
            m = -(self.mc * tanh(w / self.ws) + self.c * w)
            torques.append((b, m))
            if a == "frame":
                frame.append(("frame", -m))
            else:
                torques.append((a, -m))
        return Loads(torques=torques, frame=frame)


class GuideFriction(Effect):
    kind = "guide_friction"

    def __init__(self, coulomb: float, viscous: float, speed_smooth: float = 1e-3, name=None):
        super().__init__(name)
        self.fc = float(coulomb)
        self.c = float(viscous)
        self.vs = float(speed_smooth)
        self.acts_on = ("slider",)

    def loads(self, t, kin) -> Loads:
        f = self.force(kin.vxy("C")[0])
        return Loads(forces=[("slider", "C", f, 0.0)], frame=[("frame", "C", -f, 0.0)])

    def force(self, v: float) -> float:
        return -(self.fc * tanh(v / self.vs) + self.c * v)

    def generalized_force(self, t, kin) -> list:
        return along_x(self.force(kin.vxy("C")[0]), kin, "C")
