"""``mps`` subcommands of the ROS face and the recordings (a plugin of :mod:`mps_core.cli`).

    mps node [SCENE] [--ros-args ...]             the ROS 2 node press_twin (needs rclpy)
    mps operator [SCENE] [--at T:WORD ...]        send mode commands at simulated times
    mps demo [SCENE]                              node + operator, realtime, recorded (make run)
    mps record SCENE --out FILE.mcap|BAG          the node's recording without ROS
    mps recover IN.mcap|BAG [OUT]                 complete a recording cut short (SIGKILL)

Nothing here is imported before its subcommand runs: ``mps`` starts fast and works without
rclpy (``node``, ``operator`` and ``demo`` then say what to install).
"""

from __future__ import annotations

import argparse
import math
import sys

ROS_MISSING = (
    "mps: error: this command needs ROS 2 Jazzy's rclpy: install the ros extra "
    "(pip install -e '.[ros]', or `make run`)"
)


def _ros_import(modname):
    """Import the ROS module ``modname``, this process's ROS environment set first; None (and
    what to install, said) where ROS is missing."""
    import importlib

    from ..ros.environment import env_defaults

    env_defaults()
    try:
        return importlib.import_module(modname)
    except ImportError as exc:
        if "rclpy" in str(exc) or "_msgs" in str(exc) or "std_srvs" in str(exc):
            print(ROS_MISSING, file=sys.stderr)
            print(f"    ({exc})", file=sys.stderr)
            return None
        raise


def _node(args) -> int:
    mod = _ros_import("mps_ros.ros.node")
    if mod is None:
        return 2
    argv = ([args.scene] if args.scene else []) + (["--ros-args", *args.ros_args] if args.ros_args else [])
    return mod.main(argv)


def _operator(args) -> int:
    """Check the schedule, then start the operator (rclpy); SIGINT and SIGTERM from here on
    end it with one line (``mps_ros.ros.operator``)."""
    import signal

    if args.at:
        try:
            schedule = sorted(_at_command(item) for item in args.at)
        except ValueError as exc:  # one line, as a bad scene's (no usage: nothing else is wrong)
            print(f"mps operator: error: argument --at: {exc}", file=sys.stderr)
            return 2
    else:
        from mps_core import load_scene

        schedule = sorted((float(t), w) for t, w in load_scene(args.scene).commands)
    stop: dict = {"signum": None}

    def on_signal(signum, _frame):
        stop["signum"] = signum

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        mod = _ros_import("mps_ros.ros.operator")
        if mod is None:
            return 2
        return mod.run_operator(args, schedule, stop)
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def _demo(args) -> int:
    from . import demo

    return demo.main(args)


def _outputs(text):
    from ..wire.topics import OUTPUTS

    if text is None:
        return OUTPUTS
    return tuple(x for x in text.replace(",", " ").split() if x)


