"""``mps bench sweep``: a sweep's throughput on one worker, on N local worker processes and on a
Dask ``LocalCluster`` of N worker processes, and what a run costs beside its simulation.

The sweep: press-cycle, a Latin hypercube over the blanked sheet's thickness, the crank speed
the motor is geared for and the slider's mass. Each way starts from the same state: the kernels
of the base scene are built once in this process first; the worker processes, forked, start
from them, and so does the one worker in this process, timed after them (a run whose effects'
parameters differ builds kernels of its own: part of every way's figure). The cluster's
spawned workers build their own.
"""

from __future__ import annotations

import os
import time

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
    kw = dict(samples=runs, seed=1, t_end=t_end, dt=dt)
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
            import dask
            from dask.distributed import Client, LocalCluster
        except ModuleNotFoundError:
            log("  Dask: not installed (the batch extra)")
        else:
            # the workers' statistical profiler off: sampling every thread's stack each 10 ms,
            # it costs a pure-Python run about 80 % more here (docs/loads.md)
            with (
                dask.config.set({"distributed.worker.profile.enabled": False}),
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
