"""``mps bench accuracy``: the work-precision study.

For each case (:mod:`mps_core.bench.common`), each solver, each step size of the ladder (5 ms
and 2.5 ms, then the paper's 1.25 ms halved down to about 1e-5 s; RK6 and RK8 also at 12.5, 10
and 6.25 ms) or each tolerance (adaptive solvers), and each derivative scheme (central
differences at Δ = 1°, 0.1°, 0.01°, 0.001°, and exact derivatives): the error against the
case's reference (φ at the end time; max |φ − φ_ref|, |φ̇ − φ̇_ref|, |φ̈ − φ̈_ref| over the run,
sampled on the paper's 1.25 ms grid where the run has those times: every point from 1.25 ms
down, at the coarser steps their own outputs, every 2nd, 4th, 5th, 8th or 10th grid point;
and for scenes with events, the events' timing), the CPU time of the run (median of repeats) and
the work (right-hand sides, position points). The peer, scipy's DOP853 on the exact equations
(:mod:`mps_core.bench.peers`), runs side by side on the same cases.

Where finite differences stop helping: :func:`delta_study` shrinks Δ by decades, per evaluation
(q̈ against exact derivatives at the states of a run) and per run (RK4 at a fine step against the
reference): the error falls as Δ² until round-off, growing as ε/Δ², takes over.
"""

from __future__ import annotations

import csv
import math
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..dynamics.engine import PartialSystems
from .common import (
    COARSE_STEPS,
    DT_LADDER,
    HIGH_ORDER_STEPS,
    PEERS,
    Case,
    Reference,
    Setting,
    available_cases,
    evaluations_along,
    reference_for,
    resolve_case,
    run_setting,
    scene_for,
)

FAMILIES = ("linear-acceleration", "la-iterated", "rk4", "rk6", "rk8", "dop853", "radau", "peer", "mujoco")
#: MuJoCo's steps: 2.5 ms, then the 1.25 ms ladder halved down to about 10 µs
MUJOCO_STEPS = (2.5e-3,) + DT_LADDER
DELTAS_DEG = (1.0, 0.1, 0.01, 0.001)
#: the twin's own operating point: an output every millisecond (a 1 kHz stream)
OPERATING_EVERY = 1e-3
#: the engine's settings tried there: exact derivatives, each solver's own step (the outputs
#: between its steps from its interpolant)
OPERATING_SOLVERS = ("linear-acceleration", "rk4", "rk6", "rk8")
OPERATING_STEPS = (1e-3, 2e-3, 2.5e-3, 5e-3)
LA_ITERATIONS = 3
GRID = DT_LADDER[0]  # errors are sampled on the paper's 1.25 ms grid
#: central differences stop adaptive solvers below this tolerance (their O(Δ²) error and
#: round-off are noise to the error estimate: the steps shrink without end)
CENTRAL_MIN_RTOL = 1e-8
MAX_EVALUATIONS = 300_000
#: DOP853's tolerances are the peer's: 1 and 3 in every decade from 1e-3 to 1e-12 (the fronts
#: are the lower envelopes of the measured points; the denser the ladder, the closer to the
#: curves, for both alike)
PEER_RTOLS = tuple(float(f"{m}e-{k}") for k in range(3, 13) for m in ((1,) if k == 3 else (3, 1)))
ADAPTIVE_RTOLS = {"dop853": PEER_RTOLS, "radau": (1e-4, 1e-6, 1e-8)}
DELTA_STUDY_DEG = tuple(10.0**-k for k in range(0, 7))
#: the fixed steps from which a run with exact derivatives also has its evaluations alone
#: timed (:func:`evaluations_alone`): the short runs, where the driver's share is the largest
ALONE_FROM = 5e-3

COLUMNS = (
    "case",
    "solver",
    "scheme",
    "delta_deg",
    "iterations",
    "dt",
    "rtol",
    "steps",
    "evaluations",
    "position_points",
    "cpu_s",
    "cpu_per_sim_s",
    "repeats",
    "err_end_phi",
    "max_err_phi",
    "max_err_phi_dot",
    "max_err_phi_ddot",
    "max_err_event_t",
    "horizon_s",
    "closure_m",
    "bare_cpu_s",
    "alone_cpu_s",
)


