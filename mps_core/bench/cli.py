"""``mps bench``: the work-precision study and the speed benchmark.

    mps bench accuracy [CASE …] [--solvers NAME,…] [--quick] [--rungs N] [--repeats N]
                       [--out DIR] [--no-plot]
    mps bench speed [CASE …] [--quick] [--out DIR]
    mps bench batch [--sizes N,…] [--steps N]
    mps bench sweep [--runs N] [--workers N] [--t-end S] [--dt S] [--no-dask]
    mps bench sweep --vectorised [--sizes N,…] [--scheme central|autodiff|both] [--t-end S] [--dt S]

CASE is ``paper`` (0.1 s), ``paper-long`` (1 s), ``press-cycle`` (where that preset exists) or
any preset name or scene file (over its own t_end); by default every built-in case.
"""

from __future__ import annotations

import os
from pathlib import Path

from ..derivatives import SCHEMES
from .accuracy import FAMILIES


def register(subparsers) -> None:
    """``mps bench`` and its commands."""
    p = subparsers.add_parser("bench", help="benchmarks: work-precision study, speed")
    sub = p.add_subparsers(dest="bench", required=True)

    _register_accuracy(sub)
    _register_speed(sub)
    _register_batch(sub)
    _register_sweep(sub)


def _register_accuracy(sub) -> None:
    """``mps bench accuracy``: the work-precision study."""
    a = sub.add_parser("accuracy", help="work-precision study against an exact reference")
    a.add_argument(
        "cases",
        nargs="*",
        metavar="CASE",
        help="paper, paper-long, press-cycle, or a preset/scene file (default: every built-in case)",
    )
    a.add_argument("--solvers", metavar="NAME,…", help="comma-separated subset of " + ", ".join(FAMILIES))
    a.add_argument(
        "--quick",
        action="store_true",
        help="three step sizes, two derivative schemes, fewer tolerances, one repeat",
    )
    a.add_argument(
        "--rungs",
        type=int,
        metavar="N",
        help=(
            "step sizes: 5 ms, 2.5 ms and the first N of 1.25 ms, 0.625 ms, … (8 reach 1e-5 s); "
            "rk6 and rk8 also 12.5, 10 and 6.25 ms"
        ),
    )
    a.add_argument(
        "--repeats",
        type=int,
        default=3,
        metavar="N",
        help="CPU time: median of up to N runs (fewer for runs over 1 s)",
    )
    a.add_argument(
        "--out",
        metavar="DIR",
        default="bench-out",
        help="where to write accuracy.csv and the plots (default bench-out)",
    )
    a.add_argument("--no-plot", action="store_true", help="no PNG")
    a.set_defaults(func=_accuracy)


def _register_speed(sub) -> None:
    """``mps bench speed``: CPU a step, the effects' cost."""
    s = sub.add_parser("speed", help="CPU per step, real-time factor at 1 kHz, cost of effects")
    s.add_argument(
        "cases",
        nargs="*",
        metavar="CASE",
        help="paper, press-cycle, or a preset/scene file (default: paper and press-cycle where it exists)",
    )
    s.add_argument("--quick", action="store_true", help="fewer solvers and repeats")
    s.add_argument("--out", metavar="DIR", help="also write speed.csv there")
    s.set_defaults(func=_speed)


def _register_batch(sub) -> None:
    """``mps bench batch``: scenes stepped together."""
    b = sub.add_parser(
        "batch", help="batch mode: mechanism-steps per second against the number of scenes stepped together"
    )
    b.add_argument(
        "--sizes", default="1,10,100,1000,10000", help="numbers of scenes (default: 1,10,100,1000,10000)"
    )
    b.add_argument("--steps", type=int, default=200, help="steps of each run (default 200)")
    b.add_argument(
        "--scheme",
        choices=(*SCHEMES, "both"),
        default="both",
        help="derivatives: central differences, exact, or both side by side (default both)",
    )
    b.set_defaults(func=_batch)


