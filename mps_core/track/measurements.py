"""What a tracker reads: timestamped measurements of a press's sensors and its mode signals.

A measurement is one scalar at its stamp (s, the press's clock): the crank angle (rad, from an
encoder's counts or given in radians), the slider's position along the guide (m, up), the crank
rate (rad/s) or the motor's torque on the crank (N·m, from its current through the drive's
constant). Each carries its variance. An absolute encoder of ``bits`` bits reads
``count = floor(φ mod 2π / LSB)``, LSB = 2π/2^bits; the count's centre is ``(count + ½)·LSB`` and
its quantisation variance LSB²/12 (a uniform error over one count), to which the encoder's
electrical noise adds.

A mode signal is a command the press's controller gives (``engage``, ``disengage``) at its stamp;
the tracker applies it to its model as the simulation applies a scene's command.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import MpsError

__all__ = [
    "KINDS",
    "MODE_COMMANDS",
    "Encoder",
    "Measurement",
    "MeasurementError",
    "ModeSignal",
    "TorqueSensor",
]

#: the measured quantities by name, with their units
KINDS: dict[str, str] = {
    "crank_angle": "rad",
    "slider_position": "m",
    "crank_rate": "rad/s",
    "motor_torque": "N*m",
}

#: the mode signals a press's controller gives
MODE_COMMANDS = ("engage", "disengage")


class MeasurementError(MpsError, ValueError):
    """A measurement or a tracker's setting is malformed: names the field, the value and what
    was expected."""

    def __init__(self, field: str, value: object, expected: str) -> None:
        self.field, self.value, self.expected = field, value, expected
        super().__init__(f"{field} = {value!r}: expected {expected}")


@dataclass(frozen=True)
class Measurement:
    """One scalar measurement: its stamp (s), kind (:data:`KINDS`), value and variance."""

    t: float
    kind: str
    value: float
    variance: float

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise MeasurementError("kind", self.kind, "one of " + ", ".join(KINDS))
        if not (isinstance(self.variance, float | int) and self.variance > 0.0):
            raise MeasurementError(f"{self.kind}.variance", self.variance, "a positive number")


@dataclass(frozen=True)
class ModeSignal:
    """A command of the press's controller at its stamp (s)."""

    t: float
    command: str

    def __post_init__(self) -> None:
        if self.command not in MODE_COMMANDS:
            raise MeasurementError("mode.command", self.command, "one of " + ", ".join(MODE_COMMANDS))
        if not math.isfinite(self.t):
            raise MeasurementError("mode.t", self.t, "a finite time (s)")


@dataclass(frozen=True)
class Encoder:
    """An absolute rotary encoder on the crank: ``bits`` bits a turn, electrical noise of
    ``noise_counts`` counts (1-σ) before quantisation."""

    bits: int = 17
    noise_counts: float = 0.3

    def __post_init__(self) -> None:
        if not (isinstance(self.bits, int) and 8 <= self.bits <= 32):
            raise MeasurementError("encoder.bits", self.bits, "an integer from 8 to 32")
        if not (self.noise_counts >= 0.0 and math.isfinite(self.noise_counts)):
            raise MeasurementError("encoder.noise_counts", self.noise_counts, "a number >= 0 (counts)")

    @property
    def counts(self) -> int:
        """Return the counts in one turn."""
        return 1 << self.bits

    @property
    def lsb(self) -> float:
        """Return one count in radians."""
        return 2.0 * math.pi / self.counts

    @property
    def variance(self) -> float:
        """Return the variance of an angle read from one count (rad²): LSB²/12 + noise²."""
        return self.lsb**2 * (1.0 / 12.0 + self.noise_counts**2)

    def count(self, phi: float, noise: float = 0.0) -> int:
        """Return the count the encoder reads at crank angle ``phi`` (rad), with ``noise``
        (rad) added before quantisation."""
        return int(math.floor((phi + noise) / self.lsb)) % self.counts

    def angle(self, count: int | float) -> float:
        """Return the angle (rad, in [0, 2π)) at the centre of a count."""
        c = float(count)
        if not (math.isfinite(c) and 0.0 <= c < self.counts and c == int(c)):
            raise MeasurementError("crank_angle.count", count, f"an integer count in [0, {self.counts})")
        return (c + 0.5) * self.lsb

    def measurement(self, t: float, count: int | float) -> Measurement:
        """Return the crank-angle measurement of a count at stamp ``t``."""
        return Measurement(float(t), "crank_angle", self.angle(count), self.variance)


@dataclass(frozen=True)
class TorqueSensor:
    """The motor's torque as a drive reports it (from the motor's current through its torque
    constant): a noise of ``relative`` of the reading's magnitude, of 1 N·m's where the reading
    is smaller (a current sensor's accuracy is a share of what it reads)."""

    relative: float = 0.02

    def sigma(self, torque: float) -> float:
        """Return the 1-σ (N·m) of a reading of ``torque`` (N·m)."""
        return self.relative * max(abs(torque), 1.0)

    def variance(self, torque: float) -> float:
        """Return the variance (N·m²) of a reading of ``torque`` (N·m)."""
        return self.sigma(torque) ** 2
