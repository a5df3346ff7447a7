"""The tracking twin: follow a press from its sensors on the partial-system model.

A layer above the run (``run/``) and below the commands, with no ROS: :class:`Tracker` (an
extended Kalman filter whose mean is the model's own run), the measurements it reads
(:mod:`~mps_core.track.measurements`), its tuning (:class:`TrackSettings`), the per-stroke table
(:mod:`~mps_core.track.strokes`), the ``tracking`` status (:class:`TrackingMonitor`), the record
a recording is written from (:mod:`~mps_core.track.recording`), and a press to follow: a truth
scene read by its sensors (:mod:`~mps_core.track.truth`). How the filter was chosen, and what
it achieves: docs/tracking.md.
"""

from __future__ import annotations

from .diagnostics import DiagnosticSettings, Status, TrackingMonitor
from .measurements import Encoder, Measurement, MeasurementError, ModeSignal, TorqueSensor
from .settings import TrackSettings
from .strokes import StrokeEstimate, StrokeTable
from .tracker import Estimate, Tracker
from .truth import Fault, Sensors, TruthChanges, TruthRun, run_truth, truth_scene

__all__ = [
    "DiagnosticSettings",
    "Encoder",
    "Estimate",
    "Fault",
    "Measurement",
    "MeasurementError",
    "ModeSignal",
    "Sensors",
    "Status",
    "StrokeEstimate",
    "StrokeTable",
    "TorqueSensor",
    "TrackSettings",
    "Tracker",
    "TrackingMonitor",
    "TruthChanges",
    "TruthRun",
    "run_truth",
    "truth_scene",
]
