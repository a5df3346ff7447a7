"""The run driver: steps a solver on the engine, keeps the chart regular, records the trajectory.

Charts. After every step the driver reads the current chart's regularity at the new state. Below
``switch_below`` it moves to the regular chart of the same structure that owns the configuration
(right assembly) and is most regular there, mapping q and q̇ exactly: the configuration and the
point velocities come from jets (exact derivatives) in the old chart and are read off as the new
chart's coordinates and their rates; angles are unwrapped to stay continuous. A step that leaves
its chart's domain is not taken: the driver changes chart at the step's start and takes it again.
If no chart is regular (all below ``fail_below``) the configuration is a true singularity of the
machine and :class:`~mps_core.errors.SingularConfiguration` is raised; with switching turned off
the run stops with :class:`~mps_core.errors.ChartBreakdown` where its chart degenerates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .engine import PartialSystems
from .errors import (ChartBreakdown, ChartDomainError, NumericalError, SingularConfiguration,
                     config_in_degrees)
from .mechanism import ChartView, unwrap_to
from .names import COLUMNS
from .solvers import make_solver
from .trajectory import Trajectory


@dataclass(frozen=True)
class ChartPolicy:
    """When to change chart: below ``switch_below`` (if ``switching``); a configuration where no
    chart reaches ``fail_below`` is singular."""

    switching: bool = True
    switch_below: float = 0.5
    fail_below: float = 1e-3


@dataclass(frozen=True)
class SolverSettings:
    name: str = "linear-acceleration"
    scheme: str = "central"
    delta: float = math.radians(0.1)
    iterations: int = 1
    rtol: float = 1e-9
    atol: float = 1e-12


class Simulation:
    """One run of a mechanism in a structure, from an initial chart state."""

    def __init__(self, mechanism, structure: str, effects, initial, *,
                 solver: SolverSettings = SolverSettings(), charts: ChartPolicy = ChartPolicy(),
                 t0: float = 0.0, observers=()):
        self.mechanism = mechanism
        self.structure = structure
        self.settings = solver
        self.policy = charts
        self.engine = PartialSystems(mechanism, effects, solver.scheme, solver.delta)
        #: called at every recorded step: ``observe(simulation, evaluation)``; their
        #: ``columns()`` join the trajectory's (reactions, loads: only when a scene asks)
        self.observers = list(observers)
        self.views = mechanism.views(structure)
        view, q, qd = initial
        self.view: ChartView = view
        self.events: list[dict] = []
        self.solver_nfev = 0
        self.solver_steps = 0
        self._report = getattr(mechanism, "report", {"phi": 2, "psi": 2, "x_C": 0})
        self.phys = {}
        self.solver = self._new_solver(t0, q, qd)
        self._update_phys(self.solver.current, init=True)
        self._check_chart()

    # -- solver management ----------------------------------------------------------------
    def _fun(self, view):
        engine = self.engine

        def fun(t, q, qd):
            return engine.evaluate(view, t, q, qd)
        return fun

    def _new_solver(self, t, q, qd):
        s = self.settings
        old = getattr(self, "solver", None)
        if old is not None:
            self.solver_nfev += old.nfev
            self.solver_steps += old.nsteps
        return make_solver(s.name, self._fun(self.view), t, q, qd, iterations=s.iterations,
                           rtol=s.rtol, atol=s.atol, scales=self.view.scales)

    # -- physical observables -------------------------------------------------------------
    def _observe(self, e):
        """Reported observables (value, rate, acceleration) from an evaluation, any chart."""
        view = e.view
        out = {}
        jets = None
        for name, order in self._report.items():
            obs = self.mechanism.observables[name]
            k = view.coordinate_index(name)
            if k is not None:
                out[name] = (float(e.q[k]), float(e.qd[k]), float(e.qdd[k]))
            elif name in view.frozen:
                out[name] = (float(view.frozen[name]), 0.0, 0.0)
            elif order == 0:
                out[name] = (obs.value(e.kin.pose), math.nan, math.nan)
            else:
                if jets is None:
                    jets = view.pose_jets(e.q, e.qd)
                j = obs.jet(jets, view.n)
                v = float(j.val)
                if obs.is_angle and name in self.phys:
                    v = unwrap_to(v, self.phys[name])
                out[name] = (v, float(j.d1), float(j.grad @ e.qdd + j.d2))
        return out

    def _update_phys(self, e, init=False):
        for name, (v, _, _) in self._observe(e).items():
            self.phys[name] = v

    def config(self, e=None) -> dict:
        e = e or self.solver.current
        vals = {k: v for k, (v, _, _) in self._observe(e).items()}
        return config_in_degrees(vals) | {"chart": self.view.name}

    # -- charts ---------------------------------------------------------------------------
    def _regularity(self, view, pose) -> float:
        return view.regularity(pose)

    def _check_chart(self):
        e = self.solver.current
        reg = self.view.regularity(e.kin.pose)
        if reg >= self.policy.switch_below:
            return
        if not self.policy.switching:
            if reg < self.policy.fail_below:
                raise ChartBreakdown(
                    f"chart {self.view.name} degenerates (regularity {reg:.3g}) and chart "
                    "switching is off", e.t, self.config(e))
            return
        self._switch(reg, forced=False)

    def _switch(self, reg_now: float, forced: bool):
        e = self.solver.current
        pose = e.kin.pose
        best, best_reg = None, -1.0
        for v in self.views:
            if v.chart is self.view.chart or not v.owns(pose):
                continue
            r = v.regularity(pose)
            if r > best_reg:
                best, best_reg = v, r
        if best is None or best_reg < self.policy.fail_below:
            if forced or reg_now < self.policy.fail_below:
                raise SingularConfiguration(
                    f"no chart of structure {self.structure!r} is regular here (best "
                    f"regularity {max(best_reg, reg_now):.3g}): a singular position of the machine",
                    e.t, self.config(e))
            return
        if best_reg <= reg_now and not forced:
            return
        jets = self.view.pose_jets(e.q, e.qd)
        q, qd = best.state_from(jets, self.phys)
        check = best.positions(list(q))
        for p, (x, y) in pose.items():
            if p in check:
                cx, cy = check[p]
                if abs(cx - x) + abs(cy - y) > 1e-9 * (1.0 + abs(x) + abs(y)):
                    raise NumericalError(f"chart change {self.view.name} -> {best.name} does not "
                                         f"reproduce point {p}", e.t, self.config(e))
        self.events.append({"t": e.t, "kind": "chart", "from": self.view.name, "to": best.name,
                            "regularity_from": reg_now, "regularity_to": best_reg,
                            "forced": forced})
        self.view = best
        self.solver = self._new_solver(e.t, q, qd)

    def _interrupt(self, t, q, qd) -> bool:
        try:
            pose = self.view.positions(list(q))
        except ChartDomainError:
            return True
        reg = self.view.regularity({k: (float(x), float(y)) for k, (x, y) in pose.items()})
        limit = self.policy.switch_below if self.policy.switching else self.policy.fail_below
        return reg < limit

    # -- the run --------------------------------------------------------------------------
    def run(self, t_end: float, dt: float) -> Trajectory:
        t0 = self.solver.t
        if not (t_end > t0):
            raise ValueError(f"t_end = {t_end!r}: expected a time after the start {t0!r}")
        if not (dt > 0):
            raise ValueError(f"dt = {dt!r}: expected a positive step")
        n = max(1, int(round((t_end - t0) / dt)))
        rows = {k: [] for k in COLUMNS}
        self._record(rows, self.solver.current)
        failures = 0
        for k in range(1, n + 1):
            tk = t_end if k == n else t0 + k * (t_end - t0) / n
            while self.solver.t < tk - 1e-12 * (t_end - t0):
                try:
                    self.solver.step_to(tk, interrupt=self._interrupt)
                except ChartDomainError as exc:
                    failures += 1
                    e = self.solver.current
                    if not self.policy.switching:
                        raise ChartBreakdown(
                            f"the step from here leaves chart {self.view.name} ({exc.detail}) and "
                            "chart switching is off", e.t, self.config(e)) from None
                    if failures > len(self.views):
                        raise SingularConfiguration(
                            f"every chart of structure {self.structure!r} fails in the step "
                            f"from here ({exc.detail})", e.t, self.config(e)) from None
                    self._switch(self.view.regularity(e.kin.pose), forced=True)
                    continue
                failures = 0
                self._check_chart()
            self._update_phys(self.solver.current)
            self._record(rows, self.solver.current)
        return self._trajectory(rows)

    def _record(self, rows, e):
        obs = self._observe(e)
        rows["t"].append(e.t)
        for name in ("phi", "psi"):
            v, vd, vdd = obs[name]
            rows[name].append(v)
            rows[name + "_dot"].append(vd)
            rows[name + "_ddot"].append(vdd)
        rows["x_C"].append(obs["x_C"][0])
        rows["T"].append(e.kinetic_energy)
        rows["V"].append(self.engine.potential_energy(e.kin))
        rows["structure"].append(self.structure)
        rows["chart"].append(e.view.name)
        for ob in self.observers:
            ob.observe(self, e)

    def _trajectory(self, rows) -> Trajectory:
        cols = {k: (np.array(v, dtype=float) if k not in ("structure", "chart") else np.array(v))
                for k, v in rows.items()}
        for ob in self.observers:
            cols.update(ob.columns())
        counts = dict(self.engine.counts)
        counts["solver_evaluations"] = self.solver_nfev + self.solver.nfev
        counts["steps"] = self.solver_steps + self.solver.nsteps
        s = self.settings
        settings = {"solver": s.name, "scheme": s.scheme, "delta": s.delta,
                    "iterations": s.iterations, "rtol": s.rtol, "atol": s.atol,
                    "chart_switching": self.policy.switching}
        return Trajectory(cols, list(self.events), counts, settings)