def _record(args) -> int:
    import os
    from pathlib import Path

    from mps_core.files.outputs import check_outputs

    from ..recording.bag import is_bag
    from ..run.record import record

    bag = is_bag(args.out)
    check_outputs(
        {"recording": args.out}, inputs=[args.scene], force=args.force, folders={"recording"} if bag else ()
    )
    if not bag and (args.max_mb or args.max_s):
        print(
            f"mps: error: --max-mb and --max-s split a bag: {args.out!r} ends in .mcap (one "
            "file); expected a directory path",
            file=sys.stderr,
        )
        return 2
    out = Path(args.out)
    # a recording replaced (--force) is replaced only by one that finished: the new one is
    # written under a temporary name beside it until then
    replacing = not bag and out.exists()
    target = out.with_name(f".{out.stem}.{os.getpid()}.partial{out.suffix}") if replacing else out

    def log(level, text):
        if level == "error" and text.startswith("the run stopped at"):
            return  # said in the command's last line, with what was kept
        if level != "info" or args.verbose:
            print(f"[{level}] {text}", file=sys.stderr)

    try:
        path, stats, counts = record(
            args.scene,
            target,
            dt=args.dt,
            t_end=args.t_end,
            outputs=_outputs(args.outputs),
            publish_every=args.publish_every,
            pacing=args.pacing,
            real_time_factor=args.real_time_factor,
            scene_commands=not args.no_scene_commands,
            log=log,
            progress=not args.quiet,
            compression=args.compression,
            max_bytes=int(args.max_mb * 1e6),
            max_s=args.max_s,
            file_name=out.name,
        )
    except ValueError as exc:
        _drop(target, replacing)
        print(f"mps: error: {exc}", file=sys.stderr)
        return 2
    except BaseException as exc:  # the run failed: what it recorded is kept, the old file too
        kept = _keep(target, out, replacing)
        if kept is None:
            raise
        if isinstance(exc, KeyboardInterrupt):  # before the run's own handlers were set
            print(f"mps record: interrupted (SIGINT); {_kept_line(kept, out, replacing)}", file=sys.stderr)
            return 130
        print(f"mps: error: {exc}; {_kept_line(kept, out, replacing)}", file=sys.stderr)
        said = getattr(exc, "record_stats", None)  # what the run did up to its error (record())
        if said:
            _say_coarse(said)
        return 2
    reason = stats["stop_reason"]
    if stats["recording_failure"] is not None:
        kept = _keep(target, out, replacing) or target
        why = stats["recording_failure"].removeprefix(f"recording {str(target)!r}: ")
        print(
            f"mps record: error: recording {str(kept)!r} stopped at t = "
            f"{stats['recording_failed_at']:.6g} s: {why}; "
            f"{_kept_line(kept, out, replacing, cut_short=True)}",
            file=sys.stderr,
        )
        return 1
    if reason in ("SIGINT", "SIGTERM"):
        kept = _keep(target, out, replacing) or target
        print(
            f"mps record: interrupted ({reason}) at t = {stats['t']:.6g} s after {stats['steps']} "
            f"steps; {_kept_line(kept, out, replacing)}",
            file=sys.stderr,
        )
        return 128 + int(getattr(__import__("signal"), reason))
    if replacing:
        os.replace(target, out)
        path = out
    total = sum(counts.values())
    print(
        f"recorded {stats['steps']} steps to t = {stats['sim_time']:g} s in "
        f"{stats['wall_time']:.3g} s (real-time factor {stats['real_time_factor']:.3g}): "
        f"{total} messages on {sum(1 for n in counts.values() if n)} topics -> {path}"
    )
    for topic, n in sorted(counts.items()):
        print(f"  {topic:32s} {n}")
    _say_coarse(stats)
    return 0


def _drop(target, replacing: bool) -> None:
    """Remove the temporary recording of a run that did not start (the old file stays)."""
    import contextlib
    import os

    if replacing:
        with contextlib.suppress(OSError):
            os.unlink(target)


def _keep(target, out, replacing: bool):
    """Return where a recording that did not finish its run is kept (None: nothing was).

    Where it was to replace ``out``, it goes beside it under a name of its own
    (``NAME-partial.mcap``, ``-partial-2``...), and ``out`` stays as it was."""
    import os
    from pathlib import Path

    from ..recording.recorder import reserve_free

    target = Path(target)
    if not target.exists():
        return None
    if not replacing:
        return target
    # a name of its own, claimed empty first: the rename then replaces nothing of anyone's
    kept = reserve_free(out.with_name(f"{out.stem}-partial{out.suffix}"))
    os.replace(target, kept)
    return kept


def _kept_line(kept, out, replacing: bool, cut_short: bool = False) -> str:
    """Say what a recording that did not finish its run keeps, and where."""
    from ..recording.recover import intact

    try:
        got = intact(kept)
    except (OSError, ValueError):
        got = None
    if got is None or not got.messages:
        what = f"{str(kept)!r} holds no message"
    else:
        what = f"{str(kept)!r} keeps {got.messages} messages to t = {got.end_ns * 1e-9:.6g} s" + (
            "" if got.complete else " in its whole chunks"
        )
    if cut_short and got is not None and not got.complete:
        what += f" (complete it with `mps recover {kept} OUT.mcap` where there is room)"
    if replacing:
        what += f"; {str(out)!r} is as it was"
    return what


