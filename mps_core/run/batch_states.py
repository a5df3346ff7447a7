"""What a vectorised batch keeps for its runs' load reports (:mod:`mps_core.run.batch`): each
step's state (q, q̇, q̈) and those of its effects' loads that a state changes (the others are
kept once), one contiguous row a step, and the joint
reactions of the steps a caller names (a window of each scene's steps, e.g. its last crank
revolution), solved then by the chart view's reaction kernel on arrays.

A load report reads the reactions over one crank revolution near the run's end; solving them
there only, and keeping no other column, is what makes a batch of a sweep cheaper than its
trajectories (:class:`~mps_core.run.batch_record.BatchRecord`), with the same values at those
steps: a step's reactions depend on that step's state and loads alone."""

from __future__ import annotations

import time

import numpy as np

from .batch_record import ReactionsNotSolved, solve_reactions


class BatchStates:
    """The states and loads of ``m`` scenes over ``steps`` steps (``steps + 1`` states) of the
    chart view ``view`` (``n`` coordinates), ``effects`` the scenes'
    :class:`~mps_core.run.batch_effects.EffectArrays`; ``mech`` the mechanism, ``q`` a state
    to build the reaction kernel at, ``mass`` and ``inertia`` each scene's (scene, body)."""

    def __init__(self, m: int, steps: int, n: int, view, effects, mech, q, mass, inertia):
        S = steps + 1
        self.m, self.n, self.view, self.effects = m, n, view, effects
        self._solver = (mech, q, mass, inertia)
        self.structure = effects.structure
        self.k = 0  # the states recorded
        self.t = np.empty(S)
        #: (state, q or q̇ or q̈, coordinate, scene)
        self.states = np.empty((S, 3, n, m))
        #: the loads no state changes (their values), the indices of the others, and those
        #: at every step: (state, load of :attr:`varying`, scene)
        self.steady = effects.steady_loads()
        self.varying = [j for j, x in enumerate(self.steady) if x is None]
        self.loads = np.zeros((S, len(self.varying), m))
        self._names = [c.name for c in view.coordinates]
        #: the process's CPU seconds :meth:`reactions` took so far
        self.reaction_cpu_s = 0.0

    def record(self, t, q, qd, qdd, A, kin, work) -> None:
        """The state at ``t`` of every scene (the arguments of
        :meth:`~mps_core.run.batch_record.BatchRecord.record`; ``A`` and ``work`` unused)."""
        k = self.k
        self.t[k] = t
        row = self.states[k]
        row[0] = q.T
        row[1] = qd.T
        row[2] = qdd.T
        loads, every = self.loads[k], self.effects.loads(kin)
        for j, i in enumerate(self.varying):
            loads[j] = every[i]
        self.k = k + 1

    def coordinate(self, name: str, derivative: int = 0) -> np.ndarray | None:
        """A coordinate (``derivative`` 1: its rate, 2: its acceleration) over the steps, as
        (step, scene); None where the view holds it frozen."""
        if name not in self._names:
            return None
        return self.states[: self.k, derivative, self._names.index(name)]

    def reactions(self, steps: np.ndarray, scenes=None) -> dict:
        """The reaction columns at ``steps`` (scene, j: a step's index for each scene) of
        ``scenes`` (their indices; None: every scene), each of that shape, with each scene's
        masses and inertias. Raises
        :class:`~mps_core.run.batch_record.ReactionsNotSolved` as
        :meth:`~mps_core.run.batch_record.BatchRecord.reaction_columns` does."""
        c0 = time.process_time()
        steps = np.asarray(steps)
        if steps.size == 0:
            raise ReactionsNotSolved("no step asked for")
        which = (np.arange(self.m) if scenes is None else np.asarray(scenes))[:, None]
        args = [self.states[steps, j, i, which] for j in range(3) for i in range(self.n)]
        kept = iter(self.loads[steps, j, which] for j in range(len(self.varying)))
        given = [
            next(kept) if x is None else x if isinstance(x, float) else np.asarray(x)[which]
            for x in self.steady
        ]
        mech, q, mass, inertia = self._solver
        try:
            return solve_reactions(mech, self.view, q, mass[which[:, 0]], inertia[which[:, 0]], args, given)
        finally:
            self.reaction_cpu_s += time.process_time() - c0
