"""The ``mps`` command line.

    mps run SCENE [--t-end S] [--steps N | --dt S] [--solver NAME] [--step S] [--delta-deg D]
                  [--derivatives central|autodiff] [--iterations K] [--rtol R] [--atol A]
                  [--no-chart-switching] [--reactions] [--csv FILE] [--events FILE] [--force]
                  [--quiet]
    mps scenes
    mps cache info | clear

SCENE is a preset name (``mps scenes`` lists them) or the path of a scene file. ``mps cache``:
the generated code kept on disk (:mod:`mps_core.codegen.disk_cache`), where and how much, or
removed.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import importlib
import math
import os
import signal
import sys
import time

from . import __version__
from .errors import Interrupted, MpsError, raise_interrupted, signal_name
from .plugins import COMMANDS, found, load


def _parser() -> argparse.ArgumentParser:
    from .derivatives import SCHEMES
    from .solvers import ADAPTIVE_SOLVERS, SOLVERS

    p = argparse.ArgumentParser(prog="mps", description="Digital twin of a crank press.")
    p.add_argument("--version", action="version", version=f"mps {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("run", help="simulate a scene headless and print a summary")
    r.add_argument("scene", help="preset name or scene file (TOML)")
    r.add_argument("--t-end", type=float, metavar="S", help="end time (s)")
    g = r.add_mutually_exclusive_group()
    g.add_argument("--steps", type=int, metavar="N", help="number of steps")
    g.add_argument("--dt", type=float, metavar="S", help="step (s); the output grid for the adaptive solvers")
    r.add_argument("--solver", choices=SOLVERS)
    r.add_argument(
        "--step",
        type=float,
        metavar="S",
        help="the fixed-step solvers' own step (s), where it is not the output "
        "step: shorter, several steps an output; longer, outputs from the "
        "step's interpolant",
    )
    r.add_argument(
        "--delta-deg",
        type=float,
        metavar="D",
        help="virtual displacement of the central differences (degrees)",
    )
    r.add_argument(
        "--derivatives",
        choices=SCHEMES,
        help="derivative scheme: the seed's central differences or exact jets",
    )
    r.add_argument(
        "--iterations", type=int, metavar="K", help="corrections per step of the linear acceleration method"
    )
    adaptive = ", ".join(ADAPTIVE_SOLVERS)
    r.add_argument("--rtol", type=float, help=f"relative tolerance ({adaptive})")
    r.add_argument("--atol", type=float, help=f"absolute tolerance ({adaptive})")
    r.add_argument(
        "--no-chart-switching",
        action="store_true",
        help="stay in the initial chart; stop with an error where it degenerates",
    )
    r.add_argument(
        "--reactions",
        action="store_true",
        help="compute the joint reactions and the foundation load at every step "
        "(adds their columns to --csv)",
    )
    r.add_argument(
        "--csv", metavar="FILE", help="write one row per step to FILE (- : standard output; a FIFO or device)"
    )
    r.add_argument(
        "--events",
        metavar="FILE",
        help="write the event log (JSON lines) to FILE (- : standard output; a FIFO or device)",
    )
    r.add_argument(
        "--force",
        action="store_true",
        help="replace an output file that exists (a regular file only; never the scene itself)",
    )
    r.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="no progress line while it runs (there is one on a terminal only)",
    )

    sub.add_parser("scenes", help="list the preset scenes")
    c = sub.add_parser("cache", help="the generated code kept on disk: where and how much, or remove it")
    c.add_argument("action", choices=("info", "clear"), help="info: where, entries, bytes; clear: remove all")
    for name in PLUGINS:
        importlib.import_module(name).register(sub)
    for ep in found(COMMANDS):
        register = load(ep)
        if register is not None:
            register(sub)
    return p


#: the commands that SIGTERM interrupts as Ctrl-C does (the others, the ROS node's among them,
#: handle their signals themselves)
INTERRUPTIBLE = ("run", "loads", "sweep", "recover")
#: the commands whose outputs are written whole at their end: interrupted, they wrote nothing
WRITTEN_AT_THE_END = ("loads", "recover")

#: the core's modules that add subcommands: each has ``register(subparsers)``, whose parser sets
#: ``func``; other packages add theirs through entry points (:data:`~.plugins.COMMANDS`)
PLUGINS = (
    "mps_core.analysis.loads_cli",
    "mps_core.analysis.sweep_cli",
    "mps_core.bench.cli",
    "mps_core.track.cli",
)


def _run(args) -> int:
    from .files.outputs import STDOUT, check_outputs

    # before anything runs: a results path that cannot be written, or that would destroy the
    # scene or an existing file, is refused now, not after the run
    check_outputs(
        {"--csv": args.csv, "--events": args.events},
        inputs=[args.scene],
        force=args.force,
        streams={"--csv", "--events"},
    )
    if STDOUT in (args.csv, args.events):
        # standard output carries an output: what the command says goes to standard error
        stdout = sys.stdout
        with contextlib.redirect_stdout(sys.stderr):
            return _run_checked(args, stdout)
    return _run_checked(args, sys.stdout)


def _run_checked(args, stdout) -> int:
    """Run ``mps run`` once its outputs are checked; ``stdout``: where ``-`` writes."""
    from .scene import load_scene

    scene = load_scene(args.scene)
    scene = scene.with_overrides(
        t_end=args.t_end,
        steps=args.steps,
        dt=args.dt,
        solver=args.solver,
        delta=None if args.delta_deg is None else math.radians(args.delta_deg),
        scheme=args.derivatives,
        iterations=args.iterations,
        rtol=args.rtol,
        atol=args.atol,
        chart_switching=False if args.no_chart_switching else None,
        step=args.step,
    )
    from .run.build import build

    sim = build(scene)
    if args.reactions:
        from .dynamics.reaction_observer import ReactionObserver

        observer = ReactionObserver()
        sim.observers.append(observer)
    from .run.progress import Progress

    progress = Progress(sim.solver.t, scene.t_end, label=scene.name, quiet=args.quiet)
    c0 = time.process_time()
    try:
        traj = sim.run(scene.t_end, scene.dt, progress=progress)
    except MpsError as exc:
        progress.done()
        # what was computed up to the failure still goes to the outputs asked for, marked
        partial = getattr(exc, "partial", None)
        if partial is not None and len(partial):
            _write_outputs(args, partial, stdout, failure=str(exc))
            _say_coarse(partial, scene)
        raise
    except KeyboardInterrupt as exc:
        progress.done()
        partial = getattr(exc, "partial", None)
        said = signal_name(exc)
        kept = "nothing kept"
        if partial is not None and len(partial) and (args.csv or args.events):
            written = _write_outputs(args, partial, stdout, failure=f"interrupted ({said})", quiet=True)
            kept = ", ".join(written) + f", marked partial (up to t = {float(partial.t[-1]):.6g} s)"
        elif not (args.csv or args.events):
            kept = "nothing kept (no --csv or --events asked for)"
        raise Interrupted(said, kept) from None
    finally:
        progress.done()
    cpu = time.process_time() - c0
    _summary(scene, traj, cpu)
    if args.reactions:
        _reactions_summary(traj, observer)
    _write_outputs(args, traj, stdout)
    _say_coarse(traj, scene)
    return 0


def _summary(scene, traj, cpu: float) -> None:
    """What ``mps run`` prints of a run: the scene and solver, the last state, the energy,
    the charts and the work done."""
    s = scene.solver
    print(
        f"scene {scene.name}: {scene.structure} structure, t_end = {scene.t_end:g} s, "
        f"{scene.steps} steps of {scene.dt:.6g} s"
        + (f" (outputs; the solver's steps {s.step:.6g} s)" if s.step is not None else "")
    )
    detail = f"{s.scheme} derivatives"
    if s.scheme == "central":
        detail += f", delta = {math.degrees(s.delta):g} deg"
    if s.name == "linear-acceleration":
        detail += f", {s.iterations} correction(s) a step"
    from .solvers import ADAPTIVE_SOLVERS

    if s.name in ADAPTIVE_SOLVERS:
        detail += f", rtol = {s.rtol:g}, atol = {s.atol:g}"
    print(f"solver {s.name} ({detail})")
    i = -1
    print(
        f"at t = {traj.t[i]:.6g} s: phi = {traj.phi[i]:.10g} rad ({math.degrees(traj.phi[i]):.6g} deg), "
        f"phi_dot = {traj.phi_dot[i]:.10g} rad/s, phi_ddot = {traj.phi_ddot[i]:.10g} rad/s^2"
    )
    print(
        f"               psi = {traj.psi[i]:.10g} rad ({math.degrees(traj.psi[i]):.6g} deg), "
        f"psi_dot = {traj.psi_dot[i]:.10g} rad/s, x_C = {traj.x_C[i] * 1000:.6g} mm"
    )
    e = traj.energy
    print(f"energy T + V: {e[0]:.6g} J -> {e[-1]:.6g} J")
    charts = [ev for ev in traj.events if ev["kind"] == "chart"]
    if charts:
        seq = " -> ".join([charts[0]["from"]] + [ev["to"] for ev in charts])
        print(f"charts: {seq} (at t = " + ", ".join(f"{ev['t']:.6g}" for ev in charts) + " s)")
    else:
        print(f"chart: {traj.chart[0]} throughout")
    c = traj.counts
    print(
        f"work: {c['evaluations']} evaluations, {c['position_points']} position points in "
        f"{c['position_calls']} calls; CPU {cpu * 1e3:.1f} ms "
        f"({cpu / max(1, c['steps']) * 1e6:.1f} us a step)"
    )


def _reactions_summary(traj, observer) -> None:
    """``mps run --reactions``: the foundation load's peaks and the largest residuals."""
    import numpy as np

    f = np.hypot(traj["F_found_x"], traj["F_found_y"])
    print(
        f"reactions: foundation force peak {f.max():.6g} N, M_found_O peak "
        f"{np.abs(traj['M_found_O']).max():.6g} N*m; largest residuals: least squares "
        f"{traj['residual_force_N'].max():.3g} N, {traj['residual_moment_Nm'].max():.3g} "
        f"N*m, balance {traj['balance_residual_N'].max():.3g} N"
    )
    if observer.max_rank_deficiency:
        print(
            f"reactions: not unique at some steps (rank short by "
            f"{observer.max_rank_deficiency}): see the 'reactions-not-unique' events"
        )


