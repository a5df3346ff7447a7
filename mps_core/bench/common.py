"""What both benchmarks share: the cases, the references, runs and their CPU time.

A **case** is a scene run to a given end time. The built-in ones:

``paper``       the seed's scene over its first 0.1 s (it passes the (φ, ψ) chart's branch point
                at t ≈ 0.0568 s);
``paper-long``  the same scene over 1 s (seven branch points);
``press-cycle`` the press's working cycle (structures and events), when that preset exists.

Any other preset name or scene file is a case over its own ``t_end``.

A **reference** gives φ, φ̇, φ̈ at the times a run reports. For scenes the exact model covers
(:mod:`mps_core.bench.peers`: the free mechanism with gravity and the motor) it is that model,
derived with sympy independently of the engine and integrated with DOP853 at rtol 1e-13; for the
others (structures and events) it is the engine's own exact-derivative scheme with DOP853 at
rtol 1e-12 on the finest output grid of the study, which checks convergence rather than
correctness, and says so in its label.
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from ..run.build import build
from ..scene import Scene, load_scene, preset_names
from ..solvers import ADAPTIVE_SOLVERS

#: the step-size ladder: the paper's 1.25 ms halved down to about 1e-5 s
DT_LADDER = tuple(1.25e-3 / 2**k for k in range(8))
#: two rungs above the paper's step, for the fixed-step solvers: where the step, not the
#: derivatives, is cheap enough to matter (RK4 at 2.5 ms is within 1e-4 rad on ``paper``)
COARSE_STEPS = (5e-3, 2.5e-3)
#: three rungs more above those for the sixth- and eighth-order methods (RK8 at 10 ms is within
#: 2e-4 rad on ``paper`` at its outputs): whole multiples of the 1.25 ms grid, so that every
#: output of theirs is on it, and whole divisors of the built-in cases' end times
HIGH_ORDER_STEPS = (12.5e-3, 10e-3, 6.25e-3)
#: the peers: what a user would pick instead (not the engine's settings)
PEERS = ("peer", "mujoco")

CASE_NOTES = {
    "paper": "the seed's scene over 0.1 s (passes the (phi, psi) chart's branch point)",
    "paper-long": "the seed's scene over 1 s (seven branch points)",
    "press-cycle": "the press's working cycle with its events",
    "idle-change-point": "the idle press held at its change point (x_top 25.0 mm, the stop a "
    "clamp): the four-bar passes phi = 2 pi k with psi = 0 on the "
    "continuation chart, both of its branches",
}


@dataclass
class Case:
    name: str
    scene: Scene
    t_end: float
    note: str = ""


def available_cases() -> list[str]:
    """The built-in cases whose scenes exist in this installation."""
    out = ["paper", "paper-long"]
    if "press-cycle" in preset_names():
        out.append("press-cycle")
    return out


def change_point_scene() -> Scene:
    """The ``idle`` preset held at its change point: x_top = l2 - l3 + l1 (25.0 mm), the top
    stop a clamp (a run on the continuation chart ``phi-xc~``, which turns branch each turn)."""
    from ..scene import scene_from_text

    text = load_scene("idle").text
    for old, new in (("x_top_mm = 25.5", "x_top_mm = 25.0"), ('model = "rigid"', 'model = "clamp"')):
        if old not in text:
            raise ValueError(f"the idle preset no longer has {old!r}: the change-point case needs updating")
        text = text.replace(old, new)
    return scene_from_text(text)


def resolve_case(name: str) -> Case:
    """A built-in case, or any preset name or scene file over its own t_end."""
    if name == "idle-change-point":
        return Case(name, change_point_scene().with_overrides(scheme="autodiff"), 0.3, CASE_NOTES[name])
    if name == "paper":
        return Case(name, load_scene("paper"), 0.1, CASE_NOTES[name])
    if name == "paper-long":
        return Case(name, load_scene("paper"), 1.0, CASE_NOTES[name])
    scene = load_scene(name)
    return Case(name, scene, scene.t_end, CASE_NOTES.get(name, scene.description))


# -- settings -------------------------------------------------------------------------------
@dataclass(frozen=True)
class Setting:
    """One solver configuration: solver name, derivative scheme, Δ (degrees), corrections,
    and for the adaptive solvers the tolerance."""

    solver: str
    scheme: str = "central"
    delta_deg: float = 0.1
    iterations: int = 1
    rtol: float | None = None
    #: the scene's ``solver.switch_points`` ("auto": located by the adaptive solvers)
    switch_points: str = "auto"

    @property
    def family(self) -> str:
        """The solver's label: linear-acceleration, la-iterated, rk4, dop853, radau, peer."""
        if self.solver == "linear-acceleration" and self.iterations > 1:
            return "la-iterated"
        return self.solver

    @property
    def scheme_label(self) -> str:
        if self.solver == "peer":
            return "exact (sympy)"
        if self.solver == "mujoco":
            return "RK4, soft connect"
        if self.scheme == "autodiff":
            return "autodiff"
        return f"central {self.delta_deg:g}°"

    @property
    def label(self) -> str:
        f = self.family
        if f == "la-iterated":
            f = f"linear-acceleration ×{self.iterations}"
        tail = "" if self.switch_points == "auto" else f", switch points: {self.switch_points}"
        return f"{f}, {self.scheme_label}{tail}"

    @property
    def adaptive(self) -> bool:
        return self.solver in ADAPTIVE_SOLVERS or self.solver == "peer"


