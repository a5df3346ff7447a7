"""The ROS 2 node ``press_twin``: loads a scene, steps mps_core, publishes and records.

    mps node [SCENE] [--ros-args -p NAME:=VALUE ... --params-file FILE.yaml]

Topics, types, frames and signs: :mod:`mps_ros.wire.topics` (and the README). The run itself (steps,
pacing, commands, diagnostics) is :class:`mps_ros.run.runner.Runner`, the same one ``mps record``
uses; this module adds the ROS side: parameters, publishers, the ``~/mode`` subscription and the
``~/engage``, ``~/disengage``, ``~/stop``, ``~/start`` services (std_srvs/Trigger), the
recorder, signals. ROS callbacks run in a background executor thread and only queue commands;
the run loop applies them at the next step boundary and answers on ``~/mode/status`` (and to
the service caller).

Parameters (read-only; ``--ros-args -p`` or a YAML file, see ``config/press_twin.yaml``): the
table :data:`mps_ros.ros.parameters.PARAMETERS` (docs/ros.md lists it; ``ros2 param describe``
gives each one's description and range).
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
from pathlib import Path

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn

from mps_core import MpsError

from ..recording.background import BackgroundRecorder
from ..run.commands import Inbox
from ..run.releasing import ForwardingInbox
from ..run.sinks import RecordingSink
from ..run.twin import Twin
from ..wire.topics import BY_KEY, MODE, NODE_NAME, offered_qos
from .config import NodeRun, RunConfig, realtime_priority
from .endpoints import Commands, Endpoints
from .environment import env_defaults
from .foxglove_link import FoxgloveLink, endpoint_settings
from .parameters import ParameterError, declare, read
from .recording_files import claim_recording, discard_recording, next_recording
from .spinning import SpinThread, close

DEFAULT_SCENE = "press-cycle"


class NameTaken(RuntimeError):
    """Another node of this node's name and namespace is running in the same ROS domain."""


#: wall seconds after its creation within which a node expects to have discovered the others
#: on its machine (Fast DDS on loopback: well under one)
DISCOVERY_S = 2.5


