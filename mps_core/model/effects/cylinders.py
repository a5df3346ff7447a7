"""The pneumatic cylinders that switch the press: engage (slider down) and disengage (rocker off
the latch)."""

from __future__ import annotations

from .base import Effect, Loads, along_x
from .controls import ControlledEffect


class EngageCylinder(ControlledEffect, Effect):
    """Pushes the slider down with force F over its stroke below x_top while pressurised.

    Force on the slider ``−F·r`` with r = 1 inside the stroke, falling linearly to 0 over the last
    ``ramp`` metres before the stroke's end (x_top − stroke), so the force stays continuous. The
    cylinder sits on the frame: the frame receives +F·r.
    """

    kind = "engage_cylinder"

    def __init__(self, force: float, stroke: float, x_top: float, ramp: float = 1e-4, name=None):
        super().__init__(name)
        self.f = float(force)
        self.stroke = float(stroke)
        self.x_top = float(x_top)
        self.ramp = float(ramp)
        self.acts_on = ("slider",)

    def loads(self, t, kin) -> Loads:
        f = self.force(kin)
        if f == 0.0:
            return Loads()
        return Loads(forces=[("slider", "C", f, 0.0)], frame=[("frame", "C", -f, 0.0)])

    def force(self, kin) -> float:
        """The force on the slider along x (0 when not pressurised or past the stroke)."""
        if not self.controls.engage_on:
            return 0.0
        x_end = self.x_top - self.stroke
        r = (kin.xy("C")[0] - x_end) / self.ramp
        r = 0.0 if r <= 0.0 else (1.0 if r >= 1.0 else r)
        return -self.f * r if r != 0.0 else 0.0

    def generalized_force(self, t, kin):
        f = self.force(kin)
        return None if f == 0.0 else along_x(f, kin, "C")

    #: the ramp's ends: full force above, none past the stroke
    switches = ("ramp-top", "stroke-end")

    def switch_values(self, t, kin) -> list:
        if not self.controls.engage_on:
            return [1.0, 1.0]
        r = (kin.xy("C")[0] - (self.x_top - self.stroke)) / self.ramp
        return [r - 1.0, r]


class DisengageCylinder(ControlledEffect, Effect):
    """Turns the rocker off the latch: torque −M on the rocker (away from ψ_lock, toward the idle
    swing at ψ < 0) for ``duration`` seconds after a disengage command. It is mounted on the slider,
    which receives +M (taken by the guide).

    Whether it acts is a control (``controls.disengage_on``), not a function of time: the driver
    sets it at the command and clears it ``duration`` later, both at step boundaries, so the
    torque's jumps fall between steps (a step across a jump would see a force that is not smooth
    in t: a fixed-step solver loses its order there, an adaptive one shrinks its step by orders
    of magnitude to get past it)."""

    kind = "disengage_cylinder"

    def __init__(self, torque: float, duration: float, name=None):
        super().__init__(name)
        self.m = float(torque)
        self.duration = float(duration)
        self.acts_on = ("rocker", "slider")

    def active(self, t: float) -> bool:
        """Acting now (``t`` is not read: the driver switches the control at its times)."""
        return self.controls.disengage_on

    def loads(self, t, kin) -> Loads:
        if not self.active(t):
            return Loads()
        return Loads(torques=[("rocker", -self.m), ("slider", self.m)])

    def generalized_force(self, t, kin):
        if not self.active(t):
            return None
        wr, ws = kin.omega("rocker"), kin.omega("slider")
        return [self.m * (b - a) for a, b in zip(wr, ws)]


class Latch(ControlledEffect, Effect):
    """The latch that locks the rocker to the slider at ψ = ψ_lock when armed (by engage).

    It applies no force of its own: closing is a plastic impact into the ``locked`` structure,
    handled by the driver; its moment in ``locked`` is a reaction (mps_core.dynamics.reactions)."""

    kind = "latch"
    applies_forces = False

    def __init__(self, psi_lock: float = 0.0, name=None):
        super().__init__(name)
        self.psi_lock = float(psi_lock)
        self.acts_on = ("rocker", "slider")

    def loads(self, t, kin) -> Loads:
        return Loads()

    def generalized_force(self, t, kin):
        return None
