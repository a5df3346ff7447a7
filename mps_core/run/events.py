"""A run's events: what can happen in its present state, and where it happens inside a step.

The events of a state (:meth:`EventLocator.event_list`) are the structure layer's
(:meth:`~mps_core.run.structure_layer.StructureLayer.make_event_list`: the latch catching, the
stop, the change point, the effects' switching points), kept by the structure, the latch's
arming and the chart view. After each step the driver asks :meth:`EventLocator.locate` for the
earliest root inside it (Brent's method on the step's dense output); an adaptive solver asks
:meth:`EventLocator.interrupt` after each internal step whether to stop there.

The values at the last boundary (``Simulation._ev_prev``) and where the present segment began
(``Simulation._seg_start``) are the run's state, kept by its checkpoints; the locator holds
caches only (the event lists, the last state's kinematics and switching values).
"""

from __future__ import annotations

import numpy as np

from ..errors import ChartDomainError, NumericalError
from ..model.mechanism import unwrap_to
from .roots import brent_root
from .structure_layer import _Event

__all__ = ["EventLocator"]


class EventLocator:
    """The events of a run ``sim`` (a :class:`~mps_core.run.simulation.Simulation`);
    ``switch_points``: whether the effects' switching points are located (False where the
    solver steps over them)."""

    def __init__(self, sim, switch_points: bool):
        self.sim = sim
        #: the effects whose switching points are located
        self.switching = [e for e in sim.effects if e.switches] if switch_points else []
        self._by_state: dict[tuple, list[_Event]] = {}
        self._kin_last = None
        self._switch_last: dict = {}

    def observable(self, name, view, q, kin=None) -> float:
        """An observable's value at q in a view (``kin``: that state's kinematics, if known)."""
        sim = self.sim
        k = view.coordinate_index(name)
        if k is not None:
            return float(q[k])
        if name in view.frozen:
            return float(view.frozen[name])
        if kin is not None:
            pose = kin.pose
        else:
            pose = view.positions(list(q))
            pose = {p: (float(x), float(y)) for p, (x, y) in pose.items()}
        v = sim.mechanism.observables[name].value(pose)
        if sim.mechanism.observables[name].is_angle and name in sim.phys:
            v = unwrap_to(v, sim.phys[name])
        return v

    def reader(self, name, view):
        """``read(q, kin=None)``: the observable's value at q in ``view``, as :meth:`observable`
        gives it, with the lookups that depend on the view alone done once."""
        sim = self.sim
        k = view.coordinate_index(name)
        if k is not None:
            return lambda q, kin=None: float(q[k])
        if name in view.frozen:
            value = float(view.frozen[name])
            return lambda q, kin=None: value
        obs = sim.mechanism.observables[name]
        angle = obs.is_angle

        def read(q, kin=None):
            if kin is None:
                return self.observable(name, view, q)
            v = obs.value(kin.pose)
            if angle and name in sim.phys:
                v = unwrap_to(v, sim.phys[name])
            return v

        return read

    def event_list(self) -> list[_Event]:
        """The events that can happen now (they depend on the structure, the latch's arming and
        the chart view only; kept by those)."""
        sim = self.sim
        key = (sim.controls.structure, sim.controls.latch_armed, sim.view)
        ev = self._by_state.get(key)
        if ev is None:
            ev = self._by_state[key] = sim.structures.make_event_list()
        return ev

    def switch_fn(self, effect, i, view):
        """``fn(t, q, q̇, kin=None)``: the effect's i-th switching function in ``view``."""
        state_kin = self.state_kin
        last = self._switch_last  # the effect's values at the last state asked for

        def fn(t, q, qd, kin=None):
            if kin is None:
                kin = state_kin(view, t, q, qd)
            hit = last.get(effect)
            if hit is None or hit[0] is not kin:
                hit = last[effect] = (kin, effect.switch_values(t, kin))
            return hit[1][i]

        return fn

    def state_kin(self, view, t, q, qd):
        """The kinematics of a state between evaluations (event location), the last one kept:
        the switching functions of one state share it."""
        sim = self.sim
        ql, vl = [float(x) for x in q], [float(x) for x in qd]
        key = (view, t, *ql, *vl)
        last = self._kin_last
        if last is not None and last[0] == key:
            return last[1]
        kin = sim.engine.state_kinematics(view, t, ql, vl)
        self._kin_last = (key, kin)
        return kin

    def count_switch(self, t):
        self.sim.work_counts.switch_points += 1

    def values(self, t, q, qd, kin=None) -> dict:
        return {e.name: e.fn(t, q, qd, kin) for e in self.event_list()}

    @staticmethod
    def crossed(a: float, b: float, direction: int) -> bool:
        if direction > 0:
            return a < 0.0 <= b
        if direction < 0:
            return a > 0.0 >= b
        return (a < 0.0 <= b) or (a > 0.0 >= b)

    def interrupt(self, t, q, qd) -> bool:
        """Called by adaptive solvers after each internal step: stop for an event or a chart."""
        sim = self.sim
        try:
            pose = sim.view.positions(list(q))
        except ChartDomainError:
            return True
        reg = sim.view.regularity({k: (float(x), float(y)) for k, (x, y) in pose.items()})
        limit = sim.policy.switch_below if sim.policy.switching else sim.policy.fail_below
        if reg < limit:
            return True
        vals = self.values(t, q, qd)
        for e in self.event_list():
            if e.name in sim._ev_prev and self.crossed(sim._ev_prev[e.name], vals[e.name], e.direction):
                return True
        sim._ev_prev = vals
        sim._seg_start = t
        return False

    def locate(self):
        """(earliest event root inside the last step or None, event values at the step's end)."""
        sim = self.sim
        events = self.event_list()
        if not events:
            return None, {}
        s = sim.solver
        t1, q1, qd1, kin = s.t, s.q, s.qd, s.current.kin
        vals = {e.name: e.fn(t1, q1, qd1, kin) for e in events}
        prev = sim._ev_prev
        first = None
        for e in events:
            a, b = prev.get(e.name), vals[e.name]
            if a is None or not self.crossed(a, b, e.direction):
                continue
            dense = s.dense_output()
            t_a = sim._seg_start

            def g(t, fn=e.fn, dense=dense):
                q, qd = dense(t)
                return fn(t, q, qd)

            if a == 0.0:
                root = t_a
            else:
                ga = g(t_a)
                if ga * b > 0.0:
                    # the recorded sign was set at an event's root: no bracket in this step
                    continue
                try:
                    root = brent_root(g, t_a, t1, xtol=1e-13, rtol=4 * np.finfo(float).eps, maxiter=200)
                except (ValueError, RuntimeError) as exc:
                    raise NumericalError(
                        f"event {e.name}: its time in the step [{t_a:.9g}, {t1:.9g}] s not found ({exc})",
                        t1,
                        sim.config(),
                    ) from None
            if first is None or root < first[0]:
                first = (root, e, b)
        return first, vals