def _say_coarse(traj, scene) -> None:
    """One warning (stderr) where the fixed-step solver's step is coarse for the run's
    fastest motion (see :func:`mps_core.run.trajectory.coarse_step`)."""
    from .run.trajectory import coarse_step

    s = scene.solver
    from .solvers import ADAPTIVE_SOLVERS

    if s.name in ADAPTIVE_SOLVERS:  # their steps follow their error estimates
        return
    said = coarse_step(traj, s.step if s.step is not None else scene.dt)
    if said:
        print(f"mps: warning: {said}", file=sys.stderr)


def _write_outputs(args, traj, stdout, failure: str | None = None, quiet: bool = False) -> list[str]:
    """Write ``--csv`` and ``--events``, each whole; return what was written, one phrase each.

    ``failure``: the run stopped with this error (or was interrupted), and what it computed is
    marked partial (the CSV's last line a ``# partial: ...`` comment, the event log's last row a
    ``run-failed`` event); ``stdout``: where ``-`` writes; ``quiet``: nothing printed."""
    import json

    from .files.outputs import written_whole

    t_last = float(traj.t[-1])
    note = "" if failure is None else f" (partial: up to t = {t_last:.6g} s, where the run stopped)"
    written = []
    if args.csv:
        with written_whole(args.csv, stdout) as tmp:
            if args.reactions:
                from .dynamics.reaction_csv import write_csv

                write_csv(traj, tmp)
            else:
                traj.to_csv(tmp)
            if failure is not None:
                with tmp.open("a") as fh:
                    fh.write(f"# partial: the run stopped at t = {t_last!r} s: {failure}\n")
        written.append(f"{len(traj)} rows in {_where(args.csv)}")
    if args.events:
        with written_whole(args.events, stdout) as tmp:
            traj.events_to_jsonl(tmp)
            if failure is not None:
                with tmp.open("a") as fh:
                    fh.write(json.dumps({"t": t_last, "kind": "run-failed", "error": failure}) + "\n")
        written.append(f"{len(traj.events)} events in {_where(args.events)}")
    if not quiet:
        for phrase in written:
            n, what, _in, where = phrase.split(" ", 3)
            print(f"wrote {n} {what} to {where}{note}")
    return written


