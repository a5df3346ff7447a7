"""``mps bench sweep``: a sweep's throughput on one worker, on N local worker processes and on a
Dask ``LocalCluster`` of N worker processes, and what a run costs beside its simulation.

The sweep: press-cycle, a Latin hypercube over the blanked sheet's thickness, the crank speed
the motor is geared for and the slider's mass. Each way starts from the same state: the kernels
of the base scene are built once in this process first; the worker processes, forked, start
from them, and so does the one worker in this process, timed after them (a run whose effects'
parameters differ builds kernels of its own: part of every way's figure). The cluster's
spawned workers build their own.

``--vectorised`` (:func:`vectorised`): mechanism-steps a second of a sweep of working (locked,
no events) in one process, run by run and in vectorised batches (:mod:`mps_core.run.batch`),
the joint reactions and each run's load report included, and where a batch's time goes.
"""

from __future__ import annotations

import math
import os
import time
from typing import Any

from ..derivatives import SCHEMES

VARY = (
    "effects.blanking.thickness_mm=0.5:2.0",
    "effects.motor.crank_speed_rad_s=38:48",
    "bodies.slider.mass_kg=80:120",
)


def throughput(
    runs: int = 256,
    workers: int | None = None,
    t_end: float = 1.0,
    dt: float = 1e-3,
    dask: bool = True,
    log=print,
) -> list[dict]:
    from ..analysis.sweep import plan, sweep
    from ..run.build import simulate

    n = workers or os.cpu_count() or 1
    kw: dict[str, Any] = dict(samples=runs, seed=1, t_end=t_end, dt=dt)
    c0 = time.process_time()
    planned = plan("press-cycle", VARY, **kw)
    plan_cpu = time.process_time() - c0
    simulate(planned[0].scene)  # the kernels built, for every way alike
    rows = []

    def timed(label, workers_, **extra):
        w0 = time.perf_counter()
        res = sweep("press-cycle", VARY, workers=workers_, **kw, **extra)
        wall = time.perf_counter() - w0
        rows.append(
            {
                "way": label,
                "workers": workers_,
                "runs": len(res.rows),
                "wall_s": wall,
                "runs_per_s": len(res.rows) / wall,
                "failed": sum(1 for r in res.rows if r["status"] != "ok"),
                "cpu_s": res.cpu_s,
                "simulation_cpu_s": res.simulation_cpu_s,
            }
        )
        log(f"  {label}: {wall:.1f} s")
        return res

    log(f"sweep of {runs} press-cycle runs (t_end {t_end:g} s, dt {dt:g} s), {n} workers:")
    # the worker processes first: forked, they start from this process's kernels as they are
    # now, as the one worker in this process does after them (its own runs' kernels stay here)
    timed(f"{n} local worker processes", n)
    timed("one worker (this process)", 1)
    if dask:
        try:
            import dask as dask_
            from dask.distributed import Client, LocalCluster
        except ModuleNotFoundError:
            log("  Dask: not installed (the batch extra)")
        else:
            # the workers' statistical profiler off: sampling every thread's stack each 10 ms,
            # it costs a pure-Python run about 80 % more here (docs/loads.md)
            with (
                dask_.config.set({"distributed.worker.profile.enabled": False}),
                LocalCluster(
                    n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None
                ) as cluster,
                Client(cluster) as client,
            ):
                timed(f"Dask LocalCluster, {n} worker processes", n, client=client)
    rows.insert(0, rows.pop(1))  # one worker first in the table
    one = rows[0]["runs_per_s"]
    for r in rows:
        r["speedup"] = r["runs_per_s"] / one
    rows[0]["plan_cpu_s"] = plan_cpu
    return rows


def report(rows: list[dict]) -> None:
    print(f"{'way':42} {'wall s':>8} {'runs/s':>8} {'× one':>7} {'failed':>7}")
    for r in rows:
        print(f"{r['way']:42} {r['wall_s']:8.1f} {r['runs_per_s']:8.2f} {r['speedup']:7.2f} {r['failed']:7d}")
    one = rows[0]
    beside = one["cpu_s"] - one["simulation_cpu_s"] + one["plan_cpu_s"]
    print(
        f"beside the simulations (one worker): {beside:.2f} CPU s of {one['cpu_s']:.2f} "
        f"({100 * beside / one['cpu_s']:.1f} %): the scenes built and checked "
        f"({one['plan_cpu_s']:.2f} s), the load reports and the rows"
    )


# -- vectorised sweeps ------------------------------------------------------------------------
def _working(scheme: str):
    """The working preset (locked, no events) with derivatives by ``scheme``."""
    from ..scene import load_scene, scene_from_text

    base = load_scene("working")
    return scene_from_text(base.text.replace('derivatives = "central"', f'derivatives = "{scheme}"'))


