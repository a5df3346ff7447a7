"""The step observer of the reactions: a simulation's observer that solves the joint
reactions and the foundation load at every step it keeps (:func:`~mps_core.dynamics.reactions.
compute_reactions`), the impacts' impulses at the events (:func:`~mps_core.dynamics.reactions.
impulses`), and gives them as a trajectory's columns."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from ..model.mechanism import ChartView
from .reactions import REACTION_COLUMNS, Impulses, compute_reactions, impulses


class ReactionObserver:
    """Computes the reactions at every recorded step of a :class:`~mps_core.run.simulation.Simulation`
    (attach it to ``simulation.observers``; it costs nothing unless attached).

    ``columns()`` gives :data:`REACTION_COLUMNS` as arrays, one value a recorded step.
    :meth:`impact` records an impact's joint impulses as an event (in ``impacts`` and in the
    simulation's event log), so the time series never carries a step-dependent spike.
    """

    def __init__(self, *, drive: str | None = None, defer_impacts: bool = False):
        self.drive = drive
        self.rows: dict[str, list] = {k: [] for k in REACTION_COLUMNS}
        self.impacts: list[dict] = []
        self.max_rank_deficiency = 0
        self._deficient_since = None
        #: True: an impact's event is logged at once with its time, kind and closing, and its
        #: impulses are filled in by :meth:`resolve` (a live run calls it after the step's
        #: state is out, off the step's critical time)
        self.defer_impacts = bool(defer_impacts)
        self._pending: list = []

    def observe(self, simulation, evaluation) -> None:
        e = evaluation
        rx = compute_reactions(
            simulation.mechanism,
            simulation.engine.effects,
            e.view,
            e.t,
            e.q,
            e.qd,
            e.qdd,
            kin=e.kin,
            drive=self.drive,
        )
        deficiency = len(rx.unknowns) - rx.rank
        if deficiency > 0 and self._deficient_since is None:
            # the reactions are not unique here (a singular position): the least-squares values
            # are one choice among many; say so in the event log, once a stretch
            self._deficient_since = e.t
            simulation.events.append(
                {
                    "t": e.t,
                    "kind": "reactions-not-unique",
                    "rank_deficiency": deficiency,
                    "unknowns": list(rx.unknowns),
                }
            )
        elif deficiency == 0:
            self._deficient_since = None
        self.max_rank_deficiency = max(self.max_rank_deficiency, deficiency)
        for k, v in rx.values.items():
            self.rows[k].append(v)

    def impact(
        self,
        simulation,
        t: float,
        view: ChartView,
        q,
        qd_minus,
        qd_plus,
        *,
        closing: Iterable[str] = (),
        kind: str = "impulse",
        **extra,
    ) -> Impulses | None:
        """Record a plastic impact's impulses at time t (call it where the impact is located).
        Deferred (``defer_impacts``): the event is logged now and completed by
        :meth:`resolve`; returns None."""
        if self.defer_impacts:
            ev = {"t": float(t), "kind": kind}
            self._pending.append(
                (
                    ev,
                    simulation.mechanism,
                    view,
                    np.array(q, float),
                    np.array(qd_minus, float),
                    np.array(qd_plus, float),
                    tuple(closing),
                    extra,
                )
            )
            self.impacts.append(ev)
            simulation.events.append(ev)
            return None
        imp = impulses(simulation.mechanism, view, q, qd_minus, qd_plus, closing=closing, t=t)
        ev = imp.as_event(kind, closing=list(closing), **extra)
        self.impacts.append(ev)
        simulation.events.append(ev)
        return imp

    def checkpoint(self) -> tuple:
        """What the run changes here (see :meth:`Simulation.checkpoint`)."""
        # every column gets a value at every step (observe): one length holds for all
        return (
            len(next(iter(self.rows.values()))),
            list(self.impacts),
            list(self._pending),
            self.max_rank_deficiency,
            self._deficient_since,
        )

    def restore(self, cp: tuple) -> None:
        n, impacts, pending, self.max_rank_deficiency, self._deficient_since = cp
        for column in self.rows.values():
            del column[n:]
        self.impacts[:] = impacts
        self._pending = list(pending)

    @property
    def pending(self) -> bool:
        """Whether deferred impacts wait for :meth:`resolve`."""
        return bool(self._pending)

    def resolve(self) -> None:
        """Fill in the impulses of the deferred impacts' events (in place)."""
        pending, self._pending = self._pending, []
        for ev, mechanism, view, q, qd_minus, qd_plus, closing, extra in pending:
            imp = impulses(mechanism, view, q, qd_minus, qd_plus, closing=closing, t=ev["t"])
            ev.update(imp.as_event(ev["kind"], closing=list(closing), **extra))

    def columns(self) -> dict[str, np.ndarray]:
        return {k: np.array(v, dtype=float) for k, v in self.rows.items()}


__all__ = ["ReactionObserver"]