def _schemes(full: bool):
    out = [("central", d) for d in (DELTAS_DEG if full else (0.1,))]
    return out + [("autodiff", 0.0)]


def plan(case: Case, families=FAMILIES, quick: bool = False, rungs: int | None = None):
    """[(Setting, dt)] for a case: everything for short cases, fewer rungs, schemes and
    tolerances as the case gets longer (and with ``quick``)."""
    long = case.t_end > 0.2
    if rungs is None:
        rungs = 3 if quick else (5 if long else len(DT_LADDER))
    ladder = DT_LADDER[: 2 * rungs - 1 : 2] if quick else COARSE_STEPS + DT_LADDER[:rungs]
    schemes = _schemes(full=not quick and not long)
    out = []
    for fam in families:
        if fam in ("linear-acceleration", "la-iterated", "rk4", "rk6", "rk8"):
            solver = fam if fam in ("rk4", "rk6", "rk8") else "linear-acceleration"
            it = LA_ITERATIONS if fam == "la-iterated" else 1
            # sixth and eighth order: their errors fall below central differences' at once
            # (exact only), and they stay accurate at steps longer than 5 ms
            high = fam in ("rk6", "rk8")
            for scheme, d in schemes if not high else [("autodiff", 0.0)]:
                for dt in (HIGH_ORDER_STEPS if high and not quick else ()) + ladder:
                    out.append((Setting(solver, scheme, d, it), dt))
        elif fam in ADAPTIVE_RTOLS:
            rtols = ADAPTIVE_RTOLS[fam]
            if quick:
                rtols = (1e-6, 1e-9) if fam == "dop853" else (1e-6,)
            elif long:
                rtols = tuple(r for r in rtols if r >= 1e-10) if fam == "dop853" else (1e-4, 1e-6)
            sch = [("autodiff", 0.0)]
            if not quick and not long:
                sch += [("central", 0.1)] + ([("central", 0.01)] if fam == "dop853" else [])
            for scheme, d in sch:
                for r in rtols:
                    if scheme == "central" and r < CENTRAL_MIN_RTOL:
                        continue
                    out.append((Setting(fam, scheme, d, 1, r), GRID))
        elif fam == "mujoco":
            from .mujoco_peer import available
            from .peers import supports

            if not supports(case.scene)[0] or not available()[0]:
                continue
            for dt in MUJOCO_STEPS[:6:2] if quick else MUJOCO_STEPS:
                out.append((Setting("mujoco", "exact", 0.0), dt))
        elif fam == "peer":
            from .peers import supports

            if not supports(case.scene)[0]:
                continue
            rtols = (1e-3, 1e-6, 1e-9) if quick else PEER_RTOLS
            for r in rtols:
                out.append((Setting("peer", "exact", 0.0, 1, r), GRID))
        else:
            raise ValueError(f"solver {fam!r}: expected one of {', '.join(FAMILIES)}")
    return out


def _on_grid(t):
    t = np.asarray(t, float)
    k = np.round(t / GRID)
    return np.abs(t - k * GRID) < 1e-9 * GRID


def errors(traj_t, phi, phi_dot, phi_ddot, ref: Reference, traj=None) -> dict:
    """Errors on the 1.25 ms grid up to the reference's horizon: at its last point, and the
    maxima; and the events' timing where the reference has events."""
    t_all = np.asarray(traj_t)
    sel = _on_grid(t_all) & (t_all <= ref.horizon + 1e-12)
    t = t_all[sel]
    rp, rpd, rpdd = ref.sample(t)
    e = np.abs(np.asarray(phi)[sel] - rp)
    out = {
        "err_end_phi": float(e[-1]),
        "max_err_phi": float(e.max()),
        "max_err_phi_dot": float(np.abs(np.asarray(phi_dot)[sel] - rpd).max()),
        "max_err_phi_ddot": float(np.abs(np.asarray(phi_ddot)[sel] - rpdd).max()),
        "max_err_event_t": "",
        "horizon_s": float(t[-1]),
    }
    if ref.events and traj is not None:
        from .common import event_timing_error

        out["max_err_event_t"] = event_timing_error(traj, ref)
    return out


