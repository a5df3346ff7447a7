"""Benchmarks of the node (not tests): what the README reports, measured on this machine.

    .venv/bin/python -m mps_ros.bench [--steps 10000] [--json FILE]

1. **realtime, 1 kHz**: press-cycle at dt = 1 ms, realtime x1, recording on, for ``--steps``
   steps, with an external subscriber in another process taking every topic (reliable): the
   node's achieved real-time factor, step compute time p50/p99, latency (publication after the
   step's deadline) p50/p99, deadline misses per 10^4 steps, the messages a second the
   subscriber received, and the node's CPU a step: its own count (its process's CPU time over
   the run's steps) and, from outside, its user + system time in ``/proc`` over the wall time.
2. **as fast as possible**: the same scene and step, no subscriber, recording on and off: the
   largest real-time factor; and ``mps record`` (no ROS at all) for comparison.

``track``: the node following a press (:mod:`.track`, ``python -m mps_ros.bench track --help``).
``soak``: the realtime run for ``--minutes`` (memory, drift, messages lost); ``table``: the node
as fast as possible by outputs; ``wakeup``: the CPU one wake-up from a 1 ms timed wait costs a
thread on this machine (no ROS); ``writer``: the recording's MCAP writer against the ``mcap``
library's, CPU a message side by side (no ROS). Messages lost are counted by topic too: the recording holds
every message the node published, the subscriber counts what it received on each topic.
``--keep DIR`` keeps the realtime or soak run's logs (the node's, the subscriber's) and figures
there, which a run in the temporary folder otherwise takes with it.

Every process stays on loopback (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST unless set) with ROS
logs in a temporary folder; give it a ROS_DOMAIN_ID of its own. ``probe`` is the subscriber's
entry point (``python -m mps_ros.bench probe``). ``MPS_BENCH_NODE_PREFIX``, where set, is put
before the node's command line (split at spaces): a profiler, e.g.
``MPS_BENCH_NODE_PREFIX="perf record -e cpu-clock -F 10000 -o node.perf --"``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

from mps_core.derivatives import SCHEMES

from ..commands.demo import ros_env
from .costs import wakeup_costs, writer_costs
from .probe import probe
from .suite import PROBE_EXECUTOR, afap, keep_logs, loop_cost, publish_floor, realtime, record_only


def _lost_line(r: dict) -> str:
    if r.get("recording_error"):
        return f"  no messages by topic        {r['recording_error']}\n"
    lost = r.get("lost_by_topic")
    if not lost:
        return ""
    return "  published less received     " + ", ".join(f"{t} {n}" for t, n in lost.items()) + "\n"


def main(argv=None) -> int:
    args = sys.argv[1:] if argv is None else list(argv)
    if args[:1] == ["track"]:  # the node following a press: options of its own
        from .track import main as track_main

        return track_main(args[1:])
    a = _parser().parse_args(args)
    if a.what == "soak" and not a.minutes * 60.0 >= 10.0:
        print(
            f"python -m mps_ros.bench soak: --minutes {a.minutes:g}: expected at least 10 s "
            "(1/6 min): the node's memory is read at 5 s and at the end",
            file=sys.stderr,
        )
        return 2
    if a.what == "probe":
        return probe()
    if a.what == "wakeup":
        for name, us in wakeup_costs().items():
            print(f"{name:38s} {us:5.1f} us of CPU a wake-up (1 ms waits, this thread's own time)")
        return 0
    if a.what == "writer":
        return _writer()
    if a.what == "floor":
        return publish_floor(a.recording)
    env = ros_env()
    os.environ.update(
        {k: env[k] for k in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_LOG_DIR", "RMW_IMPLEMENTATION")}
    )
    res: dict[str, object] = {
        "machine": f"{os.cpu_count()} cores, load average "
        f"{' '.join(f'{x:.2f}' for x in os.getloadavg())} at the start"
    }
    with tempfile.TemporaryDirectory(prefix="mps-bench-") as d:
        tmp = Path(d)
        if a.what in ("all", "realtime"):
            res["realtime_1kHz"] = _realtime_run(a, env, tmp)
        if a.what == "table":
            res["table"] = _table(a, env, tmp)
        if a.what == "soak":
            res["soak"] = _soak(a, env, tmp)
        if a.what in ("all", "afap"):
            res["afap"] = _afap_runs(a, env, tmp)
    print(res["machine"])
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=2))
    return 0


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m mps_ros.bench",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "what",
        nargs="?",
        default="all",
        choices=("all", "realtime", "afap", "table", "soak", "wakeup", "writer", "probe", "floor"),
    )
    p.add_argument("recording", nargs="?", help="floor: the recording whose messages are published")
    p.add_argument(
        "--minutes",
        type=float,
        default=10.0,
        help="length of the soak run (default 10): realtime, every output, a "
        "subscriber; RSS at 5 s and at the end, drift, messages lost",
    )
    p.add_argument("--steps", type=int, default=10_000, help="steps of the realtime run")
    p.add_argument("--afap-steps", type=int, default=5_000, help="steps of each AFAP run")
    p.add_argument("--json", help="write the figures to this file")
    p.add_argument(
        "--keep",
        metavar="DIR",
        type=Path,
        help="keep the realtime or soak run's logs (the node's, the subscriber's) and figures in DIR",
    )
    _node_arguments(p.add_argument_group("the node's settings"))
    _beside_arguments(p.add_argument_group("beside the node: the machine's load, the subscriber"))
    return p


def _node_arguments(p) -> None:
    """The benchmark's arguments that set the node's parameters."""
    p.add_argument(
        "--outputs", metavar="LIST", help="the realtime run's outputs, comma-separated (default: all)"
    )
    p.add_argument(
        "--publish-every",
        type=int,
        default=1,
        metavar="N",
        help="the realtime run publishes every N-th step (default 1)",
    )
    p.add_argument(
        "--priority",
        type=int,
        default=None,
        metavar="P",
        help="the node's realtime_priority (default: the node's; 0: normal "
        "scheduling; 1-99: its stepping process and publishing thread under "
        "SCHED_FIFO, where allowed)",
    )
    p.add_argument(
        "--lead",
        type=float,
        default=None,
        metavar="S",
        help="the node's lead: steps computed up to S wall seconds ahead of their "
        "deadlines (default: the node's, 0.1; 0: one step's period, none "
        "banked)",
    )
    p.add_argument(
        "--release-period",
        type=float,
        default=None,
        metavar="S",
        help="the node's release_period: the steps due go out together about once "
        "per S wall seconds, each at most S less one step's period late (default: "
        "the node's, 0: each step at its deadline, one wake-up a step)",
    )
    p.add_argument(
        "--release-slice",
        type=float,
        default=None,
        metavar="S",
        help="the node's release_slice: the publishing thread's scheduler slice "
        "(default: the node's, 0.0001; 0: none asked)",
    )
    p.add_argument(
        "--derivatives",
        choices=SCHEMES,
        default=None,
        help="the node's derivatives (default: the scene's)",
    )
    p.add_argument(
        "--in-process",
        action="store_true",
        help="the node steps in its own process (stepping_process:=false) instead "
        "of a stepping process of its own",
    )
    p.add_argument(
        "--command-delay",
        type=float,
        default=None,
        metavar="S",
        help="the node's command_delay (default: the node's, 0.05 s)",
    )


def _beside_arguments(p) -> None:
    """The benchmark's arguments for what runs beside the node."""
    p.add_argument(
        "--neighbours",
        type=int,
        default=0,
        metavar="N",
        help="run N pure-Python busy loops beside the node for the whole realtime or soak run (default 0)",
    )
    p.add_argument(
        "--commands-every",
        type=float,
        default=None,
        metavar="S",
        help="realtime: the subscriber also sends engage, disengage, stop, start in "
        "turn on ~/mode, one every S wall seconds (the scene's own commands off)",
    )
    p.add_argument(
        "--flood",
        type=int,
        default=0,
        metavar="N",
        help="realtime: the subscriber sends N engage at once, 2 s into the run "
        "(the scene's own commands off)",
    )
    p.add_argument(
        "--foxglove",
        choices=("client", "slow"),
        help="realtime: the node's Foxglove endpoint on, with one client taking every channel (client), or "
        "one that cannot keep up, a message a millisecond at most (slow)",
    )
    p.add_argument(
        "--events-executor",
        action="store_true",
        help="probe: spin rclpy's events executor (the realtime run's subscriber "
        "does unless MPS_BENCH_EXECUTOR=single)",
    )
    p.add_argument(
        "--deserialize",
        action="store_true",
        help="the subscriber deserializes every message into a Python object "
        "(default: it takes them serialized, as delivered)",
    )


