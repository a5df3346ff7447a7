"""The structure layer of a run: the switches between the press's structures, its impacts and
its commands (contract §5), between the solver and the run loop.

:class:`~mps_core.run.simulation.Simulation` is the loop and its bookkeeping (steps, event location,
charts, energy, records); it asks this layer which events can switch the structure now
(:meth:`StructureLayer.make_event_list`) and calls their actions at the located root, and it
hands it the commands at their times:

* ``free`` → ``locked``: the latch closes (armed, ψ reaches ψ_lock), a perfectly plastic impact
  ``q̇⁺ = q̇⁻ − A⁻¹g (gᵀq̇⁻)/(gᵀA⁻¹g)`` with g = ∇ψ (:meth:`StructureLayer._impact`);
* ``free`` → ``held``: the slider reaches its top stop moving up, the same impact with g = ∇x_C;
* ``held`` → ``free``: the stop's reaction λ (from the unfrozen chart's equations,
  :meth:`StructureLayer.stop_force`) would turn tensile;
* ``locked`` → ``free``: the latch opens at a ``disengage`` command, ψ̇ = 0, no jump;
* the change point of the held four-bar: logged on the smooth continuation, or the rocker kept
  on its side with a plastic impact (``change_point="keep-side"``);
* commands (``engage``, ``disengage``, ``stop``, ``start``): checked against the present state
  (:class:`CommandRefused` says why not) and applied at their exact time; the disengage
  cylinder's end is a timer the layer sets.

The layer holds no state of its own: it reads and changes the run's (``self.sim``), so the
numbers are the run's, operation for operation. It keeps the press's parts it acts through
(:class:`MachineParts`) and caches of its own (the unfrozen charts of the held views, an exact
engine for the change point's branches).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..dynamics.engine import PartialSystems
from ..errors import MpsError, SingularConfiguration
from ..model.effects import Latch, Motor, TopStop
from ..model.mechanism import ChartView
from ..scene.settings import COMMANDS


class CommandRefused(MpsError):
    """A command that makes no sense in the machine's present state (or an unknown word)."""

    def __init__(self, command, reason: str):
        self.command = command
        self.reason = reason
        super().__init__(f"command {command!r} refused: {reason}")


@dataclass
class _Event:
    name: str
    fn: Callable  # fn(t, q, q̇, kin=None): the event function in its list's view
    direction: int  # +1 rising through zero, -1 falling, 0 either
    action: Callable
    #: a switching point of a force law: the step ends there and the solver starts afresh,
    #: nothing else happens
    restart: bool = False


@dataclass(frozen=True)
class MachineParts:
    """The effects of a scene the structure layer acts through or checks commands against:
    the latch, the rigid top stop, the motor, the engage and disengage cylinders (each None
    where the scene has none)."""

    latch: Any = None
    stop: Any = None
    motor: Any = None
    engage: Any = None
    disengage: Any = None

    @classmethod
    def of(cls, effects) -> MachineParts:
        def first(pick):
            return next((e for e in effects if pick(e)), None)

        return cls(
            latch=first(lambda e: isinstance(e, Latch)),
            stop=first(lambda e: isinstance(e, TopStop) and e.rigid),
            motor=first(lambda e: isinstance(e, Motor)),
            engage=first(lambda e: e.kind == "engage_cylinder"),
            disengage=first(lambda e: e.kind == "disengage_cylinder"),
        )

    def state(self) -> bool | None:
        """What the commands change of the parts themselves (the motor switched on or off by
        ``stop`` and ``start``), for :meth:`set_state`."""
        return None if self.motor is None else self.motor.enabled

    def set_state(self, state: bool | None) -> None:
        if self.motor is not None and self.motor.enabled != state:
            self.motor.enabled = state


