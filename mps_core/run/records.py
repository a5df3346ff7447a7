"""What a run records: a row at each output (:class:`Recorder`) and its work counts
(:class:`WorkCounts`).

A row is one tuple a step, in the order of :data:`ROW` (the columns are made once, at the end);
the observers are called at each row (``observe(simulation, evaluation)``) and their
``columns()`` join the trajectory's. An output inside a step longer than the output interval is
the step's interpolant there, evaluated, with the work, impact loss and structure of that step.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import NumericalError
from ..names import COLUMNS
from .trajectory import Trajectory

__all__ = ["ROW", "Recorder", "WorkCounts"]

#: a recorded row's columns (see :meth:`Recorder.record`), in :data:`~mps_core.names.COLUMNS`
ROW = (
    "t",
    "phi",
    "psi",
    "phi_dot",
    "psi_dot",
    "phi_ddot",
    "psi_ddot",
    "x_C",
    "T",
    "V",
    "W",
    "E_impact",
    "structure",
    "chart",
)


class Recorder:
    """The rows of one :meth:`~mps_core.run.simulation.Simulation.run` of ``sim`` and the
    trajectory made of them."""

    def __init__(self, sim) -> None:
        self.sim = sim
        self.rows: list[tuple] = []

    def record(self, e, work=None, loss=None, structure=None) -> None:
        """Append the row of :data:`ROW` at evaluation ``e`` and call the observers. ``work``,
        ``loss``, ``structure``: the run's at ``e`` where they are not the present ones (an
        output inside a step)."""
        sim = self.sim
        observables = sim.observables
        obs = observables.observations(e)
        at = observables.report_at
        energy = sim.energy
        phi, psi = obs[at["phi"]], obs[at["psi"]]
        self.rows.append(
            (
                e.t,
                phi[0],
                psi[0],
                phi[1],
                psi[1],
                phi[2],
                psi[2],
                obs[at["x_C"]][0],
                e.kinetic_energy,
                energy.potential(e.kin),
                energy.work if work is None else work,
                energy.impact_loss if loss is None else loss,
                sim.controls.structure if structure is None else structure,
                e.view.name,
            )
        )
        for ob in sim.observers:
            ob.observe(sim, e)

    def record_inside(self, tk: float, spans: list, tol: float) -> None:
        """Record the output at ``tk`` from the last step of ``spans`` that holds it (each
        ``[t_a, t_b, dense output, view, structure, work, power at t_a, impact loss]``)."""
        # the span found is read after the loop
        for t_a, t_b, dense, view, structure, work, p_a, loss in reversed(spans):  # noqa: B007
            if t_a - tol <= tk <= t_b + tol:
                break
        else:
            raise NumericalError(f"no step holds the output at t = {tk!r}", tk)
        q, qd = dense(tk)
        sim = self.sim
        e = sim.engine.evaluate(view, tk, np.array(q, float), np.array(qd, float))
        self.record(
            e, work=work + 0.5 * (p_a + sim.energy.power(e)) * (tk - t_a), loss=loss, structure=structure
        )

    def trajectory(self) -> Trajectory:
        """The rows so far as columns, the observers' columns, the events, counts and settings."""
        sim = self.sim
        data = dict(zip(ROW, zip(*self.rows)))
        cols = {
            k: (
                np.array(data.get(k, ()), dtype=float)
                if k not in ("structure", "chart")
                else np.array(data.get(k, ()))
            )
            for k in COLUMNS
        }
        for ob in sim.observers:
            cols.update(ob.columns())
        counts = sim.work_counts.counts(sim.engine.counts, sim.solver)
        settings = {**sim.settings.described(), "chart_switching": sim.policy.switching}
        return Trajectory(cols, list(sim.events), counts, settings)

    def run_long_steps(self, t0, t_end, n, step, progress=None) -> Trajectory:
        """Steps longer than the output interval. Each output inside a step is the step's
        interpolant there, evaluated (q̈, the kinematics, the observers' outputs), with the
        structure, work (trapezoid from the step's start) and impact loss of that step; an
        output at a step's end is that step's own evaluation. The steps keep the grid
        t0 + m·step; events still end steps at their roots, and commands and charts change
        between steps, as with any step."""
        times = [t_end if k == n else t0 + k * (t_end - t0) / n for k in range(1, n + 1)]
        tol = 1e-12 * max(1.0, abs(t_end))
        k = 0
        sim = self.sim
        spans: list[list] = []
        sim._spans = spans
        try:
            while k < n:
                spans.clear()
                # the steps keep their grid t0 + m·step: after an event's cut the next step
                # ends where it would have
                m = math.floor((sim.solver.t - t0) / step + 1e-9) + 1
                sim.advance_to(min(t0 + m * step, t_end))
                t_now = sim.solver.t
                while k < n and times[k] <= t_now + tol:
                    tk = times[k]
                    if abs(tk - t_now) <= tol:
                        self.record(sim.solver.current)
                    else:
                        self.record_inside(tk, spans, tol)
                    k += 1
                if progress is not None:
                    progress(t_now)
        finally:
            sim._spans = None
        return self.trajectory()


class WorkCounts:
    """A run's work beyond its engine's counts: the right-hand sides and steps of the solvers it
    has replaced (a new solver at every restart: an event's cut, a change of chart, a command)
    and the switching points of the effects' force laws crossed (a step ended at each). A
    checkpoint of the run keeps :meth:`state`."""

    __slots__ = ("solver_evaluations", "steps", "switch_points")

    def __init__(self) -> None:
        self.solver_evaluations = 0
        self.steps = 0
        self.switch_points = 0

    def retire(self, solver) -> None:
        """Count the work of a solver the run replaces."""
        self.solver_evaluations += solver.nfev
        self.steps += solver.nsteps

    def counts(self, engine_counts: dict, solver) -> dict:
        """The trajectory's counts: the engine's, and the solvers' with the present one."""
        counts = dict(engine_counts)
        counts["solver_evaluations"] = self.solver_evaluations + solver.nfev
        counts["steps"] = self.steps + solver.nsteps
        counts["switch_points"] = self.switch_points
        return counts

    def state(self) -> tuple[int, int, int]:
        """(solver evaluations, steps, switch points), for :meth:`set_state`."""
        return self.solver_evaluations, self.steps, self.switch_points

    def set_state(self, state: tuple[int, int, int]) -> None:
        self.solver_evaluations, self.steps, self.switch_points = state
