"""Batch mode: many scenes, one numpy pass per step for all of them (parameter sweeps).

``simulate_many(scenes)`` groups scenes that can share one vectorised pass and steps each group
together: the central-difference stencils of all its scenes go through the chart's position
function in one call (arrays of shape (scenes, stencil)), the mass matrices, velocity terms and
generalized forces of all scenes are formed and solved at once, and the fixed-step solver
advances all of them. What a group shares: the mechanism's geometry and centres of mass, the
structure and its chart, the set of effect kinds, the solver, step, end time and derivative
scheme. What may differ scene by scene: masses and inertias, the initial state, and every effect
parameter (gravity, motor data and ratio, spring stiffness and preload, blanking force…).

Vectorised here: fixed-step solvers (linear acceleration, RK4) with central differences or
exact derivatives, on scenes without events or commands (no latch, no rigid stop, no
cylinders) whose chart stays regular over the run (e.g. ``locked`` sweeps of ``working``), with
the effects gravity, motor, springs (and their damping) and blanking. Every other scene, and
any scene of a group that would need a change of chart or a subdivided step, is run by
:func:`mps_core.simulate` on its own: the
result is the same, only not vectorised. ``BatchResult.vectorised`` says which were.

With central differences a pass evaluates the chart's positions on the stencils of all scenes
(arrays of shape (scenes, stencil)) and forms A and h by differences, as the engine's array
code does. With exact derivatives it runs the chart's exact kernel
(:mod:`mps_core.codegen.exact_kernels`) on arrays of one value per scene
(:mod:`mps_core.codegen.array_kernels`): the kinematics and their derivatives in one call of
straight-line numpy code, A and h formed from them with each scene's masses. A scene that
leaves the kernel's branch sends its group back to the one-by-one runs.

The effects' parameters are arrays of one value a scene
(:class:`~mps_core.run.batch.effects.EffectArrays`: their forces, power, potential energy and
loads). What each step records goes into arrays allocated for the run
(:class:`~mps_core.run.batch.record.BatchRecord`). With ``outputs.reactions`` (the scenes of a
group alike) the trajectories carry the joint reactions and the foundation load
(:data:`mps_core.dynamics.reactions.REACTION_COLUMNS`), as a scalar run's: each recorded step
keeps its state and its effects' loads (from that step's evaluation), and after the run the
chart view's reaction kernel, its masses and inertias an argument, runs on arrays over every
step of every scene at once (:func:`mps_core.dynamics.reactions.array_reactions`). A state where
the kernel does not hold (a singular position) sends the group back to the one-by-one runs.

:func:`run_states` steps a group the same way but keeps no trajectory: each step's state and
the loads that a state changes, the reactions solved afterwards at the steps one asks for
(:class:`~mps_core.run.batch.states.BatchStates`); a sweep's batches make their runs' load
reports from them (:mod:`mps_core.analysis.batch_loads`).

For sweeps larger than one machine, ``simulate_many(scenes, client=...)`` sends batches to a Dask
cluster (``dask.distributed.Client``), one vectorised batch a task.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...caches import Memo
from ...codegen.array_kernels import ArrayBranchChanged
from ...derivatives import SCHEMES
from ...derivatives.stencil import stencil
from ...model.effects import Blanking, Gravity, Motor, RetentionSprings, SliderDamper
from ...model.press import SEED_BODIES
from ...scene import Scene, load_scene
from ...solvers import RK4, SOLVERS, LinearAcceleration
from ..trajectory import Trajectory
from .effects import EffectArrays
from .record import BatchRecord, ReactionsNotSolved
from .states import BatchStates

VECTOR_EFFECTS = (Gravity, Motor, RetentionSprings, SliderDamper, Blanking)
VECTOR_SOLVERS = (LinearAcceleration.name, RK4.name)
#: both derivative schemes
VECTOR_SCHEMES = SCHEMES


class NotVectorisable(Exception):
    """A group of scenes cannot (or can no longer) share one vectorised pass."""


@dataclass
class BatchResult:
    """Trajectories in the order of the scenes given, and which of them ran vectorised."""

    trajectories: list
    vectorised: list = field(default_factory=list)

    def __iter__(self):
        return iter(self.trajectories)

    def __len__(self):
        return len(self.trajectories)

    def __getitem__(self, i):
        return self.trajectories[i]


def group_key(scene: Scene):
    """Scenes with equal keys can share a vectorised pass (None: this scene cannot)."""
    s = scene.solver
    if (
        s.name not in VECTOR_SOLVERS or s.scheme not in VECTOR_SCHEMES or scene.commands or s.step is not None
    ):  # a step apart from the outputs: the scene's own run
        return None
    kinds = _effect_kinds(scene)
    if kinds is None:
        return None
    if scene.structure == "held":
        return None
    # the bodies' frames follow from the geometry; their centres of mass as the scene gives
    # them (None: the seed's for that geometry)
    bodies = tuple(
        (name, None if d.com is None else tuple(map(float, d.com)))
        for name, d in sorted(scene.bodies.items())
    )
    return (
        scene.geometry,
        scene.assembly,
        bodies,
        scene.x_top,
        scene.structure,
        scene.psi_lock,
        kinds,
        s.name,
        s.scheme,
        s.delta,
        s.iterations,
        scene.t_end,
        scene.dt,
        scene.charts,
        scene.reactions,
    )


#: :func:`_effect_kinds` by the effects' tuple a scene holds (the same tuple, kept with it, for
#: the scenes whose effect tables are alike: :func:`mps_core.scene.scene_from_dict` keeps them)
_KINDS = Memo("batch.effect_kinds", 256)


def _effect_kinds(scene: Scene) -> tuple | None:
    """The names of the classes of the effects a scene builds, sorted (None: one of them is
    not vectorised)."""
    kept = _KINDS.get(id(scene.effects))
    if kept is not None and kept[0] is scene.effects:
        return kept[1]
    effects = scene.build_effects(scene.linkage())
    kinds = (
        None
        if any(not isinstance(e, VECTOR_EFFECTS) for e in effects)
        else tuple(sorted(type(e).__name__ for e in effects))
    )
    _KINDS.keep(id(scene.effects), (scene.effects, kinds))
    return kinds


def run_batch(scenes) -> list:
    """The trajectories of scenes of one group (equal :func:`group_key`) stepped together in
    one vectorised pass; :class:`NotVectorisable` where they cannot (or can no longer) share
    it."""
    return _Batch(list(scenes)).run()


def run_states(scenes) -> BatchStates:
    """The states of scenes of one group stepped together, as :func:`run_batch` steps them,
    kept for their load reports (:class:`~mps_core.run.batch.states.BatchStates`: each step's
    state and loads, the reactions solved at the steps asked for) rather than as
    trajectories; :class:`NotVectorisable` where they cannot share the pass."""
    return _Batch(list(scenes)).run_states()


def simulate_many(scenes, *, client=None, batch_size: int = 1000) -> BatchResult:
    """Run many scenes; vectorised where they can share a pass (see the module's notes)."""
    scenes = [sc if isinstance(sc, Scene) else load_scene(sc) for sc in scenes]
    out: list = [None] * len(scenes)
    vec = [False] * len(scenes)
    groups: dict = {}
    for i, sc in enumerate(scenes):
        groups.setdefault(group_key(sc), []).append(i)
    tasks: list[tuple[str, list[int]]] = []
    for key, idx in groups.items():
        if key is None:
            tasks.extend(("single", [i]) for i in idx)
        else:
            tasks.extend(("batch", idx[k : k + batch_size]) for k in range(0, len(idx), batch_size))
    if client is not None:
        futures = [
            client.submit(_run_task, kind, [scenes[i] for i in idx], pure=False) for kind, idx in tasks
        ]
        results = client.gather(futures)
    else:
        results = [_run_task(kind, [scenes[i] for i in idx]) for kind, idx in tasks]
    for (_kind, idx), (trajs, flags) in zip(tasks, results):
        for i, tr, f in zip(idx, trajs, flags):
            out[i], vec[i] = tr, f
    return BatchResult(out, vec)


def _run_task(kind, scenes):
    """One task: (trajectories, vectorised flags)."""
    from ..build import simulate

    if kind == "batch":
        try:
            return _Batch(scenes).run(), [True] * len(scenes)
        except NotVectorisable:
            pass
    return [simulate(sc) for sc in scenes], [False] * len(scenes)


class _Batch:
    """Scenes of one group stepped together."""

    def __init__(self, scenes):
        self.scenes = scenes
        first = scenes[0]
        self.mech = first.mechanism()
        self.m = len(scenes)
        linkage = first.linkage()  # the initial states: the geometry's alone
        views = []
        q0, qd0 = [], []
        for sc in scenes:
            view, q, qd = sc.initial_state(linkage)
            views.append(view.name)
            q0.append(q)
            qd0.append(qd)
        if len(set(views)) != 1:
            raise NotVectorisable("the scenes start in different charts")
        self.view, _, _ = first.initial_state(self.mech)
        self.q0, self.qd0 = np.array(q0), np.array(qd0)
        self.settings = first.solver
        self.policy = first.charts
        bodies = self.mech.bodies
        # each scene's masses and inertias (a group's scenes differ in nothing else of a body;
        # a body a scene does not name is the seed's, as in its mechanism)
        per = [[sc.bodies.get(b.name, SEED_BODIES[b.name]) for b in bodies] for sc in scenes]
        self.mass = np.array([[d.mass for d in ds] for ds in per])  # (m, nb)
        self.inertia = np.array([[d.inertia for d in ds] for ds in per])
        self.rot = [k for k, b in enumerate(bodies) if b.rotates]
        self.rows = {p: k for k, p in enumerate(self.mech.points)}
        for b in bodies:
            self.rows[f"G_{b.name}"] = len(self.rows)
        # each scene's effects, built once for the scenes that share their specs' tuple (what
        # a builder reads of a scene beside them: the top stop's position, the lock angle)
        built: dict = {}
        for sc in scenes:
            key = (id(sc.effects), sc.x_top, sc.psi_lock)
            if key not in built:
                built[key] = sc.build_effects(self.mech)
        self.effects = EffectArrays(
            self.mech,
            self.rows,
            self.mass,
            first.structure,
            [built[id(sc.effects), sc.x_top, sc.psi_lock] for sc in scenes],
        )
        self.evaluations = 0
        self._terms: Any = None  # sums A's and h's terms (:meth:`_exact_terms`), once made
        self._kernel = self._array_kernel(first) if self.settings.scheme == "autodiff" else None
        # by body, contiguous: the centres of mass' rows, masses, inertias
        self.com_rows = self.effects.com_rows
        self.mass_of = [self.mass[:, b].copy() for b in range(len(bodies))]
        self.inertia_of = [self.inertia[:, b].copy() for b in range(len(bodies))]
        #: the joint reactions (the scenes' ``outputs.reactions``), solved after the run
        self.reactions = bool(first.reactions)

    def _array_kernel(self, first: Scene):
        """The exact kernel of the scenes' chart view, on arrays (NotVectorisable where the
        chart has none)."""
        from ...codegen.array_kernels import array_kernel
        from ...codegen.exact_kernels import exact_kernel
        from ..build import build

        engine = build(first).engine
        view, q, _ = first.initial_state(engine.mechanism)
        kernel = exact_kernel(engine, view, q)
        if kernel is None:
            raise NotVectorisable("the chart has no exact kernel")
        # A and h in its return hold the first scene's masses: the batch forms its own
        return array_kernel(kernel, drop=(3, 4))

    # -- the vectorised engine ------------------------------------------------------------------
    def evaluate(self, t, q, qd):
        """q̈ and what a step records, for all scenes: q, q̇ of shape (m, n)."""
        if self._kernel is not None:
            return self._evaluate_exact(t, q, qd)
        n = q.shape[1]
        X, V, W, d = self._differences(q, 1 + 2 * n)
        com = [self.rows[f"G_{b.name}"] for b in self.mech.bodies]
        VG = np.take(V, com, axis=1)  # (m, nb, 2, nbase, n)
        # each term weighted first: two operands an einsum (three cost it three times as much)
        Ab = np.einsum("mbkci,mbkcj->mcij", self.mass[:, :, None, None, None] * VG, VG) + np.einsum(
            "mbci,mbcj->mcij", self.inertia[:, :, None, None] * W, W
        )
        A = Ab[:, 0]
        dA = (Ab[:, 1::2] - Ab[:, 2::2]) / (2.0 * d)[None, :, None, None]
        h = np.einsum("mkij,mj,mk->mi", dA, qd, qd) - 0.5 * np.einsum("mijk,mj,mk->mi", dA, qd, qd)
        return self._solve(t, self._kinematics_at_q(X, V, W), qd, A, h)

    def _differences(self, q, bases: int):
        """The central differences at states q (m, n), from the stencil's first ``bases`` base
        points (:func:`~mps_core.derivatives.stencil.stencil`: 1, the analogs at q alone; 1 +
        2n, also at q ± Δe_i, for the mass matrix's derivatives) and only the stencil points
        they need: ``(X, V, W, Δ)``, the points' and centres of mass's positions (m, NP, 2,
        points), their analogs (m, NP, 2, bases, n) and the bodies' angular analogs (m, nb,
        bases, n) at each base point."""
        m, n = q.shape
        offsets, plus, minus = stencil(n)
        plus, minus = plus[:bases], minus[:bases]
        S = int(max(plus.max(), minus.max())) + 1  # the points the bases' differences read
        d = self.settings.delta * self.view.scales
        pts = q[:, None, :] + offsets[None, :S] * d  # (m, S, n)
        pose = self.view.positions([pts[..., i] for i in range(n)])
        points, bodies = self.mech.points, self.mech.bodies
        # the points' and the centres of mass's positions at every stencil point: a number
        # (a fixed point's) or one a state and point
        X = np.empty((m, len(points) + len(bodies), 2, S))
        for r, p in enumerate(points):
            X[:, r, 0], X[:, r, 1] = pose[p][0], pose[p][1]
        for r, b in enumerate(bodies, len(points)):
            X[:, r, 0], X[:, r, 1] = b.com_of(pose)
        if not np.isfinite(X.sum()):  # a NaN or an infinity anywhere: the sum's
            raise NotVectorisable("a stencil point left the chart")
        # (m, NP, 2, bases, n), contiguous (the einsums of A take a third of the time they take
        # on the strided array indexing gives)
        V = (np.take(X, plus, axis=-1) - np.take(X, minus, axis=-1)) / (2.0 * d)
        base = np.arange(bases)  # the base points are the stencil's first
        W = np.zeros((m, len(bodies), bases, n))
        Xb = X[..., base]  # (m, NP, 2, bases)
        for k in self.rot:
            b = bodies[k]
            p, qq = self.rows[b.origin], self.rows[b.toward]
            R = Xb[:, qq] - Xb[:, p]  # (m, 2, bases)
            VR = V[:, qq] - V[:, p]  # (m, 2, bases, n)
            r2 = R[:, 0] ** 2 + R[:, 1] ** 2
            W[:, k] = (R[:, 0, :, None] * VR[:, 1] - R[:, 1, :, None] * VR[:, 0]) / r2[..., None]
        return X, V, W, d

    @staticmethod
    def _kinematics_at_q(X, V, W) -> _Kinematics:
        """The kinematics at the stencil's first base point, q (:meth:`_differences`)."""
        return _Kinematics.of_tables(X[..., 0], V[:, :, :, 0, :], W[:, :, 0, :])

    def _evaluate_exact(self, t, q, qd):
        """:meth:`evaluate` with exact derivatives: the kinematics from the array kernel, A
        and h from them with each scene's masses and inertias."""
        m, n = q.shape
        try:
            xl, jl, wl, _, _, conv = self._kernel(*q.T, *qd.T)
        except ArrayBranchChanged as exc:
            raise NotVectorisable(str(exc)) from None
        kin = _Kinematics(xl, jl, wl, n, m)
        # A_ij = Σ m v*_G,i·v*_G,j + J ω*_i ω*_j and h_i = Σ m v*_G,i·G̈ + J ω*_i θ̈ (at q̈ = 0):
        # one term a body's centre of mass' component or its rotation, those whose analogs
        # the kernel gives (the others are zero), summed by code made for them once
        if self._terms is None:
            self._terms = self._exact_terms(kin, conv)
        A, h = self._terms(jl + wl, conv, m)
        return self._solve(t, kin, qd, A, h)

    def _exact_terms(self, kin, conv):
        """A function ``(analogs, conv, m) -> (A, h)`` that sums A's and h's terms: straight-line
        numpy code over the terms whose analogs the kernel gives (in its analogs, then its
        angular analogs, one a coordinate; a term whose analogs are all the number 0 left
        out), their convective accelerations in ``conv``, weighted by each scene's mass or
        inertia; A symmetric by construction."""
        nb, n = len(self.mech.bodies), kin.n
        analogs = list(kin.jl) + list(kin.wl)
        weights, rows, cols = [], [], []
        for b, row in enumerate(self.com_rows):
            for k, w, c in (
                ((2 * row) * n, self.mass_of[b], nb + 2 * b),
                ((2 * row + 1) * n, self.mass_of[b], nb + 2 * b + 1),
                (len(kin.jl) + b * n, self.inertia_of[b], b),
            ):
                if all(isinstance(x, float) and x == 0.0 for x in analogs[k : k + n]):
                    continue
                weights.append(w)
                rows.append(list(range(k, k + n)))
                cols.append(c)
        terms = range(len(cols))
        lines = ["def a_and_h(an, cv, m):"]
        lines += [f"    t{k}_{i} = w[{k}] * an[{rows[k][i]}]" for k in terms for i in range(n)]
        lines.append(f"    A = empty((m, {n}, {n}))")
        lines.append(f"    h = empty((m, {n}))")
        for i in range(n):
            for j in range(i, n):
                lines.append(
                    f"    A[:, {i}, {j}] = "
                    + (" + ".join(f"t{k}_{i} * an[{rows[k][j]}]" for k in terms) or "0.0")
                )
                if j > i:
                    lines.append(f"    A[:, {j}, {i}] = A[:, {i}, {j}]")
            lines.append(
                f"    h[:, {i}] = " + (" + ".join(f"t{k}_{i} * cv[{cols[k]}]" for k in terms) or "0.0")
            )
        lines.append("    return A, h")
        namespace = {"w": weights, "empty": np.empty}
        exec(compile("\n".join(lines), "<batch A and h>", "exec"), namespace)
        return namespace["a_and_h"]

    def _solve(self, t, kin, qd, A, h):
        """q̈ = A⁻¹(Q − h) with the effects' Q: (q̈, A, the kinematics, the power)."""
        Q, power = self.effects.forces(kin, list(qd.T))
        n = qd.shape[1]
        r = [Q[i] - h[:, i] for i in range(n)]
        if n == 1:
            qdd = (r[0] / A[:, 0, 0])[:, None]
        elif n == 2:
            a00, a01, a11 = A[:, 0, 0], A[:, 0, 1], A[:, 1, 1]
            det = a00 * a11 - a01 * a01
            qdd = np.stack([(a11 * r[0] - a01 * r[1]) / det, (a00 * r[1] - a01 * r[0]) / det], axis=1)
        else:
            qdd = np.linalg.solve(A, np.stack(r, axis=1)[..., None])[..., 0]
        if not np.isfinite(qdd.sum()):  # a NaN or an infinity anywhere: the sum's
            raise NotVectorisable("non-finite accelerations")
        self.evaluations += 1
        return qdd, A, kin, power

    def _check(self, kin, A):
        """The chart must stay regular and the step stable, for every scene."""
        pose = {p: (kin.x(k, 0), kin.x(k, 1)) for p, k in self.rows.items()}
        if np.any(np.asarray(self.view.chart.regularity(pose)) < self.policy.switch_below):
            raise NotVectorisable("a scene would change chart")
        if self.effects.springs is not None:
            k = self.effects.springs[0]
            j = np.stack(
                [np.broadcast_to(x, (self.m,)) for x in kin.jac(self.rows["C"], 0)], axis=1
            )  # (m, n)
            if j.shape[1] == 1:  # one coordinate: A is a number a scene
                w2 = k * (j[:, 0] * j[:, 0] / A[:, 0, 0])
            else:
                w2 = k * np.einsum("mi,mij,mj->m", j, np.linalg.inv(A), j)
            lim = SOLVERS[self.settings.name].stability_limit
            t_min = 2.0 * math.pi / np.sqrt(np.maximum(w2, 1e-300))
            if np.any(self.dt > 0.9 * lim * t_min):
                raise NotVectorisable("a step would be subdivided")

    # -- the run ----------------------------------------------------------------------------------
    def run(self):
        """The scenes' trajectories."""
        record = BatchRecord(
            self.m,
            self._steps(),
            self.q0.shape[1],
            self.view,
            self.effects.structure,
            self.rows["C"],
            self.effects,
            self.reactions,
        )
        self._step(record)
        return self._trajectories(record)

    def run_states(self) -> BatchStates:
        """The scenes' states and loads at every step, their reactions solved on the steps
        one asks for (:class:`~mps_core.run.batch.states.BatchStates`), and no trajectory."""
        states = BatchStates(
            self.m,
            self._steps(),
            self.q0.shape[1],
            self.view,
            self.effects.structure,
            self._loads_at,
            self.mech,
            self.q0[0],
            self.mass,
            self.inertia,
        )
        self._step(states)
        return states

    def _loads_at(self, q: list, qd: list, scenes: np.ndarray) -> list:
        """The effects' loads (:meth:`~mps_core.run.batch.effects.EffectArrays.loads`) at states
        given as (scene, j) arrays of each coordinate, ``scenes`` (scene, 1) their scenes'
        indices: this batch's evaluation of those states, each entry a number or an array of
        that shape or (scene, 1)."""
        g, L = q[0].shape
        if self._kernel is not None:  # the kinematics alone, on the (scene, j) arrays
            try:
                xl, jl, wl, _, _, _ = self._kernel(*q, *qd)
            except ArrayBranchChanged as exc:
                raise NotVectorisable(str(exc)) from None
            kin = _Kinematics(xl, jl, wl, len(q), g)
            effects = self.effects.take(scenes[:, 0], states=L)
            effects.forces(kin, qd)
            return [x if np.ndim(x) else float(x) for x in effects.loads(kin)]
        # by differences: the analogs at the states alone (the stencil's first points: the
        # same kinematics as the run's evaluations, without the mass matrix), one scene a state
        X, V, W, _ = self._differences(np.stack([x.ravel() for x in q], axis=1), 1)
        kin = self._kinematics_at_q(X, V, W)
        effects = self.effects.take(np.repeat(scenes[:, 0], L))
        effects.forces(kin, [x.ravel() for x in qd])
        return [np.reshape(x, (g, L)) if np.ndim(x) else float(x) for x in effects.loads(kin)]

    def _steps(self) -> int:
        """The run's steps; sets :attr:`dt`."""
        t_end = self.scenes[0].t_end
        n_steps = max(1, int(round(t_end / self.scenes[0].dt)))
        self.dt = t_end / n_steps
        return n_steps

    def _step(self, record) -> None:
        """Steps every scene from 0 to the end time, each state into ``record``."""
        t0, t_end = 0.0, self.scenes[0].t_end
        n_steps = self._steps()
        q, qd = self.q0.copy(), self.qd0.copy()
        name, its = self.settings.name, self.settings.iterations
        work = np.zeros(self.m)

        ev = self.evaluate
        qdd, A, kin, p_now = ev(t0, q, qd)
        record.record(t0, q, qd, qdd, A, kin, work)
        t = t0
        for k in range(1, n_steps + 1):
            self._check(kin, A)  # as the driver does at each step's start
            t1 = t_end if k == n_steps else t0 + k * (t_end - t0) / n_steps
            dt = t1 - t
            if name == "linear-acceleration":
                a0 = qdd
                qdp = qd + a0 * dt
                qp = q + qd * dt + a0 * (0.5 * dt * dt)
                a1 = ev(t1, qp, qdp)[0]
                for it in range(its):
                    qd1 = qd + (a0 + a1) * (0.5 * dt)
                    q1 = q + qd * dt + (2.0 * a0 + a1) * (dt * dt / 6.0)
                    out = ev(t1, q1, qd1)
                    if it + 1 < its:
                        a1 = out[0]
            else:
                h = dt
                v0, a1_ = qd, qdd
                v2 = v0 + 0.5 * h * a1_
                a2 = ev(t + 0.5 * h, q + 0.5 * h * v0, v2)[0]
                v3 = v0 + 0.5 * h * a2
                a3 = ev(t + 0.5 * h, q + 0.5 * h * v2, v3)[0]
                v4 = v0 + h * a3
                a4 = ev(t1, q + h * v3, v4)[0]
                q1 = q + (h / 6.0) * (v0 + 2.0 * v2 + 2.0 * v3 + v4)
                qd1 = v0 + (h / 6.0) * (a1_ + 2.0 * a2 + 2.0 * a3 + a4)
                out = ev(t1, q1, qd1)
            qdd, A, kin, p_new = out
            work = work + 0.5 * (p_now + p_new) * (t1 - t)
            p_now = p_new
            q, qd, t = q1, qd1, t1
            record.record(t, q, qd, qdd, A, kin, work)

    def _trajectories(self, record: BatchRecord):
        out = []
        nsteps = record.k - 1
        per_step = (1 + self.settings.iterations) if self.settings.name == "linear-acceleration" else 4
        table = record.columns()
        if self.reactions:
            try:
                table.update(record.reaction_columns(self.mech, self.q0[0], self.mass, self.inertia))
            except ReactionsNotSolved as exc:
                raise NotVectorisable(str(exc)) from None
        for i, sc in enumerate(self.scenes):
            cols = {k: v if k in ("structure", "chart") else v[i] for k, v in table.items()}
            counts = {
                "evaluations": 1 + per_step * nsteps,
                "steps": nsteps,
                "batch_evaluations": self.evaluations,
                "batch_size": self.m,
            }
            settings = {
                **sc.solver.described(),
                "chart_switching": sc.charts.switching,
                "scene": sc.name,
                "vectorised": True,
            }
            out.append(Trajectory(cols, [], counts, settings))
        return out


class _Kinematics:
    """The kinematics of all scenes at their q, one array (or a float shared by all) a number,
    in the engine's layout: positions ``x(row, c)``, analogs ``jac(row, c)`` (one a
    coordinate) and angular analogs ``omega(body)`` (one a coordinate)."""

    def __init__(self, xl, jl, wl, n: int, m: int):
        self.xl, self.jl, self.wl, self.n, self.m = xl, jl, wl, n, m

    @classmethod
    def of_tables(cls, X0, J, W0):
        """From arrays (m, NP, 2), (m, NP, 2, n) and (m, nb, n)."""
        m, n = J.shape[0], J.shape[-1]
        return cls(list(X0.reshape(m, -1).T), list(J.reshape(m, -1).T), list(W0.reshape(m, -1).T), n, m)

    def x(self, row: int, c: int):
        return self.xl[2 * row + c]

    def jac(self, row: int, c: int) -> list:
        k = (2 * row + c) * self.n
        return self.jl[k : k + self.n]

    def omega(self, body: int) -> list:
        return self.wl[body * self.n : (body + 1) * self.n]


def throughput(sizes=(1, 10, 100, 1000), steps: int = 200, scheme: str = "central") -> list[dict]:
    """Mechanism-steps per second of the vectorised pass for each number of scenes (working,
    slider mass swept, derivatives by ``scheme``), and of ``simulate`` for one scene
    (``scenes`` = 0)."""
    import time
    from dataclasses import replace

    from ...model import BodyData
    from ..build import build

    base = load_scene("working").with_overrides(t_end=steps * 1e-4, dt=1e-4)
    base = replace(base, solver=replace(base.solver, scheme=scheme))
    sim = build(base)
    c0 = time.process_time()
    sim.run(base.t_end, base.dt)
    rows = [
        {"scenes": 0, "steps_per_s": steps / (time.process_time() - c0), "cpu_s": time.process_time() - c0}
    ]
    for n in sizes:
        scenes = []
        for i in range(n):
            b = dict(base.bodies)
            b["slider"] = BodyData(80.0 + 40.0 * i / max(1, n - 1), 0.0, b["slider"].com)
            scenes.append(replace(base, bodies=b))
        batch = _Batch(scenes)
        c0 = time.process_time()
        batch.run()
        cpu = time.process_time() - c0
        rows.append({"scenes": n, "steps_per_s": n * steps / cpu, "cpu_s": cpu})
    return rows
