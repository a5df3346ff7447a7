"""What a vectorised batch's steps record (:mod:`mps_core.run.batch`): each step's columns for
every scene, in arrays allocated for the whole run, and, with the joint reactions asked for, each
step's state and its effects' loads, solved after the run by the chart view's reaction kernel on
arrays over every step of every scene at once
(:func:`mps_core.dynamics.reactions.array_reactions`)."""

from __future__ import annotations

import numpy as np

from ...names import COLUMNS

#: states a call of the reaction kernel on arrays takes: a batch's load reports ask for blocks
#: of 16 runs of about 850 steps (working at 0.2 ms), one call each (in a temporary script,
#: 4096 to 32768 in turns: 16384 the quickest, by about a tenth of the reactions' time)
REACTION_CHUNK = 16384

_TEXT = ("structure", "chart")


class ReactionsNotSolved(Exception):
    """The recorded states' reactions cannot be solved on arrays (the batch is run one by one)."""


class BatchRecord:
    """The columns of ``m`` scenes over ``steps`` steps (``steps + 1`` states) of the chart view
    ``view`` in ``structure``; ``c_row`` the row of C in the kinematics, ``effects`` the scenes'
    :class:`~mps_core.run.batch.effects.EffectArrays`, ``reactions`` whether the states and
    loads are kept for :meth:`reaction_columns`."""

    def __init__(
        self, m: int, steps: int, n: int, view, structure: str, c_row: int, effects, reactions: bool
    ):
        S = steps + 1
        self.m, self.view, self.structure, self.c_row, self.effects = m, view, structure, c_row, effects
        self.k = 0  # the states recorded
        # one array a column, (state, scene): a state's values are one contiguous row
        self.table = {c: np.zeros((S, m)) for c in COLUMNS if c not in _TEXT}
        names = [c.name for c in view.coordinates]
        #: the structure's coordinates: (column, index in q); the frozen ones filled once
        self.free = [(nm, names.index(nm)) for nm in ("phi", "psi") if nm in names]
        for nm in ("phi", "psi"):
            if nm not in names:
                self.table[nm][:] = view.frozen[nm]
        self.reactions = reactions
        nl = 3 * effects.nb + 4
        #: (q, q̇ or q̈, coordinate, scene, state) and (load, scene, state), for the reactions:
        #: a scene's states contiguous, as the reaction kernel takes them
        self.states: np.ndarray = np.empty((3, n, m, S)) if reactions else np.empty(0)
        self.loads: np.ndarray = np.zeros((nl, m, S)) if reactions else np.empty(0)

    def record(self, t, q, qd, qdd, A, kin, work) -> None:
        """The state at ``t`` of every scene: q, q̇, q̈ (scene, coordinate), the mass matrices
        ``A``, the kinematics ``kin`` of that evaluation and the work done so far."""
        k, tab = self.k, self.table
        tab["t"][k] = t
        for nm, i in self.free:
            tab[nm][k] = q[:, i]
            tab[nm + "_dot"][k] = qd[:, i]
            tab[nm + "_ddot"][k] = qdd[:, i]
        tab["x_C"][k] = kin.x(self.c_row, 0)
        n = qd.shape[1]
        tab["T"][k] = 0.5 * sum(qd[:, i] * A[:, i, j] * qd[:, j] for i in range(n) for j in range(n))
        tab["V"][k] = self.effects.potential(kin)
        tab["W"][k] = work
        if self.reactions:
            for j, x in enumerate((q, qd, qdd)):
                self.states[j, :, :, k] = x.T
            for j, x in enumerate(self.effects.loads(kin)):
                self.loads[j, :, k] = x
        self.k = k + 1

    def columns(self) -> dict:
        """Every column as (scene, state): a scene's column is then one row of it."""
        out: dict[str, np.ndarray] = {c: v.T.copy() for c, v in self.table.items()}
        for c, v in (("structure", self.structure), ("chart", self.view.name)):
            out[c] = np.full(self.k, v)
        return {c: out[c] for c in COLUMNS}

    def reaction_columns(self, mech, q, mass, inertia) -> dict:
        """The reaction columns, (scene, state) each, of the recorded states
        (:func:`solve_reactions`)."""
        _, n, _, _ = self.states.shape
        args = [self.states[j, i] for j in range(3) for i in range(n)]
        out = solve_reactions(mech, self.view, q, mass, inertia, args, list(self.loads))
        self.states = self.loads = np.empty(0)
        return out


def solve_reactions(mech, view, q, mass, inertia, args: list, loads: list, fn=None, columns=None) -> dict:
    """The reaction columns of states given as arrays (scene, state): ``args`` q…, q̇…, q̈… and
    ``loads`` the effects' loads, each of that shape (a load may also be a number, or (scene,
    1): the same at every state); the view's reaction kernel (built at
    ``q``) on arrays, ``mass`` and ``inertia`` (scene, body), on blocks of (scenes, states) of
    about :data:`REACTION_CHUNK` states a call; ``fn`` that kernel where the caller has it
    already (:func:`~mps_core.dynamics.reactions.array_reactions`, built for ``columns``);
    ``columns``: those of :data:`~mps_core.dynamics.reactions.REACTION_COLUMNS` to solve
    (None: all). Raises
    :class:`ReactionsNotSolved` where the view has no such kernel, or a state's reactions are
    not unique or not finite."""
    from ...codegen.array_kernels import ArrayBranchChanged
    from ...dynamics.reactions import REACTION_COLUMNS, array_reactions

    if fn is None:
        fn = array_reactions(mech, view, q, columns)
    if fn is None:
        raise ReactionsNotSolved("the chart view has no reaction kernel")
    m, S = args[0].shape
    # a mass or an inertia the scenes share is a number, the others one value a scene
    masses = [float(col[0]) if np.all(col == col[0]) else col[:, None] for col in [*mass.T, *inertia.T]]
    out = {c: np.empty((m, S)) for c in REACTION_COLUMNS if columns is None or c in columns}
    # blocks of whole scenes (all their states) where a scene's states fit a call, else of
    # a scene's states
    width = max(1, REACTION_CHUNK // S)
    height = min(S, REACTION_CHUNK)
    for j0 in range(0, m, width):
        cols = slice(j0, j0 + width)
        given = [x if isinstance(x, float) else x[cols] for x in masses]
        for s0 in range(0, S, height):
            rows = slice(s0, s0 + height)
            at = [x if isinstance(x, float) else x[cols, rows] if x.shape[1] > 1 else x[cols] for x in loads]
            try:
                values, _residual = fn(*[a[cols, rows] for a in args], given, at)
            except ArrayBranchChanged:
                raise ReactionsNotSolved("a scene's reactions are not unique at a step") from None
            for c, v in zip(REACTION_COLUMNS, values):
                if c in out:
                    out[c][cols, rows] = v
    # a NaN or an infinity anywhere makes the sum one
    if not all(np.isfinite(v.sum()) for v in out.values()):
        raise ReactionsNotSolved("non-finite reactions")
    return out
