"""What a vectorised batch keeps for its runs' load reports (:mod:`mps_core.run.batch`): each
step's state (q, q̇, q̈), one contiguous row a step, and the joint reactions of the steps a
caller names (a window of each scene's steps, e.g. its last crank revolution), solved then by
the chart view's reaction kernel on arrays, with the effects' loads of those steps evaluated
again from their states.

A load report reads the reactions over one crank revolution near the run's end; solving them
there only, and keeping no other column, is what makes a batch of a sweep cheaper than its
trajectories (:class:`~mps_core.run.batch.record.BatchRecord`), with the same values at those
steps: a step's reactions depend on that step's state and loads alone, and its loads on its
state alone (the batch's evaluation, on the same values, gives them again). Keeping the loads
of every step instead was most of what a batch wrote, and memory written the first time costs
a page fault every few kilobytes: about a seventh of the stepping's time in a profile.
"""

from __future__ import annotations

import time

import numpy as np

from .record import ReactionsNotSolved, solve_reactions


class BatchStates:
    """The states of ``m`` scenes over ``steps`` steps (``steps + 1`` states) of the chart view
    ``view`` (``n`` coordinates), in the ``structure``; ``loads_at(q, qd, scenes)`` the
    effects' loads at states given as (scene, j) arrays of each coordinate, ``scenes`` (g, 1)
    their scenes' indices (:meth:`~mps_core.run.batch.effects.EffectArrays.loads`' entries,
    each a number, or of that shape or (g, 1)); ``mech`` the mechanism, ``q`` a state to build the
    reaction kernel at, ``mass`` and ``inertia`` each scene's (scene, body)."""

    def __init__(self, m: int, steps: int, n: int, view, structure: str, loads_at, mech, q, mass, inertia):
        S = steps + 1
        self.m, self.n, self.view, self.structure = m, n, view, structure
        self._loads_at = loads_at
        self._solver = (mech, q, mass, inertia)
        self._kernels: dict = {}  # the reaction kernels on arrays, by the columns they solve
        self.k = 0  # the states recorded
        self.t = np.empty(S)
        #: (state, q or q̇ or q̈, coordinate, scene)
        self.states = np.empty((S, 3, n, m))
        self._names = [c.name for c in view.coordinates]
        #: the process's CPU seconds :meth:`reactions` took so far (the loads' evaluation
        #: included)
        self.reaction_cpu_s = 0.0

    def record(self, t, q, qd, qdd, A, kin, work) -> None:
        """The state at ``t`` of every scene (the arguments of
        :meth:`~mps_core.run.batch.record.BatchRecord.record`; ``A``, ``kin`` and ``work``
        unused)."""
        k = self.k
        self.t[k] = t
        row = self.states[k]
        row[0] = q.T
        row[1] = qd.T
        row[2] = qdd.T
        self.k = k + 1

    def coordinate(self, name: str, derivative: int = 0) -> np.ndarray | None:
        """A coordinate (``derivative`` 1: its rate, 2: its acceleration) over the steps, as
        (step, scene); None where the view holds it frozen."""
        if name not in self._names:
            return None
        return self.states[: self.k, derivative, self._names.index(name)]

    def reactions(self, steps: np.ndarray, scenes=None, columns=None) -> dict:
        """The reaction columns at ``steps`` (scene, j: a step's index for each scene) of
        ``scenes`` (their indices; None: every scene), each of that shape, with each scene's
        masses and inertias; ``columns``: those to solve (None: all of
        :data:`~mps_core.dynamics.reactions.REACTION_COLUMNS`). Raises
        :class:`~mps_core.run.batch.record.ReactionsNotSolved` as
        :meth:`~mps_core.run.batch.record.BatchRecord.reaction_columns` does."""
        c0 = time.process_time()
        steps = np.asarray(steps)
        if steps.size == 0:
            raise ReactionsNotSolved("no step asked for")
        which = (np.arange(self.m) if scenes is None else np.asarray(scenes))[:, None]
        args = [self.states[steps, j, i, which] for j in range(3) for i in range(self.n)]
        given = self._loads_at(args[: self.n], args[self.n : 2 * self.n], which)
        mech, q, mass, inertia = self._solver
        key = None if columns is None else frozenset(columns)
        if key not in self._kernels:  # built once: a batch's reports ask for many blocks
            from ...dynamics.reactions import array_reactions

            self._kernels[key] = array_reactions(mech, self.view, q, key)
        try:
            return solve_reactions(
                mech,
                self.view,
                q,
                mass[which[:, 0]],
                inertia[which[:, 0]],
                args,
                given,
                self._kernels[key],
                key,
            )
        finally:
            self.reaction_cpu_s += time.process_time() - c0
