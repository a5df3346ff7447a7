"""The run driver: steps a solver on the engine through structures, events, commands and charts.

The loop and its bookkeeping live here (steps, event location in the step, charts, stiffness,
energy, records); the switches between structures, their impacts and the commands are the
structure layer's (:mod:`mps_core.run.structure_layer`), which the loop calls at located events and
at the commands' times.

**Structures** (contract §5): ``free`` (φ, ψ), ``locked`` (ψ frozen at ψ_lock: the latch closed),
``held`` (x_C frozen at x_top: the slider on its top stop). Switches:

* latch closes (latch armed, ψ reaches ψ_lock): perfectly plastic impact,
  ``q̇⁺ = q̇⁻ − A⁻¹g (gᵀq̇⁻)/(gᵀA⁻¹g)`` with g = ∇ψ, then ``locked``;
* slider reaches its top stop moving up: the same impact with g = ∇x_C, then ``held``;
* slider leaves its top stop: where the stop's reaction λ (the generalized force along x_C the
  stop must give the slider, from the unfrozen chart's equations) turns tensile, then ``free``;
* latch opens at a ``disengage`` command: ``free`` with ψ̇ = 0, no jump.

**Events** are located inside the step: after each step the event functions are compared with
their values at the step's start; at a sign change the root of the function along the step's dense
output is found (Brent, |Δt| ≤ 1e-13 s), the step is cut there, the solver restarted from the
interpolated state at the root, and the event's action applied. Each event is logged (time, kind,
velocities before and after, kinetic energy lost, impulse). **Commands** (``engage``,
``disengage``, ``stop``, ``start``) are applied at their exact time by cutting the step there.

**Change point** (held four-bar at x_top = l1 + l2 − l3): by default the smooth continuation
(the continuation chart passes it, each passage logged); ``change_point="keep-side"`` keeps the
rocker on its side with a plastic impact onto that branch.

**Charts** (see :mod:`mps_core.model.mechanism`): after every step the current chart's regularity is
read; below ``switch_below`` the driver moves to the most regular chart of the structure that
owns the configuration, mapping q and q̇ exactly through jets. A step that leaves its chart's
domain is retaken in another chart. No regular chart: :class:`SingularConfiguration`; switching
off: :class:`ChartBreakdown`.

**Stiff effects**: before each fixed step the shortest period T_min of the stiff effects
(generalized eigenproblem K v = ω² A v) is compared with the method's stability limit: the
seed's linear acceleration predictor-corrector ω·Δt ≤ 2 (Δt ≤ T_min/π ≈ 0.318·T_min; the
implicit method's √3/π·T_min ≈ 0.551·T_min is not this explicit scheme's), RK4 ω·Δt ≤ 2√2
(≈ 0.450·T_min). Policy ``subdivide`` cuts the step into stable substeps; ``error`` raises
:class:`StabilityError` saying why. (With an even number of corrections the predictor-corrector
is weakly unstable at any step: its amplification exceeds 1 by about (ω·Δt)⁶/10⁴ per step for
2 corrections; one or three corrections are stable and slightly dissipative.) Where every stiff
effect bounds its ω² over all states (``stiffness_bound``, e.g. k/M for a spring at a centre of
mass M), steps well inside the limit of those bounds skip the per-step estimate: it would keep
them whole.

**Per step** the driver does only what the step needs: what depends on a chart view alone (where
each reported observable comes from, the event functions) is worked out once per view, the
recorded rows are tuples made into columns at the end (:mod:`mps_core.run.records`), and the
reported angles read for unwrapping after a step are reused by its record.

**Energy** (:mod:`mps_core.run.energy`): the work of the non-conservative effects is integrated
per step (trapezoid rule on their power at the step's ends) into ``W``; impact losses accumulate
into ``E_impact``; the balance ``T + V − (T0 + V0) − W + E_impact`` closes to the integration
error.
"""

from __future__ import annotations

import math

import numpy as np

from ..dynamics.engine import PartialSystems
from ..errors import ChartDomainError, MpsError, config_in_degrees
from ..model.effects import Controls
from ..model.effects.controls import ControlledEffect
from ..model.mechanism import ChartView
from ..scene.settings import CHANGE_POINTS, ChartPolicy, SolverSettings
from ..solvers import ADAPTIVE_SOLVERS, FIXED_STEP_SOLVERS, make_solver
from .charts import ChartChanger
from .energy import EnergyAccount
from .events import EventLocator
from .observables import Observables
from .records import Recorder, WorkCounts
from .schedule import Schedule
from .stability import StepStability
from .structure_layer import CommandRefused, StructureLayer
from .trajectory import Trajectory