def run_one(case: Case, s: Setting, dt: float, ref: Reference, repeats: int = 3, budget: float = 1.0) -> dict:
    row: dict[str, Any] = {
        "case": case.name,
        "solver": s.family,
        "scheme": s.scheme_label,
        "delta_deg": s.delta_deg if s.scheme == "central" else "",
        "iterations": s.iterations if s.solver == "linear-acceleration" else "",
        "dt": dt if not s.adaptive else "",
        "rtol": s.rtol if s.adaptive else "",
    }
    if s.solver == "mujoco":
        from .common import cpu_median
        from .mujoco_peer import bare_loop, run_mujoco

        every = max(dt, GRID)  # outputs on the error grid, at whole steps
        t_grid = np.arange(int(round(case.t_end / every)) + 1) * every
        # the stepping's CPU, as the engine's runs count theirs (not the model's compilation,
        # as the engine's do not count its build), beside the bare mj_step loop's, interleaved
        cpus, bares = [], []

        def once():
            r = run_mujoco(case.scene, case.t_end, t_grid, dt)
            cpus.append(r.cpu)
            bares.append(bare_loop(case.scene, case.t_end, dt)[0])
            return r

        _, run, n = cpu_median(once, repeats, budget)
        cpu = statistics.median(cpus)
        row.update(
            steps=int(round(case.t_end / dt)),
            evaluations=run.nfev,
            position_points="",
            cpu_s=cpu,
            cpu_per_sim_s=cpu / case.t_end,
            repeats=n,
            closure_m=run.closure,
            bare_cpu_s=statistics.median(bares),
        )
        row.update(errors(run.t, run.phi, run.phi_dot, run.phi_ddot, ref))
        return row
    if s.solver == "peer":
        from .common import cpu_median
        from .peers import run_peer

        t_grid = np.linspace(0.0, case.t_end, int(round(case.t_end / GRID)) + 1)
        rtol = s.rtol
        assert rtol is not None  # (a peer's setting carries its tolerance)
        cpu, run, n = cpu_median(lambda: run_peer(case.scene, case.t_end, t_grid, rtol=rtol), repeats, budget)
        row.update(
            steps="",
            evaluations=run.nfev,
            position_points="",
            cpu_s=cpu,
            cpu_per_sim_s=cpu / case.t_end,
            repeats=n,
        )
        row.update(errors(run.t, run.phi, run.phi_dot, run.phi_ddot, ref))
        return row
    cpu, traj, n = run_setting(case, s, dt, repeats, budget, MAX_EVALUATIONS)
    c = traj.counts
    row["setting"], row["setting_dt"] = s, dt  # to time it beside a peer (not CSV columns)
    row.update(
        steps=c["steps"],
        evaluations=c["evaluations"],
        position_points=c["position_points"],
        cpu_s=cpu,
        cpu_per_sim_s=cpu / case.t_end,
        repeats=n,
    )
    if s.scheme == "autodiff" and not s.adaptive and dt >= ALONE_FROM * (1 - 1e-9):
        per, _states, count = evaluations_alone(case, s, dt)
        row["alone_cpu_s"] = per * count
    row.update(errors(traj.t, traj.phi, traj.phi_dot, traj.phi_ddot, ref, traj))
    return row


def evaluations_alone(case: Case, s: Setting, dt: float, number: int = 100, repeats: int = 3):
    """What a run's evaluations cost alone: (the CPU s of one q̈ as a generated solver step's
    inner stage asks it, by the chart's fused function with exact derivatives (where a chart
    has none, :meth:`~mps_core.dynamics.engine.PartialSystems.accelerations`), averaged over
    the states the run kept: each step's end and each new chart's start, the first state's
    being the build's; those states; the run's evaluations). The first times the last is the
    least any driver of the run's steps costs: the steps' own arithmetic, the kept
    evaluations' kinematics, the recorded rows and the changes of chart come on top. Each
    state's figure is the median of ``repeats`` batches of ``number`` calls."""
    scene = scene_for(case, s, dt)
    sim, states = evaluations_along(scene, scene.t_end)
    states = list(states)
    eng = sim.engine
    count = eng.counts["evaluations"]
    total = 0.0
    for e in states:
        t, ql, vl, view = e.t, e.q.tolist(), e.qd.tolist(), e.view
        eng.accelerations(view, t, ql, vl)  # the view's fused function made, where it can be
        plan = eng._plans.get(view)
        fused = plan.fused if plan is not None else None
        if fused is not None:

            def call(f=fused, t=t, ql=ql, vl=vl):
                return f(t, *ql, *vl)
        else:

            def call(view=view, t=t, ql=ql, vl=vl):
                return eng.accelerations(view, t, ql, vl)

        batches = []
        for _ in range(repeats):
            c0 = time.process_time()
            for _ in range(number):
                call()
            batches.append((time.process_time() - c0) / number)
        total += statistics.median(batches)
    return total / len(states), len(states), count


