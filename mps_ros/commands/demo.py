"""``mps demo`` (what ``make run`` runs): the node on a scene in realtime with the scene's own
commands off, and an operator client that sends them on ``/press_twin/mode`` at their simulated
times, each in its own process; runs to the end, then says where the recording is and how to
view it. Discovery stays on this machine (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST unless set)
and ROS logs go to a temporary folder unless ROS_LOG_DIR is set. No process is left behind.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
from pathlib import Path


def ros_env() -> dict:
    env = dict(os.environ)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    env.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    if not env.get("ROS_LOG_DIR"):
        env["ROS_LOG_DIR"] = tempfile.mkdtemp(prefix="mps-ros-log-")
    env["PYTHONUNBUFFERED"] = "1"
    return env


def stop_group(proc: subprocess.Popen, grace: float = 3.0) -> None:
    """End a process started with its own session, and everything it started."""
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
        except ProcessLookupError:
            pass
        try:
            proc.wait(grace)
        except subprocess.TimeoutExpired:
            pass
    try:
        os.killpg(proc.pid, signal.SIGKILL)  # stragglers of the group, if any
    except ProcessLookupError:
        pass
    try:
        proc.wait(grace)
    except subprocess.TimeoutExpired:
        pass


def mps(*args) -> list[str]:
    return [sys.executable, "-m", "mps_core.cli", *args]


def summary(path: Path) -> str:
    from rosbags.highlevel import AnyReader

    with AnyReader([path]) as r:
        n = sum(c.msgcount for c in r.connections)
        topics = sorted({c.topic for c in r.connections})
    size = sum(p.stat().st_size for p in path.iterdir()) if path.is_dir() else path.stat().st_size
    return f"{n} messages on {len(topics)} topics, {size / 1e6:.2f} MB"


def view_help(path: Path) -> str:
    import importlib.util

    p = str(path)
    here = Path(sys.executable).with_name("rerun")
    rerun = str(here) if here.exists() else "pip install rerun-sdk && rerun"
    view = ""
    if importlib.util.find_spec("mps_ros.commands.view") is not None:
        view = f"\n           or .venv/bin/mps view {p} (the press drawn, its loads as arrows)"
    return f"""How to view it:
  Foxglove (desktop or web app): Open local file... -> {p}
      plot /joint_states.position[0] (crank angle), /press_twin/foundation.wrench.force.x, ...
  Rerun:   {rerun} --bind 127.0.0.1 {p}{view}
  Python:  .venv/bin/python -c "from pathlib import Path; from rosbags.highlevel import AnyReader; \\
r = AnyReader([Path('{p}')]); r.open(); [print(c.topic, c.msgtype, c.msgcount) for c in r.connections]"
  ROS 2 Jazzy:  ros2 bag info {p}   |   ros2 bag play {p}
  metadata (the scene's TOML, the software version) and a file cut short: docs/recordings.md."""


def main(args) -> int:
    """``mps demo`` (see the module's doc); its exit status."""
    from mps_core import load_scene

    scene = load_scene(args.scene)
    out = _recording(args, scene)
    env = ros_env()
    _say_what(args, scene, env)
    limit = 60.0 + scene.t_end / args.real_time_factor
    # the operator is started with the node: it waits for it as long as the node may take to start
    op_cmd = mps("operator", args.scene, "--wait", "60")
    node_rc, op_rc = _run_node_and_operator(_node_command(args, out), op_cmd, env, limit)
    return _report(out, node_rc, op_rc)


def _recording(args, scene) -> Path:
    """Where the node records: ``--out``, checked before the node starts (a path it could not
    write, or an existing file, is refused), or a new file of its own, created empty."""
    from mps_core.files.outputs import check_outputs

    from ..recording.recorder import new_recording

    if args.out:
        from ..recording.bag import is_bag

        out = Path(args.out)
        check_outputs({"--out": out}, inputs=[args.scene], folders={"--out"} if is_bag(out) else ())
        return out
    return new_recording(scene.name)  # created empty, this run's own


def _say_what(args, scene, env: dict) -> None:
    """The demo's first lines: the scene, its pacing and the operator's commands; the ROS
    domain, its discovery range and where the logs go."""
    cmds = ", ".join(f"{w} at {t:g} s" for t, w in scene.commands) or "none"
    print(
        f"demo: scene {scene.name}, {scene.t_end:g} s in realtime (x{args.real_time_factor:g}) "
        f"at {1 / args.dt:g} Hz; the operator sends: {cmds}",
        flush=True,
    )
    print(
        f"demo: ROS_DOMAIN_ID={env.get('ROS_DOMAIN_ID', '0')}, "
        f"ROS_AUTOMATIC_DISCOVERY_RANGE={env['ROS_AUTOMATIC_DISCOVERY_RANGE']}, "
        f"logs in {env['ROS_LOG_DIR']}",
        flush=True,
    )


def _node_command(args, out: Path) -> list[str]:
    """The node's command line: realtime, the scene's own commands off (the operator sends
    them), recording to ``out``, waiting for the operator before it starts."""
    return mps(
        "node",
        args.scene,
        "--ros-args",
        "-p",
        "pacing:=realtime",
        "-p",
        f"real_time_factor:={args.real_time_factor!r}",
        "-p",
        f"dt:={args.dt!r}",
        "-p",
        "scene_commands:=false",
        "-p",
        f"recording:={out}",
        "-p",
        "wait_for_commanders:=1",
        "-p",
        "wait_timeout:=30.0",
        "-p",
        "start_delay:=1.0",
    )


def _run_node_and_operator(node_cmd: list[str], op_cmd: list[str], env: dict, limit: float) -> tuple:
    """The node and the operator, each in a session of its own, the node given ``limit`` wall
    seconds to finish (then stopped) and the operator 15 more; no process left behind: (the
    node's exit code, the operator's)."""
    procs = []
    try:
        node = subprocess.Popen(node_cmd, env=env, start_new_session=True)
        procs.append(node)
        op = subprocess.Popen(op_cmd, env=env, start_new_session=True)
        procs.append(op)
        try:
            node_rc = node.wait(limit)
        except subprocess.TimeoutExpired:
            print(f"demo: the node did not finish within {limit:g} s; stopping it", flush=True)
            stop_group(node)
            node_rc = node.returncode
        try:
            op_rc = op.wait(15.0)
        except subprocess.TimeoutExpired:
            stop_group(op)
            op_rc = op.returncode
    finally:
        for p in procs:
            stop_group(p)
    return node_rc, op_rc


def _report(out: Path, node_rc, op_rc) -> int:
    """Where the recording is, what it holds and how to view it; the demo's exit status."""
    print(flush=True)
    if not out.exists():
        print(f"demo: no recording was written (node exit code {node_rc})", file=sys.stderr)
        return 1
    print(f"Recording: {out.resolve()}")
    try:
        print(f"           {summary(out)}")
    except Exception as exc:  # a file cut short: say how to recover it
        print(f"           not readable as it is ({exc}); recover it with `mps recover {out}`")
    print(view_help(out))
    if node_rc != 0 or op_rc != 0:
        print(f"demo: node exit code {node_rc}, operator exit code {op_rc}", file=sys.stderr)
        return 1
    return 0