def _where(path) -> str:
    """Name an output for a message (``-``: standard output)."""
    from .files.outputs import STDOUT

    return "standard output" if str(path) == STDOUT else str(path)


def _cache(action: str) -> int:
    """Say where the kernel cache is and what it holds (``mps cache info``), or empty it (``clear``)."""
    from .codegen import disk_cache

    store = disk_cache.store()
    if store is None:
        print("kernel cache: off (MPS_CACHE_DIR=off)")
        return 0
    if action == "clear":
        files, size = store.clear()
        print(f"kernel cache: removed {files} file(s), {size / 1024:.1f} KiB, from {store.folder}")
        return 0
    i = store.info()
    print(f"kernel cache: {i['folder']}")
    print(f"this version ({i['version']}): {i['entries']} entries, {i['bytes'] / 1024:.1f} KiB")
    print(
        f"all versions: {i['all_entries']} entries, {i['all_bytes'] / 1024:.1f} KiB "
        f"(bound {i['bound'] / 2**20:.0f} MiB)"
    )
    return 0


def main(argv=None) -> int:
    # a signal while the command starts (its imports take a third of a second or more) ends it with one
    # line, as one later does; the commands that handle their signals themselves then do so
    old = signal.signal(signal.SIGTERM, raise_interrupted)
    try:
        args = _parser().parse_args(argv)
    except KeyboardInterrupt as exc:
        print(f"mps: interrupted ({signal_name(exc)}) while starting: nothing done", file=sys.stderr)
        return 128 + int(getattr(signal, signal_name(exc)))
    if args.command not in INTERRUPTIBLE:
        signal.signal(signal.SIGTERM, old)
    try:
        if args.command == "run":
            return _run(args)
        if args.command == "scenes":
            from .scene import preset_names

            for n in preset_names():
                print(n)
            return 0
        if args.command == "cache":
            return _cache(args.action)
        if hasattr(args, "func"):
            return int(args.func(args) or 0)
    except MpsError as exc:
        print(f"mps: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # a file named on the command line (an output's folder)
        if exc.errno == errno.EPIPE and exc.filename == "-":
            # the reader of standard output stopped reading (``| head``): nothing to say, and
            # nothing more to flush into the closed pipe at exit
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return 0
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"mps: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        said = signal_name(exc)
        kept = getattr(exc, "kept", "") or ("nothing written" if args.command in WRITTEN_AT_THE_END else "")
        print(f"mps {args.command}: interrupted ({said})" + (f": {kept}" if kept else ""), file=sys.stderr)
        return 128 + int(getattr(signal, said))
    return 1


if __name__ == "__main__":
    sys.exit(main())