def vectorised(
    sizes=(10, 100, 1000, 2000),
    t_end: float = 0.35,
    dt: float = 2e-4,
    schemes=SCHEMES,
    alone: int = 10,
    repeats: int = 2,
    workers: int | None = None,
    log=print,
) -> list[dict]:
    """Mechanism-steps a second of a sweep, the joint reactions and each run's load report
    included: working with the slider's mass swept, in this process (one worker) one run by
    one (``alone`` runs) and in vectorised batches of each size (a sweep of that many runs, one
    batch), interleaved, the best of ``repeats`` in CPU seconds; then on ``workers`` local
    worker processes (the machine's cores), a batch of the largest size each, in wall-clock
    seconds; and where a batch's time goes (its stepping, the reactions, the load reports, the
    rest: the scenes built and grouped, the rows)."""
    from ..analysis.batch_loads import batch_figures
    from ..analysis.sweep import plan, sweep
    from ..run.batch import run_states

    steps = int(round(t_end / dt))
    n = workers or os.cpu_count() or 1
    rows = []
    for scheme in schemes:
        base = _working(scheme)
        kw: dict[str, Any] = dict(t_end=t_end, dt=dt)
        warm = ["bodies.slider.mass_kg=80:120:2"]
        sweep(base, warm, workers=1, **kw)  # the kernels of both paths built before any timing
        sweep(base, warm, workers=1, vectorise=False, **kw)
        ways = [("one by one", alone, False)] + [(f"batches of {m}", m, True) for m in sizes]
        best: dict = {}

        def keep(label: str, key: str, cpu: float) -> None:
            if cpu < best.setdefault(label, {}).get(key, math.inf):
                best[label][key] = cpu

        for _ in range(repeats):
            for label, m, vec in ways:
                vary = [f"bodies.slider.mass_kg=80:120:{m}"]
                c0 = time.process_time()
                res = sweep(base, vary, workers=1, vectorise=vec, batch_size=m, min_batch=1, **kw)
                cpu = time.process_time() - c0
                if cpu < best.get(label, {}).get("cpu_s", math.inf):
                    best.setdefault(label, {}).update(
                        scheme=scheme,
                        way=label,
                        runs=m,
                        steps=steps,
                        cpu_s=cpu,
                        steps_per_s=m * steps / cpu,
                        simulation_cpu_s=res.simulation_cpu_s,
                        reports_cpu_s=res.cpu_s - res.simulation_cpu_s,
                        vectorised=res.vectorised,
                        failed=sum(1 for r in res.rows if r["status"] != "ok"),
                    )
                log(f"  {scheme} {label}: {cpu:.2f} CPU s")
                if vec:  # the batch alone: its reactions' share of its reports
                    scenes = [r.scene for r in plan(base, vary, **kw)]
                    c0 = time.process_time()
                    states = run_states(scenes)
                    batch_figures(states)
                    keep(label, "batch_cpu_s", time.process_time() - c0)
                    keep(label, "batch_reactions_cpu_s", states.reaction_cpu_s)
        for label, _m, _vec in ways:
            row = best[label]
            row["speedup"] = row["steps_per_s"] / best["one by one"]["steps_per_s"]
            rows.append(row)
        m = max(sizes)
        label = f"{n} worker{'s' if n > 1 else ''}, batches of {m}"
        vary = [f"bodies.slider.mass_kg=80:120:{n * m}"]
        w0 = time.perf_counter()
        res = sweep(base, vary, workers=n, batch_size=m, min_batch=1, **kw)
        wall = time.perf_counter() - w0
        log(f"  {scheme} {label}: {wall:.2f} s")
        rows.append(
            {
                "scheme": scheme,
                "way": label,
                "runs": n * m,
                "steps": steps,
                "wall_s": wall,
                "steps_per_s": n * m * steps / wall,
                "speedup": n * m * steps / wall / best["one by one"]["steps_per_s"],
                "vectorised": res.vectorised,
                "failed": sum(1 for r in res.rows if r["status"] != "ok"),
            }
        )
    return rows


def report_vectorised(rows: list[dict]) -> None:
    print(
        f"{'derivatives':12} {'way':22} {'runs':>5} {'seconds':>11} {'steps/s':>10} {'× one':>6} "
        f"{'stepping':>9} {'reactions':>9} {'reports':>8} {'rest':>6}"
    )
    for r in rows:
        if "wall_s" in r:  # the machine's workers: wall-clock seconds, no split
            print(
                f"{r['scheme']:12} {r['way']:22} {r['runs']:5d} {r['wall_s']:6.2f} wall "
                f"{r['steps_per_s']:10,.0f} {r['speedup']:6.1f}"
            )
            continue
        cpu = r["cpu_s"]
        if "batch_cpu_s" in r:  # the sweep's reports, split as the batch alone's split
            share = min(1.0, r["batch_reactions_cpu_s"] / max(r["reports_cpu_s"], 1e-12))
            reactions = f"{100 * r['reports_cpu_s'] * share / cpu:8.0f}%"
            reports = r["reports_cpu_s"] * (1.0 - share)
        else:
            reactions, reports = "", r["reports_cpu_s"]
        rest = cpu - r["simulation_cpu_s"] - r["reports_cpu_s"]
        print(
            f"{r['scheme']:12} {r['way']:22} {r['runs']:5d} {cpu:7.2f} CPU {r['steps_per_s']:10,.0f} "
            f"{r['speedup']:6.1f} {100 * r['simulation_cpu_s'] / cpu:8.0f}% {reactions:>9} "
            f"{100 * reports / cpu:7.0f}% {100 * rest / cpu:5.0f}%"
        )
    print(
        "(steps/s: mechanism-steps a second of the whole sweep, the reactions and each run's load "
        "report included: in one process (CPU seconds), or on the workers (wall-clock seconds); "
        "stepping: the simulation (one by one: with its reactions); reactions: a batch's, solved "
        "on each run's cycle; reports: the load reports and rows; rest: the scenes built, "
        "checked and grouped)"
    )
