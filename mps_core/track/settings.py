"""A tracker's tuning: the random walks of its unknown inputs, the model's error, the gates.

Every number is a statement about the press, not a knob to make a test pass: the process
force's random walk is strong where the punch can work (the slider in the lower part of its
stroke, latch closed) and weak elsewhere; the load torque drifts slowly (friction, the motor off
its catalogue); the model's own error is a white noise on the crank's acceleration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..derivatives import SCHEMES
from .measurements import MeasurementError

__all__ = ["PREDICTIONS", "SIGNAL_LATENCY", "TrackSettings"]

#: how the covariance is predicted: the step map's Jacobian (an extended Kalman filter) or
#: sigma points through the model's run (unscented)
PREDICTIONS = ("jacobian", "unscented")
#: how late a press's mode signals may come (s) where they come and nothing else is said: the
#: node's ``track_signal_latency`` and ``mps track --signal-latency`` unless given
SIGNAL_LATENCY = 0.01


@dataclass(frozen=True)
class TrackSettings:
    """The tuning of a :class:`~mps_core.track.tracker.Tracker` (SI units).

    ``force_walk``: the process force's random-walk intensity (N/√s) inside the work window:
    latch closed, the slider moving down below ``work_zone_top`` (m; None: 2 mm above where
    the nominal scene's punch touches its part, or 4 mm where it has no process load); outside
    it the force is zero (a blanking punch pushes the slider up only while it cuts on the way
    down).
    ``torque_walk``: the load torque's (N·m/√s). ``accel_noise``: white noise on each
    coordinate's acceleration (per √s, in the chart's units divided by its scale), with the
    latch closed; ``accel_noise_unlocked`` the same where it is open (``held``, ``free``): there
    the slider and the rocker move apart from the crank, and what the model misses on their
    side (the guide's friction, the joints') is no unknown input's to take up.
    ``gate``: the normalised innovation squared above which a measurement is rejected as an
    outlier; ``max_jump``: an angle innovation (rad) beyond which the crank would have jumped
    (physically impossible between two samples). ``timeout``: a gap between measurements
    (s) reported as such. ``event_inflation``: the factor on the covariance of the rates at a
    change of structure (an impact the model locates, whose time the estimate knows only
    approximately). ``force_lag``: the process force of the last ``force_lag`` steps kept as
    states (a fixed-lag smoother: the force over a step shows in the crank only at the next
    samples, so the force ``force_lag`` steps back is known far better than the present one).
    ``prediction``: one of :data:`PREDICTIONS` (docs/tracking.md: how they compare).
    ``motor_scale_sigma``: the 1-σ of how far the motor's torque may be off its catalogue's
    characteristic, as a share of it (0.05: 5 %), taken where the motor's torque is first
    measured; ``motor_scale_walk``: how fast that share may drift (per √s; the motor warming,
    its supply).
    ``signal_latency``: how late a mode signal may come after its command took effect (s; 0:
    on time, applied at its stamp): the command is searched for over that window before its
    stamp (:mod:`~mps_core.track.signal_timing`).
    ``reacquire_after``: crank angles rejected running (beyond the gate, or a jump) after which,
    latch open (``held``, ``free``), the crank is acquired again as after a gap: the crank does
    not see the slider there, and a slider whose motion, or impact at its stop, the model has
    off moves the crank where the model cannot follow it (docs/tracking.md, The crank acquired
    again, latch open); so many slider positions rejected running there, the slider is
    acquired again.
    ``derivatives``: the model's derivative scheme, one of :data:`mps_core.derivatives.SCHEMES`
    (its mass matrix's derivatives in the velocity terms): ``autodiff`` by exact derivatives,
    each step's evaluations one generated function (the default: the estimates as the seed's
    central differences give them to the digits printed, at less CPU; docs/tracking.md),
    ``central`` as the seed differences them.
    ``fit_cuts``: whether each cut is fitted whole once over (the part's force curve from the
    crank angles over the work window: :mod:`~mps_core.track.cut_fit`), the stroke's peak force
    then the fit's.
    Without mode signals the structure follows a slider scale: engaged where the slider is
    measured ``engage_drop`` (m) below its top stop while held there, disengaged where the
    crank-slider misses the slider's position (an outlier) ``disengage_misses`` times running.
    """

    force_walk: float = 8.0e5
    work_zone_top: float | None = None
    torque_walk: float = 20.0
    accel_noise: float = 2.0
    accel_noise_unlocked: float = 4.0
    gate: float = 25.0
    max_jump: float = math.radians(10.0)
    timeout: float = 0.05
    event_inflation: float = 4.0
    force_lag: int = 2
    engage_drop: float = 5e-5
    disengage_misses: int = 3
    prediction: str = "jacobian"
    initial_force_sigma: float = 500.0
    initial_torque_sigma: float = 5.0
    motor_scale_sigma: float = 0.05
    motor_scale_walk: float = 0.001
    signal_latency: float = 0.0
    derivatives: str = "autodiff"
    reacquire_after: int = 3
    fit_cuts: bool = True

    def __post_init__(self) -> None:
        for name in (
            "force_walk",
            "torque_walk",
            "accel_noise",
            "accel_noise_unlocked",
            "gate",
            "max_jump",
            "timeout",
            "initial_force_sigma",
            "initial_torque_sigma",
            "motor_scale_sigma",
            "motor_scale_walk",
        ):
            v = getattr(self, name)
            if not (isinstance(v, float | int) and v > 0.0 and math.isfinite(v)):
                raise MeasurementError(f"track.{name}", v, "a positive number")
        if self.work_zone_top is not None and not (
            isinstance(self.work_zone_top, float | int) and math.isfinite(self.work_zone_top)
        ):
            raise MeasurementError("track.work_zone_top", self.work_zone_top, "a slider position (m) or None")
        if not (isinstance(self.engage_drop, float | int) and 0.0 < self.engage_drop < 0.01):
            raise MeasurementError("track.engage_drop", self.engage_drop, "a distance in (0, 0.01) m")
        if not (isinstance(self.disengage_misses, int) and self.disengage_misses >= 1):
            raise MeasurementError("track.disengage_misses", self.disengage_misses, "an integer >= 1")
        if not (isinstance(self.signal_latency, float | int) and 0.0 <= self.signal_latency <= 0.1):
            raise MeasurementError("track.signal_latency", self.signal_latency, "a time in [0, 0.1] s")
        if self.prediction not in PREDICTIONS:
            raise MeasurementError("track.prediction", self.prediction, "one of " + ", ".join(PREDICTIONS))
        if not (isinstance(self.reacquire_after, int) and self.reacquire_after >= 1):
            raise MeasurementError("track.reacquire_after", self.reacquire_after, "an integer >= 1")
        if self.derivatives not in SCHEMES:
            raise MeasurementError("track.derivatives", self.derivatives, "one of " + ", ".join(SCHEMES))
        if not (isinstance(self.force_lag, int) and 0 <= self.force_lag <= 10):
            raise MeasurementError("track.force_lag", self.force_lag, "an integer from 0 to 10 (steps)")
        if not (self.event_inflation >= 1.0 and math.isfinite(self.event_inflation)):
            raise MeasurementError("track.event_inflation", self.event_inflation, "a number >= 1")