def scene_for(case: Case, s: Setting, dt: float) -> Scene:
    """The case's scene with a setting's run parameters."""
    kw = dict(
        t_end=case.t_end,
        dt=dt,
        solver=s.solver,
        scheme=s.scheme,
        iterations=s.iterations,
        switch_points=s.switch_points,
    )
    if s.scheme == "central":
        kw["delta"] = math.radians(s.delta_deg)
    if s.rtol is not None:
        kw["rtol"] = s.rtol
        kw["atol"] = max(1e-15, s.rtol * 1e-3)
    return case.scene.with_overrides(**kw)


def with_effects(scene: Scene, kinds) -> Scene:
    """The scene with only the effects of the given kinds."""
    kinds = set(kinds)
    return replace(scene, effects=tuple(e for e in scene.effects if e.kind in kinds))


# -- timing ---------------------------------------------------------------------------------
def cpu_median(fn, repeats: int = 3, budget: float = 1.0):
    """(median CPU seconds, last result) of ``fn()``: at least one call, at most ``repeats``,
    fewer where the calls so far used up ``budget`` seconds of CPU."""
    times, out, used = [], None, 0.0
    for _ in range(max(1, repeats)):
        c0 = time.process_time()
        out = fn()
        dt = time.process_time() - c0
        times.append(dt)
        used += dt
        if used >= budget:
            break
    return statistics.median(times), out, len(times)


class OverBudget(RuntimeError):
    """A run that needed more right-hand sides than the benchmark allows it."""


def evaluations_along(scene: Scene, t_end: float):
    """(simulation, [every evaluation of the engine]) along a run of ``scene`` to ``t_end``:
    the states a study re-evaluates with other derivative schemes."""
    sim = build(scene)
    seen = []
    original = sim.engine.evaluate

    def spy(view, t, q, qd):
        e = original(view, t, q, qd)
        seen.append(e)
        return e

    sim.engine.evaluate = spy  # type: ignore[method-assign]  # a spy on this engine alone
    sim.run(t_end, scene.dt)
    return sim, seen


class _Budget:
    """An observer that stops a run past ``limit`` evaluations, looked at every output step
    (a fixed-step run's evaluations between two outputs are a few; the run's own code then
    runs as it does outside the bench)."""

    def __init__(self, engine, limit: int):
        self.counts, self.limit = engine.counts, limit

    def observe(self, sim, e) -> None:
        if self.counts["evaluations"] >= self.limit:
            raise OverBudget(f"more than {self.limit} evaluations (t = {e.t:.4g} s)")

    def columns(self) -> dict:
        return {}


def _cap(engine, limit: int):
    """Stop a run past ``limit`` evaluations, looked at every evaluation (an adaptive solver
    may take any number between two outputs)."""
    evaluate = engine.evaluate

    def capped(view, t, q, qd):
        if engine.counts["evaluations"] >= limit:
            raise OverBudget(f"more than {limit} evaluations (t = {t:.4g} s)")
        return evaluate(view, t, q, qd)

    engine.evaluate = capped


def run_setting(
    case: Case,
    s: Setting,
    dt: float,
    repeats: int = 3,
    budget: float = 1.0,
    max_evaluations: int | None = None,
):
    """Run one setting; returns (median CPU s of ``Simulation.run``, trajectory, repeats).
    ``max_evaluations``: give up (:class:`OverBudget`) beyond that many right-hand sides."""
    scene = scene_for(case, s, dt)

    def once():
        sim = build(scene)
        if max_evaluations and s.adaptive:
            _cap(sim.engine, max_evaluations)
        elif max_evaluations:
            sim.observers.append(_Budget(sim.engine, max_evaluations))
        c0 = time.process_time()
        traj = sim.run(scene.t_end, scene.dt)
        return time.process_time() - c0, traj

    times, traj = [], None
    used = 0.0
    for _ in range(max(1, repeats)):
        c, traj = once()
        times.append(c)
        used += c
        if used >= budget:
            break
    return statistics.median(times), traj, len(times)


