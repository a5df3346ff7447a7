"""A press's measurements and mode signals read out of a recording, for ``mps track``.

    mps track SCENE --recording FILE.mcap|BAG [--joints-topic TOPIC] [--mode-topic TOPIC]

The press's sensors as the node following a press takes them (``-p track:=TOPIC``): a
``sensor_msgs/JointState`` topic (:data:`JOINTS_TOPIC` unless named), the crank angle the
position of the joint ``crank`` (or the only position of a message that names no joint), the
slider's the joint ``slider``'s, at the header's stamp; the mode signals (``engage``,
``disengage``) on a ``std_msgs/String`` topic (:data:`MODE_TOPIC` where recorded, unless named),
each at its log time. They are taken in the recording's order, as the node took them live: a
mode signal between the measurements it came between. A node's recording (it records what it
received under the topics it subscribed to) tracked again gives the node's estimates
(``tests/ros/test_track_recording_input.py``): the node records the parameters it followed
with (its encoder, torque sensor, timeout, jump and the signals' latency, :class:`Tuning`) in
the recording's ``mps`` metadata, and they are read back from there (the node's defaults where
a recording has none). A measurement the tracker rejects (a jump, a duplicate, out of
order, not finite) is handed to it as recorded: it rejects and counts it, as the node did.

The core knows no recording format: the reader registered under the format's name in the
entry-point group :data:`~mps_core.plugins.TRACK_READERS` reads it (``mcap`` for an ``.mcap``
file, ``bag`` for a bag directory), as :mod:`~mps_core.track.recording` hands a tracked run
to a writer.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import MpsError
from ..plugins import TRACK_READERS, track_plugin
from .measurements import Encoder, Measurement, MeasurementError, ModeSignal, TorqueSensor
from .settings import TrackSettings

__all__ = [
    "JOINTS_TOPIC",
    "MODE_TOPIC",
    "SLIDER_VARIANCE",
    "RecordedInputs",
    "RecordedTopics",
    "RecordingReaderMissing",
    "Tuning",
    "in_time_order",
    "read_recording_inputs",
    "recording_format",
    "recording_variances",
    "split_inputs",
]

#: the measurements' topic unless named: what the emulator publishes and the node follows
JOINTS_TOPIC = "/press/joint_states"
#: the mode signals' topic unless named (read where the recording has it)
MODE_TOPIC = "/press/mode"
#: a slider scale's variance (m²) unless told: 1 µm of noise and 1 µm resolution, the
#: emulated press's scale (:class:`~mps_core.track.truth.Sensors`) and the node's default
SLIDER_VARIANCE = 1e-12 + 1e-12 / 12.0

#: one input of the tracker: a measurement or a mode signal
Input = Measurement | ModeSignal


@dataclass(frozen=True)
class RecordedTopics:
    """The topics a press's inputs are read from.

    ``joints``: the measurements (``sensor_msgs/msg/JointState``); ``mode``: the mode signals
    (``std_msgs/msg/String``; None: none); ``mode_required``: a ``mode`` topic the recording
    lacks is an error (it was named), else there are no mode signals.
    """

    joints: str = JOINTS_TOPIC
    mode: str | None = MODE_TOPIC
    mode_required: bool = False


@dataclass(frozen=True)
class Tuning:
    """The sensors' noise and the tracker's thresholds a press was followed with.

    The node's parameters ``track_encoder_bits``, ``track_encoder_noise``,
    ``track_torque_noise``, ``track_timeout``, ``track_max_jump`` (degrees) and
    ``track_signal_latency`` (0 where no mode topic was given), recorded under those names in
    the ``mps`` metadata record; None where a recording has none (the defaults then).
    """

    encoder: Encoder = field(default_factory=Encoder)
    torque: TorqueSensor = field(default_factory=TorqueSensor)
    timeout: float | None = None
    max_jump_deg: float | None = None
    signal_latency: float | None = None

    def metadata(self) -> dict[str, str]:
        """Return the ``mps`` metadata that records it (the values given, as text)."""
        out = {
            "track_encoder_bits": str(self.encoder.bits),
            "track_encoder_noise": repr(float(self.encoder.noise_counts)),
            "track_torque_noise": repr(float(self.torque.relative)),
        }
        for key, value in (
            ("track_timeout", self.timeout),
            ("track_max_jump", self.max_jump_deg),
            ("track_signal_latency", self.signal_latency),
        ):
            if value is not None:
                out[key] = repr(float(value))
        return out

    @classmethod
    def of(cls, meta: Mapping[str, str], where: str) -> Tuning:
        """Return the tuning a recording's ``mps`` metadata records (``where``: the recording, for errors)."""

        def number(key: str, lo: float, hi: float) -> float | None:
            text = meta.get(key)
            if text is None:
                return None
            try:
                value = float(text)
            except ValueError:
                value = math.nan
            if not lo <= value <= hi:
                raise MeasurementError(
                    f"{where}: metadata mps.{key}", text, f"a number from {lo:g} to {hi:g}"
                )
            return value

        bits = number("track_encoder_bits", 8, 32)
        if bits is not None and bits != int(bits):
            raise MeasurementError(
                f"{where}: metadata mps.track_encoder_bits", bits, "an integer from 8 to 32"
            )
        noise = number("track_encoder_noise", 0.0, 1e3)
        torque = number("track_torque_noise", 1e-6, 1.0)
        default = Encoder()
        return cls(
            encoder=Encoder(
                default.bits if bits is None else int(bits),
                default.noise_counts if noise is None else noise,
            ),
            torque=TorqueSensor() if torque is None else TorqueSensor(torque),
            timeout=number("track_timeout", 1e-3, 3600.0),
            max_jump_deg=number("track_max_jump", 0.1, 180.0),
            signal_latency=number("track_signal_latency", 0.0, 0.1),
        )

    def settings(self, **given: Any) -> TrackSettings:
        """Return a tracker's settings with this tuning's timeout, jump and signals' latency.

        Where it has them; ``given`` (any :class:`TrackSettings` field) over them.
        """
        own: dict[str, Any] = {}
        if self.timeout is not None:
            own["timeout"] = self.timeout
        if self.max_jump_deg is not None:
            own["max_jump"] = math.radians(self.max_jump_deg)
        if self.signal_latency is not None:
            own["signal_latency"] = self.signal_latency
        return TrackSettings(**(own | given))

    def variances(self) -> dict[str, float]:
        """Return the variances of the recording's measurements by kind (the torque's: :attr:`torque`)."""
        return recording_variances(self.encoder)