def _register_sweep(sub) -> None:
    """``mps bench sweep``: mps sweep's throughput."""
    w = sub.add_parser(
        "sweep", help="mps sweep's throughput: one worker, N local worker processes, a Dask LocalCluster"
    )
    w.add_argument("--runs", type=int, default=256, help="runs of the sweep (default 256)")
    w.add_argument("--workers", type=int, help="N (default: the machine's cores)")
    w.add_argument("--t-end", type=float, help="end time of each run (default 1 s)")
    w.add_argument("--dt", type=float, help="output step (default 1 ms)")
    w.add_argument("--no-dask", action="store_true", help="leave the Dask cluster out")
    w.add_argument(
        "--vectorised",
        action="store_true",
        help="instead: a sweep of working in this process, one run by one and in vectorised "
        "batches of --sizes runs, the reactions and load reports included (mechanism-steps a "
        "second; --t-end default 0.35 s, --dt 0.2 ms)",
    )
    w.add_argument(
        "--sizes",
        default="10,100,1000,2000",
        help="with --vectorised: batch sizes (default 10,100,1000,2000; a sweep's batches hold "
        "2000 runs unless told)",
    )
    w.add_argument(
        "--scheme",
        choices=(*SCHEMES, "both"),
        default="both",
        help="with --vectorised: derivatives (default both)",
    )
    w.set_defaults(func=_sweep)


def _accuracy(args) -> int:
    from . import accuracy

    families = FAMILIES
    if args.solvers:
        families = tuple(x.strip() for x in args.solvers.split(",") if x.strip())
        bad = [f for f in families if f not in FAMILIES]
        if bad:
            raise SystemExit(
                f"mps bench accuracy: unknown solver(s) {', '.join(bad)}; expected {', '.join(FAMILIES)}"
            )
    repeats = 1 if args.quick else args.repeats
    res = accuracy.study(args.cases or None, families, quick=args.quick, repeats=repeats, rungs=args.rungs)
    accuracy.report(res, Path(args.out), plot=not args.no_plot)
    return 0


def _speed(args) -> int:
    from . import speed
    from .accuracy import write_csv

    res = speed.study(args.cases or None, quick=args.quick)
    speed.report(res)
    if args.out:
        rows = speed.as_rows(res)
        cols = []
        for r in rows:
            cols += [k for k in r if k not in cols]
        print(f"\nwrote {write_csv(rows, Path(args.out) / 'speed.csv', tuple(cols))}")
    return 0


def _batch(args) -> int:
    from ..run.batch import throughput

    sizes = [int(x) for x in args.sizes.split(",") if x.strip()]
    schemes = SCHEMES if args.scheme == "both" else (args.scheme,)
    print(
        "batch mode: working (locked), slider mass swept, linear acceleration, "
        "dt = 1e-4 s; CPU of the stepping (scenes built beforehand), mechanism-steps a second"
    )
    table = {s: throughput(sizes, steps=args.steps, scheme=s) for s in schemes}
    print(f"{'scenes':>7}" + "".join(f" {s:>14}" for s in schemes))
    for k, row in enumerate(table[schemes[0]]):
        label = "1 alone" if row["scenes"] == 0 else str(row["scenes"])
        print(f"{label:>7}" + "".join(f" {table[s][k]['steps_per_s']:>14,.0f}" for s in schemes))
    print(
        "(1 alone: simulate, the one-scene path; central: central differences; autodiff: exact derivatives)"
    )
    return 0


def _sweep(args) -> int:
    from . import sweep

    if args.vectorised:
        try:
            sizes = [int(x) for x in args.sizes.split(",") if x.strip()]
        except ValueError:
            sizes = []
        if not sizes or min(sizes) < 1:
            raise SystemExit(
                f"mps bench sweep: --sizes {args.sizes!r}: expected integers >= 1, e.g. 10,100,1000"
            )
        schemes = SCHEMES if args.scheme == "both" else (args.scheme,)
        t_end, dt = args.t_end or 0.35, args.dt or 2e-4
        print(
            f"vectorised sweep: working (locked), slider mass swept, linear acceleration, "
            f"t_end {t_end:g} s, dt {dt:g} s, reactions and load reports; one process, "
            f"then {args.workers or os.cpu_count() or 1} worker processes"
        )
        vec = sweep.vectorised(tuple(sizes), t_end, dt, schemes, workers=args.workers)
        sweep.report_vectorised(vec)
        return 0
    rows = sweep.throughput(
        args.runs, args.workers, args.t_end or 1.0, args.dt or 1e-3, dask=not args.no_dask
    )
    sweep.report(rows)
    return 0
