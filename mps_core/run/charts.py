"""A run's changes of chart: where the present chart degenerates, the most regular chart of the
structure that owns the configuration, the state mapped into it exactly (contract §2).

:meth:`ChartChanger.check` runs at every step's end: below the policy's ``switch_below`` it
changes chart (:meth:`ChartChanger.change`); with chart switching off, below ``fail_below``
the run stops with :class:`~mps_core.errors.ChartBreakdown`. A step that leaves its chart's
domain is taken again in another chart (:meth:`ChartChanger.leave_failing`). A state is mapped into another
chart exactly (:meth:`ChartChanger.map_state`: through jets, or from the exact kinematics where
the scheme has them) and checked point by point; no regular chart is a singular position of
the machine (:class:`~mps_core.errors.SingularConfiguration`).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import ChartBreakdown, ChartDomainError, NumericalError, SingularConfiguration
from ..model.mechanism import ChartView, unwrap_to

__all__ = ["ChartChanger"]


class ChartChanger:
    """The changes of chart of a run ``sim`` (a :class:`~mps_core.run.simulation.Simulation`)."""

    def __init__(self, sim) -> None:
        self.sim = sim
        #: the chart views of each structure, made on first use
        self._views: dict[str, list[ChartView]] = {}

    def views(self, structure: str) -> list[ChartView]:
        """The chart views of ``structure`` (the mechanism's, kept)."""
        views = self._views.get(structure)
        if views is None:
            views = self._views[structure] = self.sim.mechanism.views(structure)
        return views

    def check(self):
        sim = self.sim
        e = sim.solver.current
        reg = sim.view.regularity(e.kin.pose)
        if reg >= sim.policy.switch_below:
            return
        if not sim.policy.switching:
            if reg < sim.policy.fail_below:
                raise ChartBreakdown(
                    f"chart {sim.view.name} degenerates (regularity {reg:.3g}) and chart switching is off",
                    e.t,
                    sim.config(e),
                )
            return
        self.change(reg, forced=False)

    def candidates(self, structure, pose, exclude=None) -> list[tuple[float, ChartView]]:
        """Views of a structure that own the configuration, most regular first."""
        out = []
        for v in self.views(structure):
            if (exclude is not None and v.chart is exclude) or not v.owns(pose):
                continue
            out.append((v.regularity(pose), v))
        out.sort(key=lambda rv: -rv[0])
        return out

    def map_first(self, candidates, q, qd, kin=None):
        """The first candidate view into which the state maps exactly: (view, q, q̇, regularity).

        A chart's branch test sees only the configuration; a chart whose branch depends on how
        often the crank has turned (the change-point continuation) is confirmed by the mapping.
        ``kin``: the state's kinematics where they are exact (see :meth:`map_state`).
        """
        sim = self.sim
        for reg, v in candidates:
            try:
                q2, qd2 = self.map_state(sim.view, q, qd, v, kin)
            except (NumericalError, ChartDomainError):
                continue
            return v, q2, qd2, reg
        return None, None, None, -1.0

    def leave_failing(self, exc: ChartDomainError, failures: int) -> None:
        """A step that left its chart's domain (``failures`` in a row from here): another chart
        of the structure (or a clear error where chart switching is off or every chart has
        failed from here)."""
        sim = self.sim
        e = sim.solver.current
        if not sim.policy.switching:
            raise ChartBreakdown(
                f"the step from here leaves chart {sim.view.name} ({exc.detail}) and chart switching is off",
                e.t,
                sim.config(e),
            ) from None
        if failures > len(self.views(sim.structure)):
            raise SingularConfiguration(
                f"every chart of structure {sim.structure!r} fails in the step from here ({exc.detail})",
                e.t,
                sim.config(e),
            ) from None
        self.change(sim.view.regularity(e.kin.pose), forced=True)

    def change(self, reg_now: float, forced: bool):
        sim = self.sim
        e = sim.solver.current
        cands = [
            c
            for c in self.candidates(sim.structure, e.kin.pose, exclude=sim.view.chart)
            if c[0] >= sim.policy.fail_below and (forced or c[0] > reg_now)
        ]
        exact = e.kin if sim.settings.scheme == "autodiff" else None
        best, q, qd, best_reg = self.map_first(cands, e.q, e.qd, exact)
        if best is None:
            if forced or reg_now < sim.policy.fail_below:
                raise SingularConfiguration(
                    f"no chart of structure {sim.structure!r} is regular here (best "
                    f"regularity {reg_now:.3g}): a singular position of the machine",
                    e.t,
                    sim.config(e),
                )
            return
        sim.events.append(
            {
                "t": e.t,
                "kind": "chart",
                "from": sim.view.name,
                "to": best.name,
                "regularity_from": reg_now,
                "regularity_to": best_reg,
                "forced": forced,
            }
        )
        sim._restart(best, e.t, q, qd)

    def map_state(self, view, q, qd, target, kin=None):
        """(q, q̇) of ``target`` for the state (q, q̇) of ``view``: exact, through jets, or from
        ``kin``, the state's exact kinematics (positions and velocities of the points, from an
        exact kernel: the same numbers to round-off, without the jets)."""
        sim = self.sim
        if kin is not None and kin._xl is not None:
            q2, qd2 = self.state_from_kinematics(target, kin)
            pose = {p: kin.xy(p) for p in sim.mechanism.points}
        else:
            jets = view.pose_jets(q, qd)
            q2, qd2 = target.state_from(jets, sim.phys)
            pose = {
                k: (
                    float(x.val) if hasattr(x, "val") else float(x),
                    float(y.val) if hasattr(y, "val") else float(y),
                )
                for k, (x, y) in jets.items()
            }
        check = target.positions(list(q2))
        for p, (x, y) in pose.items():
            cx, cy = check[p]
            if abs(cx - x) + abs(cy - y) > 1e-9 * (1.0 + abs(x) + abs(y)):
                raise NumericalError(
                    f"changing to chart {target.name} does not reproduce point {p}",
                    sim.solver.t,
                    sim.config(),
                )
        return q2, qd2

    def state_from_kinematics(self, target, kin) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`~mps_core.model.mechanism.ChartView.state_from` from exact kinematics: each
        coordinate's value (angles unwrapped to ``phys``) and rate, the angle of P→Q's as
        (d × ḋ)/|d|² with d = Q − P."""
        sim = self.sim
        q = np.empty(target.n)
        qd = np.empty(target.n)
        phys = sim.phys
        for k, obs in enumerate(target.coordinates):
            if obs.kind == "angle":
                (px, py), (qx, qy) = kin.xy(obs.points[0]), kin.xy(obs.points[1])
                (pu, pv), (qu, qv) = kin.vxy(obs.points[0]), kin.vxy(obs.points[1])
                dx, dy, du, dv = qx - px, qy - py, qu - pu, qv - pv
                v = math.atan2(dy, dx)
                if obs.name in phys:
                    v = unwrap_to(v, phys[obs.name])
                q[k] = v
                qd[k] = (dx * dv - dy * du) / (dx * dx + dy * dy)
            else:
                c = 0 if obs.kind == "x" else 1
                q[k] = kin.xy(obs.points[0])[c]
                qd[k] = kin.vxy(obs.points[0])[c]
        return q, qd