class RecordedInputs(list):
    """A recording's measurements and mode signals, in its order, and the :class:`Tuning` it records."""

    def __init__(self, inputs: Iterable[Input] = (), tuning: Tuning | None = None) -> None:
        super().__init__(inputs)
        self.tuning = tuning or Tuning()


class RecordingReaderMissing(MpsError, ValueError):
    """No installed package reads a press's measurements out of recordings of the format given."""


def recording_variances(encoder: Encoder | None = None) -> dict[str, float]:
    """Return the variances of a recording's measurements by kind, as the node takes them.

    The encoder's (17 bits, 0.3 counts of noise unless given) and :data:`SLIDER_VARIANCE`.
    """
    return {"crank_angle": (encoder or Encoder()).variance, "slider_position": SLIDER_VARIANCE}


def recording_format(path: str | Path) -> str:
    """Return the format of a recording by its path: ``bag`` (a directory) or ``mcap`` (``.mcap``)."""
    p = Path(path)
    if p.is_dir():
        return "bag"
    if p.suffix.lower() == ".mcap":
        return "mcap"
    if not p.exists():
        raise MeasurementError("--recording", str(path), "an .mcap file or a bag directory that exists")
    raise MeasurementError("--recording", str(path), "an .mcap file or a bag directory")


def read_recording_inputs(path: str | Path, topics: RecordedTopics | None = None) -> RecordedInputs:
    """Return the measurements and mode signals of a recording, in its order, with its tuning.

    Read by the reader registered for its format (:func:`recording_format`), with the
    variances of the :class:`Tuning` the recording records.
    """
    fmt = recording_format(path)
    read = track_plugin(
        TRACK_READERS,
        fmt,
        f"--recording {str(path)!r}",
        "reads",
        RecordingReaderMissing,
        "give the measurements as CSV (--csv FILE)",
    )
    return read(Path(path), topics or RecordedTopics())


def in_time_order(measurements: Sequence[Measurement], modes: Iterable[ModeSignal]) -> list[Input]:
    """Return measurements and mode signals as one sequence, as a measurements file is taken.

    Each mode signal before the first measurement at or after its stamp; those after the last
    measurement left out (the tracker has no estimate after it).
    """
    out: list[Input] = []
    pending = sorted(modes, key=lambda s: s.t)
    for m in measurements:
        while pending and pending[0].t <= m.t:
            out.append(pending.pop(0))
        out.append(m)
    return out


def split_inputs(inputs: Iterable[Input]) -> tuple[list[Measurement], list[ModeSignal]]:
    """Return the measurements and the mode signals of ``inputs``, each in its order."""
    measurements: list[Measurement] = []
    modes: list[ModeSignal] = []
    for x in inputs:
        if isinstance(x, ModeSignal):
            modes.append(x)
        else:
            measurements.append(x)
    return measurements, modes