class PressTwin(LifecycleNode):
    """The node, a managed one (``rclpy.lifecycle``). Construct (its parameters declared and
    checked), configure (:meth:`configure`: the scene, the publishers, the kernels, the
    stepping process, the recording), activate (the run may start: :meth:`run` blocks until it
    ends or is stopped), deactivate and activate again (pause and go on), cleanup or shutdown
    (the run ends, its recording finished). Its parts: the run's settings (:class:`RunConfig`),
    the publishers, subscription and services (:class:`Endpoints`) and the commands that come
    through them (:class:`Commands`)."""

    def __init__(self, default_scene: str | None = None, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        self._created = time.monotonic()
        self._recording_reserved = False
        declare(self, default_scene or DEFAULT_SCENE)
        self.settings = read(self)
        #: the run's settings from the parameters (every run of the node alike)
        self.config = RunConfig(self.settings, self.get_fully_qualified_name().lstrip("/"))
        self.twin: Twin | None = None
        #: the run: stepped in this process, or in a stepping process (made at configure)
        self.runner: NodeRun | None = None
        self.recorder: BackgroundRecorder | None = None
        self.recording_sink: RecordingSink | None = None
        #: the publishers, the command subscription and services (made at configure)
        self.endpoints: Endpoints | None = None
        #: the commands from outside (the callbacks of the subscription and services)
        self.commands = Commands(self)
        self.closed = False
        self.priority_got = 0
        self.split = False
        #: why configure failed (the node then ends)
        self.configure_error: Exception | None = None
        #: the run may start (the first activate); the node is to end (cleanup, shutdown)
        self.activated = threading.Event()
        self.ending = threading.Event()
        self.inactive = False  # deactivated (paused)
        self.runs = 0  # runs begun (a reset begins another)
        #: the Foxglove endpoint's commands (``foxglove_port``), for the run's recording process
        self.foxglove: FoxgloveLink | None = None

    def _run(self) -> NodeRun:
        """Return the run (RuntimeError before configure has made it)."""
        if self.runner is None:
            raise RuntimeError("the node has no run yet: configure it first")
        return self.runner

    def _twin(self) -> Twin:
        """Return the twin (RuntimeError before configure has made it)."""
        if self.twin is None:
            raise RuntimeError("the node has no twin yet: configure it first")
        return self.twin

    def _endpoints(self) -> Endpoints:
        """Return the publishers and services (RuntimeError before configure has made them)."""
        if self.endpoints is None:
            raise RuntimeError("the node has no publishers yet: configure it first")
        return self.endpoints

    # -- the lifecycle (its transitions' callbacks: the executor's thread, or autostart's) --
    def on_configure(self, state) -> TransitionCallbackReturn:
        if self.runner is not None:  # configured once: a node runs one run
            return TransitionCallbackReturn.SUCCESS
        try:
            self.configure()
        except (ParameterError, MpsError, OSError) as exc:
            self.configure_error = exc
            if not self.settings.autostart:  # autostart: the node's last line says it
                self.get_logger().error(f"configure failed: {exc}")
            self.ending.set()
            return TransitionCallbackReturn.FAILURE
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state) -> TransitionCallbackReturn:
        self.inactive = False
        if not self.activated.is_set():
            self.activated.set()
        else:
            self._run().resume()
            self.get_logger().info("activated: the run goes on")
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        why = self._run().pause() if self.activated.is_set() else None
        if why is not None:
            self.get_logger().error(f"cannot pause: {why}")
            return TransitionCallbackReturn.FAILURE
        self.inactive = True
        self.get_logger().info(
            "deactivated: paused (simulated time holds; a command is applied where it holds)"
        )
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, state) -> TransitionCallbackReturn:
        self._end("cleanup")
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state) -> TransitionCallbackReturn:
        self._end("shutdown")
        return TransitionCallbackReturn.SUCCESS

    def _end(self, reason: str) -> None:
        self.ending.set()
        if self.runner is not None:
            self.runner.resume()
            self.runner.request_stop(reason)

    def configure(self) -> None:
        """The scene, the publishers, the command subscription and services, the run
        (:meth:`new_run`)."""
        twin = self.twin = self.config.twin()
        self.endpoints = Endpoints(self, twin.outputs, self.settings.qos_depth)
        self.inbox: Inbox | ForwardingInbox = Inbox()  # before the subscription that fills it
        self.endpoints.listen(self, self.commands)
        if self.settings.track:  # following a press: its topics beside the simulator's
            from .tracking_source import add_endpoints

            add_endpoints(self)
        self.new_run(twin)

    def new_run(self, twin: Twin | None = None) -> None:
        """A run of the scene from its start: the twin (``twin``, or a new one), the runner (or
        the stepping process, started and its kernels built), the recording opened (after a
        reset, a new file beside the last: :func:`next_recording`). Paused from its start
        where the node is inactive."""
        self.runs += 1
        twin = self.twin = self.config.twin() if twin is None else twin
        self.closed = False
        #: the twin steps in a process of its own (:mod:`mps_ros.run.stepping`); this process
        #: publishes what it releases and forwards the commands (as fast as possible, where
        #: the twin can come back to a step: a command's boundary is the last step released)
        self.split = self.config.splits(twin) and not self.settings.track
        runner: NodeRun
        if self.settings.track:  # following a press: its measurements pace the run
            from .tracking_source import tracking_run

            tracking = tracking_run(self)
            self.inbox = tracking.inbox  # its commands refused, answered
            runner = tracking
        elif self.split:
            stepping = self.config.stepping_process(twin, self._endpoints().sink, self._log)
            self.inbox = stepping.inbox
            runner = stepping
        else:
            assert isinstance(self.inbox, Inbox)  # the node's own, until a split run's
            runner = self.config.runner(twin, self._endpoints().sink, self.inbox, self._log)
        self.runner = runner
        rec = self.open_recording()
        if rec is not None:
            self.get_logger().info(f"recording to {rec.path}")
        # the kernels built (and the stepping process started) before the run may start
        runner.prepare()
        if self.inactive:
            runner.pause()

    # -- the runner's log (any of its threads) ------------------------------------------------
    def _log(self, level: str, text: str):
        lg = self.get_logger()
        # one call site a severity: rclpy's logger insists
        if level == "warn":
            lg.warning(text)
        elif level == "error":
            lg.error(text)
        else:
            lg.info(text)

    # -- the run ----------------------------------------------------------------------------
    def _wait_for_peers(self, stop: threading.Event) -> None:
        n_sub, n_cmd = self.settings.wait_for_subscribers, self.settings.wait_for_commanders
        n_fox = self.settings.wait_for_foxglove if self.foxglove is not None else 0
        if not (n_sub or n_cmd or n_fox):
            return
        deadline = time.monotonic() + self.settings.wait_timeout
        while not stop.is_set():
            endpoints = self._endpoints()
            subs = min(pub.get_subscription_count() for pub in endpoints.pubs.values())
            cmds = self.count_publishers(endpoints.names[MODE.key])
            fox = self.foxglove.ready if self.foxglove is not None else 0
            if subs >= n_sub and cmds >= n_cmd and fox >= n_fox:
                return
            if time.monotonic() > deadline:
                self.get_logger().warning(
                    f"starting without all peers after {self.settings.wait_timeout:g} s "
                    f"(subscribers {subs}/{n_sub}, commanders {cmds}/{n_cmd}"
                    + (f", foxglove clients {fox}/{n_fox})" if n_fox else ")")
                )
                return
            time.sleep(0.01)

    def open_recording(self) -> BackgroundRecorder | None:
        from ..recording.background import BackgroundRecorder
        from ..recording.recorder import new_recording
        from ..run.record import run_metadata
        from ..run.sinks import RecordingSink

        path = self.settings.recording
        self.recorder = self.recording_sink = None
        if path.lower() in ("", "none", "off", "false"):
            if self.settings.foxglove_port:
                raise ParameterError(
                    f"parameter foxglove_port: {self.settings.foxglove_port}: the endpoint is served by "
                    f"the recording process: expected a recording (recording {path!r} is none)"
                )
            return None
        twin = self._twin()
        target: Path
        if path == "auto":
            target = new_recording(twin.scene.name)
        elif self.runs > 1:  # after a reset: a new file (or bag) beside the first
            target, self._recording_reserved = next_recording(path), False
        else:
            target, self._recording_reserved = claim_recording(path)
        st = self.settings
        meta = run_metadata(twin, "mps node", st.pacing, st.real_time_factor, st.publish_every)
        meta["node"] = self.get_fully_qualified_name()
        meta["ros_domain_id"] = os.environ.get("ROS_DOMAIN_ID", "0")
        meta["rmw_implementation"] = os.environ.get("RMW_IMPLEMENTATION", "")
        meta["fastdds_profiles_file"] = os.environ.get("FASTRTPS_DEFAULT_PROFILES_FILE", "")
        if st.track:  # followed again by mps track --recording with the same tuning
            from .tracking_source import tracking_tuning

            meta.update(tracking_tuning(st).metadata())
        link = FoxgloveLink(self) if self.settings.foxglove_port else None
        self.foxglove = link
        try:
            recorder = self.recorder = BackgroundRecorder(
                target,
                scene_name=twin.scene.name,
                scene_text=twin.scene.text,
                metadata=meta,
                flush_period=self.settings.recording_flush_period,
                compression=self.settings.recording_compression,
                max_bytes=int(self.settings.recording_max_mb * 1e6),
                max_s=self.settings.recording_max_s,
                # the Foxglove endpoint: served by the recording process (mps_ros.foxglove.live)
                module="mps_ros.foxglove.live" if link is not None else "mps_ros.recording.background",
                tap=endpoint_settings(self, link.child_fd) if link is not None else None,
                pass_fds=(link.child_fd,) if link is not None else (),
            )
        except OSError:
            if link is not None:  # the endpoint could not start: no run, no recording left
                link.close()
                self.foxglove = None
                discard_recording(target, self._recording_reserved and self.settings.recording != "auto")
            raise
        if link is not None:
            link.start()
            self.get_logger().info(f"foxglove endpoint: {recorder.tap_info.get('url')}")
        self.recording_sink = RecordingSink(
            recorder,
            names=dict(self._endpoints().names),
            qos=offered_qos(self.settings.qos_depth),
            log=self._log,
        )
        self._run().sinks.append(self.recording_sink)
        return recorder

    def run(self, stop: threading.Event) -> dict:
        """Run to the end or a stop (the run's statistics), once the peers it waits for came."""
        tw, runner, endpoints = self._twin(), self._run(), self._endpoints()
        names, unpublished = endpoints.names, endpoints.unpublished
        if self.settings.track:  # following a press: no steps of its own
            self.get_logger().info(
                f"scene {tw.scene.name}: following the press on {self.settings.track}"
                + (f" and {self.settings.track_mode}" if self.settings.track_mode else "")
                + f", outputs {', '.join(tw.outputs)}"
            )
        else:
            self.get_logger().info(
                f"scene {tw.scene.name}: {tw.n} steps of {tw.dt:.6g} s to t = {tw.t_end:g} s, "
                f"{self.settings.pacing}"
                + (f" x{self.settings.real_time_factor:g}" if self.settings.pacing == "realtime" else "")
                + f", outputs {', '.join(tw.outputs)}"
                + (
                    ""
                    if self.settings.scene_commands
                    else f", scene commands off (listening on {names[MODE.key]})"
                )
            )
        if unpublished:
            types = sorted({BY_KEY[k].msgtype.split("/")[0] for k in unpublished})
            self.get_logger().warning(
                f"{', '.join(names[k] for k in unpublished)}: recorded, not "
                f"published ({', '.join(types)} cannot be imported here; a full ROS install "
                "has it)"
            )
        # the kernels built and the channels registered while the peers are awaited
        runner.prepare()
        self._refuse_a_second_of_my_name(self._created + DISCOVERY_S, stop)
        self._wait_for_peers(stop)
        stop.wait(self.settings.start_delay)
        if stop.is_set():
            runner.request_stop("signal")
        if not self.split:
            self._set_priority()
        self.get_logger().info("stepping starts")
        return runner.run()

    def _refuse_a_second_of_my_name(self, until: float, stop: threading.Event) -> None:
        """:class:`NameTaken` where another node of this node's name and namespace runs in
        its domain (its topics, services and /clock would mix with this one's), looked for in
        the graph until ``until`` (monotonic s: the discovery's time), a stop, or one seen. A
        node that ended without a word (SIGKILL) before this one started is never in this
        one's graph: a participant learns of the others from themselves."""
        me = (self.get_name(), self.get_namespace())
        while not stop.is_set():
            if sum(1 for n in self.get_node_names_and_namespaces() if tuple(n) == me) > 1:
                raise NameTaken(
                    f"a node {self.get_fully_qualified_name()} is already running in ROS "
                    f"domain {os.environ.get('ROS_DOMAIN_ID', '0')}; give this one another "
                    "name or namespace (--ros-args -r __node:=NAME or -r __ns:=/NAMESPACE), or "
                    "another ROS_DOMAIN_ID"
                )
            if time.monotonic() >= until:
                return
            stop.wait(0.02)

    def _set_priority(self) -> None:
        """``realtime_priority`` > 0: the stepping thread runs under SCHED_FIFO at that priority
        (it sleeps between steps; the machine's real-time throttling still bounds it), so a
        step is not kept waiting by ordinary processes. Where the system does not allow it (no
        CAP_SYS_NICE, no such policy) the run goes on at normal priority, with a warning."""
        prio = realtime_priority(self.settings)
        if not prio:
            return
        from ..run.stepping import HOW_TO_ALLOW, ask_fifo

        why = ask_fifo(prio)
        if why is not None:
            self.get_logger().warning(
                f"realtime_priority {prio}: SCHED_FIFO refused here "
                f"({why}); stepping at normal priority; {HOW_TO_ALLOW}"
            )
            return
        self.priority_got = prio
        self.get_logger().info(f"stepping and publishing threads: SCHED_FIFO, priority {prio}")


