"""What a recording of a tracked run holds, gathered as the tracker goes.

It is handed to the package that writes recordings.

``mps track --out FILE.mcap`` writes the measured and the estimated topics as the twin's node
records its own. The core knows no recording format: it gathers a :class:`TrackRecording` (the
nominal scene, each estimate as a :class:`TrackStep`, the smoother's loads by their time, the
measurements and mode signals, the model's events, the tracking status's changes, the strokes)
and hands it to the writer that another package registers in the entry-point group
:data:`~mps_core.plugins.TRACK_WRITERS` under the format's name (``mcap``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import MpsError
from ..plugins import TRACK_WRITERS, track_plugin
from .diagnostics import Status
from .measurements import Measurement, ModeSignal
from .strokes import StrokeEstimate

if TYPE_CHECKING:
    from ..scene import Scene
    from .tracker import Tracker

__all__ = ["TrackRecording", "TrackStep", "joint_values", "write_recording"]


@dataclass(frozen=True)
class TrackStep:
    """One estimate (a measurement taken).

    Its time, structure, the joints' positions and rates (crank, rod, rocker, slider: as the
    twin's joint states), the estimate's figures by the estimates file's column names, and the
    tracking status then.
    """

    t: float
    structure: str
    positions: tuple[float, float, float, float]
    velocities: tuple[float, float, float, float]
    estimate: dict[str, float]
    status: Status


@dataclass
class TrackRecording:
    """A tracked run's record, for a recording's writer (see the module's doc).

    ``scene``: the nominal press followed (its name and text go into the recording).
    ``loads``: the joint reactions and the foundation load by their time (s), each column's
    (value, 1-σ): the fixed-lag smoother's, the last estimate of a time kept."""

    scene: Scene
    steps: list[TrackStep] = field(default_factory=list)
    loads: dict[float, dict[str, tuple[float, float]]] = field(default_factory=dict)
    measurements: list[Measurement] = field(default_factory=list)
    modes: list[ModeSignal] = field(default_factory=list)
    events: list[dict[str, Any]] = field(default_factory=list)
    statuses: list[Status] = field(default_factory=list)
    strokes: list[StrokeEstimate] = field(default_factory=list)
    metadata: dict[str, str] = field(default_factory=dict)

    def add(self, tracker: Tracker, estimate: dict[str, float], status: Status) -> None:
        """Add the tracker's present estimate (its row ``estimate``) as a step."""
        pos, vel = joint_values(tracker)
        t = float(estimate["t"])
        self.steps.append(TrackStep(t, tracker.sim.structure, pos, vel, dict(estimate), status))

    def add_loads(self, t: float, loads: dict[str, tuple[float, float]]) -> None:
        """Keep the loads at time ``t`` (a later estimate of the same time replaces an earlier)."""
        self.loads[float(t)] = dict(loads)


def joint_values(
    tracker: Tracker,
) -> tuple[tuple[float, float, float, float], tuple[float, float, float, float]]:
    """Return the joints' positions and rates at the tracker's estimate.

    The crank's angle, the rod's angle from x (A to B), the rocker's angle, the slider's
    position; their rates.
    """
    sim = tracker.sim
    phi, phi_dot, psi, psi_dot, x, x_dot = (float(v) for v in sim.joint_state())
    kin = sim.solver.current.kin
    xa, ya = (float(v) for v in kin.xy("A"))
    xb, yb = (float(v) for v in kin.xy("B"))
    rod = math.atan2(yb - ya, xb - xa)
    return (phi, rod, psi, x), (phi_dot, float(kin.rate("rod")), psi_dot, x_dot)


class RecordingWriterMissing(MpsError, ValueError):
    """No installed package writes recordings of the format asked for."""


def write_recording(path: str | Path, recording: TrackRecording, fmt: str = "mcap") -> int:
    """Write ``recording`` to ``path`` with the writer registered for ``fmt``.

    Return the messages written.
    """
    write = track_plugin(
        TRACK_WRITERS,
        fmt,
        f"--out {str(path)!r}",
        "writes",
        RecordingWriterMissing,
        "write the estimates as CSV (--out FILE.csv)",
    )
    return int(write(Path(path), recording))