def _writer() -> int:
    """``writer``: the recordings' MCAP writer against the mcap library's, side by side."""
    r = writer_costs()
    print(
        f"the recording's MCAP writer, {r['messages']} messages of press-cycle at 1 kHz "
        f"({r['per_step']:.0f} a step), zstd chunks of 512 KiB, best of 5, CPU:\n"
        f"  mps_ros.recording.mcap_writer.McapWriter   {r['mps_us']:5.2f} us a message\n"
        f"  the mcap library's Writer         {r['mcap_us']:5.2f} us a message "
        f"({r['mcap_us'] / r['mps_us']:.1f}x)\n"
        f"  the same bytes                    {'yes' if r['same_bytes'] else 'NO'}"
    )
    return 0 if r["same_bytes"] else 1


def _node_settings(a) -> dict:
    """The realtime and soak runs' settings from the command line, as :func:`realtime`'s
    keywords."""
    return dict(
        deserialize=a.deserialize,
        outputs=a.outputs,
        publish_every=a.publish_every,
        priority=a.priority,
        lead=a.lead,
        release_period=a.release_period,
        derivatives=a.derivatives,
        release_slice=a.release_slice,
        n_neighbours=a.neighbours,
        in_process=a.in_process,
    )


def _realtime_run(a, env, tmp: Path) -> dict:
    """``realtime``: the run and its figures, printed."""
    r = realtime(
        a.steps,
        env,
        tmp,
        **_node_settings(a),
        commands_every=a.commands_every,
        command_delay=a.command_delay,
        flood=a.flood,
        foxglove=a.foxglove or "",
    )
    if a.keep:
        keep_logs(tmp, a.keep, "realtime", r)
    _print_realtime(a, r)
    return r