def _split_argv(argv):
    """(scene or None, ROS arguments) from a command line like ``[SCENE] [--ros-args ...]``."""
    argv = list(argv)
    if "--ros-args" in argv:
        i = argv.index("--ros-args")
        plain, ros = argv[:i], argv[i:]
    else:
        plain, ros = argv, []
    plain = [a for a in plain if a]
    if len(plain) > 1:
        raise SystemExit(f"press_twin: one scene at most, got {plain}")
    return (plain[0] if plain else None), ros


def _one_run(node: PressTwin, stop: threading.Event) -> tuple[int, bool]:
    """The node's run, from its start to its end, its recording finished and its last lines
    said: (the exit status, whether another run follows: a reset, its run begun)."""
    taken = None
    try:
        stats = node.run(stop)
        code = _status(node)
    except NameTaken as exc:
        taken = exc
    except MpsError as exc:
        node.get_logger().error(f"the simulation stopped: {exc}")
        stats = node._run().stats()
        code = 2
    except OSError as exc:  # the stepping process could not start its run
        if not node.split:
            raise
        node.get_logger().error(f"the run could not start: {exc}")
        return 2, False
    finally:
        recording_error = _closed(node)
    if taken is not None:  # nothing ran: the recording begun is not one
        if node.recorder is not None:
            discard_recording(node.recorder.path, node._recording_reserved)
        print(f"press_twin: error: {taken}", file=sys.stderr, flush=True)
        return 2, False
    node._endpoints().drain()
    _say_run_end(node, stats)
    if node.recorder is not None and node.recording_sink is not None:
        failure = node.recording_sink.failure or recording_error
        if failure is None:
            node.get_logger().info(
                f"recording finished: {node.recorder.path} ({node.recorder.messages} messages)"
            )
        else:
            node.get_logger().error(f"recording incomplete ({failure})")
            code = code or 1
    again = node.commands.reset_wanted and not (stop.is_set() or node.ending.is_set())
    if again:
        node.commands.reset_wanted = False
        try:
            node.new_run()
        except (ParameterError, MpsError, OSError) as exc:
            node.get_logger().error(f"reset: no new run: {exc}")
            again, code = False, 2
    node.commands.run_started.set()  # a reset waiting for its answer: the new run, or none
    return code, again