# -- where finite differences stop helping ----------------------------------------------------
def delta_study(
    case: Case,
    ref: Reference | None,
    deltas=DELTA_STUDY_DEG,
    dt: float = DT_LADDER[4],
    trajectory: bool = True,
):
    """Rows (Δ, max relative error of q̈ per evaluation, max φ error of an RK4 run at ``dt``).

    Per evaluation: at the states of an RK4 run with exact derivatives (every fourth
    right-hand side, all charts it visits), q̈ by central differences against q̈ exact.
    Per run (``trajectory``): RK4 at ``dt`` with central differences against the reference."""
    scene = case.scene.with_overrides(
        t_end=min(case.t_end, 0.1), dt=DT_LADDER[3], solver="rk4", scheme="autodiff"
    )
    sim, states = evaluations_along(scene, scene.t_end)
    states = states[::4]
    rows = []
    sub = Case(case.name, case.scene, min(case.t_end, 0.1))
    # exact derivatives again now: effects with state (controls) are compared on one footing
    exact = PartialSystems(sim.mechanism, sim.engine.effects, "autodiff")
    states = [(e, exact.evaluate(e.view, e.t, e.q, e.qd).qdd) for e in states]
    for d in deltas:
        eng = PartialSystems(sim.mechanism, sim.engine.effects, "central", math.radians(d))
        rel = 0.0
        for e, qdd_exact in states:
            try:
                qdd = eng.evaluate(e.view, e.t, e.q, e.qd).qdd
            except Exception:  # a stencil leaving the chart's domain: not counted
                continue
            rel = max(rel, float(np.abs(qdd - qdd_exact).max() / np.abs(qdd_exact).max()))
        if not trajectory:
            rows.append(
                {
                    "delta_deg": d,
                    "max_rel_err_qdd": rel,
                    "max_err_phi_rk4": math.nan,
                    "rk4_dt": dt,
                    "states": len(states),
                }
            )
            continue
        assert ref is not None, "a run's errors need the reference"
        _cpu, traj, _n = run_setting(sub, Setting("rk4", "central", d), dt, repeats=1)
        sel = _on_grid(traj.t)
        err = float(np.abs(np.asarray(traj.phi)[sel] - ref.sample(np.asarray(traj.t)[sel])[0]).max())
        rows.append(
            {
                "delta_deg": d,
                "max_rel_err_qdd": rel,
                "max_err_phi_rk4": err,
                "rk4_dt": dt,
                "states": len(states),
            }
        )
    if not trajectory:
        return rows
    assert ref is not None, "a run's errors need the reference"
    _cpu, traj, _n = run_setting(sub, Setting("rk4", "autodiff"), dt, repeats=1)
    sel = _on_grid(traj.t)
    exact_err = float(np.abs(np.asarray(traj.phi)[sel] - ref.sample(np.asarray(traj.t)[sel])[0]).max())
    rows.append(
        {
            "delta_deg": 0.0,
            "max_rel_err_qdd": 0.0,
            "max_err_phi_rk4": exact_err,
            "rk4_dt": dt,
            "states": len(states),
        }
    )
    return rows


# -- picking a setting ----------------------------------------------------------------------
#: the accuracies :func:`recommendations` picks a setting for: max |φ − φ_ref| = 1e-2 … 1e-10 rad
TARGETS = tuple(10.0**-e for e in range(2, 11))


