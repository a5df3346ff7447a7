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

With ``outputs.reactions`` (the scenes of a group alike) the trajectories carry the joint
reactions and the foundation load (:data:`mps_core.dynamics.reactions.REACTION_COLUMNS`), as a
scalar run's: each recorded step keeps its state and its effects' loads (from that step's
evaluation), and after the run the chart view's reaction kernel, its masses and inertias an
argument, runs on arrays over every step of every scene at once
(:func:`mps_core.dynamics.reactions.array_reactions`). A state where the kernel does not hold
(a singular position) sends the group back to the one-by-one runs.

For sweeps larger than one machine, ``simulate_many(scenes, client=...)`` sends batches to a Dask
cluster (``dask.distributed.Client``), one vectorised batch a task.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..derivatives.stencil import stencil
from ..model.effects import Blanking, Gravity, Motor, RetentionSprings, SliderDamper
from ..names import COLUMNS
from ..scene import Scene, load_scene
from ..solvers import SOLVERS
from .trajectory import Trajectory

VECTOR_EFFECTS = (Gravity, Motor, RetentionSprings, SliderDamper, Blanking)
VECTOR_SOLVERS = ("linear-acceleration", "rk4")
VECTOR_SCHEMES = ("central", "autodiff")


#: states a call of the reaction kernel on arrays takes (its arrays stay in the caches)
_REACTION_CHUNK = 4096


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
    mech = scene.mechanism()
    effects = scene.build_effects(mech)
    if any(not isinstance(e, VECTOR_EFFECTS) for e in effects):
        return None
    if scene.structure == "held":
        return None
    bodies = tuple((b.name, b.origin, b.toward, b.length, b.com) for b in mech.bodies)
    return (
        scene.geometry,
        scene.assembly,
        bodies,
        scene.x_top,
        scene.structure,
        scene.psi_lock,
        tuple(sorted(type(e).__name__ for e in effects)),
        s.name,
        s.scheme,
        s.delta,
        s.iterations,
        scene.t_end,
        scene.dt,
        scene.charts,
        scene.reactions,
    )


def run_batch(scenes) -> list:
    """The trajectories of scenes of one group (equal :func:`group_key`) stepped together in
    one vectorised pass; :class:`NotVectorisable` where they cannot (or can no longer) share
    it."""
    return _Batch(list(scenes)).run()


