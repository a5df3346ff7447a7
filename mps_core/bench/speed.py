"""``mps bench speed``: what a step costs, and what each effect costs.

For each case, streaming at 1 kHz (an output every 1 ms, as the ROS node does):

* **solvers**: CPU per step of every solver and derivative scheme (median of repeats of a whole
  ``Simulation.run``), the real-time factor (1 ms / CPU per step), right-hand sides per step, and
  the run's max |φ − φ_ref|, so that "the fastest scheme of at least equal accuracy" can be read
  off; the peer on the same footing where it applies;
* **core**: the same solvers stepping the engine directly in the initial chart, without the
  driver (recording, chart checks, events, energies), and one evaluation alone, per scheme;
* **effects**: each effect's own cost per evaluation (its generalized force alone), and whole
  runs with the scene's effects, each one left out, and none: fewer effects, fewer microseconds.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import replace

import numpy as np

from ..dynamics.engine import PartialSystems
from ..errors import MpsError
from ..run.build import build
from ..solvers import make_solver
from .common import (
    Case,
    Setting,
    available_cases,
    cpu_median,
    evaluations_along,
    reference_for,
    resolve_case,
    run_setting,
    scene_for,
    with_effects,
)

DT = 1e-3  # 1 kHz

SOLVERS = (
    Setting("linear-acceleration", "central", 0.1),
    Setting("linear-acceleration", "autodiff"),
    Setting("linear-acceleration", "central", 0.1, iterations=3),
    Setting("rk4", "central", 0.1),
    Setting("rk4", "central", 0.01),
    Setting("rk4", "autodiff"),
    Setting("rk8", "autodiff"),
    Setting("dop853", "autodiff", rtol=1e-6),
    Setting("dop853", "autodiff", rtol=1e-9),
    # the price of locating the force laws' switching points (scenes that have them)
    Setting("dop853", "autodiff", rtol=1e-6, switch_points="step-over"),
    Setting("dop853", "autodiff", rtol=1e-9, switch_points="step-over"),
    Setting("radau", "autodiff", rtol=1e-6),
    Setting("peer", "exact", rtol=1e-6),
    Setting("peer", "exact", rtol=1e-9),
)


def _max_err_phi(t, phi, ref) -> float:
    if ref is None:  # no reference could be made: no error to give
        return float("nan")
    t = np.asarray(t)
    sel = (np.abs(t / DT - np.round(t / DT)) < 1e-6) & (t <= ref.horizon + 1e-12)
    return float(np.abs(np.asarray(phi)[sel] - ref.sample(t[sel])[0]).max())


def solver_costs(case: Case, ref, settings=SOLVERS, repeats: int = 5, budget: float = 2.0):
    rows = []
    switching = any(e.switches for e in build(case.scene).effects)
    for s in settings:
        if s.switch_points != "auto" and not switching:
            continue  # no switching points: the same run as "auto"
        label = s.label + (f", rtol {s.rtol:.0e}" if s.rtol else "")
        if s.solver == "peer":
            from .peers import run_peer, supports

            if not supports(case.scene)[0]:
                continue
            t_grid = np.linspace(0.0, case.t_end, int(round(case.t_end / DT)) + 1)
            cpu, run, n = cpu_median(
                lambda: run_peer(case.scene, case.t_end, t_grid, s.rtol), repeats, budget
            )
            steps = len(t_grid) - 1
            rows.append(
                {
                    "setting": label,
                    "us_per_step": cpu / steps * 1e6,
                    "rtf_1khz": DT * steps / cpu,
                    "evals_per_step": run.nfev / steps,
                    "max_err_phi": _max_err_phi(run.t, run.phi, ref),
                    "repeats": n,
                }
            )
            continue
        try:
            cpu, traj, n = run_setting(case, s, DT, repeats, budget)
        except Exception as exc:
            rows.append({"setting": label, "failed": f"{type(exc).__name__}: {exc}"})
            continue
        steps = len(traj.t) - 1
        rows.append(
            {
                "setting": label,
                "us_per_step": cpu / steps * 1e6,
                "rtf_1khz": DT * steps / cpu,
                "evals_per_step": traj.counts["evaluations"] / steps,
                "max_err_phi": _max_err_phi(traj.t, traj.phi, ref),
                "repeats": n,
            }
        )
    return rows


def core_costs(case: Case, settings=SOLVERS, steps: int = 40, repeats: int = 5):
    """Engine + solver alone, in the initial chart: CPU per step, and per evaluation."""
    rows = []
    for s in settings:
        if s.solver == "peer" or s.switch_points != "auto":
            continue  # the driver's business: the same steps here
        scene = scene_for(case, s, DT)
        sim = build(scene)
        view = sim.view
        engine = sim.engine
        q0, qd0 = sim.solver.q.copy(), sim.solver.qd.copy()

        def fun(t, q, qd):
            return engine.evaluate(view, t, q, qd)

        def accel(t, ql, vl):
            return engine.accelerations(view, t, ql, vl)

        def stepping():
            # as a run builds it: q̈ alone for the stages whose evaluation is not kept
            sol = make_solver(
                s.solver,
                fun,
                0.0,
                q0,
                qd0,
                iterations=s.iterations,
                rtol=s.rtol or 1e-9,
                atol=(s.rtol or 1e-9) * 1e-3,
                scales=view.scales,
                accel=accel,
            )
            k = 0
            try:
                for k in range(1, steps + 1):
                    sol.step_to(k * DT)
            except Exception:
                k -= 1
            return k, sol.nfev

        times = []
        for _ in range(repeats):
            c0 = time.process_time()
            k, nfev = stepping()
            times.append((time.process_time() - c0) / max(k, 1))
        rows.append(
            {
                "setting": s.label + (f", rtol {s.rtol:.0e}" if s.rtol else ""),
                "us_per_step": statistics.median(times) * 1e6,
                "steps": k,
                "evals_per_step": nfev / max(k, 1),
                "chart": view.name,
            }
        )
    return rows


def _per_call(fn, number: int = 2000, repeats: int = 5) -> float:
    """Median over ``repeats`` batches of the CPU microseconds of one call."""
    best = []
    for _ in range(repeats):
        c0 = time.process_time()
        for _ in range(number):
            fn()
        best.append((time.process_time() - c0) / number * 1e6)
    return statistics.median(best)


def evaluation_costs(case: Case, number: int = 2000):
    rows = []
    for scheme, d in (("central", 0.1), ("autodiff", 0.0)):
        scene = scene_for(case, Setting("linear-acceleration", scheme, d), DT)
        sim = build(scene)
        e = sim.solver.current
        eng = sim.engine
        us = _per_call(lambda: eng.evaluate(e.view, e.t, e.q, e.qd), number)
        rows.append(
            {
                "scheme": scheme if scheme == "autodiff" else f"central {d:g}°",
                "chart": e.view.name,
                "n": e.view.n,
                "us_per_evaluation": us,
                "position_points": 1 if scheme == "autodiff" else {1: 5, 2: 13}.get(e.view.n, 0),
            }
        )
        if scheme == "autodiff":
            # q̈ alone, what a solver's inner stage asks (the fused function where it has one)
            ql, vl = e.q.tolist(), e.qd.tolist()
            eng.accelerations(e.view, e.t, ql, vl)
            us = _per_call(lambda: eng.accelerations(e.view, e.t, ql, vl), number)
            plan = eng._plans.get(e.view)
            rows.append(
                {
                    "scheme": "autodiff, q̈ alone"
                    + (" (fused)" if plan is not None and plan.fused is not None else ""),
                    "chart": e.view.name,
                    "n": e.view.n,
                    "us_per_evaluation": us,
                    "position_points": 1,
                }
            )
            if plan is not None and plan.fused is not None:
                # the same evaluation without the fused function: the exact kernel, the
                # effects one by one and the solve (what the fused function replaces)
                fused = plan.fused
                plan.fused, plan.fused_at = None, eng.version[0]
                us = _per_call(lambda: eng.evaluate(e.view, e.t, e.q, e.qd), number)
                plan.fused = fused
                rows.append(
                    {
                        "scheme": "autodiff, effects one by one",
                        "chart": e.view.name,
                        "n": e.view.n,
                        "us_per_evaluation": us,
                        "position_points": 1,
                    }
                )
    return rows


def reaction_costs(case: Case, number: int = 200, limit: int = 60, scheme: str = "central"):
    """What the reactions cost beside an exact evaluation, side by side at the same states
    (``limit`` states spread evenly over the whole run, linear acceleration in ``scheme``: the
    seed's central differences, or exact derivatives, whose evaluations carry the bodies'
    motion that the reaction kernel then reads): µs of one exact evaluation, of the reactions
    by the view's reaction kernel (with the effects' loads), and by the general Newton–Euler
    least squares; medians over the states, one row for all of them and one for each number
    of free coordinates n (a structure's charts: n = 1 held or locked, n = 2 free in the
    press)."""
    from ..dynamics.reactions import compute_reactions, reaction_values

    scene = scene_for(case, Setting("linear-acceleration", scheme, 0.1 if scheme == "central" else 0.0), DT)
    sim = build(scene)
    exact = build(scene_for(case, Setting("linear-acceleration", "autodiff", 0.0), DT)).engine
    states = []
    n = max(1, round(case.t_end / DT))
    for k in range(1, n + 1):
        sim.advance_to(k * case.t_end / n)
        states.append(sim.solver.current)
    states = states[:: max(1, len(states) // limit)][:limit]
    mech, effects = sim.mechanism, sim.engine.effects
    got = []
    for e in states:
        ql, vl, al = e.q.tolist(), e.qd.tolist(), e.qdd.tolist()
        try:
            exact.evaluate(e.view, e.t, e.q, e.qd)
        except Exception:
            continue
        if reaction_values(mech, effects, e.view, e.t, ql, vl, al, e.kin) is None:
            continue
        got.append(
            (
                e.view.n,
                _per_call(lambda: exact.evaluate(e.view, e.t, e.q, e.qd), number, 3),
                _per_call(lambda: reaction_values(mech, effects, e.view, e.t, ql, vl, al, e.kin), number, 3),
                _per_call(
                    lambda: compute_reactions(
                        mech, effects, e.view, e.t, e.q, e.qd, e.qdd, kin=e.kin, kernel=False
                    ),
                    max(1, number // 20),
                    3,
                ),
            )
        )
    med = statistics.median
    rows = []
    for label, sel in [("all", got)] + [
        (f"n = {k}", [g for g in got if g[0] == k]) for k in sorted({g[0] for g in got})
    ]:
        if not sel or (label != "all" and len(sel) == len(got)):
            continue
        _, ev, fast, general = zip(*sel)
        rows.append(
            {
                "states": len(sel),
                "which": label,
                "run": scheme,
                "us_exact_evaluation": med(ev),
                "us_reactions_kernel": med(fast),
                "us_reactions_general": med(general),
                "kernel_over_evaluation": med([f / x for f, x in zip(fast, ev)]),
                "general_over_kernel": med([g / f for g, f in zip(general, fast)]),
            }
        )
    return rows


def _states(case: Case, scene, every: int = 5, limit: int = 200):
    """(engine, [evaluations]) along a run of the scene: every ``every``-th right-hand side."""
    sim, seen = evaluations_along(scene, min(case.t_end, 0.1))
    return sim, seen[::every][:limit]


def effect_costs(case: Case, repeats: int = 5, budget: float = 2.0, number: int = 5000):
    """What the effects cost: each one's generalized force alone (µs per evaluation); whole
    evaluations along the same states (the first 0.1 s of a run) with all the scene's effects,
    each one left out, and none, so that the dynamics are the same for every variant; and whole
    runs with those effects (there the motion changes too)."""
    scene = scene_for(case, Setting("linear-acceleration", "central", 0.1), DT)
    sim, states = _states(case, scene)
    e = sim.solver.current if not states else states[0]
    kin = e.kin
    effects = list(sim.engine.effects)
    per = []
    for eff in effects:
        eng = PartialSystems(sim.mechanism, [eff], "central", scene.solver.delta)
        us = _per_call(lambda: eng.generalized_forces(e.t, kin), number)
        per.append({"effect": eff.kind, "us_per_evaluation": us})
    empty = PartialSystems(sim.mechanism, [], "central", scene.solver.delta)
    per.append(
        {
            "effect": "(none)",
            "us_per_evaluation": _per_call(lambda: empty.generalized_forces(e.t, kin), number),
        }
    )
    kinds = [x.kind for x in effects]
    variants = [("all: " + ", ".join(kinds), kinds)]
    if len(kinds) > 1:
        variants += [(f"without {k}", [x for x in kinds if x != k]) for k in kinds]
    variants.append(("none", []))
    evals = []
    for label, keep in variants:
        eng = PartialSystems(
            sim.mechanism, [x for x in effects if x.kind in keep], "central", scene.solver.delta
        )

        def sweep():
            for st in states:
                try:
                    eng.evaluate(st.view, st.t, st.q, st.qd)
                except Exception:  # a state the reduced forces cannot solve: skipped
                    pass

        us = _per_call(sweep, number=max(1, 2000 // max(1, len(states))), repeats=repeats)
        evals.append({"effects": label, "us_per_evaluation": us / max(1, len(states)), "states": len(states)})
    runs = []
    for label, keep in variants:
        sub = replace(case, scene=with_effects(case.scene, keep))
        try:
            cpu, traj, n = run_setting(
                sub, Setting("linear-acceleration", "central", 0.1), DT, repeats, budget
            )
        except Exception as exc:
            runs.append({"effects": label, "failed": f"{type(exc).__name__}: {exc}"})
            continue
        steps = len(traj.t) - 1
        runs.append(
            {
                "effects": label,
                "us_per_step": cpu / steps * 1e6,
                "evals_per_step": traj.counts["evaluations"] / steps,
            }
        )
    return per, evals, runs


def study(case_names=None, quick: bool = False, log=print):
    # the change point: its continuation chart's cost is watched here
    names = case_names or [*(c for c in available_cases() if c != "paper-long"), "idle-change-point"]
    repeats = 3 if quick else 7
    out = {}
    for name in names:
        case = resolve_case(name)
        try:
            ref = reference_for(case, DT)
            said = ref.label
        except MpsError as exc:  # the costs stand without it; the errors are not given
            ref, said = None, f"none ({exc})"
        log(f"case {case.name}: {case.note}; t_end = {case.t_end:g} s, dt = 1 ms (1 kHz); reference: {said}")
        settings = (
            SOLVERS
            if not quick
            else tuple(
                s for s in SOLVERS if s.solver in ("linear-acceleration", "rk4", "peer") and s.iterations == 1
            )
        )
        res = {
            "case": case,
            "reference": ref,
            "solvers": solver_costs(case, ref, settings, repeats),
            "core": core_costs(case, settings, repeats=3 if quick else 5),
            "evaluation": evaluation_costs(case, 500 if quick else 2000),
            "reactions": reaction_costs(case, 100 if quick else 300, scheme="autodiff")
            + reaction_costs(case, 100 if quick else 300),
        }
        res["effects"], res["effect_evals"], res["effect_runs"] = effect_costs(case, repeats)
        out[name] = res
    return out


def report(results, log=print) -> None:
    """Log each case's tables: whole runs, the engine and solver alone, the effects."""
    for name, res in results.items():
        _report_runs(name, res, log)
        _report_core(name, res, log)
        _report_effects(name, res, log)


