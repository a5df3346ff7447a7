"""Retention springs between the frame and the slider, and their damping."""

from __future__ import annotations

from .base import Effect, Loads, along_x, stiffness_x, stiffness_x_bound


class RetentionSprings(Effect):
    """Springs that pull the slider up (+x) toward its top stop.

    Force on the slider at C along x: ``F = F0 + k·(x_top − x_C)`` (the preload F0 at x_top, more
    as the slider goes down); the frame receives −F. Potential
    ``V = F0·(x_top − x_C) + ½k·(x_top − x_C)²``. Generalized stiffness ``k·J_Cxᵀ J_Cx`` (for the
    stability check of fixed-step solvers).
    """

    kind = "springs"
    conservative = True

    def __init__(self, stiffness: float, preload: float, x_top: float, name=None):
        super().__init__(name)
        self.k = float(stiffness)
        self.f0 = float(preload)
        self.x_top = float(x_top)
        self.acts_on = ("slider",)

    def force(self, x: float) -> float:
        return self.f0 + self.k * (self.x_top - x)

    def loads(self, t, kin) -> Loads:
        f = self.force(kin.xy("C")[0])
        return Loads(forces=[("slider", "C", f, 0.0)], frame=[("frame", "C", -f, 0.0)])

    def generalized_force(self, t, kin) -> list:
        return along_x(self.force(kin.xy("C")[0]), kin, "C")

    def potential(self, kin) -> float:
        s = self.x_top - kin.xy("C")[0]
        return self.f0 * s + 0.5 * self.k * s * s

    def stiffness(self, kin) -> list:
        return stiffness_x(self.k, kin, "C")

    def stiffness_bound(self, mechanism) -> float | None:
        return stiffness_x_bound(self.k, mechanism, "C")


class SliderDamper(Effect):
    """Viscous damping of the slider against the frame: ``F = −c·ẋ_C`` (non-conservative)."""

    kind = "damper"

    def __init__(self, damping: float, name=None):
        super().__init__(name)
        self.c = float(damping)
        self.acts_on = ("slider",)

    def loads(self, t, kin) -> Loads:
        f = -self.c * kin.vxy("C")[0]
        return Loads(forces=[("slider", "C", f, 0.0)], frame=[("frame", "C", -f, 0.0)])

    def generalized_force(self, t, kin) -> list:
        return along_x(-self.c * kin.vxy("C")[0], kin, "C")