def _say_coarse(stats) -> None:
    """Warn (stderr) where the run's step was coarse for its fastest motion, as ``mps run``."""
    from mps_core.run.trajectory import coarse_for_rate
    from mps_core.solvers import ADAPTIVE_SOLVERS

    if stats["solver"] in ADAPTIVE_SOLVERS:  # their steps follow their error estimates
        return
    said = coarse_for_rate(max(stats["fastest_rates"]), stats["solver_step"])
    if said:
        print(f"mps: warning: {said}", file=sys.stderr)


def _recover(args) -> int:
    from pathlib import Path

    from mps_core.files.inputs import MCAP_MAGIC, check_file
    from mps_core.files.outputs import check_outputs, written_whole

    from ..recording.recover import recover

    if Path(args.input).is_dir():
        return _recover_bag(args)
    src = check_file(args.input, "recording", MCAP_MAGIC, "an MCAP file")
    dst = Path(args.output) if args.output else src.with_name(src.stem + "-recovered.mcap")
    check_outputs({"output": dst}, inputs=[src], force=args.force)
    try:
        # whole or not at all: a disk that fills up leaves no half-written file behind
        with written_whole(dst) as tmp:
            rep = recover(src, tmp, name=dst.name)
            if not rep.messages:  # an empty recording is no recovery: nothing is written
                raise ValueError(_nothing_to_recover(src, rep))
    except OSError as exc:  # the disk full: nothing of OUT is left behind
        print(f"mps: error: output {str(dst)!r}: {exc.strerror or exc}; nothing written", file=sys.stderr)
        return 2
    except ValueError as exc:
        print(f"mps: error: {exc}", file=sys.stderr)
        return 2
    state = "complete" if rep.complete else (f"cut short at byte {rep.truncated_at} of {src.stat().st_size}")
    print(
        f"{src}: {state}; {rep.chunks} whole chunks, {rep.messages} messages on "
        f"{len(rep.topics)} topics -> {dst}"
    )
    return 0


def _nothing_to_recover(src, rep) -> str:
    """Say that ``src`` holds no whole chunk, so no message, to recover."""
    return (
        f"recording {str(src)!r}: no message to recover ({rep.chunks} whole chunks"
        + ("" if rep.truncated_at is None else f", cut short at byte {rep.truncated_at}")
        + "); nothing written"
    )


def _recover_bag(args) -> int:
    """``mps recover BAG [OUT]``: every file of a bag recovered into a new bag, written under
    a temporary name beside it and renamed once whole."""
    import shutil
    from pathlib import Path

    from mps_core.files.outputs import check_outputs, partial_name

    from ..recording.recover import recover_bag

    src = Path(args.input)
    dst = Path(args.output) if args.output else src.with_name(src.name + "-recovered")
    check_outputs({"output": dst}, inputs=[src], folders={"output"})
    tmp = partial_name(dst)
    try:
        rep = recover_bag(src, tmp, name=dst.name)
        if not rep.messages:
            raise ValueError(_nothing_to_recover(src, rep))
        tmp.replace(dst)
    except BaseException as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(exc, OSError):
            print(f"mps: error: output {str(dst)!r}: {exc.strerror or exc}; nothing written", file=sys.stderr)
            return 2
        if isinstance(exc, ValueError):
            print(f"mps: error: {exc}", file=sys.stderr)
            return 2
        raise
    state = "complete" if rep.complete else "cut short"
    print(
        f"{src}: {state}; {rep.chunks} whole chunks, {rep.messages} messages on "
        f"{len(rep.topics)} topics -> {dst}"
    )
    return 0