def _status(node: PressTwin) -> int:
    """The exit status of a run that ended without an exception: 2 where its simulation failed
    in the stepping process (which said why: its log line), 1 where the stepping process failed
    otherwise, else 0."""
    runner = node._run()
    if node.split and runner.error_kind == "simulation":
        return 2
    if node.split and runner.error:
        node.get_logger().error(f"the run failed: {runner.error}")
        return 1
    return 0


def _closed(node: PressTwin) -> str | None:
    """The run closed, however it ended: commands refused from now on, its recording finished,
    its stepping process (or its cuts' fitting process) ended. Why the recording could not be
    finished (said when it happened: the sink's line), or None."""
    node.closed = True
    recording_error = None
    if node.recorder is not None:
        try:
            node.recorder.finish()
        except OSError as exc:
            recording_error = str(exc)
    node._run().close()  # what the run started beside it: a stepping or cuts' fitting process
    return recording_error


def _say_run_end(node: PressTwin, stats: dict) -> None:
    """The run's last line: how it ended and its statistics (``mps bench`` reads it)."""
    from ..run.tracking import TrackingRun

    runner = node._run()
    if isinstance(runner, TrackingRun):  # following a press: its own figures
        node.get_logger().info(runner.summary())
        return
    why = runner.stop_reason or "end"
    node.get_logger().info(
        f"run {'ended' if why == 'end' else 'stopped (' + why + ')'} at t = "
        f"{stats.get('t', node._twin().t):.6g} s after {stats['steps']} steps: real-time factor "
        f"{stats['real_time_factor']:.3g}, step p50 {stats['step_time_p50_ms']:.3g} ms, "
        f"p99 {stats['step_time_p99_ms']:.3g} ms, publish p50 "
        f"{stats['publish_time_p50_ms']:.3g} ms, p99 {stats['publish_time_p99_ms']:.3g} ms, "
        + (
            f"latency p50 {stats['latency_p50_ms']:.3g} ms, p99 {stats['latency_p99_ms']:.3g} ms, "
            if "latency_p50_ms" in stats
            else ""
        )
        + f"{stats['deadline_misses']} deadline misses, {stats['messages']} messages, "
        f"stepping thread CPU {stats['step_thread_cpu_per_step_us']:.0f} us a step, "
        f"process CPU {stats['process_cpu_per_step_us']:.0f} us a step, "
        + (
            f"stepping process {stats['stepping_process_cpu_per_step_us']:.0f} us and ROS "
            f"process {stats['ros_process_cpu_per_step_us']:.0f} us of it, "
            if "ros_process_cpu_per_step_us" in stats
            else ""
        )
        + f"realtime priority {stats.get('realtime_priority', node.priority_got)}, "
        + (
            f"publishing thread's slice {stats['release_slice_ms']:.3g} ms, "
            if "release_slice_ms" in stats
            else ""
        )
        + f"{stats['commands_accepted']} commands applied, {stats['commands_refused']} refused, "
        f"{stats['commands_lost']} lost"
    )