def recommendations(rows, targets=TARGETS):
    """For each target max |φ − φ_ref|: the cheapest measured setting that meets it (the
    engine's, and the peers' for comparison: scipy's, MuJoCo's): (target, engine, scipy peer,
    MuJoCo), None where none meets it."""
    out = []
    for tgt in targets:
        ok = [r for r in rows if r["max_err_phi"] <= tgt]

        def cheapest(keep):
            rs = [r for r in ok if keep(r["solver"])]
            return min(rs, key=lambda r: r["cpu_s"]) if rs else None

        out.append(
            (
                tgt,
                cheapest(lambda s: s not in PEERS),
                cheapest(lambda s: s == "peer"),
                cheapest(lambda s: s == "mujoco"),
            )
        )
    return out


def versus(rows, peer: str = "mujoco"):
    """For each of a peer's measured points (coarsest first): (its row, the cheapest setting
    of the engine at least as accurate or None, that one's CPU over the peer's)."""
    mine = [r for r in rows if r["solver"] not in PEERS]
    out = []
    for p in sorted((r for r in rows if r["solver"] == peer), key=lambda r: -r["max_err_phi"]):
        ok = [r for r in mine if r["max_err_phi"] <= p["max_err_phi"]]
        best = min(ok, key=lambda r: r["cpu_s"]) if ok else None
        out.append((p, best, None if best is None else best["cpu_s"] / p["cpu_s"]))
    return out


def side_by_side(case: Case, pairs, rows, rounds: int = 9, budget: float = 20.0, candidates: int = 3):
    """Time each MuJoCo point of :func:`versus` again beside the engine's cheapest settings at
    least as accurate (up to ``candidates`` of them, the cheapest by the study's own timing),
    all their runs in turns (MuJoCo, each setting, MuJoCo, …), so that they meet the machine as
    it is at the same moments; the setting whose rounds' ratios have the smallest median is the
    point's. Returns, for each point, None (no setting as accurate) or (that setting's row,
    median CPU s of MuJoCo's runs, of its runs, the median of the rounds' ratios mps / MuJoCo,
    the spread of those ratios (their interquartile range over their median), the rounds).
    ``budget``: CPU seconds a point may take (fewer rounds where it would take more; at least
    three)."""
    from .mujoco_peer import run_mujoco

    mine = [r for r in rows if r["solver"] not in PEERS and r.get("setting") is not None]
    out: list[tuple | None] = []
    for p, _best, _ratio in pairs:
        ok = sorted((r for r in mine if r["max_err_phi"] <= p["max_err_phi"]), key=lambda r: r["cpu_s"])
        ok = ok[: max(1, candidates)]
        if not ok:
            out.append(None)
            continue
        every = max(p["dt"], GRID)
        t_grid = np.arange(int(round(case.t_end / every)) + 1) * every
        k, turns = in_turns(
            lambda dt=p["dt"]: run_mujoco(case.scene, case.t_end, t_grid, dt).cpu,
            [lambda r=r: run_setting(case, r["setting"], r["setting_dt"], repeats=1)[0] for r in ok],
            rounds,
            budget,
        )
        out.append((ok[k], *turns))
    return out


def in_turns(peer, mine, rounds: int, budget: float):
    """Time ``peer()`` and each of ``mine`` (callables returning CPU s) in turns, round after
    round (at least three; fewer than ``rounds`` where they used ``budget`` CPU s); return
    the index of the one whose rounds' ratios to the peer's have the smallest median, and
    (the peer's median CPU s, that one's, that median ratio, the ratios' interquartile range
    over it, the rounds)."""
    peers: list[float] = []
    times: list[list[float]] = [[] for _ in mine]
    used = 0.0
    for i in range(max(3, rounds)):
        peers.append(peer())
        used += peers[-1]
        for once, got in zip(mine, times):
            got.append(once())
            used += got[-1]
        if i >= 2 and used >= budget:
            break
    ratios = [[b / a for a, b in zip(peers, got)] for got in times]
    k = min(range(len(mine)), key=lambda n: statistics.median(ratios[n]))
    mid = statistics.median(ratios[k])
    q = statistics.quantiles(ratios[k], n=4)
    return k, (
        statistics.median(peers),
        statistics.median(times[k]),
        mid,
        (q[2] - q[0]) / mid,
        len(ratios[k]),
    )