def _report_runs(name, res, log) -> None:
    """Whole runs streaming at 1 kHz, and the fastest setting at least as accurate as the
    paper's scheme."""
    log(f"\n== {name}: streaming at 1 kHz (t_end {res['case'].t_end:g} s), whole runs ==")
    log(f"{'setting':52s} {'us/step':>9s} {'x real time':>11s} {'evals/step':>10s} {'max|dphi| rad':>13s}")
    base = None
    for r in res["solvers"]:
        if "failed" in r:
            log(f"{r['setting']:52s} failed: {r['failed']}")
            continue
        if base is None and r["setting"].startswith("linear-acceleration, central 0.1"):
            base = r
        log(
            f"{r['setting']:52s} {r['us_per_step']:9.1f} {r['rtf_1khz']:11.1f} "
            f"{r['evals_per_step']:10.2f} {r['max_err_phi']:13.2e}"
        )
    if base is not None and res["reference"] is not None:
        ok = [
            r
            for r in res["solvers"]
            if "failed" not in r
            and not r["setting"].startswith("peer")
            and r["max_err_phi"] <= base["max_err_phi"]
        ]
        best = min(ok, key=lambda r: r["us_per_step"])
        log(
            f"paper's scheme (linear acceleration, central 0.1°): {base['rtf_1khz']:.1f}× "
            f"real time; fastest of at least equal accuracy: {best['setting']} "
            f"{best['rtf_1khz']:.1f}× ({best['max_err_phi']:.1e} rad ≤ "
            f"{base['max_err_phi']:.1e})"
        )


