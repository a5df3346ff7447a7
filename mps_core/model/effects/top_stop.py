"""The slider's top stop.

``rigid`` (the press preset): no force law; the structure handles it. The slider reaching x_top
moving up is a plastic impact into the ``held`` structure, and leaving it is an event where the
stop's reaction would turn tensile (:mod:`mps_core.run.simulation`).

``clamp``: the slider is clamped at x_top (a bilateral hold): ``held`` never releases, whatever
the reaction. For studies of the idle four-bar itself, e.g. through its change point, where a
one-sided stop cannot hold (the reaction grows without bound as the transmission angle → 0).

``elastic``: a one-sided penalty spring-damper for studies of contact stiffness:
``F = −k·(x_C − x_top) − c·ẋ_C`` on the slider while x_C > x_top (never pulling).
"""

from __future__ import annotations

from .base import Effect, Loads, along_x, stiffness_x, stiffness_x_bound

#: a top stop's models: rigid and clamp hold the slider (the structure ``held``), elastic
#: pushes it back by a contact law
MODELS = ("rigid", "clamp", "elastic")
#: the models with no force law of their own, whose stop the held structure is
HOLDING_MODELS = ("rigid", "clamp")


class TopStop(Effect):
    kind = "top_stop"

    def __init__(
        self, x_top: float, model: str = "rigid", stiffness: float = 0.0, damping: float = 0.0, name=None
    ):
        super().__init__(name)
        self.x_top = float(x_top)
        self.model = model
        self.k = float(stiffness)
        self.c = float(damping)
        self.acts_on = ("slider",)
        self.conservative = model == "elastic" and self.c == 0.0

    @property  # the base's class attribute, here read from the model (which may change)
    def applies_forces(self) -> bool:  # type: ignore[override]
        return not self.rigid

    @property
    def rigid(self) -> bool:
        """No force law: the structure ``held`` does the holding (rigid or clamp)."""
        return self.model in HOLDING_MODELS

    def loads(self, t, kin) -> Loads:
        if self.rigid:
            return Loads()
        f = self.force(kin)
        if f == 0.0:
            return Loads()
        return Loads(forces=[("slider", "C", f, 0.0)], frame=[("frame", "C", -f, 0.0)])

    def force(self, kin) -> float:
        """The force on the slider along x (0 when rigid or out of contact)."""
        if self.rigid:
            return 0.0
        pen = kin.xy("C")[0] - self.x_top
        if pen <= 0.0:
            return 0.0
        return min(-self.k * pen - self.c * kin.vxy("C")[0], 0.0)

    def generalized_force(self, t, kin):
        f = self.force(kin)
        return None if f == 0.0 else along_x(f, kin, "C")

    #: a compliant stop: contact begins (penetration 0), the damper would pull (k·pen + c·v = 0)
    switches = ("contact", "pull")

    def switch_values(self, t, kin) -> list:
        if self.rigid:
            return [1.0, 1.0]
        pen = kin.xy("C")[0] - self.x_top
        return [pen, self.k * pen + self.c * kin.vxy("C")[0]]

    def potential(self, kin) -> float:
        if self.rigid:
            return 0.0
        pen = kin.xy("C")[0] - self.x_top
        return 0.5 * self.k * pen * pen if pen > 0.0 else 0.0

    def stiffness(self, kin) -> list | None:
        if self.rigid or kin.xy("C")[0] <= self.x_top:
            return None
        return stiffness_x(self.k, kin, "C")

    def stiffness_bound(self, mechanism) -> float | None:
        """0 for a rigid stop (no stiffness of its own), else the spring's bound at C."""
        if self.rigid:
            return 0.0
        return stiffness_x_bound(self.k, mechanism, "C")