def _print_realtime(a, r: dict) -> None:
    how = "deserializing" if a.deserialize else "taking them serialized"
    scheme = a.derivatives or "the scene's (autodiff)"
    print(
        f"realtime, 1 kHz, {a.steps} steps, recording on, outputs "
        f"{a.outputs or 'all'}, publishing every {a.publish_every}, one external "
        f"subscriber ({how}, rclpy's {PROBE_EXECUTOR} executor), "
        f"{'stepping in the node process' if a.in_process else 'a stepping process'}"
        f", {a.neighbours} busy neighbour process(es), "
        f"realtime_priority {'40 (default)' if a.priority is None else a.priority}, lead "
        f"{'0.1 (default)' if a.lead is None else a.lead} s, release_period "
        f"{'0 (default)' if a.release_period is None else a.release_period} s, "
        f"release_slice {'0.0001 (default)' if a.release_slice is None else a.release_slice}"
        f" s, derivatives {scheme}"
        + (f", an operator command every {a.commands_every:g} s" if a.commands_every else "")
        + (
            f", a flood of {a.flood} engage at once 2 s in (sent in {r.get('flood_s') or float('nan'):.3f} s)"
            if a.flood
            else ""
        )
        + (
            f", command_delay {'0.05 (default)' if a.command_delay is None else a.command_delay} s"
            if a.commands_every or a.flood
            else ""
        )
        + ":\n"
        f"  priority the node got       {r['priority'] or 'normal (SCHED_OTHER)'}"
        f"{' (SCHED_FIFO)' if r['priority'] else ''}\n"
        f"  achieved real-time factor   {r['rtf']:.3f}\n"
        f"  step compute p50 / p99      {r['step_p50_ms']:.3f} / "
        f"{r['step_p99_ms']:.3f} ms\n"
        f"  publish p50 / p99           {r['publish_p50_ms']:.3f} / "
        f"{r['publish_p99_ms']:.3f} ms\n"
        f"  latency p50 / p99           {r.get('latency_p50_ms', float('nan')):.3f} / "
        f"{r.get('latency_p99_ms', float('nan')):.3f} ms (publication after the "
        f"step's deadline)\n"
        f"  deadline misses             {r['misses_per_1e4']:.0f} per 10^4 steps\n"
        + (
            f"  commands                    {r['commands_applied']} applied, "
            f"{r['commands_refused']} refused\n"
            if a.commands_every or a.flood
            else ""
        )
        + _foxglove_line(r)
        + f"  subscriber received         {r['subscriber_msgs_per_s']:.0f} messages/s "
        f"({r['subscriber_received']} of {r['messages']} published)\n"
        + _lost_line(r)
        + f"  the subscriber's CPU        {100 * r['subscriber_cpu_share']:.0f} % of one core\n"
        f"  stepping thread CPU         {r['step_thread_cpu_us']:.0f} us a step "
        f"({r['step_thread_cpu_us'] / 10:.1f} % of the 1 ms period)\n"
        f"  publishing thread's slice   {r['release_slice_ms']:.3g} ms as granted "
        f"(0: the system's own)\n"
        f"  node process CPU            {r['process_cpu_us']:.0f} us a step over "
        f"the run's steps (the node's own count: every thread of its "
        f"{r['node_processes']} process(es); not the recording process)"
        + (
            f": stepping process {r['stepping_process_cpu_us']:.0f} us, ROS process "
            f"{r['ros_process_cpu_us']:.0f} us\n"
            f"{'':30s}stepping process {r['stepping_process_cpu_us'] / r['loop_us']:.2f}× "
            f"the same steps' work in a plain loop here ({r['loop_us']:.0f} us a step: stepped, "
            f"messages made, checkpoint; no ROS, no waiting)\n"
            f"{'':30s}ROS process {r['ros_process_cpu_us'] / r['ros_floor_us']:.2f}× "
            f"the floor here ({r['ros_floor_us']:.0f} us a step: rclpy publishing the same "
            f"serialized messages to the same subscriber in a bare loop)"
            if r["stepping_process_cpu_us"] == r["stepping_process_cpu_us"]
            else ""
        )
        + "\n"
        f"                              {r['process_cpu_us'] / r['loop_us']:.2f}× the "
        f"same steps' work in a plain loop here (the whole node)\n"
        f"                              {r['cpu_per_step_us']:.0f} us a step from "
        f"outside ({100 * r['cpu_share']:.0f} % of one core, /proc from 0.2 s after "
        f"the start to the run's end); the recording process "
        f"{100 * r['recorder_cpu_share']:.0f} %\n"
        f"  the node's threads (/proc; CPU a step, context switches a step: "
        f"voluntary, involuntary):\n"
        + "".join(
            f"    {t['thread']:<22s}{t['cpu_us']:6.0f} us  {t['voluntary']:5.2f}  {t['involuntary']:5.2f}\n"
            for t in r["threads"]
        ).rstrip("\n"),
        flush=True,
    )


