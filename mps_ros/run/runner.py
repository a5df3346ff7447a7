"""The twin's run, without ROS: steps a :class:`~mps_ros.run.twin.Twin`, turns each step into
messages, takes commands, paces, measures, and hands every message to its sinks (the ROS
publishers, the MCAP recorder).

The node (:mod:`mps_ros.ros.node`) and ``mps record`` run the same :class:`Runner` over the same
:class:`Twin`, so a recording made with or without ROS holds the same messages, and what the
node publishes is exactly what it records. Messages are plain dicts in the field layout of their
ROS types (what the MCAP writer serializes and the node copies into rclpy messages).

**Steps.** Step k is at ``t_k = t0 + k·(t_end − t0)/n`` with ``n = round((t_end − t0)/dt)``, as
``mps_core``'s own ``run`` takes them; the state at t_k is published, then the commands that
came in meanwhile are applied at t_k (the first step boundary after their arrival), then the
twin steps to t_{k+1}. Events (impacts, chart changes, commands) keep their exact times.

**Pacing.** ``as_fast_as_possible``: no waiting. ``realtime``: step k's messages go out at wall
time ``start + (t_k − t0)/real_time_factor``, its deadline; steps are computed up to ``lead``
wall seconds ahead and released by a thread of their own, never before their deadlines and at
most ``release_period`` less one step's period after them (the thread wakes about once per
``release_period`` and sends every step that is due: a wake-up costs the machine more than a
step's publishing), and a command comes back to the checkpoint of its boundary
(:class:`~mps_ros.run.paced.PacedInProcess`); a step computed after its deadline is a *deadline miss* (it goes
out late; the schedule is kept, so the run catches up when it can).
"""

from __future__ import annotations

import collections
import math
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from ..wire import diagnostics
from ..wire.diagnostics import hardware_id
from ..wire.json_text import to_json
from ..wire.topics import BY_KEY
from .commands import Gate, Inbox, RunCommands
from .metrics import Measurements, RunClocks
from .sinks import Fanout, Message, Sink
from .twin import Twin

PACINGS = ("realtime", "as_fast_as_possible")


def _check_pacing(
    pacing, real_time_factor, publish_every, lead, command_delay, release_slice, release_period
):
    """A :class:`Runner`'s pacing settings, each checked: ValueError names the first that is
    out of its range and what it expects."""
    if pacing not in PACINGS:
        raise ValueError(f"pacing {pacing!r}: expected one of {', '.join(PACINGS)}")
    if not (real_time_factor > 0 and math.isfinite(real_time_factor)):
        raise ValueError(f"real_time_factor {real_time_factor!r}: expected a positive number")
    if int(publish_every) < 1:
        raise ValueError(f"publish_every {publish_every!r}: expected an integer >= 1")
    if not (lead >= 0 and math.isfinite(lead)):
        raise ValueError(f"lead {lead!r}: expected a number of seconds >= 0")
    if not (0 <= command_delay <= 1.0):
        raise ValueError(f"command_delay {command_delay!r}: expected 0 to 1 s")
    if not (release_slice == 0 or 1e-4 <= release_slice <= 0.1):
        raise ValueError(f"release_slice {release_slice!r}: expected 0 (the system's) or 0.0001 to 0.1 s")
    if not (release_period >= 0 and math.isfinite(release_period)):
        raise ValueError(f"release_period {release_period!r}: expected a number of seconds >= 0")


@dataclass(frozen=True)
class RealtimeSettings:
    """What a :class:`Runner` in realtime pacing is asked for beyond its pace (its keywords of
    the same names, checked there)."""

    #: how far ahead of its deadline (wall s) a step may be computed (at least one step's
    #: period; only that where the twin cannot come back to a checkpoint)
    lead: float = 0.1
    #: steps computed ahead: a command takes effect at the first step boundary at least this
    #: long (wall s) after it arrived, so that the steps redone after it (a command's first
    #: steps cost more: events, new charts) are ready by their deadlines; at most the lead,
    #: where the steps ahead end
    command_delay: float = 0.0
    #: the releasing thread wakes about once per this many wall seconds and sends every step
    #: whose deadline has passed, so a step goes out at most this less one step's period after
    #: its deadline; up to one step's period (0 too): each at its deadline
    release_period: float = 0.0
    #: the scheduler slice (s) the releasing thread asks for, where the system grants one
    #: (:func:`mps_ros.os_threads.short_slice`); 0: it asks for none
    release_slice: float = 1e-4
    #: simulated seconds run ahead in :meth:`Runner.prepare` (:meth:`Twin.warm_up`)
    warm_up: float = 1.0
    #: once prepared: the objects made so far (scene, kernels, ROS) are frozen out of the
    #: garbage collector's passes (``gc.freeze``), so that a full collection during the run
    #: scans only what the run made since (milliseconds, not tens of them, holding the
    #: interpreter); a process-wide choice, the node's
    freeze_gc: bool = False