#: the defaults of a simulation built by hand (frozen: shared safely)
_DEFAULT_SOLVER, _DEFAULT_CHARTS = SolverSettings(), ChartPolicy()


def _check_settings(solver: SolverSettings, change_point: str) -> None:
    """The settings a simulation refuses: an unknown change-point rule, keep-side without
    central differences, a step that is not a positive time or given to an adaptive solver."""
    if change_point not in CHANGE_POINTS:
        expected = " or ".join(repr(c) for c in CHANGE_POINTS)
        raise ValueError(f"change_point = {change_point!r}: expected {expected}")
    if change_point == "keep-side" and solver.scheme != "central":
        # the run restarts exactly at the change point, where √h² has no derivative: jets
        # are undefined there, central stencils straddle it on the smooth chart
        raise ValueError(
            "change_point = 'keep-side' needs central differences (solver.derivatives = 'central')"
        )
    if solver.step is not None:
        if not (solver.step > 0.0 and math.isfinite(solver.step)):
            raise ValueError(f"step = {solver.step!r}: expected a positive number of seconds")
        if solver.name in ADAPTIVE_SOLVERS:
            raise ValueError(
                f"step = {solver.step!r}: the adaptive solver {solver.name} "
                f"chooses its own steps (a step is for {', '.join(FIXED_STEP_SOLVERS)})"
            )


def _whole_rows(traj: Trajectory) -> Trajectory:
    """Return ``traj`` with every column cut to the rows all of them hold (an interruption
    can fall between a row and its observers' columns)."""
    n = min(len(v) for v in traj.columns.values())
    traj.columns = {k: v[:n] for k, v in traj.columns.items()}
    return traj