def _foxglove_line(r: dict) -> str:
    """The Foxglove client's figures, where there was one."""
    f = r.get("foxglove")
    if not f:
        return ""
    rate = f["received"] / f["span_s"] if f["span_s"] else float("nan")
    return (
        f"  foxglove client received    {f['received']} of the {f['recorded']} messages recorded "
        f"({rate:.0f} a second over {f['span_s']:.2f} s), its CPU {f['cpu_s']:.2f} s\n"
    )


def _table(a, env, tmp: Path) -> list:
    """``table``: the node as fast as possible by outputs."""
    rows = []
    from ..wire.topics import OUTPUTS

    no_markers = ",".join(o for o in OUTPUTS if o != "markers")
    for label, outs, rec in (
        ("joint_states, clock", "joint_states,clock", False),
        ("every output but markers, recording", no_markers, True),
        ("every output, no recording", None, False),
        ("every output, recording", None, True),
    ):
        r = afap(rec, env, tmp, a.afap_steps, outs)
        rows.append(dict(r, outputs=label))
    print(
        f"the node as fast as possible, no subscriber, {a.afap_steps} steps of "
        f"press-cycle at 1 kHz:\n"
        f"  | outputs | step p50 | publish p50 | real-time factor |\n"
        f"  |---|---|---|---|"
    )
    for r in rows:
        print(
            f"  | {r['outputs']} | {r['step_p50_ms']:.3f} ms | "
            f"{r['publish_p50_ms']:.3f} ms | {r['rtf']:.2f} |",
            flush=True,
        )
    return rows


