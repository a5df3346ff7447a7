"""The reported observables (φ, ψ, x_C) of a run: value, rate and acceleration in any chart.

Each chart view gets a plan once (:class:`_ViewPlan`): a free coordinate is read from q, q̇, q̈;
a frozen one is its value; a position-only observable comes from the evaluation's pose; a
body's angle takes its rates from the body's analogs; anything else goes through jets (exact).
Angles are unwrapped to the run's references (``Simulation.phys``, kept by its checkpoints),
which :meth:`Observables.update_phys` moves at every accepted step.
"""

from __future__ import annotations

import math
from typing import Any

from ..model.mechanism import ChartView, unwrap_to

__all__ = ["Observables"]


#: where a reported observable comes from in a chart view (see :class:`_ViewPlan`)
_COORD, _FROZEN, _POSE, _BODY, _JETS = range(5)


class _ViewPlan:
    """What the driver reads of one chart view at every step, worked out once per view.

    ``report``: for each reported observable (the mechanism's ``report``, in order)
    ``(name, how, observable, arg)``: ``_COORD`` (a free coordinate, arg its index), ``_FROZEN``
    (arg its value), ``_POSE`` (position only, from the evaluation's pose), ``_BODY`` (a body's
    angle: rates from the body's analogs, arg the body's name), ``_JETS`` (exact, through jets).
    """

    __slots__ = ("report",)

    def __init__(self, obs: Observables, view: ChartView):
        report: list[tuple[str, int, Any, Any]] = []
        for name, order in obs.report.items():
            observable = obs.mechanism.observables[name]
            k = view.coordinate_index(name)
            if k is not None:
                report.append((name, _COORD, observable, k))
            elif name in view.frozen:
                report.append((name, _FROZEN, observable, float(view.frozen[name])))
            elif order == 0:
                report.append((name, _POSE, observable, None))
            elif name in obs.angle_body:
                report.append((name, _BODY, observable, obs.angle_body[name]))
            else:
                report.append((name, _JETS, observable, None))
        self.report = tuple(report)


class Observables:
    """The reported observables of a run ``sim`` (a :class:`~mps_core.run.simulation.Simulation`):
    ``report`` (name: the highest derivative reported, the mechanism's ``report``),
    ``report_at`` (name: its place), ``angle_body`` (an angle observable: the body whose angle
    it is)."""

    def __init__(self, sim):
        self.sim = sim
        mechanism = self.mechanism = sim.mechanism
        self.report = getattr(mechanism, "report", {"phi": 2, "psi": 2, "x_C": 0})
        self.report_at = {name: k for k, name in enumerate(self.report)}
        #: the body whose angle an angle observable is (its rates come from the body's analogs)
        self.angle_body = {
            o.name: b.name
            for o in mechanism.observables.values()
            if o.is_angle
            for b in mechanism.bodies
            if (b.origin, b.toward) == tuple(o.points)
        }
        self._plans: dict[ChartView, _ViewPlan] = {}

    def plan(self, view) -> _ViewPlan:
        """The view's :class:`_ViewPlan` (built on first use, kept by the view object)."""
        plan = self._plans.get(view)
        if plan is None:
            plan = self._plans[view] = _ViewPlan(self, view)
        return plan

    def observe(self, e):
        """Reported observables (value, rate, acceleration) from an evaluation, any chart."""
        return dict(zip(self.report, self.observations(e)))

    def observations(self, e) -> list:
        """(value, rate, acceleration) of each reported observable, in the report's order."""
        sim = self.sim
        view = e.view
        out = []
        # floats of q, q̇ (q̈) and the jets, made on first use
        jets: Any = None
        q: Any = None
        qd: Any = None
        qdd: Any = None
        phys = sim.phys
        # right after update_phys(e) an observable read from the pose is already in phys (an
        # angle unwrapped to its reference): the same number as reading it again
        same = sim._phys_of is e
        for name, how, obs, arg in self.plan(view).report:
            if how == _COORD:
                if q is None:
                    q, qd = e.q.tolist(), e.qd.tolist()
                    if qdd is None:
                        qdd = e.qdd.tolist()
                out.append((q[arg], qd[arg], qdd[arg]))
                continue
            if how == _FROZEN:
                out.append((arg, 0.0, 0.0))
                continue
            if how == _POSE:
                out.append(
                    (phys[name] if same and not obs.is_angle else obs.value(e.kin.pose), math.nan, math.nan)
                )
                continue
            kin = e.kin
            if how == _BODY and (conv := kin.angular_convective(arg)) is not None:
                # the body's angle: rate ω*·q̇, acceleration ω*·q̈ + Σ ∂ω*/∂q q̇ q̇ by the
                # evaluation's own central differences (the scheme's accuracy, no jets)
                if same:
                    v = phys[name]
                else:
                    v = obs.value(kin.pose)
                    if name in phys:
                        v = unwrap_to(v, phys[name])
                if qdd is None:
                    qdd = e.qdd.tolist()
                acc = conv
                for wi, ai in zip(kin.omega(arg), qdd):
                    acc += wi * ai
                out.append((v, kin.rate(arg), acc))
                continue
            if jets is None:
                jets = view.pose_jets(e.q, e.qd)
            j = obs.jet(jets, view.n)
            v = float(j.val)
            if obs.is_angle and name in phys:
                v = unwrap_to(v, phys[name])
            out.append((v, float(j.d1), float(j.grad @ e.qdd + j.d2)))
        return out

    def update_phys(self, e):
        """The current values of the reported angles: references for unwrapping (positions only)."""
        sim = self.sim
        phys = sim.phys
        q = None
        for name, how, obs, arg in self.plan(e.view).report:
            if how == _COORD:
                if q is None:
                    q = e.q.tolist()
                phys[name] = q[arg]
            elif how == _FROZEN:
                phys[name] = arg
            else:
                v = obs.value(e.kin.pose)
                phys[name] = unwrap_to(v, phys[name]) if (obs.is_angle and name in phys) else v
        sim._phys_of = e

    def physical_rates(self, view, q, qd) -> dict:
        """Physical φ, ψ, x_C and their rates at a chart state (exact, through jets)."""
        sim = self.sim
        jets = view.pose_jets(q, qd)
        out = {}
        for name in ("phi", "psi", "x_C"):
            j = sim.mechanism.observables[name].jet(jets, view.n)
            v = float(j.val)
            if name in sim.phys and sim.mechanism.observables[name].is_angle:
                v = unwrap_to(v, sim.phys[name])
            out[name] = v
            out[name + "_dot"] = float(j.d1)
        return out