# -- references -----------------------------------------------------------------------------
#: the reference's own uncertainty that ends its horizon (rad)
HORIZON_TOL = 1e-7


@dataclass
class Reference:
    """φ, φ̇, φ̈ of a case at any time of a run's grid, the events' times, and the horizon:
    the time up to which the reference agrees with itself at a tenfold looser tolerance to
    ``HORIZON_TOL``, and ``uncertainty``, that disagreement's maximum up to the horizon. Beyond
    the horizon the motion's sensitivity (the free mechanism is chaotic over seconds) makes
    pointwise errors meaningless; errors are measured up to it."""

    label: str
    sample: Callable[[np.ndarray], tuple]  # t (array) -> (phi, phi_dot, phi_ddot)
    events: list = field(default_factory=list)
    cpu: float = 0.0
    horizon: float = math.inf
    uncertainty: float = 0.0


def _horizon(t, a, b, t_end) -> tuple[float, float]:
    d = np.abs(np.asarray(a) - np.asarray(b))
    bad = np.nonzero(d > HORIZON_TOL)[0]
    k = len(d) if len(bad) == 0 else max(bad[0], 1)
    return (t_end if len(bad) == 0 else float(t[k - 1])), float(d[:k].max())


def exact_reference(case: Case, rtol: float = 1e-13, grid: float = DT_LADDER[0]) -> Reference:
    from .peers import exact_model, run_peer

    model = exact_model(case.scene)
    t_grid = np.linspace(0.0, case.t_end, int(round(case.t_end / grid)) + 1)
    run = run_peer(case.scene, case.t_end, t_grid, rtol=rtol, atol=rtol, dense=True, model=model)
    loose = run_peer(case.scene, case.t_end, t_grid, rtol=10 * rtol, atol=10 * rtol, model=model)
    dense = run.dense
    cache: dict = {}

    def sample(t):
        t = np.asarray(t, float)
        key = (len(t), float(t[0]), float(t[-1]))
        if key not in cache:
            Y = dense(t)
            acc = np.array([model.accelerations(Y[:, k])[0] for k in range(Y.shape[1])])
            cache[key] = (Y[0], Y[3], acc)
        return cache[key]

    return Reference(
        f"exact model (sympy, redundant coordinates), DOP853 rtol {rtol:g}",
        sample,
        [],
        run.cpu + loose.cpu,
        *_horizon(t_grid, run.phi, loose.phi, case.t_end),
    )


def self_reference(case: Case, dt: float, rtol: float = 1e-12) -> Reference:
    """The engine's exact-derivative scheme with DOP853 at a tight tolerance, on a grid of
    step ``dt`` (every run's grid must contain it)."""
    s = Setting("dop853", "autodiff", rtol=rtol)
    scene = scene_for(case, s, dt)
    c0 = time.process_time()
    traj = build(scene).run(scene.t_end, scene.dt)
    loose = build(scene_for(case, replace(s, rtol=10 * rtol), dt)).run(scene.t_end, scene.dt)
    cpu = time.process_time() - c0
    T = np.asarray(traj.t)

    def sample(t):
        t = np.asarray(t, float)
        idx = np.clip(np.searchsorted(T, t - 1e-12), 0, len(T) - 1)
        if np.abs(T[idx] - t).max() > 1e-9 * max(1.0, case.t_end):
            raise ValueError("the run's grid is not a subset of the reference's")
        return traj.phi[idx], traj.phi_dot[idx], traj.phi_ddot[idx]

    events = [
        (ev["kind"], ev.get("name", ev.get("to")), ev["t"]) for ev in traj.events if ev.get("kind") != "chart"
    ]
    return Reference(
        f"mps dop853 + autodiff, rtol {rtol:g} (self-convergence, not independent)",
        sample,
        events,
        cpu,
        *_horizon(T, traj.phi, loose.phi, case.t_end),
    )


def reference_for(case: Case, grid: float) -> Reference:
    from .peers import supports

    ok, _why = supports(case.scene)
    if ok:
        return exact_reference(case, grid=grid)
    return self_reference(case, grid)


def event_timing_error(traj, ref: Reference) -> float:
    """max |t_event − t_event,ref| over the events the run and the reference share (matched
    by kind in order); inf where the run misses one or has one more."""
    mine = [
        (ev["kind"], ev.get("name", ev.get("to")), ev["t"]) for ev in traj.events if ev.get("kind") != "chart"
    ]
    if [m[:2] for m in mine] != [r[:2] for r in ref.events]:
        return math.inf
    return max((abs(a[2] - b[2]) for a, b in zip(mine, ref.events)), default=0.0)