def simulate_many(scenes, *, client=None, batch_size: int = 1000) -> BatchResult:
    """Run many scenes; vectorised where they can share a pass (see the module's notes)."""
    scenes = [sc if isinstance(sc, Scene) else load_scene(sc) for sc in scenes]
    out: list = [None] * len(scenes)
    vec = [False] * len(scenes)
    groups: dict = {}
    for i, sc in enumerate(scenes):
        groups.setdefault(group_key(sc), []).append(i)
    tasks = []
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
    from .build import simulate

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
        views = []
        q0, qd0 = [], []
        for sc in scenes:
            view, q, qd = sc.initial_state(self.mech)
            views.append(view.name)
            q0.append(q)
            qd0.append(qd)
        if len(set(views)) != 1:
            raise NotVectorisable("the scenes start in different charts")
        self.view, _, _ = first.initial_state(self.mech)
        self.q0, self.qd0 = np.array(q0), np.array(qd0)
        self.settings = first.solver
        self.policy = first.charts
        self.structure = first.structure
        bodies = self.mech.bodies
        mechanisms = [sc.mechanism() for sc in scenes]  # each scene's masses and inertias
        per = [mech.bodies for mech in mechanisms]
        self.mass = np.array([[b.mass for b in bs] for bs in per])  # (m, nb)
        self.inertia = np.array([[b.inertia for b in bs] for bs in per])
        self.rot = [k for k, b in enumerate(bodies) if b.rotates]
        self.rows = {p: k for k, p in enumerate(self.mech.points)}
        for b in bodies:
            self.rows[f"G_{b.name}"] = len(self.rows)
        self._effects([sc.build_effects(mech) for sc, mech in zip(scenes, mechanisms)])
        self.evaluations = 0
        self._kernel = self._array_kernel(first) if self.settings.scheme == "autodiff" else None
        # by body, contiguous: the centres of mass' rows, masses, inertias, weights (m g)
        self.com_rows = [self.rows[f"G_{b.name}"] for b in bodies]
        names = [b.name for b in bodies]
        #: the body the effects along the guide act on, at C (springs, damper, blanking)
        self._slider = names.index("slider") if "slider" in names else None
        self.mass_of = [self.mass[:, b].copy() for b in range(len(bodies))]
        self.inertia_of = [self.inertia[:, b].copy() for b in range(len(bodies))]
        #: the joint reactions (the scenes' ``outputs.reactions``): at each recorded step its
        #: state and the effects' loads (:meth:`_loads`), all solved after the run
        self.reactions = bool(first.reactions)
        self._states = np.empty(0)  # (q, q̇ or q̈, coordinate, scene, step)
        self._loads_of = np.empty(0)  # (load, scene, step)
        self._at_C = None  # the last evaluation's motor torque and force along x at C

    def _array_kernel(self, first: Scene):
        """The exact kernel of the scenes' chart view, on arrays (NotVectorisable where the
        chart has none)."""
        from ..codegen.array_kernels import array_kernel
        from ..codegen.exact_kernels import exact_kernel
        from .build import build

        engine = build(first).engine
        view, q, _ = first.initial_state(engine.mechanism)
        kernel = exact_kernel(engine, view, q)
        if kernel is None:
            raise NotVectorisable("the chart has no exact kernel")
        return array_kernel(kernel)

    # -- effects, as parameter arrays ------------------------------------------------------
    def _effects(self, lists):
        def take(cls):
            found = [[e for e in lst if type(e) is cls] for lst in lists]
            return [f[0] for f in found] if all(found) else None

        g = take(Gravity)
        bodies = self.mech.bodies
        # each body's weight (m g, x and y), one array a component: None without gravity
        self.weight_of = (
            None
            if g is None
            else [
                [self.mass[:, b] * np.array([e.g[c] for e in g]) for c in (0, 1)] for b in range(len(bodies))
            ]
        )
        mo = take(Motor)
        if mo is not None:
            self.motor = {
                "index": [b.name for b in bodies].index(mo[0].body),
                "ratio": np.array([e.ratio for e in mo]),
                "eff": np.array([e.efficiency for e in mo]),
                "wsync": np.array([e.data.omega_sync for e in mo]),
                "mk": np.array([e.data.breakdown_torque for e in mo]),
                "sk": np.array([e.data.breakdown_slip for e in mo]),
                "on": np.array([1.0 if e.enabled else 0.0 for e in mo]),
            }
        else:
            self.motor = None
        sp = take(RetentionSprings)
        self.springs = (
            None
            if sp is None
            else (np.array([e.k for e in sp]), np.array([e.f0 for e in sp]), np.array([e.x_top for e in sp]))
        )
        da = take(SliderDamper)
        self.damper = None if da is None else np.array([e.c for e in da])
        bl = take(Blanking)
        self.blanking = (
            None
            if bl is None
            else (
                np.array([e.f for e in bl]),
                np.array([e.x_contact for e in bl]),
                np.array([e.pb for e in bl]),
            )
        )

    # -- the vectorised engine ------------------------------------------------------------------
    def evaluate(self, t, q, qd):
        """q̈ and what a step records, for all scenes: q, q̇ of shape (m, n)."""
        if self._kernel is not None:
            return self._evaluate_exact(t, q, qd)
        n = q.shape[1]
        offsets, plus, minus = stencil(n)
        d = self.settings.delta * self.view.scales
        pts = q[:, None, :] + offsets[None] * d  # (m, S, n)
        pose = self.view.positions([pts[..., i] for i in range(n)])
        S = pts.shape[1]
        shape = (self.m, S)
        rows = [
            np.broadcast_to(np.asarray(pose[p][k], float), shape) for p in self.mech.points for k in (0, 1)
        ]
        for b in self.mech.bodies:
            gx, gy = b.com_of(pose)
            rows += [
                np.broadcast_to(np.asarray(gx, float), shape),
                np.broadcast_to(np.asarray(gy, float), shape),
            ]
        X = np.stack(rows, axis=1).reshape(self.m, -1, 2, S)  # (m, NP, 2, S)
        if not np.all(np.isfinite(X)):
            raise NotVectorisable("a stencil point left the chart")
        V = (X[..., plus] - X[..., minus]) / (2.0 * d)  # (m, NP, 2, nbase, n)
        base = np.array([0] + [k for i in range(n) for k in (1 + 2 * i, 2 + 2 * i)])
        nb = len(self.mech.bodies)
        W = np.zeros((self.m, nb, len(base), n))
        for k in self.rot:
            b = self.mech.bodies[k]
            p, qq = self.rows[b.origin], self.rows[b.toward]
            R = X[:, qq][..., base] - X[:, p][..., base]  # (m, 2, nbase)
            VR = V[:, qq] - V[:, p]  # (m, 2, nbase, n)
            r2 = R[:, 0] ** 2 + R[:, 1] ** 2
            W[:, k] = (R[:, 0, :, None] * VR[:, 1] - R[:, 1, :, None] * VR[:, 0]) / r2[..., None]
        com = [self.rows[f"G_{b.name}"] for b in self.mech.bodies]
        VG = V[:, com]  # (m, nb, 2, nbase, n)
        Ab = np.einsum("mb,mbkci,mbkcj->mcij", self.mass, VG, VG) + np.einsum(
            "mb,mbci,mbcj->mcij", self.inertia, W, W
        )
        A = Ab[:, 0]
        dA = (Ab[:, 1::2] - Ab[:, 2::2]) / (2.0 * d)[None, :, None, None]
        h = np.einsum("mkij,mj,mk->mi", dA, qd, qd) - 0.5 * np.einsum("mijk,mj,mk->mi", dA, qd, qd)
        J = V[:, :, :, 0, :]  # (m, NP, 2, n) at q
        W0 = W[:, :, 0, :]  # (m, nb, n)
        X0 = X[..., 0]  # (m, NP, 2)
        kin = _Kinematics.of_tables(X0, J, W0)
        return self._solve(t, kin, qd, A, h)

    def _evaluate_exact(self, t, q, qd):
        """:meth:`evaluate` with exact derivatives: the kinematics from the array kernel, A
        and h from them with each scene's masses and inertias."""
        from ..codegen.array_kernels import ArrayBranchChanged

        m, n = q.shape
        try:
            xl, jl, wl, _, _, conv = self._kernel(*q.T, *qd.T)
        except ArrayBranchChanged as exc:
            raise NotVectorisable(str(exc)) from None
        kin = _Kinematics(xl, jl, wl, n, m)
        nb = len(self.mech.bodies)
        A = np.empty((m, n, n))
        h = np.empty((m, n))
        for i in range(n):
            # h_i = Σ m v*_G,i·G̈ + J ω*_i θ̈ (at q̈ = 0); A_ij = Σ m v*_G,i·v*_G,j + J ω*_i ω*_j
            terms = []
            for b, row in enumerate(self.com_rows):
                for c in (0, 1):
                    terms.append((self.mass_of[b], kin.jac(row, c)[i], conv[nb + 2 * b + c]))
                terms.append((self.inertia_of[b], kin.omega(b)[i], conv[b]))
            h[:, i] = _weighted(terms, m)
            for j in range(i, n):
                terms = []
                for b, row in enumerate(self.com_rows):
                    for c in (0, 1):
                        terms.append((self.mass_of[b], kin.jac(row, c)[i], kin.jac(row, c)[j]))
                    terms.append((self.inertia_of[b], kin.omega(b)[i], kin.omega(b)[j]))
                A[:, i, j] = A[:, j, i] = _weighted(terms, m)
        return self._solve(t, kin, qd, A, h)

    def _solve(self, t, kin, qd, A, h):
        """q̈ = A⁻¹(Q − h) with the effects' Q: (q̈, A, the kinematics, the power)."""
        Q, power = self._forces(t, kin, list(qd.T))
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
        if not np.all(np.isfinite(qdd)):
            raise NotVectorisable("non-finite accelerations")
        self.evaluations += 1
        return qdd, A, kin, power

    def _forces(self, t, kin, v):
        """Generalized forces of the effects (one array a coordinate) and the power of the
        non-conservative ones; ``v``: q̇, one array a coordinate."""
        n, m = len(v), self.m
        Q = [np.zeros(m) for _ in range(n)]
        power = np.zeros(m)
        c = self.rows["C"]
        jc = kin.jac(c, 0)  # ∂x_C/∂q
        vC = sum(jc[i] * v[i] for i in range(n))
        if self.weight_of is not None:
            for b, row in enumerate(self.com_rows):
                for cc in (0, 1):
                    jg, mg = kin.jac(row, cc), self.weight_of[b][cc]
                    for i in range(n):
                        Q[i] += mg * jg[i]
        if self.motor is not None:
            mo = self.motor
            wk = kin.omega(mo["index"])
            w = sum(wk[i] * v[i] for i in range(n))
            s = 1.0 - mo["ratio"] * w / mo["wsync"]
            torque = (
                mo["on"]
                * mo["ratio"]
                * mo["eff"]
                * (2.0 * mo["mk"] * s * mo["sk"] / (s * s + mo["sk"] * mo["sk"]))
            )
            for i in range(n):
                Q[i] += torque * wk[i]
            power += torque * w
        else:
            torque = None
        xC = kin.x(c, 0)
        forces = []  # along the guide, at C
        if self.springs is not None:
            k, f0, xt = self.springs
            forces.append(f0 + k * (xt - xC))
        if self.damper is not None:
            f = -self.damper * vC
            forces.append(f)
            power += f * vC
        if self.blanking is not None and self.structure == "locked":
            fmax, xcon, pb = self.blanking
            p = xcon - xC
            on = (vC < 0.0) & (p > 0.0) & (p < pb)
            f = np.where(on, fmax * np.sin(np.pi * np.clip(p, 0.0, None) / pb), 0.0)
            forces.append(f)
            power += f * vC
        for f in forces:
            for i in range(n):
                Q[i] += f * jc[i]
        self._at_C = (torque, sum(forces) if forces else None)
        return Q, power

    def _potential(self, kin):
        V = np.zeros(self.m)
        if self.weight_of is not None:
            for b, row in enumerate(self.com_rows):
                for cc in (0, 1):
                    V -= self.weight_of[b][cc] * kin.x(row, cc)
        if self.springs is not None:
            k, f0, xt = self.springs
            s = xt - kin.x(self.rows["C"], 0)
            V += f0 * s + 0.5 * k * s * s
        return V

    def _check(self, kin, A):
        """The chart must stay regular and the step stable, for every scene."""
        pose = {p: (kin.x(k, 0), kin.x(k, 1)) for p, k in self.rows.items()}
        if np.any(np.asarray(self.view.chart.regularity(pose)) < self.policy.switch_below):
            raise NotVectorisable("a scene would change chart")
        if self.springs is not None:
            k = self.springs[0]
            j = np.stack(
                [np.broadcast_to(x, (self.m,)) for x in kin.jac(self.rows["C"], 0)], axis=1
            )  # (m, n)
            w2 = k * np.einsum("mi,mij,mj->m", j, np.linalg.inv(A), j)
            lim = SOLVERS[self.settings.name].stability_limit
            t_min = 2.0 * math.pi / np.sqrt(np.maximum(w2, 1e-300))
            if np.any(self.dt > 0.9 * lim * t_min):
                raise NotVectorisable("a step would be subdivided")

    # -- the run ----------------------------------------------------------------------------------
    def run(self):
        sc = self.scenes[0]
        t0, t_end = 0.0, sc.t_end
        n_steps = max(1, int(round((t_end - t0) / sc.dt)))
        self.dt = (t_end - t0) / n_steps
        q, qd = self.q0.copy(), self.qd0.copy()
        name, its = self.settings.name, self.settings.iterations
        rows = {k: [] for k in COLUMNS}
        work = np.zeros(self.m)
        if self.reactions:
            nl = 3 * len(self.mech.bodies) + 4
            self._states = np.empty((3, q.shape[1], self.m, n_steps + 1))
            self._loads_of = np.zeros((nl, self.m, n_steps + 1))

        ev = self.evaluate
        qdd, A, kin, p_now = ev(t0, q, qd)
        self._record(rows, t0, q, qd, qdd, A, kin, work)
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
            self._record(rows, t, q, qd, qdd, A, kin, work)
        return self._trajectories(rows)

    def _record(self, rows, t, q, qd, qdd, A, kin, work):
        # the structure's coordinates: phi free (locked), psi frozen; free: phi and psi free
        names = [c.name for c in self.view.coordinates]
        frozen = self.view.frozen
        rows["t"].append(np.full(self.m, t))
        for nm in ("phi", "psi"):
            if nm in names:
                k = names.index(nm)
                rows[nm].append(q[:, k].copy())
                rows[nm + "_dot"].append(qd[:, k].copy())
                rows[nm + "_ddot"].append(qdd[:, k].copy())
            else:
                rows[nm].append(np.full(self.m, frozen[nm]))
                rows[nm + "_dot"].append(np.zeros(self.m))
                rows[nm + "_ddot"].append(np.zeros(self.m))
        rows["x_C"].append(np.array(np.broadcast_to(kin.x(self.rows["C"], 0), (self.m,))))
        n = qd.shape[1]
        rows["T"].append(0.5 * sum(qd[:, i] * A[:, i, j] * qd[:, j] for i in range(n) for j in range(n)))
        rows["V"].append(self._potential(kin))
        rows["W"].append(work.copy())
        rows["E_impact"].append(np.zeros(self.m))
        rows["structure"].append(self.structure)
        rows["chart"].append(self.view.name)
        if self.reactions:
            k = len(rows["t"]) - 1
            for j, x in enumerate((q, qd, qdd)):
                self._states[j, :, :, k] = x.T
            for j, x in enumerate(self._loads(kin)):
                self._loads_of[j, :, k] = x

    def _loads(self, kin) -> list:
        """The effects' loads at a recorded state as the reaction kernel takes them
        (:class:`~mps_core.codegen.reaction_kernels.LoadSums`): per body the force (x, y) and its
        moment about O, then the frame's own (force x, y, moment about O) and the motor's
        torque; from the state's evaluation (its kinematics, its motor torque and force at C)."""
        nb = len(self.mech.bodies)
        out: list = [0.0] * (3 * nb + 4)
        o = self.rows.get("O")
        ox, oy = (kin.x(o, 0), kin.x(o, 1)) if o is not None else (0.0, 0.0)
        if self.weight_of is not None:
            for b, row in enumerate(self.com_rows):
                fx, fy = self.weight_of[b]
                out[3 * b] += fx
                out[3 * b + 1] += fy
                out[3 * b + 2] += (kin.x(row, 0) - ox) * fy - (kin.x(row, 1) - oy) * fx
        torque, f = self._at_C
        if torque is not None:
            k = self.motor["index"]
            out[3 * k + 2] += torque
            out[3 * nb + 2] -= torque  # the stator's
            out[3 * nb + 3] += torque
        if f is not None:  # along x at C on the slider, the frame the opposite
            c = self.rows["C"]
            k = self._slider
            py = kin.x(c, 1) - oy
            out[3 * k] += f
            out[3 * k + 2] -= py * f
            out[3 * nb] -= f
            out[3 * nb + 2] += py * f
        return out

    def _reaction_columns(self) -> dict:
        """The reaction columns, (scene, step) each, of the recorded states: the view's
        reaction kernel on arrays (:func:`~mps_core.dynamics.reactions.array_reactions`), on
        blocks of (scenes, steps) of about :data:`_REACTION_CHUNK` states a call."""
        from ..codegen.array_kernels import ArrayBranchChanged
        from ..dynamics.reactions import REACTION_COLUMNS, array_reactions

        fn = array_reactions(self.mech, self.view, self.q0[0])
        if fn is None:
            raise NotVectorisable("the chart view has no reaction kernel")
        _, n, m, S = self._states.shape
        # a mass or an inertia the scenes share is a number, the others one value a scene
        masses = [
            float(col[0]) if np.all(col == col[0]) else col[:, None]
            for col in [*self.mass.T, *self.inertia.T]
        ]
        out = {c: np.empty((m, S)) for c in REACTION_COLUMNS}
        # blocks of whole scenes (all their steps) where a scene's steps fit a call, else of
        # a scene's steps
        width = max(1, _REACTION_CHUNK // S)
        height = min(S, _REACTION_CHUNK)
        for j0 in range(0, m, width):
            cols = slice(j0, j0 + width)
            given = [x if isinstance(x, float) else x[cols] for x in masses]
            for s0 in range(0, S, height):
                rows = slice(s0, s0 + height)
                args = [self._states[j, i, cols, rows] for j in range(3) for i in range(n)]
                try:
                    values, _residual = fn(*args, given, [x[cols, rows] for x in self._loads_of])
                except ArrayBranchChanged:
                    raise NotVectorisable("a scene's reactions are not unique at a step") from None
                for c, v in zip(REACTION_COLUMNS, values):
                    out[c][cols, rows] = v
        # a NaN or an infinity anywhere makes the sum one
        if not all(np.isfinite(v.sum()) for v in out.values()):
            raise NotVectorisable("non-finite reactions")
        self._states = self._loads_of = np.empty(0)
        return out

    def _trajectories(self, rows):
        out = []
        nsteps = len(rows["t"]) - 1
        per_step = (1 + self.settings.iterations) if self.settings.name == "linear-acceleration" else 4
        # each column once as (scene, step): a scene's column is then one row of it
        table = {
            k: np.array(v) if k in ("structure", "chart") else np.array(v, dtype=float).T.copy()
            for k, v in rows.items()
        }
        if self.reactions:
            table.update(self._reaction_columns())
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


def _weighted(terms, m: int):
    """Σ w·x·y over (w, x, y), the terms where x or y is the float 0.0 left out."""
    acc = np.zeros(m)
    for w, x, y in terms:
        if (isinstance(x, float) and x == 0.0) or (isinstance(y, float) and y == 0.0):
            continue
        acc += w * (x * y)
    return acc


def throughput(sizes=(1, 10, 100, 1000), steps: int = 200, scheme: str = "central") -> list[dict]:
    """Mechanism-steps per second of the vectorised pass for each number of scenes (working,
    slider mass swept, derivatives by ``scheme``), and of ``simulate`` for one scene
    (``scenes`` = 0)."""
    import time
    from dataclasses import replace

    from ..model import BodyData
    from .build import build

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
