"""The node following a press, measured: ``python -m mps_ros.bench track`` (not a test).

    python -m mps_ros.bench track [--scene working] [--seconds 10] [--sigma-every 1,10]
                                  [--neighbours 0] [--slider] [--modes] [--json FILE]

For each ``--sigma-every`` (the node's ``track_sigma_every``), ``mps node SCENE`` follows
``mps emulator SCENE`` (a 17-bit encoder at 1 kHz, its truth off the nominal press; with ``--slider``
its slider scale too, and with ``--modes`` the node follows the press's mode signals,
``track_mode``) for ``--seconds``, with ``--neighbours`` busy processes beside them; the node's
last line gives what it measured itself: the measurements received and the estimates published,
the CPU a measurement of the thread that takes it (p50, p99) and of the whole process (its CPU
time over the measurements), the delay from a measurement's arrival to its estimate published
(p50, p99, max), the estimates later than 1 ms and those taken but not published (over
``track_max_behind`` behind). Beside each run, in this process and on the same machine at the
same time, the *plain loop*: the same tracking run over the same kind of measurements with no
ROS at all (:class:`~mps_ros.run.tracking.TrackingRun` into a sink that drops the messages), CPU
a measurement; the node's process CPU over it is the cost of following through ROS.

Every process stays on loopback (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST unless set); give
the command a ROS_DOMAIN_ID of its own.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from ..commands.demo import ros_env, stop_group
from .processes import neighbours

__all__ = ["main", "node_figures", "plain_run", "track_run"]

_SUMMARY = re.compile(
    r"tracking run .*? at t = [\d.e+-]+ s: (\d+) measurements received, (\d+) estimates published, "
    r"rejected: (.*?); CPU a measurement p50 ([\d.e+-]+|nan) ms, p99 ([\d.e+-]+|nan) ms "
    r"\(the process's ([\d.e+-]+|nan) ms\); published after its arrival p50 ([\d.e+-]+|nan) ms, "
    r"p99 ([\d.e+-]+|nan) ms, max ([\d.e+-]+|nan) ms, (\d+) estimates over [\d.e+-]+ ms, "
    r"(\d+) taken but not published"
)


def node_figures(log: str) -> dict:
    """Return the figures of a tracking node's last line (its log ``log``)."""
    m = _SUMMARY.search(log)
    if m is None:
        raise RuntimeError("no tracking run's summary in the node's log:\n" + log[-3000:])
    g = m.groups()
    return {
        "received": int(g[0]),
        "estimates": int(g[1]),
        "rejected": g[2],
        "cpu_p50_ms": float(g[3]),
        "cpu_p99_ms": float(g[4]),
        "process_cpu_ms": float(g[5]),
        "delay_p50_ms": float(g[6]),
        "delay_p99_ms": float(g[7]),
        "delay_max_ms": float(g[8]),
        "late": int(g[9]),
        "skipped": int(g[10]),
    }


def plain_run(
    scene: str,
    sigma_every: int,
    measurements: int = 2000,
    seed: int = 0,
    slider: bool = False,
    modes: bool = False,
    prepared: bool = False,
) -> tuple[Any, float]:
    """Return the node's tracking run with no ROS (the messages dropped) and its CPU ms a measurement.

    The truth of ``scene`` read by its encoder (and its slider scale: ``slider``) for
    ``measurements`` samples; each taken by a :class:`~mps_ros.run.tracking.TrackingRun` into a
    sink that keeps nothing, the truth's mode signals given before the first sample at or after
    their time where ``modes`` (the node's ``track_mode``, searched for as its default
    ``track_signal_latency`` has it). ``prepared``: made ready as the node's run is before
    the measurements are timed (its warm-up, about 1 s, and the garbage collector's freeze, which
    holds for the rest of this process).
    """
    from mps_core import load_scene
    from mps_core.track import Sensors, TrackSettings, run_truth, truth_scene
    from mps_core.track.settings import SIGNAL_LATENCY
    from mps_core.track.truth import nominal_scene

    from ..run.sinks import Fanout, Sink
    from ..run.tracking import TrackingRun

    class Dropped(Sink):
        live = True

        def emit_all(self, msgs) -> None:
            pass

    nominal = nominal_scene(load_scene(scene))
    truth = run_truth(truth_scene(nominal), measurements * 1e-3, sensors=Sensors(slider=slider), seed=seed)
    settings = TrackSettings(signal_latency=SIGNAL_LATENCY if modes and truth.modes else 0.0)
    run = TrackingRun(
        nominal,
        Fanout([Dropped()]),
        settings=settings,
        sigma_every=sigma_every,
        freeze_gc=prepared,
        fit_elsewhere=True,
    )
    if prepared:
        run.prepare()
    stamps = len({m.t for m in truth.measurements})
    offset = time.monotonic() - truth.measurements[0].t  # the press's clock on the wall clock
    t0 = time.thread_time()
    run.take_all(truth.measurements, truth.modes if modes else [], offset)
    cpu_ms = (time.thread_time() - t0) / max(stamps, 1) * 1e3
    run.finish_fits()
    run.close()
    return run, cpu_ms