def operating_point(case: Case, ref: Reference, rounds: int = 9, budget: float = 20.0, candidates: int = 3):
    """Time the twin's own operating point: an output every :data:`OPERATING_EVERY` s (a 1 kHz
    stream), MuJoCo stepping at that step, beside the engine's cheapest settings whose every
    output is at least as accurate (of :data:`OPERATING_SOLVERS` with exact derivatives, their
    own step of :data:`OPERATING_STEPS`), the three cheapest by a first timing, all their runs
    in turns as in :func:`side_by_side`. Returns None where no setting is as accurate, else a
    dict: MuJoCo's max |φ − φ_ref| over the outputs and median CPU s, the chosen setting's
    label, error and median CPU s, the median of the rounds' ratios mps / MuJoCo, their spread
    and the rounds."""
    from ..run.build import build
    from .mujoco_peer import run_mujoco

    every = OPERATING_EVERY
    t_grid = np.arange(int(round(case.t_end / every)) + 1) * every

    def worst(t, phi) -> float:
        t = np.asarray(t, float)
        sel = t <= ref.horizon + 1e-12
        return float(np.abs(np.asarray(phi)[sel] - ref.sample(t[sel])[0]).max())

    mj_run = run_mujoco(case.scene, case.t_end, t_grid, every)
    e_mj = worst(mj_run.t, mj_run.phi)
    found = []
    for solver in OPERATING_SOLVERS:
        for step in OPERATING_STEPS:
            scene = scene_for(case, Setting(solver, "autodiff"), every)
            if step > every * (1 + 1e-9):
                scene = scene.with_overrides(step=step)
            sim = build(scene)
            c0 = time.process_time()
            try:
                traj = sim.run(scene.t_end, scene.dt)
            except Exception:  # a setting that fails there is no candidate
                continue
            cpu = time.process_time() - c0
            err = worst(traj.t, traj.phi)
            if err <= e_mj:
                found.append((cpu, f"{solver}, exact, step {step * 1e3:g} ms", scene, err))
    if not found:
        return None
    found = sorted(found, key=lambda f: f[0])[: max(1, candidates)]

    def once(scene) -> float:
        sim = build(scene)
        c0 = time.process_time()
        sim.run(scene.t_end, scene.dt)
        return time.process_time() - c0

    k, (mj_cpu, cpu, ratio, spread, n) = in_turns(
        lambda: run_mujoco(case.scene, case.t_end, t_grid, every).cpu,
        [lambda f=f: once(f[2]) for f in found],
        rounds,
        budget,
    )
    return {
        "every_s": every,
        "mujoco_err": e_mj,
        "mujoco_cpu_s": mj_cpu,
        "setting": found[k][1],
        "err": found[k][3],
        "cpu_s": cpu,
        "ratio": ratio,
        "spread": spread,
        "rounds": n,
    }


def describe(r) -> str:
    if r is None:
        return "-"
    s = f"{r['solver']}, {r['scheme']}"
    if r["dt"] != "":
        s += f", dt {r['dt']:.3g} s"
    if r["rtol"] != "":
        s += f", rtol {r['rtol']:.0e}"
    return s


# -- output ---------------------------------------------------------------------------------
def _fmt(v, kind="g"):
    if v == "" or v is None:
        return "-"
    if isinstance(v, float):
        if math.isinf(v):
            return "inf"
        return f"{v:.2e}" if kind == "e" else f"{v:.3g}"
    return str(v)


def format_table(rows) -> str:
    head: tuple[str, ...] = (
        "solver",
        "scheme",
        "dt/rtol",
        "steps",
        "evals",
        "points",
        "CPU s",
        "CPU/sim s",
        "err_end φ",
        "max|Δφ|",
        "max|Δφ̇|",
        "max|Δφ̈|",
    )
    lines: list[tuple[str, ...]] = []
    for r in rows:
        step = _fmt(r["dt"], "g") if r["dt"] != "" else "rtol " + f"{r['rtol']:.0e}"
        lines.append(
            (
                r["solver"],
                r["scheme"],
                step,
                _fmt(r["steps"]),
                _fmt(r["evaluations"]),
                _fmt(r["position_points"]),
                f"{r['cpu_s']:.4f}",
                f"{r['cpu_per_sim_s']:.3g}",
                _fmt(r["err_end_phi"], "e"),
                _fmt(r["max_err_phi"], "e"),
                _fmt(r["max_err_phi_dot"], "e"),
                _fmt(r["max_err_phi_ddot"], "e"),
            )
        )
        if r.get("max_err_event_t") not in ("", None):
            lines[-1] = lines[-1] + (_fmt(r["max_err_event_t"], "e"),)
    if any(len(x) > len(head) for x in lines):
        head = head + ("max|Δt_event|",)
    widths = [max(len(str(x[i])) for x in [head] + lines if i < len(x)) for i in range(len(head))]

    def fmt(x):
        return "  ".join(
            str(v).rjust(w) if i > 1 else str(v).ljust(w) for i, (v, w) in enumerate(zip(x, widths))
        )

    return "\n".join([fmt(head), fmt(tuple("-" * w for w in widths))] + [fmt(x) for x in lines])