class Runner:
    """Steps a :class:`Twin`, paces it, takes commands from an :class:`Inbox`, and hands every
    message to every sink (:class:`~mps_ros.run.sinks.Sink`, through one
    :class:`~mps_ros.run.sinks.Fanout`): its CDR bytes (encoded once:
    :meth:`Twin.state_payloads` for the step's messages, :meth:`encoder` for the others) and its
    simulated time in ns, a step's state in one ``emit_all`` call, the commands received
    marked so; ``tick`` once a step.

    The pacings drive a run through its public hooks: :meth:`begin`, :meth:`timed_step`,
    :meth:`publish_step`, :meth:`emit_events`, :meth:`publish_diagnostics`,
    :meth:`take_commands`, :meth:`failed`, :meth:`end`, with :meth:`staged` to fill a release
    instead of handing it to the sinks, and :attr:`stopping`, set when the run is to stop.

    Its parts: ``realtime``, the settings of realtime pacing (:class:`RealtimeSettings`);
    ``commands``, the commands taken, answered and counted (:class:`RunCommands`);
    ``measurements``, step and publish times, and in realtime pacing the latency after each
    step's deadline, as :class:`Timings` (percentiles to 1 %, memory flat over any run
    length), with the run's counts (:class:`Measurements`); ``clocks``, the run's clocks
    (:class:`RunClocks`)."""

    def __init__(
        self,
        twin: Twin,
        *,
        sinks: Iterable[Sink] = (),
        pacing: str = "as_fast_as_possible",
        real_time_factor: float = 1.0,
        publish_every: int = 1,
        diagnostics_period: float = 1.0,
        inbox: Inbox | None = None,
        gate: Gate | None = None,
        log: Callable[[str, str], None] | None = None,
        name: str = "press_twin",
        warm_up: float = 1.0,
        lead: float = 0.1,
        command_delay: float = 0.0,
        release_period: float = 0.0,
        release_slice: float = 1e-4,
        freeze_gc: bool = False,
    ):
        _check_pacing(
            pacing, real_time_factor, publish_every, lead, command_delay, release_slice, release_period
        )
        self.twin = twin
        self.pacing = pacing
        self.rtf = float(real_time_factor)
        self.every = int(publish_every)
        self.period = float(diagnostics_period)
        self.realtime = RealtimeSettings(
            lead=float(lead),
            command_delay=float(command_delay),
            release_period=float(release_period),
            release_slice=float(release_slice),
            warm_up=float(warm_up),
            freeze_gc=bool(freeze_gc),
        )
        self.sinks = Fanout(sinks)
        self.inbox = inbox if inbox is not None else Inbox()
        self.log = log or (lambda level, text: None)
        self.name = name
        self.commands = RunCommands(self, gate or Gate(), self.log)
        self.measurements = Measurements()
        self.clocks = RunClocks()
        self.stop_reason: str | None = None
        self.error: str | None = None
        #: what kind of error ended the run, where the run says (a stepping process's); None
        self.error_kind: str | None = None
        self.stopping = threading.Event()
        self._paused = threading.Event()  # as fast as possible: held (pause())
        self._step_replies: collections.deque = collections.deque()  # step_paused()
        self._prepared = False
        self._encoders: dict = {}
        self._staging: list | None = None  # the release being filled (realtime)

    @property
    def commands_lost(self) -> int:
        """Commands lost on the way (:attr:`RunCommands.lost`: the node's QoS events count
        them)."""
        return self.commands.lost

    @commands_lost.setter
    def commands_lost(self, n: int) -> None:
        self.commands.lost = n

    def close(self) -> None:
        """End what the run started beside it: nothing (it steps in this process's threads)."""

    def request_stop(self, reason: str) -> None:
        """Ask the loop to end after the step in progress (from a signal handler or thread)."""
        if self.stop_reason is None:
            self.stop_reason = reason
        self.stopping.set()
        self.inbox.wake()

    # -- emitting -------------------------------------------------------------------------
    def encoder(self, key: str) -> Callable[[dict], bytes]:
        """Return the CDR encoder of ``key``'s message type (made once)."""
        enc = self._encoders.get(key)
        if enc is None:
            from ..wire.cdr import encoder

            enc = self._encoders[key] = encoder(BY_KEY[key].msgtype)
        return enc

    def emit(self, key: str, msg: dict, t_ns: int) -> None:
        """Encode ``msg`` and hand it to every sink (:meth:`send`)."""
        self.send(key, self.encoder(key)(msg), t_ns)

    def send(self, key: str, data: bytes, t_ns: int, received: bool = False) -> None:
        """Hand one message to every sink (``received``: a command as it came in); while a
        release is being filled (:meth:`staged`), to it instead."""
        if self._staging is not None:
            self._staging.append((key, data, t_ns, received))
            return
        if not received:
            self.measurements.messages += 1
        self.sinks.emit_all([(key, data, t_ns, received)])

    def staged(self, msgs: list[Message]) -> _Staged:
        """Return a context in which what the run emits goes into ``msgs`` (a paced run's
        release being filled) instead of to the sinks."""
        return _Staged(self, msgs)

    def emit_events(self, events, t_ns):
        m = self.measurements
        if "events" not in self.twin.outputs:
            m.events += len(events)
            return
        for ev in events:
            m.events += 1
            self.emit("~/events", {"data": to_json(ev)}, t_ns)

    def publish_step(self, payloads, t_ns):
        """Hand the step's state to every sink at once (then ``tick``); then its events,
        whose impulses are worked out now, after the state is out."""
        if self._staging is not None:  # realtime: into the step's release
            self._staging.extend((key, data, t_ns, False) for key, data in payloads)
        else:
            self.measurements.messages += len(payloads)
            self.sinks.emit_all([(key, data, t_ns, False) for key, data in payloads])
            self.sinks.tick(None)
        events = self.twin.new_events()
        if events:
            self.emit_events(events, t_ns)

    def take_commands(self) -> None:
        """The commands waiting in the inbox, each taken at the present step boundary
        (:meth:`RunCommands.take`)."""
        cmds = self.inbox.drain()
        if cmds:
            self.commands.take(cmds)

    # -- diagnostics ----------------------------------------------------------------------
    def stats(self) -> dict:
        clocks, m, cmds, twin = self.clocks, self.measurements, self.commands, self.twin
        wall = clocks.wall()
        sim = twin.t - twin.t0
        st, pt = m.step_times, m.publish_times
        out = {
            "pacing": self.pacing,
            "real_time_factor_target": self.rtf if self.pacing == "realtime" else math.inf,
            "real_time_factor": sim / wall if wall > 0 else math.nan,
            "sim_time": sim,
            "wall_time": wall,
            "steps": twin.k,
            "t": twin.t,
            "step_time_p50_ms": st.percentile(50) * 1e3,
            "step_time_p99_ms": st.percentile(99) * 1e3,
            "step_time_max_ms": st.max * 1e3,
            "publish_time_p50_ms": pt.percentile(50) * 1e3,
            "publish_time_p99_ms": pt.percentile(99) * 1e3,
            "deadline_misses": m.misses,
            "steps_recomputed": m.steps_recomputed,
            "messages": m.messages,
            "events": m.events,
            "commands_accepted": cmds.accepted,
            "commands_refused": cmds.refused,
            "commands_lost": cmds.lost,
            "cpu_time": clocks.cpu(),
            # the stepping thread's own CPU (steps, messages, commands; not the publishing
            # thread, the middleware's threads or the recording process)
            "step_thread_cpu_per_step_us": clocks.thread() / max(1, twin.k) * 1e6,
        }
        # the whole process's CPU over the run (every thread: stepping, releasing, the
        # middleware's; not the recording process), from the clocks' start to the run's end
        out["process_cpu_per_step_us"] = out["cpu_time"] / max(1, twin.k) * 1e6
        if self.pacing == "realtime":
            # the releasing thread's own scheduler slice (0: none was granted)
            out["release_slice_ms"] = (m.release_slice or 0.0) * 1e3
        if m.latencies.n:
            lat = m.latencies
            out["latency_p50_ms"] = lat.percentile(50) * 1e3
            out["latency_p99_ms"] = lat.percentile(99) * 1e3
        return out

    def publish_diagnostics(self, t_ns: int) -> None:
        """/diagnostics (:mod:`mps_ros.wire.diagnostics`): pacing, commands, and the status of each
        sink that has one (the recording), about the window since the last."""
        if "diagnostics" not in self.twin.outputs:
            return
        s = self.stats()
        cmds = self.commands
        refused, floods, lost = cmds.elsewhere
        refused += cmds.refused
        floods += cmds.gate.floods
        lost += cmds.lost
        new = self.measurements.window.since(
            misses=s["deadline_misses"], steps=self.twin.k, floods=floods, lost=lost
        )
        hw = hardware_id(self.twin.scene.name)
        statuses = [
            diagnostics.pacing(self.name, hw, s, new["misses"], new["steps"], self.pacing == "realtime"),
            diagnostics.commands(
                self.name, hw, cmds.accepted, refused, floods, lost, new["floods"], new["lost"]
            ),
        ]
        statuses += self.sinks.statuses(self.name, hw)
        self.emit("/diagnostics", diagnostics.array(t_ns, statuses), t_ns)

    # -- the loop -------------------------------------------------------------------------
    def prepare(self) -> None:
        """Everything slow done once before the clock starts: the kernels the first steps
        would build (:meth:`Twin.warm_up`, paced runs), encoders, the sinks' channels. The run
        calls it; a caller may call it earlier (the node, while it waits for its peers): the
        second call does nothing."""
        if self._prepared:
            return
        self._prepared = True
        rt = self.realtime
        if self.pacing == "realtime" and rt.warm_up > 0:
            self.twin.warm_up(rt.warm_up)
        keys = [t.key for t in BY_KEY.values() if not t.output or t.output in self.twin.outputs]
        for k in keys:
            self.encoder(k)
        self.sinks.prepare(keys)
        if rt.freeze_gc and self.pacing == "realtime":
            import gc

            gc.collect()
            gc.freeze()

    def begin(self) -> None:
        """The run's start event and the first state, then the commands already waiting."""
        twin = self.twin
        t_ns = twin.t_ns
        self.emit_events(
            [
                {
                    "t": twin.t,
                    "kind": "run-start",
                    **twin.describe(),
                    "pacing": self.pacing,
                    "real_time_factor": self.rtf,
                    "publish_every": self.every,
                }
            ],
            t_ns,
        )
        self.publish_step(twin.state_payloads(), t_ns)
        self.take_commands()

    def failed(self, exc: Exception) -> None:
        self.error = f"{type(exc).__name__}: {exc}"
        self.stop_reason = "error"
        self.log("error", f"the run stopped at t = {self.twin.t:.6f} s: {self.error}")

    def end(self) -> None:
        """The run's last messages: commands still waiting refused, the last events, the
        diagnostics and the end event (never lost over a late error)."""
        twin = self.twin
        self.clocks.stop()
        reason = self.stop_reason or "end"
        t_ns = twin.t_ns
        self.commands.refusals.close()
        end = {"t": twin.t, "kind": "run-end", "reason": reason, "steps": twin.k}
        if self.error:
            end["error"] = self.error
        for part in (
            lambda: self.commands.refuse_pending(
                "the run has ended" if reason == "end" else f"the run is stopping ({reason})"
            ),
            lambda: self.emit_events(twin.new_events(), t_ns),
            lambda: self.publish_diagnostics(t_ns),
            lambda: self.emit_events([end], t_ns),
        ):
            try:
                part()
            except Exception as exc:  # never lose the recording's end over a late message
                self.log("error", f"could not emit one of the run's last messages: {exc}")

    def run(self) -> dict:
        if self.pacing == "realtime":
            from .paced import PacedInProcess

            return PacedInProcess(self).run()
        twin = self.twin
        clock = time.perf_counter
        self.prepare()
        self.clocks.start()
        next_diag = self.clocks.wall_start + self.period
        publish_times = self.measurements.publish_times
        try:
            self.begin()
            reply = None
            while not twin.done and not self.stopping.is_set():
                if self._paused.is_set():
                    reply = self._hold()
                    if reply is None:
                        continue
                _k, msgs, p0 = self.timed_step(math.inf, clock)  # no deadline: no miss
                t_ns = twin.t_ns
                if msgs is not None:
                    self.publish_step(msgs, t_ns)
                else:
                    self.emit_events(twin.new_events(), t_ns)
                publish_times.add(clock() - p0)
                self.take_commands()
                if msgs is None:  # once a step: publish_step() has ticked where it published
                    self.sinks.tick(None)
                now = clock()
                if now >= next_diag:
                    next_diag = now + self.period
                    self.publish_diagnostics(t_ns)
                if reply is not None:  # a step taken while paused: said
                    done: Callable = reply
                    reply = None
                    done(twin.t)
        except Exception as exc:
            self.failed(exc)
            raise
        finally:
            self.end()
        return self.stats()

    def pause(self) -> str | None:
        """Hold the run at its present step until :meth:`resume` (the node's lifecycle:
        deactivate, activate): None, or why it cannot."""
        if self.pacing == "realtime":
            return "a realtime run pauses in its stepping process (stepping_process:=true, the default)"
        self._paused.set()
        return None

    def resume(self) -> None:
        self._paused.clear()
        self.inbox.wake()

    def step_paused(self, reply) -> str | None:
        """One step while paused (the node's ``~/step``); ``reply(t)`` once it is out. None,
        or why not."""
        if not self._paused.is_set():
            return "the node is active: ~/step takes a step while it is deactivated"
        self._step_replies.append(reply)
        self.inbox.wake()
        return None

    def _hold(self):
        """Paused: simulated time holds; commands are taken at this step; the diagnostics say
        STALE once a period (with the sinks' statuses), nothing else goes out. Returns when
        resumed or stopped (None), or with the reply of a step asked for meanwhile."""
        t_ns = self.twin.t_ns
        hw = hardware_id(self.twin.scene.name)
        next_diag = 0.0
        while self._paused.is_set() and not self.stopping.is_set():
            self.take_commands()
            if self._step_replies:
                return self._step_replies.popleft()
            now = time.perf_counter()
            if now >= next_diag and "diagnostics" in self.twin.outputs:
                next_diag = now + self.period
                statuses = [diagnostics.paused(self.name, hw, self.twin.t)]
                statuses += self.sinks.statuses(self.name, hw)
                self.emit("/diagnostics", diagnostics.array(t_ns, statuses), t_ns)
                self.sinks.tick(None)
            self.inbox.wait(0.05)

    def timed_step(self, deadline: float, clock) -> tuple[int, list | None, float]:
        """One step: the twin stepped and its messages made where due, the compute time kept
        and a deadline miss counted where it ended after ``deadline``; (k, the messages or
        None, the wall time it ended)."""
        twin = self.twin
        c0 = clock()
        twin.step()
        k = twin.k
        msgs = twin.state_payloads() if (k % self.every == 0 or twin.done) else None
        c1 = clock()
        m = self.measurements
        m.step_times.add(c1 - c0)
        if c1 > deadline:
            m.misses += 1
        return k, msgs, c1


class _Staged:
    """While entered, what a :class:`Runner` emits goes into a release's list."""

    __slots__ = ("runner", "msgs")

    def __init__(self, runner: Runner, msgs: list[Message]):
        self.runner, self.msgs = runner, msgs

    def __enter__(self) -> list[Message]:
        self.runner._staging = self.msgs
        return self.msgs

    def __exit__(self, *exc) -> None:
        self.runner._staging = None


__all__ = ["Runner", "RealtimeSettings", "PACINGS"]