def _soak(a, env, tmp: Path) -> dict:
    """``soak``: the long realtime run."""
    steps = int(round(a.minutes * 60_000))
    r = realtime(steps, env, tmp, **_node_settings(a))
    if a.keep:
        keep_logs(tmp, a.keep, "soak", r)
    print(
        f"soak: realtime, 1 kHz, {steps} steps ({a.minutes:g} min), "
        f"{a.neighbours} busy neighbour(s), priority {r['priority']}, recording on, "
        f"every output, one external subscriber:\n"
        f"  node RSS                    {r['rss_start_mb']:.1f} MB at 5 s, "
        f"{r['rss_end_mb']:.1f} MB at the end "
        f"({r['rss_end_mb'] - r['rss_start_mb']:+.1f} MB)\n"
        f"  simulated vs wall drift     {r['drift_ms']:.2f} ms (wall behind simulated: "
        f"the lowest offset of the subscriber's /clock over the last 5 s against the "
        f"first 5 s; first message against last "
        f"{r.get('drift_end_to_end_ms', float('nan')):.2f} ms)\n"
        f"  messages                    {r['messages']} published, "
        f"{r['subscriber_received']} received "
        f"({r['messages'] - r['subscriber_received']} lost)\n"
        + _lost_line(r)
        + f"  real-time factor            {r['rtf']:.4f}, deadline misses "
        f"{r['misses_per_1e4']:.1f} per 10^4 steps, latency p99 "
        f"{r.get('latency_p99_ms', float('nan')):.2f} ms\n"
        f"  CPU                         stepping thread {r['step_thread_cpu_us']:.0f} "
        f"us a step, node process {r['process_cpu_us']:.0f} us a step (its own "
        f"count over the run's steps; {100 * r['cpu_share']:.0f} % of one core from "
        f"outside), recording process {100 * r['recorder_cpu_share']:.0f} %",
        flush=True,
    )
    return r


def _afap_runs(a, env, tmp: Path) -> dict:
    """``afap``: the node as fast as possible with and without recording, and mps record."""
    on = afap(True, env, tmp, a.afap_steps)
    off = afap(False, env, tmp, a.afap_steps)
    one = afap(True, env, tmp, a.afap_steps, in_process=True)
    rec = record_only(tmp, a.afap_steps)
    plain = loop_cost(min(a.afap_steps, 3000))
    print(
        f"as fast as possible, 1 kHz steps, {a.afap_steps} steps, no subscriber:\n"
        f"  node, recording on          real-time factor {on['rtf']:.2f}\n"
        f"  node, recording off         real-time factor {off['rtf']:.2f}\n"
        f"  node, recording on, stepping in the node's process (stepping_process:=false)\n"
        f"                              real-time factor {one['rtf']:.2f}\n"
        f"  mps record (no ROS)         real-time factor {rec['rtf']:.2f}\n"
        f"  the plain loop of the same steps: {plain:.0f} us a step, "
        f"{1e3 / plain:.2f}x real time by itself",
        flush=True,
    )
    return {
        "recording_on": on,
        "recording_off": off,
        "recording_on_in_process": one,
        "mps_record": rec,
        "plain_loop_us": plain,
    }


if __name__ == "__main__":
    sys.exit(main())
