"""``mps emulator``: a press to follow on ROS, its sensors' readings published from a truth scene.

    mps emulator SCENE [--t-end S] [--seed N] [--slider] [--motor-torque] [--fault T:KIND ...]
                       [--glitch T:KIND ...] [--signals-late S]
                       [--topic /press/joint_states] [--mode-topic /press/mode]
                       [--real-time-factor F] [--subscribers N] [--wait S]

The node that follows it: ``mps node SCENE --ros-args -p track:=/press/joint_states -p
track_mode:=/press/mode`` (docs/ros.md, Following a press). Everything given is checked before
the truth is run; a bad value is one line naming it and exit status 2.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

__all__ = ["register"]


def register(subparsers: Any) -> None:
    """Add ``emulator`` to the ``mps`` command line."""
    p = subparsers.add_parser(
        "emulator",
        help="a press to follow on ROS: its sensors' readings from a truth scene, at 1 kHz on the wall clock",
    )
    p.add_argument("scene", help="the nominal press: preset name or scene file (its truth is run)")
    p.add_argument("--t-end", type=float, default=1.0, metavar="S", help="seconds of the press (1.0)")
    p.add_argument("--seed", type=int, default=0, help="the noise's and the jitter's seed")
    p.add_argument("--slider", action="store_true", help="a linear scale on the slider too (joint slider)")
    p.add_argument(
        "--motor-torque",
        action="store_true",
        help="the motor's torque on the crank too (the crank's effort, N*m; 2 %% of its reading)",
    )
    p.add_argument(
        "--fault",
        action="append",
        default=[],
        metavar="T:KIND",
        help="a fault of the truth at T s (repeatable)",
    )
    p.add_argument(
        "--glitch",
        action="append",
        default=[],
        metavar="T:KIND",
        help="a bad measurement at T s: jump, duplicate, out-of-order (repeatable)",
    )
    p.add_argument(
        "--signals-late",
        type=float,
        default=0.0,
        metavar="S",
        help="publish each mode signal S seconds after its command took effect (a controller's latency)",
    )
    p.add_argument(
        "--topic", default="/press/joint_states", help="the measurements' topic (sensor_msgs/JointState)"
    )
    p.add_argument(
        "--mode-topic", default="/press/mode", help="the mode signals' topic (std_msgs/String); '' none"
    )
    p.add_argument(
        "--real-time-factor",
        type=float,
        default=1.0,
        metavar="F",
        help="the press's seconds a wall second (1: as fast as the press; the stamps are the press's)",
    )
    p.add_argument("--subscribers", type=int, default=1, metavar="N", help="start once N follow (1)")
    p.add_argument("--wait", type=float, default=60.0, metavar="S", help="... waiting at most S seconds (60)")
    p.set_defaults(func=_emulator)


def _ros_emulator() -> Any:
    """Return the ROS emulator's module, this process's ROS environment set first.

    None (and what to install, said) where ROS is missing.
    """
    import importlib

    from ..ros.environment import env_defaults
    from .cli import ROS_MISSING

    env_defaults()
    try:
        return importlib.import_module("mps_ros.ros.emulator")
    except ImportError as exc:
        if "rclpy" in str(exc) or "_msgs" in str(exc):
            print(ROS_MISSING, file=sys.stderr)
            print(f"    ({exc})", file=sys.stderr)
            return None
        raise


def _emulator(args: argparse.Namespace) -> int:
    """Check the arguments, run the truth, publish its sensors' readings."""
    from mps_core import MpsError, load_scene
    from mps_core.track import Fault, Sensors, run_truth, truth_scene
    from mps_core.track.measurements import ModeSignal
    from mps_core.track.truth import FAULTS, nominal_scene, timed_kinds

    def say(text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    try:
        if not (args.t_end > 0.0):
            raise ValueError(f"--t-end = {args.t_end!r}: expected a positive number of seconds")
        if not (0.001 <= args.real_time_factor <= 1000.0):
            raise ValueError(
                f"--real-time-factor = {args.real_time_factor!r}: expected a number from 0.001 to 1000"
            )
        if not (0.0 <= args.signals_late <= 1.0):
            raise ValueError(f"--signals-late = {args.signals_late!r}: expected a time in [0, 1] s")
        if args.subscribers < 0:
            raise ValueError(f"--subscribers = {args.subscribers!r}: expected an integer >= 0")
        faults = tuple(Fault(t, k) for t, k in timed_kinds(args.fault, "--fault", FAULTS))
        glitch_specs = timed_kinds(args.glitch, "--glitch", ("jump", "duplicate", "out-of-order"))
        nominal = nominal_scene(load_scene(args.scene))
    except (ValueError, MpsError) as exc:
        say(f"mps emulator: error: {exc}")
        return 2
    mod = _ros_emulator()
    if mod is None:
        return 2
    import rclpy

    truth = run_truth(
        truth_scene(nominal),
        args.t_end,
        sensors=Sensors(slider=args.slider, motor_torque=args.motor_torque),
        faults=faults,
        seed=args.seed,
    )
    stream = mod.samples(truth.measurements)
    say(f"emulator: the truth of {nominal.name} run to {args.t_end:g} s: {len(stream)} samples")
    rclpy.init(args=["press_emulator"], signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    try:
        return mod.publish(
            stream,
            [ModeSignal(m.t + args.signals_late, m.command) for m in truth.modes],
            [mod.Glitch(t, k) for t, k in glitch_specs],
            topic=args.topic,
            mode_topic=args.mode_topic,
            subscribers=args.subscribers,
            wait=args.wait,
            real_time_factor=args.real_time_factor,
            log=say,
        )
    except KeyboardInterrupt:
        say("emulator: stopped by SIGINT")
        return 130
    finally:
        rclpy.try_shutdown()