def _report_core(name, res, log) -> None:
    """The engine and solver alone, one evaluation alone, and the reactions beside one."""
    log(f"\n-- {name}: engine + solver alone (initial chart, no driver) --")
    for r in res["core"]:
        log(
            f"{r['setting']:52s} {r['us_per_step']:9.1f} us/step "
            f"({r['evals_per_step']:.2f} evaluations, {r['steps']} steps, chart {r['chart']})"
        )
    for r in res["evaluation"]:
        log(
            f"one evaluation, {r['scheme']:14s} chart {r['chart']:10s} n = {r['n']}: "
            f"{r['us_per_evaluation']:6.1f} us ({r['position_points']} position points)"
        )
    lone = {r["scheme"]: r["us_per_evaluation"] for r in res["evaluation"]}
    for r in res["core"]:
        if r["setting"] == "rk4, autodiff" and "autodiff" in lone:
            # RK4's step: three stages asking for q̈ alone, one whole evaluation
            alone = [v for k, v in lone.items() if k.startswith("autodiff, q̈ alone")]
            each = (3 * alone[0] + lone["autodiff"]) / 4 if alone else lone["autodiff"]
            per = r["us_per_step"] / r["evals_per_step"]
            log(
                f"inside an RK4 run (autodiff, engine + solver alone): {per:.1f} us per "
                f"evaluation, {per / each:.2f}× the same mix measured alone ({each:.1f} us)"
            )
    for r in res.get("reactions", ()):
        run = (
            "an exact run: the kernel reads the evaluation's motion"
            if r.get("run") == "autodiff"
            else "the seed's central run: the kernel traces the motion itself"
        )
        log(
            f"reactions beside one exact evaluation ({run}; {r['which']}: median of "
            f"{r['states']} states over the run, side by side): exact evaluation "
            f"{r['us_exact_evaluation']:.1f} us, reaction kernel "
            f"with the loads {r['us_reactions_kernel']:.1f} us "
            f"({r['kernel_over_evaluation']:.2f}× the evaluation), general least squares "
            f"{r['us_reactions_general']:.1f} us ({r['general_over_kernel']:.0f}× the kernel)"
        )


