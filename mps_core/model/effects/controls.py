"""The machine's control state: what the operator's commands and the structure switch on and off.

One :class:`Controls` object is shared by a run's driver (which changes it at commands and
structure events) and the effects that depend on it (cylinders, latch, technological load).
"""

from __future__ import annotations

from dataclasses import dataclass

from .base import Watched


@dataclass
class Controls(Watched):
    structure: str = "free"
    motor_on: bool = True
    #: the engage cylinder is pressurised (engage command until disengage)
    engage_on: bool = False
    #: the latch catches the rocker when it reaches psi_lock
    latch_armed: bool = False
    #: time of the last disengage command (the disengage cylinder acts from then)
    disengage_at: float | None = None
    #: the disengage cylinder is acting (from a disengage command for its duration: the driver
    #: switches it off at a step boundary, so that no step straddles the jump in its torque)
    disengage_on: bool = False


class ControlledEffect:
    """Mixin: an effect that reads the shared controls (set by the driver through ``use``)."""

    controls: Controls = None  # type: ignore[assignment]

    def use(self, controls: Controls) -> None:
        self.controls = controls
        for version in self.__dict__.get("_watchers") or ():  # who watches the effect
            controls.watch(version)