def _positive(text):
    v = float(text)
    if not (v > 0 and math.isfinite(v)):
        raise argparse.ArgumentTypeError(f"{text}: expected a positive number")
    return v


def _at_command(text):
    """Parse ``--at T:WORD``: a time in seconds >= 0 and a command word the node knows (else
    ValueError naming the value, the part at fault and what was expected)."""
    from mps_core.scene.settings import COMMANDS

    t_text, colon, word = text.partition(":")
    if not colon:
        raise ValueError(f"{text!r}: expected T:WORD, e.g. 0.008:engage")
    try:
        t = float(t_text)
    except ValueError:
        t = math.nan
    if not (math.isfinite(t) and t >= 0):
        raise ValueError(f"{text!r}: T = {t_text.strip()!r}: expected a time in seconds >= 0")
    word = word.strip()
    if word not in COMMANDS:
        raise ValueError(f"{text!r}: WORD = {word!r}: expected one of " + ", ".join(COMMANDS))
    return t, word


def _count(text):
    try:
        v = int(text)
    except ValueError:
        v = 0
    if v < 1:
        raise argparse.ArgumentTypeError(f"{text}: expected an integer >= 1")
    return v


def register(sub) -> None:
    """The ROS commands of ``mps``: node, operator, demo, record, recover."""
    _register_node(sub)
    _register_operator(sub)
    _register_demo(sub)
    _register_record(sub)
    _register_recover(sub)


def _register_node(sub) -> None:
    """``mps node``: the ROS 2 node press_twin."""
    n = sub.add_parser(
        "node",
        help="the ROS 2 node press_twin (publishes, records; needs rclpy)",
        description="Start the ROS 2 node press_twin on SCENE (default "
        "press-cycle). Parameters as ROS arguments, e.g. --ros-args "
        "-p pacing:=as_fast_as_possible -p dt:=0.001 or "
        "--params-file config/press_twin.yaml.",
    )
    n.add_argument("scene", nargs="?", help="preset name or scene file (the scene parameter's default)")
    n.add_argument(
        "--ros-args",
        dest="ros_args",
        nargs=argparse.REMAINDER,
        default=[],
        help="ROS 2 arguments (everything after it goes to ROS)",
    )
    n.set_defaults(func=_node)


def _register_operator(sub) -> None:
    """``mps operator``: mode commands sent at simulated times."""
    from mps_core.scene.settings import COMMANDS

    o = sub.add_parser(
        "operator",
        help="send mode commands to press_twin at simulated times",
        description="A small ROS 2 client: watches /clock and sends each command "
        "on /press_twin/mode when the simulated time reaches it "
        "(default: the scene's own [[commands]]), prints the node's "
        "answers, and ends with the run. Exit status: 0 every command "
        "applied; 1 one refused, unanswered or not sent, or no node "
        "answered within --wait; 2 bad input (checked before anything is "
        "sent); 130 on SIGINT (Ctrl-C), 143 on SIGTERM.",
    )
    o.add_argument(
        "scene",
        nargs="?",
        default="press-cycle",
        help="scene whose [[commands]] to send (default press-cycle)",
    )
    o.add_argument(
        "--at",
        action="append",
        metavar="T:WORD",
        default=None,
        help=f"send WORD ({', '.join(COMMANDS)}) at simulated time T (s) >= 0 instead of the "
        "scene's commands; repeat",
    )
    o.add_argument("--node", default="/press_twin", help="the node's name (default /press_twin)")
    o.add_argument(
        "--wait",
        type=_positive,
        default=10.0,
        metavar="S",
        help="give up when no node has subscribed to the mode topic after this many wall seconds "
        "(default 10)",
    )
    o.add_argument(
        "--timeout", type=_positive, default=120.0, help="give up after this many wall seconds (default 120)"
    )
    o.set_defaults(func=_operator)