def write_csv(rows, path: Path, columns=COLUMNS) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(columns), extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in r.items()})
    return path


def study(case_names=None, families=FAMILIES, quick=False, repeats=3, budget=1.0, rungs=None, log=print):
    """Run the study; returns {case: {"rows": [...], "delta": [...], "reference": Reference}}."""
    out = {}
    for name in case_names or available_cases():
        case = resolve_case(name)
        settings = plan(case, families, quick, rungs)
        ref = reference_for(case, GRID)
        hz = f"; reference uncertain to {ref.uncertainty:.1e} rad (against a tenfold tolerance)"
        if ref.horizon < case.t_end:
            hz += (
                f" up to t = {ref.horizon:.3g} s, where that passes 1e-7 rad (the motion is "
                "chaotic): errors are measured up to there"
            )
        log(
            f"case {case.name}: {case.note}; t_end = {case.t_end:g} s; reference: {ref.label} "
            f"({ref.cpu:.2f} s CPU){hz}; {len(settings)} runs"
        )
        rows = []
        for s, dt in settings:
            try:
                rows.append(run_one(case, s, dt, ref, repeats, budget))
            except Exception as exc:  # a setting that fails (unstable, singular) is a result
                log(f"  {s.label} at {dt:g}: failed ({type(exc).__name__}: {exc})")
        delta = [] if quick or out else delta_study(case, ref)
        vs = versus(rows)
        if vs:
            log(f"  against MuJoCo: {len(vs)} points timed again, the two engines' runs in turns")
        side = side_by_side(case, vs, rows, rounds=max(3, repeats)) if vs else []
        op = operating_point(case, ref, rounds=max(3, repeats)) if vs else None
        out[case.name] = {
            "rows": rows,
            "delta": delta,
            "reference": ref,
            "case": case,
            "versus": list(zip(vs, side)),
            "operating_point": op,
        }
    return out


