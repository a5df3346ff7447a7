"""The tracker: an extended Kalman filter on the partial-system model of the press.

**State.** The independent coordinates q and rates q̇ of the chart view the model is in now
(n = 1 in ``held`` and ``locked``, 2 in ``free``), augmented with the unknown inputs
(:mod:`mps_core.track.unknown_inputs`): the process force F_p on the slider and the load torque
tau_b on the crank, both random walks, and the work W the punch has done in the stroke under way
(an integrator, dW/dt = −F_p·ẋ_C, reset at each top dead centre), and how far the motor's
torque is off its catalogue's characteristic as a share of it, s_m (a random walk, where the
motor's torque is measured: a motor torque measurement is (1 + s_m) times the catalogue's torque
at the crank's rate; no variance until the first such measurement comes, so that a tracker
without one is the filter it was; the drive's torque in the model stays the catalogue's, its
difference in tau_b): (q, q̇, F_p, tau_b, W, s_m), 2n + 4 numbers, followed by the fixed-lag
smoother's slots (:mod:`mps_core.track.lags`): the state and the force of each of the last
``force_lag`` steps.

**Prediction.** The mean goes through the model's own run (:class:`~mps_core.run.simulation.
Simulation` of the nominal scene, without its process load and its commands, with the unknown
inputs as an effect), so that structures, impacts, chart changes and every event are located as
the simulation locates them. The covariance goes through the step map's Jacobian
Φ = exp(J·Δt) (to second order), J the continuous Jacobian at the step's start: ∂q̈/∂q and
∂q̈/∂q̇ by forward differences of the engine's q̈ from the run's own, ∂q̈/∂F_p = A⁻¹·∂x_C/∂q and
∂q̈/∂tau_b = A⁻¹·∂φ/∂q exactly from the mass matrix and the analogs. Near the bottom dead centre
∂x_C/∂q → 0: the crank says nothing of F_p there, and its variance grows as its random walk
says (what the estimate must show). Where the run changes chart or structure within a step, the
covariance is carried across through the physical coordinates (φ, ψ, x_C): P_new = T⁺·T_old·P·
T_oldᵀ·T⁺ᵀ, the rates' part inflated at a change of structure (an impact located with the
estimated state).

**Update.** Each scalar measurement (:mod:`mps_core.track.measurements`) in turn, Joseph form.
Rejected and counted by reason in :attr:`Tracker.rejected`, the estimate left exactly as it was:
a stamp already seen (``duplicate``), older than the last of its kind (``out-of-order``), older
than the tracker's present time (``late``), not finite (``not-finite``), a crank angle
``max_jump`` or more from where its rate takes it (``jump``). An innovation beyond the gate
(``outlier``) is rejected after the estimate is predicted to its stamp (it is not corrected).
A gap longer than ``timeout`` is counted (``gap``) and the measurement taken.

**Cuts.** Once a cut is over, its crank angles are fitted whole by the part's force curve
(:mod:`~mps_core.track.cut_fit`), here or in the fitting process
(:mod:`~mps_core.track.fit_process`, :attr:`Tracker.defer_fits`): the stroke's peak force and
foundation load then the fit's. The filter's estimates are the same with and without.

**Loads.** The joint reactions and the foundation load at the estimated state and inputs
(:func:`~mps_core.dynamics.reactions.compute_reactions`), their standard deviations from the
reactions' Jacobian in the state (forward differences) and the state's covariance.
"""

from __future__ import annotations

import functools
import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from ..dynamics.reactions import REACTION_COLUMNS, compute_reactions, reaction_values
from ..errors import MpsError
from . import lags
from .cut_fit import CutFit, CutFitter, CutJob, CutStart, part_guess
from .measurements import Measurement, MeasurementError, ModeSignal
from .nominal_model import PROCESS_EFFECTS, NominalModel
from .settings import TrackSettings
from .signal_timing import SignalTiming
from .strokes import StrokeTable, stroke_index
from .unscented import unscented_step

if TYPE_CHECKING:
    from ..scene import Scene

__all__ = ["KEEP_INNOVATIONS", "LOAD_COLUMNS", "Estimate", "LoadEstimates", "Tracker"]

#: the reactions and foundation load a tracker estimates (the residual checks left out)
LOAD_COLUMNS = tuple(c for c in REACTION_COLUMNS if "residual" not in c)
#: where each of LOAD_COLUMNS is in REACTION_COLUMNS
_LOAD_INDEX = tuple(list(REACTION_COLUMNS).index(c) for c in LOAD_COLUMNS)
#: the foundation force's components among LOAD_COLUMNS
_FOUND_X, _FOUND_Y = LOAD_COLUMNS.index("F_found_x"), LOAD_COLUMNS.index("F_found_y")
#: the innovations a tracker that follows a press for long keeps at least (10 s at 1 kHz;
#: :attr:`Tracker.keep_innovations`): the tracking status reads each as it comes, a late
#: signal's search the last few of its windows
KEEP_INNOVATIONS = 10_000
#: how far above the work window a cut's fit may start (m): the last state filtered there is its start
CUT_MARGIN = 0.003
#: the reasons a measurement is rejected for
REJECTIONS = ("duplicate", "out-of-order", "late", "not-finite", "jump", "outlier", "model")


class LoadEstimates(dict):
    """The loads at an estimate: name → (value, 1-σ), in :data:`LOAD_COLUMNS`' order, and the
    covariance of the foundation force's two components (N², ``foundation_xy_covariance``:
    the same linearisation as their 1-σ), which the magnitude's 1-σ needs."""

    foundation_xy_covariance: float = 0.0


@dataclass(frozen=True)
class Estimate:
    """The tracker's estimate at one time, physical quantities with their 1-σ (SI units)."""

    t: float
    structure: str
    phi: float
    phi_sigma: float
    phi_dot: float
    phi_dot_sigma: float
    x_C: float
    x_C_sigma: float
    force: float
    force_sigma: float
    torque: float
    torque_sigma: float
    work: float
    work_sigma: float
    #: the process force ``force_lag`` steps back (the fixed-lag smoother's) and the middle
    #: of the step it acted over (the present force where ``force_lag`` is 0)
    force_smoothed: float
    force_smoothed_sigma: float
    t_force_smoothed: float
    #: how far the motor's torque is off its catalogue, a share of it (0 with no variance until
    #: the motor's torque is measured)
    motor_scale: float = 0.0
    motor_scale_sigma: float = 0.0