def _register_demo(sub) -> None:
    """``mps demo``: node and operator, realtime, recorded."""
    d = sub.add_parser(
        "demo",
        help="node + operator on a scene, realtime, recorded (make run)",
        description="Start press_twin on SCENE in realtime with the scene's "
        "commands off, and an operator that sends them on "
        "/press_twin/mode at their simulated times; run to the end; "
        "print where the recording is and how to view it.",
    )
    d.add_argument("scene", nargs="?", default="press-cycle")
    d.add_argument("--dt", type=_positive, default=1e-3, help="step (s), default 0.001 (1 kHz)")
    d.add_argument("--real-time-factor", type=_positive, default=1.0)
    d.add_argument(
        "--out", help="recording path (default recordings/SCENE-DATE-TIME-MS.mcap; never an existing file)"
    )
    d.set_defaults(func=_demo)


def _register_record(sub) -> None:
    """``mps record``: the node's recording made without ROS."""
    r = sub.add_parser(
        "record",
        help="write the node's MCAP recording without ROS",
        description="Run SCENE headless (the scene's own commands) and write "
        "every message the node would publish to an MCAP file: same "
        "topics, types, values and metadata, no ROS needed.",
    )
    r.add_argument("scene", help="preset name or scene file")
    r.add_argument(
        "--out",
        required=True,
        metavar="FILE.mcap|BAG",
        help="an .mcap file, or a new directory: a bag (rosbag2's layout: "
        "BAG/metadata.yaml and BAG/BAG_0.mcap, _1, ... split by --max-mb, "
        "--max-s)",
    )
    r.add_argument("--dt", type=_positive, help="step (s); default the scene's")
    r.add_argument("--t-end", type=_positive, help="end time (s); default the scene's")
    r.add_argument(
        "--publish-every", type=_count, default=1, metavar="N", help="record every N-th step (default 1)"
    )
    r.add_argument(
        "--outputs",
        metavar="LIST",
        help="comma-separated subset of joint_states,reactions,foundation,clock,"
        "structure,events,diagnostics (default all)",
    )
    r.add_argument("--pacing", choices=("as_fast_as_possible", "realtime"), default="as_fast_as_possible")
    r.add_argument("--real-time-factor", type=_positive, default=1.0)
    r.add_argument("--no-scene-commands", action="store_true", help="ignore the scene's [[commands]]")
    r.add_argument(
        "--compression",
        choices=("zstd", "lz4", "none"),
        default="zstd",
        help="the chunks' compression (default zstd; the node's recording_compression)",
    )
    r.add_argument(
        "--max-mb",
        type=float,
        default=0.0,
        metavar="MB",
        help="a bag: a new file once one holds this many MB (default 0: never; the node's recording_max_mb)",
    )
    r.add_argument(
        "--max-s",
        type=float,
        default=0.0,
        metavar="S",
        help="a bag: a new file once one spans this many simulated seconds "
        "(default 0: never; the node's recording_max_s)",
    )
    r.add_argument("-v", "--verbose", action="store_true", help="print every command applied")
    r.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="no progress line while it runs (there is one on a terminal only)",
    )
    r.add_argument(
        "--force",
        action="store_true",
        help="replace FILE.mcap where it exists, once the new run has finished (never the scene itself)",
    )
    r.set_defaults(func=_record)


def _register_recover(sub) -> None:
    """``mps recover``: a recording cut short made whole."""
    c = sub.add_parser(
        "recover",
        help="complete an MCAP recording cut short (e.g. SIGKILL)",
        description="Copy every whole chunk of IN (a recording whose writer was "
        "killed: no summary, no footer) into a complete file OUT "
        "(default IN-recovered.mcap).",
    )
    c.add_argument("input", metavar="IN.mcap|BAG", help="a recording, or a bag directory")
    c.add_argument(
        "output",
        nargs="?",
        metavar="OUT.mcap|OUT",
        help="default IN-recovered.mcap; for a bag, a new directory IN-recovered",
    )
    c.add_argument("--force", action="store_true", help="replace OUT.mcap where it exists")
    c.set_defaults(func=_recover)