class StructureLayer:
    """The structures' switches, impacts and commands of one run (``sim``)."""

    def __init__(self, sim) -> None:
        self.sim = sim
        #: the press's parts the layer acts through
        self.parts = MachineParts.of(sim.effects)
        #: per held view: (its chart unfrozen, the index of x_C there, the free coordinates);
        #: the unfrozen views by chart name
        self._held: dict[ChartView, tuple] = {}
        self._full: dict[str, ChartView] = {}
        #: an engine with exact derivatives for the change point's branches (made when needed)
        self._exact_engine: PartialSystems | None = None

    def make_event_list(self) -> list[_Event]:
        """The events of the present structure and arming in the present view: each ``fn(t, q,
        q̇, kin=None)`` reads that view's state."""
        sim = self.sim
        ev = []
        s = sim.structure
        view = sim.view
        parts = self.parts
        if s == "free":
            if parts.latch is not None and sim.controls.latch_armed:
                lock = parts.latch.psi_lock
                psi = sim.events_now.reader("psi", view)
                ev.append(
                    _Event(
                        "latch-closes", lambda t, q, qd, kin=None: psi(q, kin) - lock, 0, self._close_latch
                    )
                )
            if parts.stop is not None:
                top = parts.stop.x_top
                x_C = sim.events_now.reader("x_C", view)
                ev.append(
                    _Event("stop-contact", lambda t, q, qd, kin=None: x_C(q, kin) - top, +1, self._hit_stop)
                )
        elif s == "held" and parts.stop is not None and parts.stop.model != "clamp":
            ev.append(
                _Event(
                    "stop-release",
                    lambda t, q, qd, kin=None: self.stop_force(t, q, qd, view),
                    +1,
                    self.release_stop,
                )
            )
        if view.chart.name.startswith("phi-xc~"):
            phi = sim.events_now.reader("phi", view)
            ev.append(
                _Event(
                    "change-point",
                    lambda t, q, qd, kin=None: math.sin(0.5 * phi(q, kin)),
                    0,
                    self.record_change_point,
                )
            )
        for effect in sim.events_now.switching:
            for i, name in enumerate(effect.switches):
                ev.append(
                    _Event(
                        f"{effect.name}:{name}",
                        sim.events_now.switch_fn(effect, i, view),
                        0,
                        sim.events_now.count_switch,
                        restart=True,
                    )
                )
        return ev

    def _impact(self, obs_name: str, kind: str, new_structure: str, t: float) -> dict:
        """Perfectly plastic impact on the constraint ∇(observable) · q̇ = 0."""
        sim = self.sim
        view, e = sim.view, sim.solver.current
        q, qd = e.q, e.qd
        jets = view.pose_jets(q, qd)
        g = np.asarray(sim.mechanism.observables[obs_name].jet(jets, view.n).grad, float)
        Ainv_g = np.linalg.solve(e.A, g)
        gAg = float(g @ Ainv_g)
        s = float(g @ qd)
        qd_plus = qd - Ainv_g * (s / gAg)
        lost = 0.5 * s * s / gAg
        before = sim.observables.physical_rates(view, q, qd)
        after = sim.observables.physical_rates(view, q, qd_plus)
        sim.energy.impact_loss += lost
        for ob in sim.observers:
            if hasattr(ob, "impact"):
                ob.impact(sim, t, view, q, qd, qd_plus, closing=(obs_name,))
        rec = {
            "t": t,
            "kind": kind,
            "from": sim.structure,
            "to": new_structure,
            "velocities_before": {k: before[k] for k in ("phi_dot", "psi_dot", "x_C_dot")},
            "velocities_after": {k: after[k] for k in ("phi_dot", "psi_dot", "x_C_dot")},
            "energy_lost": lost,
            "impulse": -s / gAg,
            "impulse_unit": "N*m*s" if obs_name == "psi" else "N*s",
            "state": {k: before[k] for k in ("phi", "psi", "x_C")},
        }
        self._enter(new_structure, q, qd_plus, t)
        return rec

    def _enter(self, structure: str, q, qd, t):
        """Change structure at t from the current view's state (q, q̇) (already consistent)."""
        sim = self.sim
        jets = sim.view.pose_jets(q, qd)
        pose = {
            k: (
                float(x.val) if hasattr(x, "val") else float(x),
                float(y.val) if hasattr(y, "val") else float(y),
            )
            for k, (x, y) in jets.items()
        }
        cands = [c for c in sim.charts.candidates(structure, pose) if c[0] >= sim.policy.fail_below]
        best, q2, qd2, _ = sim.charts.map_first(cands, q, qd)
        if best is None:
            raise SingularConfiguration(
                f"no chart of structure {structure!r} is regular here", t, sim.config()
            )
        sim.controls.structure = structure
        sim._restart(best, t, q2, qd2)

    def _close_latch(self, t):
        sim = self.sim
        rec = self._impact("psi", "latch-closes", "locked", t)
        sim.events.append(rec)

    def _hit_stop(self, t):
        sim = self.sim
        rec = self._impact("x_C", "stop-contact", "held", t)
        sim.events.append(rec)

    def release_stop(self, t):
        sim = self.sim
        e = sim.solver.current
        rates = sim.observables.physical_rates(sim.view, e.q, e.qd)
        self._enter("free", e.q, e.qd, t)
        sim.events.append(
            {
                "t": t,
                "kind": "stop-release",
                "from": "held",
                "to": "free",
                "velocities_before": {k: rates[k] for k in ("phi_dot", "psi_dot", "x_C_dot")},
                "energy_lost": 0.0,
                "impulse": 0.0,
            }
        )

    def record_change_point(self, t, q=None, qd=None):
        """Log a passage through the change point (at the step's cut, or at (q, q̇) when the
        step stands); with ``keep-side`` apply that choice's impact."""
        sim = self.sim
        e = sim.solver.current
        q = e.q if q is None else q
        qd = e.qd if qd is None else qd
        rates = sim.observables.physical_rates(sim.view, q, qd)
        rec = {
            "t": t,
            "kind": "change-point",
            "choice": "smooth continuation",
            "phi": rates["phi"],
            "psi": rates["psi"],
            "velocities": {k: rates[k] for k in ("phi_dot", "psi_dot")},
            "energy_lost": 0.0,
        }
        if sim.change_point == "keep-side":
            rec.update(self._keep_side(t))
        sim.events.append(rec)

    def _branch_analogs(self, view, phi: float, eps: float = 1e-4):
        """Analogs (centres of mass, body rates) of a continuation chart at the change point φ*,
        as the mean of those at φ* ± ε (the chart is smooth there; error O(ε²))."""
        sim = self.sim
        exact = self._exact_engine
        assert exact is not None  # made by _keep_side
        ks = [exact.kinematics(view, sim.solver.t, [phi + s * eps], [0.0]) for s in (1.0, -1.0)]
        rows = [ks[0].names[f"G_{b.name}"] for b in sim.mechanism.bodies]
        JG = 0.5 * sum(k.J[rows, :, 0] for k in ks)  # (bodies, 2)
        W = 0.5 * sum(k.W[:, 0] for k in ks)  # (bodies,)
        return JG, W

    def _keep_side(self, t) -> dict:
        """The rocker kept on its side at the change point: the motion leaves on the other
        branch (the other continuation chart) after a perfectly plastic impact. The admissible
        directions are forward along that branch or back along the incoming one; the velocity
        after is the projection (in the mass metric) onto them: φ̇⁺ = max(0, J_oᵀMJ_s / J_oᵀMJ_o)·φ̇⁻.
        Where the new branch turns back more than a right angle (J_oᵀMJ_s < 0) the mechanism
        stops dead at the change point, and the forces take it on from rest."""
        sim = self.sim
        if self._exact_engine is None:
            self._exact_engine = PartialSystems(sim.mechanism, (), "autodiff")
        e = sim.solver.current
        phi = float(e.q[0])
        other = next(
            v
            for v in sim.views(sim.structure)
            if v.chart.name.startswith("phi-xc~") and v.chart is not sim.view.chart
        )
        m = np.array([b.mass for b in sim.mechanism.bodies])
        inertia = np.array([b.inertia for b in sim.mechanism.bodies])
        Js, Ws = self._branch_analogs(sim.view, phi)
        Jo, Wo = self._branch_analogs(other, phi)
        A_s = float(np.sum(m * np.sum(Js * Js, axis=1)) + inertia @ (Ws * Ws))
        A_o = float(np.sum(m * np.sum(Jo * Jo, axis=1)) + inertia @ (Wo * Wo))
        C = float(np.sum(m * np.sum(Jo * Js, axis=1)) + inertia @ (Wo * Ws))
        w_minus = float(e.qd[0])
        w_plus = max(0.0, C / A_o) * w_minus
        lost = 0.5 * A_s * w_minus**2 - 0.5 * A_o * w_plus**2
        sim.energy.impact_loss += lost
        sim._restart(other, t, np.array([phi]), np.array([w_plus]))
        return {"choice": "keep side", "phi_dot_after": w_plus, "energy_lost": lost, "to_chart": other.name}

    def stop_force(self, t, q, qd, view=None) -> float:
        """λ: the force along x the top stop must give the slider to keep it at x_top (< 0:
        pushing it down, compressive; > 0 would be a pull). From the unfrozen chart's equations:
        λ = (A q̈ + h − Q) along x_C, with q̈ the held structure's accelerations."""
        sim = self.sim
        view = view or sim.view
        held = self._held.get(view)
        if held is None:
            chart = view.chart
            full = self._full.get(chart.name)
            if full is None:
                full = self._full[chart.name] = ChartView(chart)
            held = self._held[view] = (full, full.coordinate_index("x_C"), list(view.free))
        full, c, f = held
        ql = q.tolist() if isinstance(q, np.ndarray) else [float(x) for x in q]
        qdl = qd.tolist() if isinstance(qd, np.ndarray) else [float(x) for x in qd]
        qdf = [0.0] * full.n
        for k, i in enumerate(f):
            qdf[i] = qdl[k]
        A, h, Q = sim.engine.equations(full, t, [float(x) for x in view.full(ql)], qdf)
        if len(f) == 1:
            # one free coordinate: on floats
            i = f[0]
            qdd = (Q[i] - h[i]) / A[i][i]
            return A[c][i] * qdd + h[c] - Q[c]
        A, h, Q = np.array(A), np.array(h), np.array(Q)
        qdd_f = np.linalg.solve(A[np.ix_(f, f)], Q[f] - h[f])
        return float(A[c, f] @ qdd_f + h[c] - Q[c])

    def command_state(self) -> tuple:
        """What :meth:`check_command` reads of the present state: where two states give the
        same tuple, every command gets the same answer in both."""
        c = self.sim.controls
        return self.sim.structure, c.engage_on, c.motor_on

    def check_command(self, name) -> None:
        """Raise :class:`CommandRefused` if ``name`` makes no sense now."""
        sim = self.sim
        if not isinstance(name, str) or name not in COMMANDS:
            raise CommandRefused(name, "expected one of " + ", ".join(COMMANDS))
        c = sim.controls
        if name == "engage":
            if self.parts.latch is None or self.parts.engage is None:
                raise CommandRefused(name, "this scene has no latch and engage cylinder")
            if sim.structure == "locked":
                raise CommandRefused(name, "the latch is already closed (working)")
            if c.engage_on:
                raise CommandRefused(name, "already engaging")
        elif name == "disengage":
            if sim.structure != "locked" and not c.engage_on:
                raise CommandRefused(name, "the press is not engaged")
        elif name in ("stop", "start"):
            if self.parts.motor is None:
                raise CommandRefused(name, "this scene has no motor")
            if name == "stop" and not c.motor_on:
                raise CommandRefused(name, "the motor is already off")
            if name == "start" and c.motor_on:
                raise CommandRefused(name, "the motor is already on")

    def command(self, name: str, t: float | None = None) -> None:
        """Take a command now (t None) or at a later simulated time; refused ones raise."""
        sim = self.sim
        if t is None or t <= sim.solver.t:
            self.check_command(name)
            self.apply_command(name, sim.solver.t)
        else:
            if not isinstance(name, str) or name not in COMMANDS:
                raise CommandRefused(name, "expected one of " + ", ".join(COMMANDS))
            sim.schedule.add_command(t, name)

    def apply_command(self, name, t):
        sim = self.sim
        c = sim.controls
        rec = {"t": t, "kind": "command", "command": name, "structure": sim.structure}
        if name == "engage":
            c.engage_on = True
            c.latch_armed = True
        elif name == "disengage":
            c.engage_on = False
            c.latch_armed = False
            c.disengage_at = t
            if self.parts.disengage is not None:
                c.disengage_on = True
                sim.schedule.set_timer(t + self.parts.disengage.duration, "disengage-ends")
            if sim.structure == "locked":
                e = sim.solver.current
                sim.events.append(rec)
                self._enter("free", e.q, e.qd, t)
                sim.events.append(
                    {
                        "t": t,
                        "kind": "latch-opens",
                        "from": "locked",
                        "to": "free",
                        "energy_lost": 0.0,
                        "impulse": 0.0,
                    }
                )
                return
        elif name == "stop":
            c.motor_on = False
            self.parts.motor.enabled = False
        elif name == "start":
            c.motor_on = True
            self.parts.motor.enabled = True
        sim.events.append(rec)
        # the forces changed: the state carries on, its accelerations are new
        e = sim.solver.current
        sim._restart(sim.view, t, e.q, e.qd)

    def apply_timer(self, name, t):
        """A control change the driver scheduled, due at t (a step ends there)."""
        sim = self.sim
        if name == "disengage-ends":
            sim.controls.disengage_on = False
            sim.events.append({"t": t, "kind": "cylinder-off", "effect": "disengage_cylinder"})
        else:  # pragma: no cover - internal
            raise AssertionError(f"unknown timer {name!r}")
        e = sim.solver.current
        sim._restart(sim.view, t, e.q, e.qd)


__all__ = ["COMMANDS", "CommandRefused", "MachineParts", "StructureLayer"]