def main(argv=None) -> int:
    """``mps node [SCENE] [--ros-args ...]`` (argv without the program name)."""
    env_defaults()  # (and a crash in native code said where each thread was)
    # the stepping, publishing and executor threads share the interpreter: a thread that wants
    # it waits at most this long for another to let go (the default 5 ms is five steps)
    sys.setswitchinterval(0.0002)
    if argv is None:
        argv = sys.argv[1:]
    scene, ros = _split_argv(argv)
    stop = threading.Event()
    runner_box: dict = {}
    old = _stop_on_signals(stop, runner_box)
    rclpy.init(args=[NODE_NAME, *ros], signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = None
    spin = None
    try:
        try:
            node = PressTwin(scene)
        except ParameterError as exc:
            print(f"press_twin: error: {exc}", file=sys.stderr, flush=True)
            return 2
        runner_box["node"] = node
        spin = _spin_in_background(node)
        _start(node)
        while not (node.activated.is_set() or node.ending.is_set() or stop.is_set()):
            stop.wait(0.05)
        if not node.activated.is_set():  # never activated: what was begun is not a run
            return _never_ran(node)

        code = 0
        again = True
        while again:
            status, again = _one_run(node, stop)
            code = max(code, status)
        return code
    finally:
        if not close(spin, [node]):
            print(
                "press_twin: the executor's thread did not end: the node is left to the process's end",
                file=sys.stderr,
                flush=True,
            )
        rclpy.try_shutdown()
        for s, h in old.items():
            signal.signal(s, h)


def _stop_on_signals(stop: threading.Event, runner_box: dict) -> dict:
    """SIGINT and SIGTERM set ``stop`` and stop the run of the node in ``runner_box`` (once
    there is one); the handlers they had before, to put back."""

    def on_signal(signum, _frame):
        name = signal.Signals(signum).name
        stop.set()
        node = runner_box.get("node")
        if node is not None and node.runner is not None:
            node.runner.resume()
            node.runner.request_stop(name)

    return {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}


def _spin_in_background(node: PressTwin) -> SpinThread:
    """The node's callbacks spun in a thread of their own, started; a callback that fails ends
    the node's run."""

    def failed(exc: Exception) -> None:  # the run must not go on deaf
        if node.runner is None or node.runner.stop_reason is None:
            node.get_logger().error(f"executor stopped: {type(exc).__name__}: {exc}")
            node._end("error")

    executor = SingleThreadedExecutor()
    executor.add_node(node)
    return SpinThread(executor, "press_twin-executor", failed)


def _start(node: PressTwin) -> None:
    """``autostart``: the node configured and activated at once; else it waits, unconfigured,
    for a lifecycle manager."""
    if node.settings.autostart:
        node.trigger_configure()
        if node.configure_error is None:
            node.trigger_activate()
    else:
        node.get_logger().info(
            "autostart false: unconfigured, waiting for a lifecycle manager "
            f"({node.get_fully_qualified_name()}/change_state: configure, activate)"
        )


def _never_ran(node: PressTwin) -> int:
    """A node that ended before its run started (never activated): what was begun is undone
    (the stepping process ended, the recording discarded); its exit status."""
    if node.runner is not None:
        node.runner.close()
    if node.recorder is not None:
        with contextlib.suppress(OSError):
            node.recorder.finish()
        discard_recording(node.recorder.path, node._recording_reserved)
    if node.configure_error is not None:
        print(f"press_twin: error: {node.configure_error}", file=sys.stderr, flush=True)
        return 2
    node.get_logger().info("ended before its run started")
    return 0


if __name__ == "__main__":
    sys.exit(main())