def _report_effects(name, res, log) -> None:
    """Each effect's own cost, evaluations and whole runs with effects left out."""
    log(f"\n-- {name}: effects --")
    for r in res["effects"]:
        log(f"generalized force of {r['effect']:18s} {r['us_per_evaluation']:6.2f} us per evaluation")
    for r in res["effect_evals"]:
        log(
            f"evaluation with effects {r['effects']:34s} {r['us_per_evaluation']:7.1f} us "
            f"(central 0.1°, the same {r['states']} states)"
        )
    for r in res["effect_runs"]:
        if "failed" in r:
            log(f"run with effects {r['effects']:41s} failed: {r['failed']}")
            continue
        log(
            f"run with effects {r['effects']:41s} {r['us_per_step']:7.1f} us/step "
            f"(linear acceleration, central 0.1°; the motion changes with the forces)"
        )


def as_rows(results):
    """Flat rows for a CSV."""
    out = []
    for name, res in results.items():
        for part in ("solvers", "core", "evaluation", "reactions", "effects", "effect_evals", "effect_runs"):
            for r in res.get(part, ()):
                out.append(dict(r, case=name, part=part))
    return out


__all__ = [
    "study",
    "report",
    "as_rows",
    "solver_costs",
    "core_costs",
    "evaluation_costs",
    "reaction_costs",
    "effect_costs",
]
