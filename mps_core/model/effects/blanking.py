"""The technological load: blanking a part near the bottom of the stroke, only when locked.

The punch (on the slider) touches the part at ``x_contact`` moving down; with penetration
p = x_contact − x_C the force rises and falls as ``F_max·sin(π·p / p_b)`` until breakthrough at
``p_b = breakthrough·thickness`` (a smooth stand-in for the measured blanking curve, whose peak is
the shear force L·t·τ). The slider receives +F (up); the die on the bed receives −F, so the force
closes inside the press frame. Acts only while the slider moves down in ``locked``.
"""

from __future__ import annotations

import math

from ...derivatives.tracing import sin
from .base import Effect, Loads, along_x
from .controls import ControlledEffect


class Blanking(ControlledEffect, Effect):
    kind = "blanking"

    def __init__(
        self, peak_force: float, x_contact: float, thickness: float, breakthrough: float = 0.5, name=None
    ):
        super().__init__(name)
        self.f = float(peak_force)
        self.x_contact = float(x_contact)
        self.pb = float(breakthrough) * float(thickness)
        self.acts_on = ("slider",)

    def force(self, x: float, v: float) -> float:
        p = self.x_contact - x
        if v >= 0.0 or p <= 0.0 or p >= self.pb:
            return 0.0
        return self.f * sin(math.pi * p / self.pb)

    def loads(self, t, kin) -> Loads:
        if self.controls.structure != "locked":
            return Loads()
        f = self.force(kin.xy("C")[0], kin.vxy("C")[0])
        if f == 0.0:
            return Loads()
        return Loads(forces=[("slider", "C", f, 0.0)], frame=[("frame", "C", -f, 0.0)])

    #: the punch touches the part (p = 0), breaks through (p = p_b), the slider turns (v = 0:
    #: the force drops to nothing if it turns inside the part)
    switches = ("contact", "breakthrough", "turn")

    def switch_values(self, t, kin) -> list:
        if self.controls.structure != "locked":
            return [1.0, 1.0, 1.0]
        p = self.x_contact - kin.xy("C")[0]
        return [p, p - self.pb, kin.vxy("C")[0]]

    def generalized_force(self, t, kin):
        if self.controls.structure != "locked":
            return None
        f = self.force(kin.xy("C")[0], kin.vxy("C")[0])
        return None if f == 0.0 else along_x(f, kin, "C")