def report(results, out_dir: Path | None, plot: bool = True, log=print) -> None:
    for name, res in results.items():
        rows = res["rows"]
        ref = res["reference"]
        upto = "" if ref.horizon >= res["case"].t_end else f", up to t = {ref.horizon:.3g} s"
        log(f"\n== {name}: work-precision (errors against: {ref.label}{upto}) ==")
        log(format_table(rows))
        if res["delta"]:
            log(f"\n-- {name}: central differences against exact derivatives as Δ shrinks --")
            log(
                "   Δ (deg)   max rel. error of q̈ (per evaluation)   max|Δφ| RK4 "
                f"dt={res['delta'][0]['rk4_dt']:.3g} s"
            )
            for d in res["delta"]:
                lab = f"{d['delta_deg']:g}" if d["delta_deg"] else "exact"
                log(f"   {lab:>7}   {d['max_rel_err_qdd']:>36.2e}   {d['max_err_phi_rk4']:.2e}")
        log(f"\n-- {name}: the cheapest setting for a target accuracy (max |φ − φ_ref|) --")
        for tgt, best, peer, mj in recommendations(rows):
            b = (
                "-"
                if best is None
                else (f"{describe(best)}: {best['cpu_per_sim_s']:.3g} s CPU per simulated s")
            )
            p = "peer -" if peer is None else f"peer {peer['cpu_per_sim_s']:.3g} s"
            if any(r["solver"] == "mujoco" for r in rows):
                p += ", MuJoCo " + ("-" if mj is None else f"{mj['cpu_per_sim_s']:.3g} s")
            log(f"   {tgt:.0e} rad: {b}   [{p}]")
        vs = res.get("versus") or [(v, None) for v in versus(rows)]
        if vs:
            t_end = res["case"].t_end
            log(
                f"\n-- {name}: against MuJoCo (RK4 from Python, motor torque at every stage; "
                "CPU s per simulated s, each pair timed in turns) --"
            )
            log(
                f"   {'max φ error':>11}  {'MuJoCo':>22}  {'cheapest mps at least as accurate':<58}"
                f"  {'ratio mps/MuJoCo':>16}  {'spread':>6}  {'rounds':>6}"
                f"  {'its evaluations alone/MuJoCo':>28}  {'MuJoCo/bare mj_step':>19}"
            )
            for (p, best, ratio), side in vs:
                if side is not None:  # timed in turns: its setting, the CPU and ratio of then
                    best, mj_cpu, mine, ratio, spread, rounds = side
                else:
                    mj_cpu, mine, spread, rounds = p["cpu_s"], best and best["cpu_s"], None, None
                mj = f"dt {p['dt'] * 1e3:.4g} ms: {mj_cpu / t_end:.3g}"
                b = "-" if best is None else f"{describe(best)}: {mine / t_end:.3g}"
                rt = "-" if ratio is None else f"{ratio:.2f}"
                spread = "-" if spread is None else f"{100 * spread:.0f} %"
                rounds = "-" if rounds is None else str(rounds)
                alone = None if best is None else best.get("alone_cpu_s")
                al = f"{alone / mj_cpu:.2f}" if alone else "-"
                bare = p.get("bare_cpu_s")
                br = f"{p['cpu_s'] / bare:.2f}" if bare else "-"
                log(
                    f"   {p['max_err_phi']:>11.1e}  {mj:>22}  {b:<58}  {rt:>16}  {spread:>6}  {rounds:>6}"
                    f"  {al:>28}  {br:>19}"
                )
            op = res.get("operating_point")
            if op is not None:
                log(
                    f"   the twin's operating point, an output every {op['every_s'] * 1e3:g} ms: MuJoCo "
                    f"at that step {op['mujoco_cpu_s'] / t_end:.3g} ({op['mujoco_err']:.1e} rad at "
                    f"worst over the outputs), the cheapest mps at least as accurate at every output "
                    f"{op['setting']} {op['cpu_s'] / t_end:.3g} ({op['err']:.1e} rad): ratio "
                    f"{op['ratio']:.2f}, spread {100 * op['spread']:.0f} %, {op['rounds']} rounds"
                )
            closure = max(p.get("closure_m", 0.0) for (p, _, _), _side in vs)
            log(
                "   MuJoCo: integrator RK4, contacts off, the closure at B an equality connect "
                "with solref (2 dt, 1), solimp (0.9999, 0.9999, 0.001): its soft constraint "
                f"opens by up to {closure:.1e} m over these runs (mps_core/bench/mujoco_peer.py); "
                "its CPU is the stepping's (mj_RungeKutta, then mj_forward for the new state's "
                "accelerations), against a bare mj_step loop of the same model in the last "
                "column; 'ratio mps/MuJoCo': the median of the rounds' ratios, the two engines' "
                "runs in turns, 'spread' their interquartile range over that median; "
                "'its evaluations alone': the mps setting's evaluations times one q̈ "
                "by its charts' fused functions at the run's states (steps from "
                f"{ALONE_FROM * 1e3:g} ms), what no driver of those steps can go below"
            )
    if out_dir is None:
        return
    out_dir = Path(out_dir)
    allrows = [r for res in results.values() for r in res["rows"]]
    log(f"\nwrote {write_csv(allrows, out_dir / 'accuracy.csv')}")
    drows = [dict(d, case=n) for n, res in results.items() for d in res["delta"]]
    if drows:
        cols = ("case",) + tuple(k for k in drows[0] if k != "case")
        log(f"wrote {write_csv(drows, out_dir / 'accuracy-delta.csv', cols)}")
    if plot:
        from .plot import plot_accuracy

        for name, res in results.items():
            p = plot_accuracy(name, res, out_dir / f"accuracy-{name}.png")
            if p is not None:
                log(f"wrote {p}")
            else:
                log("no plot: matplotlib is not installed (pip install 'mps[bench]')")
                break