class Tracker:
    """Follow a press from its measurements on the partial-system model of a nominal scene.

    ``scene``: the nominal press (its process load and commands are left out: the process
    force is estimated, the commands come as mode signals). ``initial``: (view, q, q̇) to start
    from (default the scene's initial state); ``sigma``: the initial 1-σ of (q, q̇) in the
    chart's units.
    """

    def __init__(
        self,
        scene: Scene,
        settings: TrackSettings | None = None,
        *,
        initial: tuple | None = None,
        sigma: tuple[float, float] = (1e-3, 1.0),
        t0: float = 0.0,
        phi_tdc: float = 0.0,
    ) -> None:
        self.settings = settings or TrackSettings()
        #: the top of the work window (m): the slider below it moving down, the punch may work
        self.work_zone_top = work_zone_top(scene, self.settings)
        model = NominalModel(scene, self.settings)
        mech = model.mechanism
        #: the unknown inputs' effect (its values follow the state)
        self.inputs = model.inputs
        self.motor = model.motor
        new_run = model.new_run
        self._scene = scene

        def initial_state(phi: float, phi_dot: float) -> tuple:
            i = scene.initial
            psi, psi_dot = i.get("psi"), i.get("psi_dot", 0.0)
            return mech.initial_state(scene.structure, phi, phi_dot, psi, psi_dot, sigma=scene.assembly)

        #: a model run from the scene's initial structure at a crank angle and rate, and at a time
        #: (the first, and where a run fails: :meth:`_start_again`)
        self._new_run, self._initial_state, self._sigma = new_run, initial_state, sigma
        self._initial_rate = float(scene.initial["phi_dot"])
        self._initial_structure = scene.structure
        #: the model's run, which the estimate's mean follows (on the tracker's own clock: the
        #: press's less :attr:`origin`)
        self.sim = new_run(initial or scene.initial_state(mech), t0)
        #: the press's time at the model run's time 0 (s): the first measurement's stamp less
        #: ``t0`` where that stamp is over the ``timeout`` past ``t0`` (a press's stamps on
        #: the system's clock, 1.8e9 s: the run keeps its times small, its steps exact)
        self.origin = 0.0
        #: whether a measurement has come (before it the origin may move to its stamp)
        self.started = False
        #: mode signals come before the first measurement (applied as it comes)
        self._early: list[ModeSignal] = []
        self.phi_tdc = float(phi_tdc)
        s = self.settings
        self.x, self.P = self._initial_estimate(0.0, s.initial_torque_sigma**2, 0.0, 0.0)
        if not self._window_now():
            self._hold_force()

        #: measurements rejected, by reason; ``gap``: gaps longer than the timeout
        self.rejected: Counter[str] = Counter()
        self.accepted = 0
        #: steps whose unscented prediction fell back on the Jacobian's (``prediction``)
        self.fallbacks = 0
        #: the process force's variance before the last measurement taken
        self.force_prior_variance = 0.0
        #: whether the press gives mode signals (else the structure follows the measurements)
        self.signalled = False
        #: whether the motor's torque has been measured (its share off the catalogue, s_m, a
        #: state since)
        self.motor_measured = False
        #: the commands inferred from the measurements, by name
        self.inferred: Counter[str] = Counter()
        #: the times the crank was acquired again, off the model by more than the gate
        #: allows (the first measurement, the first after a gap, or, latch open, after
        #: ``reacquire_after`` rejected running)
        self.acquired = 0
        #: the times the slider was acquired again, latch open, after ``reacquire_after`` of its
        #: positions rejected running
        self.slider_acquired = 0
        #: the times the model's run failed and was started again (:meth:`_start_again`)
        self.restarted = 0
        self._slider_misses = 0
        #: crank angles rejected running (beyond the gate, jumps: ``reacquire_after``)
        self._crank_misses = 0
        #: slider positions rejected running (beyond the gate: ``reacquire_after``)
        self._slider_rejects = 0
        self._returned = True
        #: the normalised innovation squared of each accepted measurement: (t, kind, NIS)
        self.innovations: list[tuple[float, str, float]] = []
        #: how many of the first innovations were dropped (where :attr:`keep_innovations` bounds
        #: them): an innovation's number is this plus its place in :attr:`innovations`
        self.innovations_dropped = 0
        #: keep the last this many innovations at least, the older dropped as twice as many
        #: gather (None: every one; a node following a press for days keeps a bounded log)
        self.keep_innovations: int | None = None
        self._last: dict[str, float] = {}
        self._t_last = -math.inf
        #: the start times of the last steps (the lagged forces' steps)
        self._starts: list[float] = []
        #: the per-stroke figures
        self.strokes = StrokeTable()
        self._stroke = self._stroke_now()
        if self._stroke is not None:
            self.strokes.begin(self._stroke, self.sim.t)
        #: the part's force curve (F_max, x_0, p_b) a cut's fit starts from: the nominal part's,
        #: then the last cut's fitted (None: no cut is fitted)
        self._part = part_guess(model.process_params) if self.settings.fit_cuts else None
        #: the last fit's load torque off its start's (None before a cut is fitted)
        self._part_torque_offset: float | None = None
        #: the last state filtered just above the work window (a cut's fit starts there)
        self._cut_start: CutStart | None = None
        #: the cut under way: its start and its crank angles taken, (t, angle, variance)
        self._cut: tuple[CutStart, tuple] | None = None
        #: the cuts fitted, those whose fit did not converge, those with no part to fit
        self.cuts_fitted = 0
        self.cuts_unfitted = 0
        self.cuts_without_part = 0
        #: the cuts closed so far (a cut's job's ``serial``)
        self._cuts = 0
        #: fit the cuts elsewhere (another process, say): each cut's job is put on
        #: :attr:`cut_jobs` for the owner, who hands the fit back (:meth:`take_fit`); the next
        #: cut waits for it (:attr:`await_fit`), so that every fit begins where it would here
        self.defer_fits = False
        #: the cuts' jobs to fit (``defer_fits``), taken off by the owner
        self.cut_jobs: list[CutJob] = []
        #: return the fit of a job handed out (``defer_fits``), waiting for it
        self.await_fit: Callable[[CutJob], CutFit | None] | None = None
        #: the job handed out whose fit has not come back
        self._pending: CutJob | None = None
        self._fitter: CutFitter | None = None
        #: the log-likelihood of the last measurement taken (:meth:`take`)
        self.score = 0.0
        #: the first of :attr:`innovations` replaced since :meth:`take_replaced` was last called
        #: (a mode signal's command tried earlier: the measurements since taken again)
        self.replaced_from: int | None = None
        #: when a late mode signal's command took effect (None where signals are on time)
        self.timing: SignalTiming | None = None
        if s.signal_latency > 0.0:
            if not self.sim.rewindable:
                raise MeasurementError(
                    "track.signal_latency",
                    s.signal_latency,
                    f"0 with solver {self.sim.solver.name!r}, which cannot rewind to try a command earlier",
                )
            self.timing = SignalTiming(s.signal_latency)

    # -- the state ----------------------------------------------------------------------
    @property
    def t(self) -> float:
        """Return the time of the estimate (on the press's clock)."""
        return self.sim.t + self.origin

    def take_events(self) -> list[dict]:
        """Return the events the model located since the last call, on the press's clock."""
        events = self.sim.events
        out = [dict(ev, t=ev["t"] + self.origin) if self.origin and "t" in ev else ev for ev in events]
        del events[:]
        return out

    def _initial_estimate(
        self, torque: float, torque_variance: float, motor_scale: float, motor_scale_variance: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Return (x, P) at the run's present state, the initial 1-σ of (q, q̇) and of the force,
        the load torque and the motor's share as given, the smoother's slots started."""
        s = self.settings
        e = self.sim.solver.current
        x = np.concatenate([e.q, e.qd, [0.0, torque, 0.0, motor_scale]])
        scales = np.asarray(self.sim.view.scales, dtype=float)
        sigma = self._sigma
        P = np.diag(
            np.concatenate(
                [
                    (sigma[0] * scales) ** 2,
                    (sigma[1] * scales) ** 2,
                    [s.initial_force_sigma**2, torque_variance, 0.0, motor_scale_variance],
                ]
            )
        )
        return lags.restart(x, P, self.n, s.force_lag)

    def _start_again(self, m: Measurement, e0: Any, error: Exception) -> None:
        """Start the model's run again at ``m``'s time, its prediction there from ``e0`` having failed.

        The run's state had no configuration to go on from (a singular position, equations
        without a solution: the estimate had wandered where the press cannot be). The new run
        starts in the scene's initial structure, its crank at the angle measured (or where its
        rate at ``e0`` takes it) at that rate, with the initial covariance; the load torque and the
        motor's share are kept. Counted (:attr:`restarted`) and logged as an event
        (``tracker-restart``).
        """
        n = self.n
        x, P = self.x, self.P
        try:
            phi, phi_dot = self.sim.observables.observe(e0)["phi"]
        except (MpsError, ArithmeticError, ValueError):
            phi, phi_dot = math.nan, math.nan
        if not math.isfinite(phi_dot):
            phi_dot = self._initial_rate
        if m.kind == "crank_angle":
            phi = m.value
        elif math.isfinite(phi):
            phi = phi + phi_dot * (m.t - e0.t)
        else:
            phi = 0.0
        self.sim = self._new_run(self._initial_state(phi, phi_dot), m.t)
        i = 2 * n
        self.x, self.P = self._initial_estimate(
            float(x[i + 1]), float(P[i + 1, i + 1]), float(x[i + 3]), float(P[i + 3, i + 3])
        )
        self.inputs.set(0.0, float(self.x[2 * self.n + 1]))
        self._starts = []
        self._cut_start = self._cut = None  # a new run: the cut under way is not fitted
        if not self._window_now():
            self._hold_force()
        self.restarted += 1
        self.sim.events.append(
            {"t": m.t, "kind": "tracker-restart", "structure": self._initial_structure, "why": str(error)}
        )
        self._follow_strokes()

    @property
    def n(self) -> int:
        """Return the number of independent coordinates of the present chart view."""
        return int(self.sim.view.n)

    def _hold_force(self) -> None:
        """Set the process force to zero with no variance (outside the work window)."""
        i = 2 * self.n
        was = self.inputs.values[0]
        self.x[i] = 0.0
        self.P[i, :] = 0.0
        self.P[:, i] = 0.0
        self.inputs.set(0.0, self.x[i + 1])
        if was != 0.0:  # the run's present evaluation holds the force it had: made again
            e = self.sim.solver.current
            self.sim.restart_at(e.q, e.qd)

    def _in_window(self, x_C: float, v_C: float, structure: str) -> bool:
        """Return whether the punch can work at this state: latch closed, the slider moving down in the
        lower part of its stroke (below ``work_zone_top``)."""
        return structure == "locked" and x_C < self.work_zone_top and v_C < 0.0

    @property
    def in_window(self) -> bool:
        """Return whether the estimate is in the work window (the process force a state there)."""
        return self._window_now()

    def _window_now(self) -> bool:
        """Return whether the run's present state is in the work window."""
        kin = self.sim.solver.current.kin
        return self._in_window(float(kin.xy("C")[0]), float(kin.vxy("C")[0]), self.sim.structure)

    def _stroke_now(self) -> int | None:
        """Return the stroke the run is in (None outside the working structure)."""
        if self.sim.structure != "locked":
            return None
        return stroke_index(self.sim.joint_state()[0], self.phi_tdc)

    def estimate(self) -> Estimate:
        """Return the present estimate in physical quantities with their 1-σ."""
        n = self.n
        e = self.sim.solver.current
        kin = e.kin
        P = self.P
        g_phi = kin.omega("crank")
        g_x = kin.jac("C")[0]
        phi, phi_dot = self.sim.joint_state()[:2]
        i = 2 * n
        lag = self.settings.force_lag
        j = lags.slot(n, lag).stop - 1 if lag else i
        ends = self._starts + [self.sim.t]  # the last steps' boundaries
        t_smoothed = self.sim.t
        if lag and len(ends) > lag:
            t_smoothed = 0.5 * (ends[-lag - 1] + ends[-lag])
        t_smoothed += self.origin
        return Estimate(
            t=self.t,
            structure=self.sim.structure,
            phi=phi,
            phi_sigma=_sd(_quadratic(g_phi, P, 0)),
            phi_dot=phi_dot,
            phi_dot_sigma=_sd(_quadratic(g_phi, P, n)),
            x_C=float(kin.xy("C")[0]),
            x_C_sigma=_sd(_quadratic(g_x, P, 0)),
            force=float(self.x[i]),
            force_sigma=_sd(P[i, i]),
            torque=float(self.x[i + 1]),
            torque_sigma=_sd(P[i + 1, i + 1]),
            work=float(self.x[i + 2]),
            work_sigma=_sd(P[i + 2, i + 2]),
            force_smoothed=float(self.x[j]),
            force_smoothed_sigma=_sd(P[j, j]),
            t_force_smoothed=t_smoothed,
            motor_scale=float(self.x[i + 3]),
            motor_scale_sigma=_sd(P[i + 3, i + 3]),
        )

    def physical_covariance(self) -> np.ndarray:
        """Return the covariance of (φ, φ̇, F_p) at the present estimate."""
        n = self.n
        kin = self.sim.solver.current.kin
        g = np.asarray(kin.omega("crank"), dtype=float)
        T = np.zeros((3, len(self.x)))
        T[0, :n] = g
        T[1, n : 2 * n] = g
        T[2, 2 * n] = 1.0
        return T @ self.P @ T.T

    # -- checkpoints ----------------------------------------------------------------------
    def checkpoint(self) -> tuple:
        """Return the tracker's state now, for :meth:`restore` (the model run's among it).

        Of its logs (:attr:`innovations`, the strokes closed) it keeps how long they were.
        """
        d = dict(self.__dict__)
        d["x"], d["P"] = self.x.copy(), self.P.copy()
        d["rejected"], d["inferred"], d["_last"] = dict(self.rejected), dict(self.inferred), dict(self._last)
        return d, self.log_lengths(), self.strokes.state(), list(self.inputs.values), self.sim.checkpoint()

    def restore(self, cp: tuple) -> None:
        """Come back to a :meth:`checkpoint`: its logs cut to the lengths they had.

        What the logs held before then is what they hold now (:meth:`set_logs` writes them
        again); whether the press gives mode signals stays as it is now.
        """
        d, (n_innovations, n_strokes), strokes, inputs, sim = cp
        signalled, replaced = self.signalled, self.replaced_from
        dropped, keep = self.innovations_dropped, self.keep_innovations
        self.__dict__.clear()
        self.__dict__.update(d)
        self.x, self.P = d["x"].copy(), d["P"].copy()
        self.rejected, self.inferred = Counter(d["rejected"]), Counter(d["inferred"])
        self._last = dict(d["_last"])
        self.signalled, self.innovations_dropped, self.keep_innovations = signalled, dropped, keep
        del self.innovations[max(n_innovations - dropped, 0) :]
        del self.strokes.strokes[n_strokes:]
        self.replaced_from = n_innovations if replaced is None else min(replaced, n_innovations)
        self.strokes.set_state(strokes)
        self.inputs.values[:] = inputs
        self.sim.restore(sim)

    def log_lengths(self) -> tuple[int, int]:
        """Return how long the logs are now (:attr:`innovations`, the strokes closed)."""
        return self.innovations_dropped + len(self.innovations), len(self.strokes.strokes)

    def logs_since(self, lengths: tuple[int, int]) -> tuple[list, list]:
        """Return the innovations and the strokes closed since the logs had ``lengths`` (copies)."""
        n_innovations, n_strokes = lengths
        return self.innovations[max(n_innovations - self.innovations_dropped, 0) :], self.strokes.strokes[
            n_strokes:
        ]

    def set_logs(self, lengths: tuple[int, int], logs: tuple[list, list]) -> None:
        """Write the logs since they had ``lengths`` (what :meth:`logs_since` gave)."""
        n_innovations, n_strokes = lengths
        innovations, strokes = logs
        self.innovations[max(n_innovations - self.innovations_dropped, 0) :] = innovations
        self.strokes.strokes[n_strokes:] = strokes
        if self.replaced_from is None or n_innovations < self.replaced_from:
            self.replaced_from = n_innovations

    def take_replaced(self) -> int | None:
        """Return the number of the first innovation replaced since the last call (None: none)."""
        out, self.replaced_from = self.replaced_from, None
        return out

    # -- mode signals ---------------------------------------------------------------------
    def mode(self, signal: ModeSignal) -> None:
        """Apply a mode signal of the press's controller at its stamp (now, if it is past;
        held until the first measurement where none has come)."""
        self.signalled = True
        if not self.started:
            self._early.append(signal)
            return
        if self.origin:
            signal = ModeSignal(signal.t - self.origin, signal.command)
        if self.timing is not None:
            self.timing.signal(self, signal)
            return
        self.apply_command(signal.command, signal.t)

    def apply_command(self, command: str, t: float) -> None:
        """Apply a command to the model at ``t`` on the tracker's clock: scheduled where the
        run is before it, now where it is there or past it (counted ``mode`` where the model
        refuses it)."""
        if t > self.sim.t:
            try:
                self.sim.command(command, t)
            except MpsError:
                self.rejected["mode"] += 1
            return
        self._command_now(command)

    def _command_now(self, command: str) -> bool:
        """Apply a command to the model now, the state carried into the chart view it leaves
        the run in; return whether the model took it."""
        sim = self.sim
        e0, structure0, n0 = sim.solver.current, sim.structure, sim.view.n
        try:
            sim.command(command)
        except MpsError:
            self.rejected["mode"] += 1
            return False
        e1 = sim.solver.current
        x = np.concatenate([e1.q, e1.qd, self.x[2 * n0 : lags.core_size(n0)]])
        if sim.view is not e0.view:
            self.x, self.P = self._carry(x, self.P, e0, e1, structure0 != sim.structure)
        else:
            self.x[: 2 * n0] = x[: 2 * n0]
        if not self._window_now():
            self._hold_force()
        return True

    def _infer_mode(self, m: Measurement, predicted: float, nis: float) -> None:
        """Follow the structure from the slider's position where no mode signal comes: engaged
        when the slider is measured ``engage_drop`` below where the idle model puts it (its top
        stop, or lower where the model's slider swings free) while idle (and back on its stop
        since the last disengage);
        disengaged when the crank-slider's slider position is missed ``disengage_misses``
        times running."""
        sim = self.sim
        top = sim.mechanism.x_top
        s = self.settings
        if sim.structure == "held":
            self._returned = True  # the slider back on its stop since the last disengage
        idle = sim.structure != "locked" and not sim.controls.engage_on and self._returned
        if idle and top is not None and m.value < min(top, predicted) - s.engage_drop:
            if self._command_now("engage"):
                self.inferred["engage"] += 1
                self._widen(s.engage_drop)
            return
        if sim.structure != "locked":
            return
        self._slider_misses = self._slider_misses + 1 if nis > s.gate else 0
        if self._slider_misses >= s.disengage_misses and self._command_now("disengage"):
            self.inferred["disengage"] += 1
            self._slider_misses = 0
            self._returned = False
            self._widen(abs(m.value - predicted))

    def _widen(self, distance: float) -> None:
        """Widen the covariance of (q, q̇) after a command applied late (found from the
        measurements): the model is behind the press by what the slider moved meanwhile,
        ``distance`` (m), within about a millisecond."""
        self._widen_crank(distance / float(self.sim.mechanism.geometry.l1), 1e-3)

    def _widen_crank(self, angle: float, within: float) -> None:
        """Widen the covariance of (q, q̇) by a crank ``angle`` (rad) the model may be off by,
        come about within ``within`` seconds (the rates' by angle / within; none where inf)."""
        n = self.n
        scales = np.asarray(self.sim.view.scales, dtype=float)
        sigma = angle * scales  # in each coordinate's units
        idx = np.arange(n)
        self.P[idx, idx] += sigma**2
        self.P[n + idx, n + idx] += (sigma / within) ** 2

    def _acquire(self, m: Measurement) -> None:
        """Acquire the crank again at the first angle measured (or the first after a gap):
        where the model's run, come to its stamp, is off the measurement by more than its
        covariance allows (beyond the gate), widen the covariance of (q, q̇) by the angle it is
        off by (the rates' by that angle over the gap), so the measurement is taken and the
        next ones set the rate (counted, ``acquired``)."""
        _value, H, y = self._innovation(m)
        S = float(H @ self.P @ H) + m.variance
        if y * y / S <= self.settings.gate:
            return
        self.acquired += 1
        self._widen_crank(abs(y), max(m.t - self._t_last, self.settings.timeout))

    def _acquire_slider(self, m: Measurement) -> None:
        """Acquire the slider again, latch open, after its positions were rejected running:
        where the model's slider is off the measured one by more than the covariance allows,
        widen the covariance of (q, q̇) by that distance (:meth:`_widen`), so the measurement is
        taken and the next ones follow it (counted, ``slider_acquired``)."""
        _value, H, y = self._innovation(m)
        S = float(H @ self.P @ H) + m.variance
        if y * y / S <= self.settings.gate:
            return
        self.slider_acquired += 1
        self._widen(abs(y))

    # -- measurements ---------------------------------------------------------------------
    def update(self, m: Measurement) -> bool:
        """Take one measurement: predict to its stamp, correct; return whether it was taken.

        The first measurement (or the first after a gap: none taken for over the ``timeout``,
        missing or rejected) is not screened for a jump: the estimate is not recent enough to
        say what the crank could have turned to. The model runs to its stamp, and where it
        is then further from the measured crank angle than its covariance allows, the crank
        is acquired again (:meth:`_acquire`): a gap, or a start beside a press already
        running, never loses the track for good.
        """
        if math.isfinite(m.t):
            self.start(m.t)
        if self.origin:
            m = replace(m, t=m.t - self.origin)
        if self.timing is not None:
            return self.timing.take(self, m)
        return self.take(m)

    def take(self, m: Measurement) -> bool:
        """Take one measurement on the tracker's clock (:meth:`update`'s work); set
        :attr:`score` to its log-likelihood."""
        gap = m.t - self._t_last > self.settings.timeout
        crank = m.kind == "crank_angle"
        slider = m.kind == "slider_position"
        # latch open, the crank does not see the slider: where its angles are rejected running,
        # the model's slider has gone off the press's, and the crank is acquired again; so is a
        # slider whose positions are rejected running there
        latch_open = self.sim.structure != "locked"
        misses = self._crank_misses if crank else self._slider_rejects if slider else 0
        lost = (crank or slider) and latch_open and misses >= self.settings.reacquire_after
        reason = self._screen(m, recent=not (gap or lost))
        if reason is not None:
            self.rejected[reason] += 1
            if reason == "jump":
                self._crank_misses += 1
            self.score = -self.settings.gate  # worse than any innovation computed
            return False
        if gap and self._t_last > -math.inf:
            self.rejected["gap"] += 1
        e0 = self.sim.solver.current
        try:
            self._predict(m.t)
        except (MpsError, ArithmeticError, ValueError) as exc:
            self._start_again(m, e0, exc)
        if crank and (gap or lost):
            self._acquire(m)
        elif lost:
            self._acquire_slider(m)
        taken = self._correct(m)
        if crank:
            self._crank_misses = 0 if taken else self._crank_misses + 1
        elif slider:
            self._slider_rejects = 0 if taken else self._slider_rejects + 1
        self._last[m.kind] = m.t
        if taken:
            self._t_last = max(self._t_last, m.t)
            self.accepted += 1
        if self._part is not None:
            self._follow_cut(m, taken)
        return taken

    def start(self, t: float) -> None:
        """Start the model's run at the first measurement's stamp ``t`` where it is later than
        the run's start by over the ``timeout`` (:attr:`origin`: a press's stamps on its own
        clock, not seconds since the tracker was made), then apply the mode signals that came
        before it; nothing once a measurement has come."""
        if self.started:
            return
        self.started = True
        if t - self.sim.t > self.settings.timeout:
            self.origin = t - self.sim.t
            if self._stroke is not None:
                self.strokes.begin(self._stroke, self.t)
        for signal in self._early:
            self.mode(signal)
        self._early.clear()

    def _screen(self, m: Measurement, recent: bool = True) -> str | None:
        """Return the reason to reject ``m`` before anything is computed, or None (``recent``:
        whether the estimate is recent enough to screen a crank angle for a jump)."""
        if not (math.isfinite(m.t) and math.isfinite(m.value)):
            return "not-finite"
        last = self._last.get(m.kind)
        if last is not None:
            if m.t == last:
                return "duplicate"
            if m.t < last:
                return "out-of-order"
        if m.t < self.sim.t - 1e-12:
            return "late"
        if m.kind == "crank_angle" and recent:
            # a crank that would have turned by max_jump more or less than its rate says: no
            # press does that between two samples (screened before the estimate moves)
            phi, phi_dot = self.sim.joint_state()[:2]
            guess = phi + phi_dot * (m.t - self.sim.t)
            y = m.value - guess
            y -= 2.0 * math.pi * round(y / (2.0 * math.pi))
            if abs(y) >= self.settings.max_jump:
                return "jump"
        return None

    def _predict(self, t1: float) -> None:
        """Predict the state and its covariance to ``t1``."""
        sim = self.sim
        t0 = sim.t
        dt = t1 - t0
        if dt <= 1e-12:
            return
        view0, structure0 = sim.view, sim.structure
        e0 = sim.solver.current
        if self.settings.prediction == "unscented":
            moved = unscented_step(self, t1)
            if moved is not None:
                self.finish_step(t0, e0, structure0, *moved)
                return
            self.fallbacks += 1
        n = view0.n
        J, x_C0 = self._jacobian(e0)
        Phi = self._step_map(J * dt, n)
        P = Phi @ self.P @ Phi.T + self.process_noise(view0, structure0, dt)
        F, tau, W, s_m = self.x[2 * n : 2 * n + 4].tolist()
        lagged = lags.shifted(self.x, n, self.settings.force_lag)
        sim.advance_to(t1)
        e1 = sim.solver.current
        x_C1 = float(e1.kin.xy("C")[0])
        W = W - F * (x_C1 - x_C0)  # exact for a force constant over the step
        x = np.concatenate((e1.q, e1.qd, (F, tau, W, s_m), lagged))
        if sim.view is not view0:
            x, P = self._carry(x, P, e0, e1, structure0 != sim.structure)
        self.finish_step(t0, e0, structure0, x, P)

    def finish_step(self, t0: float, e0: Any, structure0: str, x: np.ndarray, P: np.ndarray) -> None:
        """Take (x, P) predicted over a step from t0 (where the run's evaluation was e0, in
        structure0): the force held at zero outside the work window, the strokes followed."""
        self._starts = (self._starts + [t0])[-self.settings.force_lag - 1 :]
        self.x = x
        self.P = 0.5 * (P + P.T)
        kin0 = e0.kin
        if not (
            self._in_window(float(kin0.xy("C")[0]), float(kin0.vxy("C")[0]), structure0) or self._window_now()
        ):
            self._hold_force()
        self._follow_strokes()

    def _step_map(self, Adt: np.ndarray, n: int) -> np.ndarray:
        """Return Φ of the whole state from J·Δt of (q, q̇, F_p, tau_b, W, s_m) in a chart view
        of n coordinates: exp to second order, and the slots shifted
        (:mod:`~mps_core.track.lags`)."""
        k = Adt.shape[0]
        Phi = _step_rows(len(self.x), n, self.settings.force_lag).copy()
        Phi[:k, :k] = _identity(k) + Adt + 0.5 * (Adt @ Adt)
        return Phi

    def _jacobian(self, e: Any) -> tuple[np.ndarray, float]:
        """Return the continuous Jacobian J of (q̇, q̈, Ḟ_p, τ̇_b, Ẇ, ṡ_m) at the run's evaluation
        ``e`` (its A and analogs exact; ∂q̈/∂q, ∂q̈/∂q̇ by forward differences from its q̈),
        and x_C there. On floats (n is 1 or 2: numpy's per-call cost would dominate)."""
        view, t = e.view, e.t
        n = view.n
        m = lags.core_size(n)
        J = np.zeros((m, m))
        ql, vl = e.q.tolist(), e.qd.tolist()
        base = e.qdd.tolist()
        scales = view.scales
        difference = self._difference
        columns = [difference(view, t, ql, vl, base, i, 1e-6 * float(scales[i]), 0) for i in range(n)]
        columns += [difference(view, t, ql, vl, base, i, 1e-5 * (1.0 + abs(vl[i])), 1) for i in range(n)]
        for i in range(n):
            J[i, n + i] = 1.0
        J[n : 2 * n, : 2 * n] = np.array(columns).T
        kin = e.kin
        jx = kin.jac("C")[0]
        J[n : 2 * n, 2 * n : 2 * n + 2] = _per_unit_input(e)
        F = float(self.x[2 * n])
        J[2 * n + 2, n : 2 * n] = [-F * a for a in jx]
        J[2 * n + 2, 2 * n] = -sum(a * v for a, v in zip(jx, vl))
        return J, float(kin.xy("C")[0])

    def _difference(
        self, view: Any, t: float, ql: list, vl: list, base: list, i: int, h: float, which: int
    ) -> list:
        """Return ∂q̈/∂q_i (which 0) or ∂q̈/∂q̇_i (which 1) by a forward difference of step h
        from q̈ = ``base`` (a backward one where the step forward leaves the chart), n floats."""
        accel = self.sim.engine.accelerations
        for sign in (1.0, -1.0):
            moved = list(ql if which == 0 else vl)
            moved[i] += sign * h
            try:
                a = accel(view, t, moved, vl) if which == 0 else accel(view, t, ql, moved)
            except (MpsError, ArithmeticError, ValueError):
                continue
            if sign > 0.0:
                return [(x - b) / h for x, b in zip(a, base)]
            return [(b - x) / h for x, b in zip(a, base)]
        return [0.0] * view.n

    def process_noise(self, view: Any, structure: str, dt: float) -> np.ndarray:
        """Return the discrete process noise over a step of dt in a chart view and structure."""
        n = view.n
        s = self.settings
        Q = np.zeros((len(self.x), len(self.x)))
        noise = s.accel_noise if structure == "locked" else s.accel_noise_unlocked
        for i in range(n):
            qa = (noise * float(view.scales[i])) ** 2
            Q[i, i] = qa * dt**3 / 3.0
            Q[i, n + i] = Q[n + i, i] = qa * dt**2 / 2.0
            Q[n + i, n + i] = qa * dt
        if structure == "locked":
            Q[2 * n, 2 * n] = s.force_walk**2 * dt
        Q[2 * n + 1, 2 * n + 1] = s.torque_walk**2 * dt
        if self.motor_measured:
            Q[2 * n + 3, 2 * n + 3] = s.motor_scale_walk**2 * dt
        return Q

    def _carry(
        self, x: np.ndarray, P: np.ndarray, e0: Any, e1: Any, impact: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        """Carry (x, P) from the chart view of e0 into that of e1: P's core through (φ, ψ, x_C),
        x's core from the run (it is there already); the slots start again."""
        n0, n1 = e0.view.n, e1.view.n
        k0, k1 = lags.core_size(n0), lags.core_size(n1)
        T0 = self._physical_map(e0)
        T1 = np.linalg.pinv(self._physical_map(e1))
        P1 = T1 @ (T0 @ P[:k0, :k0] @ T0.T) @ T1.T
        if impact:
            r = slice(n1, 2 * n1)
            P1[r, r] *= self.settings.event_inflation
        self._starts = []
        return lags.restart(x[:k1], P1, n1, self.settings.force_lag)

    def _physical_map(self, e: Any) -> np.ndarray:
        """Return the map from a chart view's (q, q̇, F, τ, W, s_m) to (φ, ψ, x_C/l1, rates, F, τ,
        W, s_m)."""
        n = e.view.n
        kin = e.kin
        scale = float(self.sim.mechanism.geometry.l1)
        G = np.array(
            [kin.omega("crank"), kin.omega("rocker"), [v / scale for v in kin.jac("C")[0]]],
            dtype=float,
        )
        T = np.zeros((10, lags.core_size(n)))
        T[:3, :n] = G
        T[3:6, n : 2 * n] = G
        T[6:, 2 * n :] = np.eye(4)
        return T

    def _prediction(self, kind: str) -> tuple[float, np.ndarray]:
        """Return the predicted value of a measurement of ``kind`` and its row of H."""
        n = self.n
        kin = self.sim.solver.current.kin
        H = np.zeros(len(self.x))
        if kind == "crank_angle":
            H[:n] = kin.omega("crank")
            return self.sim.joint_state()[0], H
        if kind == "slider_position":
            H[:n] = kin.jac("C")[0]
            return float(kin.xy("C")[0]), H
        rate = float(kin.rate("crank"))
        if kind == "crank_rate":
            H[n : 2 * n] = kin.omega("crank")
            return rate, H
        motor = self.motor
        if motor is None:
            raise MeasurementError("kind", kind, "a scene with a motor for motor_torque measurements")
        d = 1e-4 * (1.0 + abs(rate))
        slope = (motor.torque(rate + d) - motor.torque(rate - d)) / (2.0 * d)
        scale = 1.0 + float(self.x[2 * n + 3])  # the motor off its catalogue
        catalogue = float(motor.torque(rate))
        H[n : 2 * n] = scale * slope * np.asarray(kin.omega("crank"), dtype=float)
        H[2 * n + 3] = catalogue
        return scale * catalogue, H

    def _innovation(self, m: Measurement) -> tuple[float, np.ndarray, float]:
        """Return the predicted value of ``m``, its row of H and the innovation (a crank angle
        brought to the prediction's turn: the encoder counts within a turn)."""
        value, H = self._prediction(m.kind)
        z = m.value
        if m.kind == "crank_angle":
            z += 2.0 * math.pi * round((value - z) / (2.0 * math.pi))
        return value, H, z - value

    def _correct(self, m: Measurement) -> bool:
        """Correct the estimate with ``m`` (gated); return whether it was taken."""
        if m.kind == "motor_torque" and not self.motor_measured:
            self._measure_motor()
        value, H, y = self._innovation(m)
        if m.kind == "slider_position" and not self.signalled:
            S0 = float(H @ self.P @ H) + m.variance
            self._infer_mode(m, value, y * y / S0)
            value, H, y = self._innovation(m)  # predicted again: the structure may have moved
        i = 2 * self.n
        #: the process force's variance before this measurement (what it learned: how much less after)
        self.force_prior_variance = float(self.P[i, i])
        PH = self.P @ H
        S = float(H @ PH) + m.variance
        nis = y * y / S
        gate = self.settings.gate
        self.score = -0.5 * (min(nis, gate) + math.log(S / m.variance))
        if nis > gate:
            self.rejected["outlier"] += 1
            return False
        K = PH / S
        x = self.x + K * y
        IKH = _identity(len(x)) - np.outer(K, H)
        P = IKH @ self.P @ IKH.T + m.variance * np.outer(K, K)
        if not self._set_state(x, P):
            self.rejected["model"] += 1
            self.score = -gate
            return False
        self.innovations.append((m.t + self.origin, m.kind, nis))
        keep = self.keep_innovations
        if keep is not None and len(self.innovations) > 2 * keep:
            cut = len(self.innovations) - keep
            del self.innovations[:cut]
            self.innovations_dropped += cut
        self._follow_strokes()
        return True

    def _measure_motor(self) -> None:
        """Make the motor's share off its catalogue, s_m, a state from now on, the motor's torque
        measured for the first time (the prior of ``motor_scale_sigma``; none before: no
        variance moved there). A scene without a motor: the measurement is refused, the state
        left as it was."""
        if self.motor is None:
            raise MeasurementError(
                "kind", "motor_torque", "a scene with a motor for motor_torque measurements"
            )
        self.motor_measured = True
        k = 2 * self.n + 3
        self.P[k, k] = self.settings.motor_scale_sigma**2

    def _set_state(self, x: np.ndarray, P: np.ndarray) -> bool:
        """Restart the model's run at state x (covariance P); False (the run and the estimate as
        they were) where x has no configuration in the present chart. Where the corrected
        state changes the structure (the top stop lets go of a slider it would now pull), the
        state is carried into the chart view the run is in then, as at any change of structure."""
        n = self.n
        sim = self.sim
        e, structure0 = sim.solver.current, sim.structure
        saved = list(self.inputs.values)
        self.inputs.set(float(x[2 * n]), float(x[2 * n + 1]))
        try:
            sim.restart_at(x[:n], x[n : 2 * n])
        except (MpsError, ArithmeticError, ValueError):
            self.inputs.set(*saved)
            sim.restart_at(e.q, e.qd)
            return False
        carried = sim.view is not e.view
        if carried:
            e1 = sim.solver.current
            core = np.concatenate([e1.q, e1.qd, x[2 * n : lags.core_size(n)]])
            x, P = self._carry(core, P, e, e1, structure0 != sim.structure)
            self.P = 0.5 * (P + P.T)
        self.x = x
        if not self._window_now():
            self._hold_force()
        if not carried:
            self.P = 0.5 * (P + P.T)  # (after the hold, which zeroed the force's variance before it)
        return True

    # -- cuts -----------------------------------------------------------------------------
    def _follow_cut(self, m: Measurement, taken: bool) -> None:
        """Gather a cut's crank angles over the work window, from the last state filtered above
        it; once the window closes, fit the cut whole (:mod:`~mps_core.track.cut_fit`)."""
        if self._window_now():
            if self._cut is None:
                if self._cut_start is None:  # a window entered without a start: not fitted
                    return
                self._cut, self._cut_start = (self._cut_start, ()), None
            if taken and m.kind == "crank_angle":
                start, samples = self._cut
                self._cut = (start, samples + ((m.t, m.value, m.variance),))
            return
        if self._cut is not None:
            start, samples = self._cut
            self._cut = None
            if self.sim.structure == "locked":
                self._close_cut(start, samples)
        self._cut_start = None
        sim = self.sim
        if not (taken and sim.structure == "locked" and self.n == 1):
            return
        kin = sim.solver.current.kin
        if float(kin.vxy("C")[0]) < 0.0 and float(kin.xy("C")[0]) < self.work_zone_top + CUT_MARGIN:
            i = 2 * self.n + 1
            self._cut_start = CutStart(
                sim.t,
                sim.structure,
                sim.view.name,
                NominalModel.controls_of(sim),
                float(self.x[0]),
                float(self.x[1]),
                self.P[:2, :2].copy(),
                float(self.x[i]),
                float(self.P[i, i]),
            )

    def _close_cut(self, start: CutStart, samples: tuple) -> None:
        """Fit a cut whole, or hand its job out (:attr:`defer_fits`). A cut whose work the
        filter finds within three of its 1-σ of none blanked no part: not fitted."""
        assert self._part is not None
        i = 2 * self.n + 2
        work, work_sd = float(self.x[i]), _sd(self.P[i, i])
        if work < 3.0 * work_sd:
            self.cuts_without_part += 1
            return
        if self._pending is not None:  # the last cut's curve is where this one's search begins
            job = self._pending
            self.take_fit(job, self.await_fit(job) if self.await_fit is not None else self._fit(job))
        self._cuts += 1
        stroke = -1 if self._stroke is None else self._stroke
        f_max, _x0, pb = self._part
        if self._part_torque_offset is None:  # the nominal part, scaled to the filter's work
            job = CutJob(start, samples, self._part, work, 0.0, stroke, self._cuts)
        elif abs(work - 2.0 * f_max * pb / math.pi) > 3.0 * work_sd:
            # another part than the last (two in the die, none...): the last one's curve scaled
            # to the filter's work
            job = CutJob(start, samples, self._part, work, self._part_torque_offset, stroke, self._cuts)
        else:  # the last cut's curve
            job = CutJob(start, samples, self._part, None, self._part_torque_offset, stroke, self._cuts)
        if self.defer_fits:
            self._pending = job
            self.cut_jobs.append(job)
            self.strokes.pending(stroke)
            return
        self.take_fit(job, self._fit(job))

    def _fit(self, job: CutJob) -> CutFit | None:
        """Fit ``job`` here."""
        if self._fitter is None:
            self._fitter = CutFitter(self._scene, self.settings)
        return self._fitter.fit(job)

    def take_fit(self, job: CutJob, fit: CutFit | None) -> bool:
        """Take a cut's fit (None: it did not converge): the peak of its stroke, the curve the
        next cut's search begins at. Return False (nothing taken) for a job the tracker no
        longer waits for (a late signal's search took the measurements since again)."""
        if self.defer_fits:
            if job is not self._pending:
                return False
            self._pending = None
        if fit is None:
            self.cuts_unfitted += 1
            self.strokes.unfitted(job.stroke)
            return True
        self.cuts_fitted += 1
        self._part, self._part_torque_offset = fit.curve, fit.torque_offset
        self.strokes.fitted(job.stroke, fit, fit.t_peak + self.origin)
        return True

    # -- strokes and loads ----------------------------------------------------------------
    def _follow_strokes(self) -> None:
        """Close the stroke under way at a top dead centre and start the next."""
        k = self._stroke_now()
        if k == self._stroke:
            return
        i = 2 * self.n + 2
        if self._stroke is not None:
            self.strokes.close(self.t, float(self.x[i]), _sd(self.P[i, i]))
        self.x[i] = 0.0
        self.P[i, :] = 0.0
        self.P[:, i] = 0.0
        self._stroke = k
        if k is not None:
            self.strokes.begin(k, self.t)

    def observe_stroke(
        self, loads: dict[str, tuple[float, float]] | None = None, estimate: Estimate | None = None
    ) -> None:
        """Give the stroke table the present estimate (``estimate``, where the caller has it) and
        the foundation load, if computed."""
        est = estimate or self.estimate()
        found = sigma = None
        if loads is not None:
            found, sigma = foundation_magnitude(loads)
        self.strokes.observe(
            est.t_force_smoothed,
            est.force_smoothed,
            est.force_smoothed_sigma,
            found,
            math.nan if sigma is None else sigma,
        )

    def loads(self, reactions: list | None = None, sigma: bool = True) -> dict[str, tuple[float, float]]:
        """Return the joint reactions and the foundation load at the present estimate: name →
        (value, 1-σ; NaN unless ``sigma``). ``reactions``: those of the present estimate in
        ``REACTION_COLUMNS`` order, where the caller has solved them already (solved here
        otherwise)."""
        n = self.n
        i = 2 * n
        e = self.sim.solver.current
        where = list(range(2 * n)) + [i, i + 1]
        present = e if self.inputs.values[0] == float(self.x[i]) else None
        base = None
        if present is not None and reactions is not None:
            base = [float(reactions[k]) for k in _LOAD_INDEX]
        return self._loads_at(e.t, e.q, e.qd, self.x[i], where, present, base, sigma)

    def smoothed_loads(self, sigma: bool = True) -> tuple[float, dict[str, tuple[float, float]]]:
        """Return the time ``force_lag`` steps back and the joint reactions and the foundation
        load there, from the fixed-lag smoother's state and force (the present ones where the
        slots have not filled since the chart view last changed); their 1-σ NaN unless ``sigma``
        (the values the same either way: the sensitivities are what the 1-σ costs)."""
        lag = self.settings.force_lag
        if lag == 0 or len(self._starts) < lag:
            return self.t, self.loads(sigma=sigma)
        n = self.n
        sl = lags.slot(n, lag)
        x = self.x[sl]
        where = list(range(sl.start, sl.start + 2 * n)) + [sl.stop - 1, 2 * n + 1]
        t = self._starts[-lag]
        return t + self.origin, self._loads_at(t, x[:n], x[n : 2 * n], x[2 * n], where, sigma=sigma)

    def _loads_at(
        self,
        t: float,
        q: np.ndarray,
        qd: np.ndarray,
        force: float,
        where: list[int],
        present: Any = None,
        base: list | None = None,
        sigma: bool = True,
    ) -> dict[str, tuple[float, float]]:
        """Return the loads at (t, q, q̇) with the process force ``force`` and the present load
        torque, their 1-σ from the covariance of the state's components ``where`` (those of q,
        q̇, the force, the torque; NaN, and no sensitivity computed, unless ``sigma``).

        ``present``: the run's evaluation at exactly that state and force, where the caller has
        it (evaluated again otherwise); ``base``: the loads there, where the caller has them.
        The loads' sensitivities to q and q̇ are forward differences; to the force and the
        torque they are exact: the loads are affine in both (q̈ moves by A⁻¹·∂x_C/∂q and
        A⁻¹·∂φ/∂q per unit, the kinematics stay).
        """
        view, n = self.sim.view, self.n
        fun = self.sim.engine.evaluator(view)
        q, qd = np.array(q, dtype=float), np.array(qd, dtype=float)
        saved = list(self.inputs.values)
        self.inputs.values[0] = float(force)
        columns = []  # ∂(loads)/∂ each of q, q̇, the force, the torque
        try:
            e0 = present if present is not None else fun(t, q, qd)
            if base is None:
                base = self._reaction_values(e0)
            if not sigma:
                out = LoadEstimates(zip(LOAD_COLUMNS, zip(base, [math.nan] * len(base))))
                out.foundation_xy_covariance = math.nan
                return out
            zero = [0.0] * len(base)
            scales, rates = view.scales, qd.tolist()
            for j in range(2 * n):
                qj, qdj = q.copy(), qd.copy()
                if j < n:
                    h = 1e-6 * float(scales[j])
                    qj[j] += h
                else:
                    h = 1e-4 * (1.0 + abs(rates[j - n]))
                    qdj[j - n] += h
                try:
                    moved = self._reaction_values(fun(t, qj, qdj))
                except (MpsError, ArithmeticError, ValueError):
                    columns.append(zero)
                    continue
                columns.append([(a - b) / h for a, b in zip(moved, base)])
            dqdd = _per_unit_input(e0).T.tolist()
            qdd0 = e0.qdd.tolist()
            for k in range(2):
                self.inputs.values[k] += 1.0
                try:
                    moved = self._reaction_values(e0, [a + d for a, d in zip(qdd0, dqdd[k])])
                    columns.append([a - b for a, b in zip(moved, base)])
                except (MpsError, ArithmeticError, ValueError):
                    columns.append(zero)
                self.inputs.values[k] -= 1.0
        finally:
            self.inputs.values[:] = saved
        J = np.array(columns).T
        rows = np.asarray(where)
        C = self.P[rows][:, rows]
        var = np.einsum("ij,jk,ik->i", J, C, J).tolist()
        out = LoadEstimates(zip(LOAD_COLUMNS, zip(base, map(_sd, var))))
        out.foundation_xy_covariance = float(J[_FOUND_X] @ C @ J[_FOUND_Y])
        return out

    def _reaction_values(self, e: Any, qdd: list | None = None) -> list:
        """Return the reactions of :data:`LOAD_COLUMNS` at the run's evaluation ``e`` (at
        accelerations ``qdd`` instead of its own, where given), floats."""
        sim = self.sim
        a = e.qdd.tolist() if qdd is None else qdd
        fast = reaction_values(
            sim.mechanism, sim.engine.effects, e.view, e.t, e.q.tolist(), e.qd.tolist(), a, e.kin
        )
        if fast is not None:
            values = fast[0]
            return [float(values[k]) for k in _LOAD_INDEX]
        rx = compute_reactions(
            sim.mechanism, sim.engine.effects, e.view, e.t, e.q, e.qd, np.array(a, dtype=float), kin=e.kin
        )
        return [float(rx.values[c]) for c in LOAD_COLUMNS]


@functools.cache
def _identity(m: int) -> np.ndarray:
    """Return the identity of size m (read-only: one for every caller)."""
    out = np.eye(m)
    out.flags.writeable = False
    return out


@functools.cache
def _step_rows(m: int, n: int, lag: int) -> np.ndarray:
    """Return a step's Φ of a state of size m in a chart view of n coordinates with only its slots'
    rows filled (:func:`~mps_core.track.lags.step_rows`; read-only: copied, the core's rows set)."""
    out = np.zeros((m, m))
    lags.step_rows(out, n, lag)
    out.flags.writeable = False
    return out


def _per_unit_input(e: Any) -> np.ndarray:
    """Return the columns of q̈ per unit process force and per unit load torque at evaluation ``e``.

    A⁻¹·∂x_C/∂q and A⁻¹·∂φ/∂q: one solve for both (a division in a one-coordinate chart).
    """
    kin = e.kin
    gx, gphi = kin.jac("C")[0], kin.omega("crank")
    if e.view.n == 1:
        a = float(e.A[0, 0])
        return np.array([[gx[0] / a, gphi[0] / a]])
    return np.linalg.solve(e.A, np.array([gx, gphi], dtype=float).T)


def work_zone_top(scene: Scene, settings: TrackSettings) -> float:
    """Return the top of the work window: the setting's, else 2 mm above where the nominal
    scene's punch touches its part, else 4 mm (the lower third of the preset's stroke)."""
    if settings.work_zone_top is not None:
        return float(settings.work_zone_top)
    contacts = [e.params["x_contact"] for e in scene.effects if e.kind in PROCESS_EFFECTS]
    return max(contacts) + 0.002 if contacts else 0.004


def foundation_magnitude(loads: dict[str, tuple[float, float]]) -> tuple[float, float]:
    """Return the foundation force's magnitude and its 1-σ, linearised: with g = F/|F|,
    σ² = gᵀ·C·g, C the two components' covariance (their 1-σ and, where ``loads`` is a
    :class:`LoadEstimates`, their covariance; none where it is a plain mapping)."""
    fx, sx = loads["F_found_x"]
    fy, sy = loads["F_found_y"]
    cxy = float(getattr(loads, "foundation_xy_covariance", 0.0))
    f = math.hypot(fx, fy)
    if f == 0.0:
        return 0.0, math.hypot(sx, sy)
    var = (fx * fx * sx * sx + fy * fy * sy * sy + 2.0 * fx * fy * cxy) / (f * f)
    return f, _sd(var)


def _quadratic(g: list, P: np.ndarray, o: int) -> float:
    """Return gᵀ·P[o:o+n, o:o+n]·g for n floats g, on floats ((gᵀ·P)·g in numpy's order)."""
    n = len(g)
    if n == 1:
        return g[0] * float(P[o, o]) * g[0]
    block = P[o : o + n, o : o + n].tolist()
    row = [sum(g[a] * block[a][b] for a in range(n)) for b in range(n)]
    return sum(row[b] * g[b] for b in range(n))


def _sd(variance: float) -> float:
    """Return the standard deviation of a variance that round-off may have made slightly negative."""
    return math.sqrt(max(float(variance), 0.0))