def track_run(
    scene: str,
    seconds: float,
    sigma_every: int,
    env: dict,
    tmp: Path,
    slider: bool = False,
    modes: bool = False,
) -> dict:
    """Return the figures of ``mps node SCENE`` following ``mps emulator SCENE`` for ``seconds``.

    ``slider``: the press's slider scale too; ``modes``: its mode signals followed.
    """
    log = tmp / f"node-{sigma_every}.log"
    cli = [sys.executable, "-m", "mps_core.cli"]
    node = subprocess.Popen(
        [
            *cli,
            "node",
            scene,
            "--ros-args",
            "-p",
            "track:=/press/joint_states",
            "-p",
            f"track_sigma_every:={sigma_every}",
            *(["-p", "track_mode:=/press/mode"] if modes else []),
        ],
        env=env,
        stdout=open(log, "wb"),
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    try:
        # the emulator waits for its subscriber: it starts when the node follows
        emulator = subprocess.run(
            [*cli, "emulator", scene, "--t-end", str(seconds), *(["--slider"] if slider else [])],
            env=env,
            capture_output=True,
            text=True,
            timeout=seconds + 600.0,
        )
        if emulator.returncode != 0:
            raise RuntimeError("mps emulator failed:\n" + emulator.stdout[-2000:] + emulator.stderr[-2000:])
        time.sleep(0.5)
        node.send_signal(signal.SIGINT)
        node.wait(60.0)
    finally:
        stop_group(node)
    return node_figures(log.read_text(errors="replace"))


def main(argv: list[str] | None = None) -> int:
    """Run the tracking benchmark and print its table."""
    p = argparse.ArgumentParser(
        prog="python -m mps_ros.bench track",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--scene", default="working", help="the press followed (default working)")
    p.add_argument("--seconds", type=float, default=10.0, help="seconds of the press's run (default 10)")
    p.add_argument(
        "--sigma-every",
        default="1,10",
        metavar="LIST",
        help="the node's track_sigma_every values, comma-separated (default 1,10)",
    )
    p.add_argument("--neighbours", type=int, default=0, help="busy processes beside the node (default 0)")
    p.add_argument("--slider", action="store_true", help="the press's slider scale too (emulator --slider)")
    p.add_argument("--modes", action="store_true", help="the node follows the press's mode signals")
    p.add_argument("--json", help="write the figures to this file")
    a = p.parse_args(argv)
    try:
        everys = [int(x) for x in a.sigma_every.split(",")]
    except ValueError:
        p.error(f"--sigma-every = {a.sigma_every!r}: expected integers >= 1, comma-separated")
    if not everys or min(everys) < 1:
        p.error(f"--sigma-every = {a.sigma_every!r}: expected integers >= 1, comma-separated")
    env = ros_env()
    machine = (
        f"{os.cpu_count()} cores, load average {' '.join(f'{x:.2f}' for x in os.getloadavg())} at the start, "
        f"{a.neighbours} busy neighbour(s)"
    )
    rows = []
    busy = neighbours(a.neighbours)
    try:
        with tempfile.TemporaryDirectory(prefix="mps-bench-track-") as d:
            for every in everys:
                fig = track_run(a.scene, a.seconds, every, env, Path(d), a.slider, a.modes)
                fig["sigma_every"] = every
                fig["plain_loop_ms"] = plain_run(
                    a.scene, every, slider=a.slider, modes=a.modes, prepared=True
                )[1]
                rows.append(fig)
    finally:
        for n in busy:
            stop_group(n)
    sensors = " with its slider scale" if a.slider else ""
    followed = ", its mode signals followed" if a.modes else ""
    what = f"mps node {a.scene} following mps emulator {a.scene}{sensors} at 1 kHz for {a.seconds:g} s"
    print(what + followed)
    print(
        f"{'sigma every':>11s} {'received':>8s} {'published':>9s} {'CPU p50/p99 ms':>15s} "
        f"{'process ms':>10s} {'plain loop ms':>13s} {'delay p50/p99/max ms':>21s} "
        f"{'late':>6s} {'skipped':>7s}"
    )
    for r in rows:
        print(
            f"{r['sigma_every']:11d} {r['received']:8d} {r['estimates']:9d} "
            f"{r['cpu_p50_ms']:7.3f}/{r['cpu_p99_ms']:<7.3f} {r['process_cpu_ms']:10.3f} "
            f"{r['plain_loop_ms']:13.3f} {r['delay_p50_ms']:6.3f}/{r['delay_p99_ms']:<6.3g}/"
            f"{r['delay_max_ms']:<7.3g} {r['late']:6d} {r['skipped']:7d}"
        )
    print(machine)
    if a.json:
        Path(a.json).write_text(json.dumps({"machine": machine, "runs": rows}, indent=2))
    return 0