class Simulation:
    """One run of a mechanism: structures, events, commands, charts."""

    def __init__(
        self,
        mechanism,
        structure: str,
        effects,
        initial,
        *,
        solver: SolverSettings = _DEFAULT_SOLVER,
        charts: ChartPolicy = _DEFAULT_CHARTS,
        t0: float = 0.0,
        observers=(),
        commands=(),
        controls: Controls | None = None,
        change_point: str = "continue",
    ):
        _check_settings(solver, change_point)
        self.mechanism = mechanism
        #: at a change point (held four-bar at x_top = l1 + l2 − l3): the smooth continuation,
        #: or the rocker kept on its side with a plastic impact
        self.change_point = change_point
        self.settings = solver
        self.policy = charts
        self.effects = list(effects)
        self.controls = controls or Controls(structure=structure)
        self.controls.structure = structure
        for e in self.effects:
            if isinstance(e, ControlledEffect):
                e.use(self.controls)
        self.engine = PartialSystems(
            mechanism, self.effects, solver.scheme, solver.delta, kernels=solver.kernels
        )
        #: called at every recorded step: ``observe(simulation, evaluation)``; their
        #: ``columns()`` join the trajectory's (reactions, loads: only when a scene asks)
        self.observers = list(observers)
        #: the switches between structures, the impacts and the commands (and the press's
        #: parts they act through)
        self.structures = StructureLayer(self)
        motor = self.structures.parts.motor
        if motor is not None:
            self.controls.motor_on = motor.enabled
        #: the fixed steps' stability limit for the stiff effects
        self.stability = StepStability(self.effects, mechanism, solver)
        view, q, qd = initial
        self.view: ChartView = view
        self.events: list[dict] = []
        #: the commands given for later and the driver's own control changes (the disengage
        #: cylinder's end): step boundaries
        self.schedule = Schedule(commands)
        #: the events that can happen now and where they happen inside a step
        self.events_now = EventLocator(self, solver.locates_switch_points())
        #: the changes of chart where the present one degenerates
        self.charts = ChartChanger(self)
        #: the solvers' work and the switching points crossed (the engine counts its own)
        self.work_counts = WorkCounts()
        #: W, E_impact and V: the energy balance's terms
        self.energy = EnergyAccount(self.effects)
        #: the reported observables' values, rates and accelerations in any chart
        self.observables = Observables(self)
        self.phys: dict[str, float] = {}
        self._phys_of = None  # the evaluation phys was last read from
        #: (evaluation, phys's evaluation, joint state) of the last :meth:`joint_state`
        self._joint_memo: tuple | None = None
        #: the steps of a run with steps longer than its outputs (``Recorder.run_long_steps``)
        self._spans = None
        self.solver = self._new_solver(t0, q, qd)
        self.observables.update_phys(self.solver.current)
        self.energy.power_now = self.energy.power(self.solver.current)
        self._chart_due = False
        self.charts.check()
        self._ev_prev = self.events_now.values(self.solver.t, self.solver.q, self.solver.qd)
        self._seg_start = self.solver.t
        if self._ev_prev.get("stop-release", -1.0) > 0.0:
            self.structures.release_stop(self.solver.t)

    # -- state ----------------------------------------------------------------------------
    @property
    def structure(self) -> str:
        return self.controls.structure

    @property
    def t(self) -> float:
        return self.solver.t

    # -- checkpoints ----------------------------------------------------------------------
    @property
    def rewindable(self) -> bool:
        """Whether :meth:`checkpoint` works here: the solver keeps its state (scipy's Radau
        does not) and every observer has ``checkpoint`` and ``restore``."""
        return self.solver.rewindable and all(
            hasattr(ob, "checkpoint") and hasattr(ob, "restore") for ob in self.observers
        )

    def checkpoint(self) -> tuple:
        """The run's state now, for :meth:`restore`: a driver that took steps ahead comes back
        to a step boundary (a command arrived for it) and goes on from there exactly as if it
        had stopped there. Shallow and cheap (a few µs): the state's objects are replaced, not
        changed, by a step, except the containers copied here (the controls, the motor switched
        on or off, the event log, the schedule's commands and timers, the energy account, the
        work counts, the unwrapping references, the observers' own ``checkpoint``). Caches
        (kernels, views, plans) are shared, not kept."""
        if not self.rewindable:
            raise NotImplementedError(
                f"no checkpoint of this run: solver {self.solver.name!r} or an observer "
                "without checkpoint/restore cannot be rewound"
            )
        return (
            dict(self.__dict__),
            self.solver.state(),
            dict(vars(self.controls)),
            self.structures.parts.state(),
            list(self.events),
            self.schedule.state(),
            self.energy.state(),
            self.work_counts.state(),
            dict(self.phys),
            [ob.checkpoint() if hasattr(ob, "checkpoint") else None for ob in self.observers],
        )

    def restore(self, cp: tuple) -> None:
        """Come back to a :meth:`checkpoint` of this run."""
        state, solver, controls, parts, events, schedule, energy, work, phys, observers = cp
        d = self.__dict__
        d.clear()
        d.update(state)
        self.solver.set_state(dict(solver))
        vars(self.controls).update(controls)
        self.controls.touch()  # restored behind __setattr__: code folded on them is stale
        self.structures.parts.set_state(parts)
        self.events[:] = events
        self.schedule.set_state(schedule)
        self.energy.set_state(energy)
        self.work_counts.set_state(work)
        self.phys.clear()
        self.phys.update(phys)
        for ob, st in zip(self.observers, observers):
            if st is not None:
                ob.restore(st)

    def views(self, structure: str) -> list[ChartView]:
        """The chart views of ``structure`` (:meth:`ChartChanger.views <.charts.ChartChanger.views>`)."""
        return self.charts.views(structure)

    # -- solver management ----------------------------------------------------------------
    def _fun(self, view):
        return self.engine.evaluator(view)

    def _new_solver(self, t, q, qd):
        s = self.settings
        old = getattr(self, "solver", None)
        first = None
        if old is not None:
            self.work_counts.retire(old)
            first = getattr(old, "step_size", None)  # an adaptive solver carries on its step
        view = self.view
        return make_solver(
            s.name,
            self._fun(view),
            t,
            q,
            qd,
            iterations=s.iterations,
            rtol=s.rtol,
            atol=s.atol,
            scales=view.scales,
            first_step=first,
            accel=self.engine.accelerator(view),
        )

    def _restart(self, view, t, q, qd):
        self.view = view
        self.solver = self._new_solver(t, q, qd)
        self.energy.power_now = self.energy.power(self.solver.current)
        self._ev_prev = self.events_now.values(t, self.solver.q, self.solver.qd)
        self._seg_start = t
        # the forces may have changed (a command, an impact): a stop that would now pull lets go
        if self._ev_prev.get("stop-release", -1.0) > 0.0:
            self.structures.release_stop(t)

    def config(self, e=None) -> dict:
        e = e or self.solver.current
        vals = {k: v for k, (v, _, _) in self.observables.observe(e).items()}
        return config_in_degrees(vals) | {"structure": self.structure, "chart": self.view.name}

    def _cut_at(self, t_e: float):
        """Restart the solver from the last step's interpolant at t_e (same chart)."""
        q, qd = self.solver.dense_output()(t_e)
        self.solver = self._new_solver(t_e, np.array(q, float), np.array(qd, float))

    def restart_at(self, q, qd) -> None:
        """Take (q, q̇) in the present chart view as the state now and restart the solver there
        (a state estimator's correction of the run it follows)."""
        self._restart(self.view, self.solver.t, np.asarray(q, dtype=float), np.asarray(qd, dtype=float))
        self.observables.update_phys(self.solver.current)

    # -- commands (the structure layer's) -------------------------------------------------
    def check_command(self, name) -> None:
        """Raise :class:`CommandRefused` if ``name`` makes no sense now."""
        self.structures.check_command(name)

    def command(self, name: str, t: float | None = None) -> None:
        """Take a command now (t None) or at a later simulated time; refused ones raise."""
        self.structures.command(name, t)

    # -- the state, for sinks ---------------------------------------------------------------
    def joint_state(self) -> tuple:
        """(φ, φ̇, ψ, ψ̇, x_C, ẋ_C) of the present state, floats: the numbers :meth:`snapshot`
        gives under those names, without the energies (read again from the same evaluation, with
        the angles' references unchanged, they are the same numbers: kept)."""
        e = self.solver.current
        memo = self._joint_memo
        if memo is not None and memo[0] is e and memo[1] is self._phys_of:
            return memo[2]
        obs = self.observables.observe(e)
        phi, psi, x = obs["phi"], obs["psi"], obs["x_C"]
        out = (phi[0], phi[1], psi[0], psi[1], x[0], e.kin.vxy("C")[0])
        self._joint_memo = (e, self._phys_of, out)
        return out

    def snapshot(self) -> dict:
        """The present state by the trajectory's column names (physical φ, ψ, x_C and rates,
        energies, structure, chart), plus ``x_C_dot`` and the controls."""
        e = self.solver.current
        obs = self.observables.observe(e)
        out = {"t": e.t}
        for name in ("phi", "psi"):
            v, vd, vdd = obs[name]
            out[name], out[name + "_dot"], out[name + "_ddot"] = v, vd, vdd
        out["x_C"] = obs["x_C"][0]
        out["x_C_dot"] = float(e.kin.velocity("C")[0])
        out["T"] = e.kinetic_energy
        out["V"] = self.engine.potential_energy(e.kin)
        out["W"] = self.energy.work
        out["E_impact"] = self.energy.impact_loss
        out["structure"] = self.structure
        out["chart"] = self.view.name
        c = self.controls
        out["motor_on"], out["engage_on"], out["latch_armed"] = c.motor_on, c.engage_on, c.latch_armed
        return out

    # -- the run --------------------------------------------------------------------------
    def advance_to(self, t_target: float) -> None:
        """Integrate to t_target, through commands, events and chart changes on the way."""
        tol = 1e-12 * max(1.0, abs(t_target))
        failures = 0
        while self.solver.t < t_target - tol:
            if self._chart_due:
                # the chart's regularity at the last step's end, looked at when the next step
                # is about to start (a run that ends there changes no chart for nothing)
                self._chart_due = False
                self.charts.check()
            t0 = self.solver.t
            if self._at_boundary(t0, tol):
                continue
            p_a = self.energy.power_now
            self._seg_start = t0
            try:
                self.solver.step_to(t0 + self._step_size(t0, t_target), interrupt=self.events_now.interrupt)
            except ChartDomainError as exc:
                failures += 1
                self.charts.leave_failing(exc, failures)
                continue
            left = self._after_step(t0, p_a)
            if left is not None:  # its interpolant left the chart: the step is undone
                failures += 1
                self.charts.leave_failing(left, failures)
                continue
            failures = 0

    def _at_boundary(self, t0: float, tol: float) -> bool:
        """A command or a timer due at t0 applied (or the command refused, logged): True."""
        schedule = self.schedule
        commands = schedule.commands
        if commands and commands[0][0] <= t0 + tol:
            _t_cmd, name = commands.pop(0)
            try:
                self.structures.check_command(name)
            except CommandRefused as exc:
                self.events.append(
                    {"t": t0, "kind": "command-refused", "command": name, "reason": exc.reason}
                )
                return True
            self.structures.apply_command(name, t0)
            return True
        timers = schedule.timers
        if timers and timers[0][0] <= t0 + tol:
            self.structures.apply_timer(timers.pop(0)[1], t0)
            return True
        return False

    def _step_size(self, t0: float, t_target: float) -> float:
        """The next step from t0: to the target, the next command or timer, at most the
        solver's own step, within the stability limit of the stiff effects."""
        dt = self.schedule.until(t_target) - t0
        step = self.settings.step
        if step is not None and dt > step * (1.0 + 1e-9):
            dt = step
        if dt > self.stability.always:  # else stable in any state: no estimate needed
            dt = self.stability.stable_step(dt, self.solver.current, self.config)
        return dt

    def _after_step(self, t0: float, p_a: float) -> ChartDomainError | None:
        """A step taken from t0: cut at its first event (the event's action taken), or kept
        whole with its work, its event values and the chart to look at. Where the step's
        interpolant leaves the chart between its ends (a long step over a chart's edge), the
        step is undone (the solver back at t0) and the chart's error returned, for the step to
        be taken again as one whose end left the chart."""
        spans = self._spans
        energy = self.energy
        if spans is not None:  # outputs inside the step: its interpolant
            spans.append(
                [
                    t0,
                    self.solver.t,
                    self.solver.dense_output(),
                    self.view,
                    self.controls.structure,
                    energy.work,
                    p_a,
                    energy.impact_loss,
                ]
            )
        try:
            hit, vals = self.events_now.locate()
        except ChartDomainError as exc:
            if spans is not None:
                spans.pop()
            self._cut_at(t0)
            return exc
        if hit is not None and hit[1].name == "change-point" and self.change_point != "keep-side":
            # the continuation chart is smooth through the change point: the step stands,
            # the passage is logged at its root
            q_e, qd_e = self.solver.dense_output()(hit[0])
            self.structures.record_change_point(hit[0], np.array(q_e, float), np.array(qd_e, float))
            hit = None
        if hit is not None:
            t_e, ev, after_value = hit
            if spans is not None:
                spans[-1][1] = t_e
            self._cut_at(t_e)
            energy.work += 0.5 * (p_a + energy.power(self.solver.current)) * (t_e - t0)
            ev.action(t_e)
            if ev.restart or ev.name == "change-point":
                # a new dict: a checkpoint may hold the one before
                self._ev_prev = {**self._ev_prev, ev.name: after_value}
            self.observables.update_phys(self.solver.current)
            return None
        # the step stands: its work (trapezoid on the power at its ends), the event values
        # and unwrap references at its end, and the chart's regularity there
        solver = self.solver
        e = solver.current
        p_b = energy.power(e)
        energy.work += 0.5 * (p_a + p_b) * (solver.t - t0)
        energy.power_now = p_b
        self._ev_prev = vals
        self.observables.update_phys(e)
        self._chart_due = True
        return None

    def run(self, t_end: float, dt: float, progress=None) -> Trajectory:
        """Integrate to ``t_end`` and record every ``dt``. A fixed-step solver steps by
        ``dt``, or by the settings' ``step`` where given: shorter, several steps an output;
        longer, the outputs inside a step from its interpolant
        (:meth:`Recorder.run_long_steps <mps_core.run.records.Recorder.run_long_steps>`).
        ``progress``: called with the simulated time after each output (e.g. a
        :class:`~mps_core.run.progress.Progress`)."""
        t0 = self.solver.t
        if not (t_end > t0):
            raise ValueError(f"t_end = {t_end!r}: expected a time after the start {t0!r}")
        if not (dt > 0):
            raise ValueError(f"dt = {dt!r}: expected a positive step")
        n = max(1, int(round((t_end - t0) / dt)))
        rec = Recorder(self)
        rec.record(self.solver.current)
        step = self.settings.step
        try:
            if (
                step is not None
                and step > (t_end - t0) / n * (1.0 + 1e-9)
                and self.settings.name not in ADAPTIVE_SOLVERS
            ):
                return rec.run_long_steps(t0, t_end, n, step, progress)
            for k in range(1, n + 1):
                tk = t_end if k == n else t0 + k * (t_end - t0) / n
                self.advance_to(tk)  # keeps the unwrap references current
                rec.record(self.solver.current)
                if progress is not None:
                    progress(tk)
            return rec.trajectory()
        except (MpsError, KeyboardInterrupt) as exc:
            # what was computed up to the failure or the interruption (Ctrl-C), for a caller
            # that writes it (marked partial): the rows recorded whole
            # (an attribute added to whatever was raised, Ctrl-C's too: readers getattr it)
            try:
                exc.partial = _whole_rows(rec.trajectory())  # type: ignore[union-attr]
            except Exception:
                exc.partial = None  # type: ignore[union-attr]
            raise
