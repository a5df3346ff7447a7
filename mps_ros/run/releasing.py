"""The node's side of a split run (:class:`SteppingProcess`): the steps its stepping process
(:mod:`mps_ros.run.stepping`) computed, held and released at their deadlines (or as they come,
as fast as possible), to the ROS publishers first and then to the recorder
(:class:`~.publication.Publication`); the commands taken as they arrive, each at its boundary
(:class:`~.boundaries.Boundaries`); the stepping process started, watched and ended
(:class:`~.child.SteppingChild`). See :mod:`mps_ros.run.stepping` for the frames, the commands'
rules and the faults."""

from __future__ import annotations

import collections
import json
import marshal
import math
import time

from ..wire.pipe import Frame
from .boundaries import Boundaries, HeldStep, HeldSteps, Schedule
from .child import Scheduling, SteppingChild, exit_words
from .commands import Command, Gate
from .publication import Publication
from .sinks import Fanout

#: as fast as possible, the node tells the stepping process of its releases (frame
#: ``RELEASED``) every this many steps, fewer than the steps it may compute ahead
#: (``_Ahead.AHEAD`` of :mod:`mps_ros.run.stepping`): each frame wakes that process's reading
#: thread, which takes the interpreter from the stepping thread (told at every release, the
#: stepping process took about 7 % more CPU a step)
TOLD_EVERY = 64


class ForwardingInbox:
    """The node's inbox in a split run: each command is taken at once (:meth:`put`)."""

    def __init__(self, stepper: SteppingProcess):
        self.stepper = stepper

    def put(self, cmd: Command) -> None:
        self.stepper.command(cmd)

    def wake(self) -> None:
        pass

    def __bool__(self) -> bool:
        return False

    def drain(self) -> list:
        return []


class SteppingProcess:
    """The ROS process's side of a split run, with what the node needs of a
    :class:`~mps_ros.run.runner.Runner` (``prepare``, ``run``, ``request_stop``, ``stats``,
    ``stop_reason``, ``error``, ``commands_lost``, ``inbox``, ``sinks``).

    It holds the steps the stepping process has computed ahead and releases each at its
    deadline: to ``sink.emit_all`` (the ROS publishers) at once, then to the other
    ``sinks`` (the recorder). A command is taken as it arrives: the gate (a flood, an empty,
    overlong or unknown word) answers here, at the boundary, without disturbing the stepping;
    any other command's boundary is chosen here (the first step whose deadline is not before
    its arrival plus :attr:`command_delay`, among the last released and those held), the
    steps held beyond it are dropped, and the stepping process applies it there and computes
    on.

    ``spec``: the stepping process's settings (``scene``; ``twin``: :class:`Twin`'s keywords;
    ``runner``: :class:`Runner`'s). ``log(level, text)``; ``gate``: the command gate;
    ``priority``: the SCHED_FIFO priority asked for the stepping process and this process's
    publishing thread (0: none).

    Its parts: ``child``, the stepping process itself (:class:`SteppingChild`);
    ``publication``, the steps released, published and recorded (:class:`~.publication.Publication`);
    ``scheduling``, the run's real-time scheduling (:class:`Scheduling`); ``boundaries``, the
    commands (:class:`Boundaries`)."""

    def __init__(self, spec: dict, sink, log, gate: Gate, priority: int = 0):
        self.spec = spec
        #: as fast as possible: each step released as it comes, a command applied at the
        #: boundary of the last step released (the steps held beyond it computed again)
        self.afap = bool(spec.get("afap"))
        self.log = log
        self.inbox = ForwardingInbox(self)
        self.stop_reason: str | None = None
        self.error: str | None = None
        self.error_kind: str | None = None
        self._lost = 0
        #: the stepping process itself, once started (:meth:`prepare`)
        self.child: SteppingChild | None = None
        #: the steps released: published, recorded, measured
        self.publication = Publication(spec, sink, log)
        self.scheduling = Scheduling(priority, log)
        #: the steps held for their deadlines (shared with the commands' boundaries)
        self.held = HeldSteps()
        #: the steps' times
        self.schedule = Schedule.of(spec)
        self._stats: dict = {}
        self._prepared = False
        self.paused_s = 0.0  # wall seconds paused so far
        #: this process's CPU over the run (s), once it has ended
        self.ros_cpu: float | None = None
        #: the replies of the steps asked for while paused (~/step), in order
        self._step_replies: collections.deque = collections.deque()
        #: the commands, each at its boundary
        self.boundaries = Boundaries(
            self.held,
            self.schedule,
            gate,
            log,
            send_command=self._send_command,
            counts_changed=self._tell_counts,
            command_delay=float(spec["runner"].get("command_delay", 0.0)),
        )

    @property
    def sinks(self) -> Fanout:
        """The sinks after the publishers: the recorder (:attr:`Publication.sinks`)."""
        return self.publication.sinks

    @property
    def commands_refused(self) -> int:
        """Commands answered as refused in this process (the gate's and the machine's)."""
        return self.boundaries.commands_refused

    @property
    def commands_lost(self) -> int:
        """Commands lost on the way to the node (the node's QoS events count them)."""
        return self._lost

    @commands_lost.setter
    def commands_lost(self, n: int) -> None:
        self._lost = n
        self._tell_counts()

    def _tell_counts(self) -> None:
        """This process's command counts (refused here, of which as floods; lost) to the
        stepping process, whose /diagnostics say them."""
        if self.child is not None:
            refused, floods = self.boundaries.commands_refused, self.boundaries.gate.floods
            self.child.out.frame(Frame.REFUSED, marshal.dumps((refused, floods, self._lost)))

    # -- start ------------------------------------------------------------------------------
    def prepare(self) -> None:
        """Start the stepping process and wait until it has built its twin and its kernels
        (raises OSError with its reason where it could not); the sinks' channels."""
        if self._prepared:
            return
        self._prepared = True
        self.child = SteppingChild(self.spec)
        self.publication.prepare()
        self.child.wait_ready(self.log)

    # -- commands and stops (any thread) ------------------------------------------------------
    def command(self, cmd: Command) -> None:
        self.boundaries.command(cmd)

    def _started(self) -> SteppingChild:
        """Return the stepping process (:meth:`prepare` has started it)."""
        if self.child is None:
            raise RuntimeError("the stepping process has not been started (prepare())")
        return self.child

    def _send_command(self, payload: bytes) -> None:
        """A command on to the stepping process (:class:`Boundaries` chose its boundary)."""
        self._started().out.frame(Frame.COMMAND, payload)

    def pause(self) -> str | None:
        """Hold the run (the node's lifecycle: deactivate): nothing more is released or
        computed ahead, simulated time holds at the last step released; commands are still
        taken (at the next boundary). None, or why not."""
        with self.held.lock:
            if self.held.ended:
                return "the run has ended"
            if self.held.paused_at is None:
                self.held.paused_at = time.perf_counter()
                self._started().out.frame(Frame.PAUSE, b"")
        return None

    def step_paused(self, reply) -> str | None:
        """One step while paused (the node's ``~/step``): the next step held is released, or
        the stepping process computes one; ``reply(t)`` once it is out. None, or why not."""
        with self.held.lock:
            if self.held.ended:
                return "the run has ended"
            if self.held.paused_at is None:
                return "the node is active: ~/step takes a step while it is deactivated"
            self._step_replies.append(reply)
            if len(self._step_replies) > sum(1 for e in self.held.queue if e.state):
                self._started().out.frame(Frame.STEP, b"")
        return None

    def resume(self) -> None:
        """Go on after :meth:`pause`: every deadline (held, and in the stepping process) moves
        on by the time since the pause (or since the deadline of the last step taken with
        ``~/step``, where that is later)."""
        with self.held.lock:
            if self.held.paused_at is None:
                return
            since = self.held.paused_at
            if self.held.released is not None and self.held.released.deadline > since:
                since = self.held.released.deadline
            d = time.perf_counter() - since
            self.held.paused_at = None
            self.paused_s += d
            for e in self.held.queue:
                e.deadline += d
            self.boundaries.shift(d)
            self._started().out.frame(Frame.RESUME, marshal.dumps(d))

    def request_stop(self, reason: str) -> None:
        if self.stop_reason is None:
            self.stop_reason = reason
        if self.child is not None:
            self.child.out.frame(Frame.STOP, reason.encode())

    # -- the run ----------------------------------------------------------------------------
    def run(self) -> dict:
        """Go; release each step at its deadline until the stepping process's end (or its
        death: :attr:`error` says so)."""
        self.prepare()
        self.scheduling.apply(0.0 if self.afap else self.spec["runner"].get("release_slice", 1e-4))
        child = self._started()
        out, reader, pub = child.out, child.reader, self.publication
        out.frame(Frame.GO, json.dumps({"priority": self.scheduling.priority}).encode())
        cpu0 = time.process_time()
        clock = time.perf_counter
        fd = reader.fd
        queue, lock, boundaries = self.held.queue, self.held.lock, self.boundaries
        end = None
        eof = False
        told = -1  # as fast as possible: the last step released that the stepping process knows of
        if self.afap:
            pub.first = clock()  # the run's start: the first step goes out as it comes
        import select

        while True:
            now = clock()
            # a run stopped early lets go of what it holds at once
            flush = end is not None and (end.get("stop_reason") or end.get("error"))
            self._release_due(now, flush, clock)
            if self.afap and self.held.released is not None and self.held.released.k - told >= TOLD_EVERY:
                # the stepping process steps on up to _Ahead.AHEAD past it
                told = self.held.released.k
                out.frame(Frame.RELEASED, marshal.dumps(told))
            if self.held.paused_at is not None and now >= pub.next_status:
                released = self.held.released
                pub.stale(now, None if released is None else self.schedule.time_of(released.k))
            if (end is not None or eof) and not queue:
                break
            if eof:
                if queue:
                    wait = queue[0].deadline - clock()
                    if wait > 0:
                        time.sleep(min(wait, 0.05))
                continue
            if self.held.paused_at is not None:
                wait = 0.05  # paused: awake for the diagnostics' STALE
            else:
                wait = (queue[0].deadline - clock()) if queue else 0.5
            # the next deadline, or what the stepping process sends, whichever comes first
            if not select.select([fd], [], [], wait if wait > 0.0 else 0.0)[0]:
                continue
            got = reader.read()
            if not got:
                eof = True
                continue
            end = self._take_frames(got) or end
            if boundaries.has_waiting():
                with lock:
                    boundaries.take_waiting()
        boundaries.end()
        self.ros_cpu = time.process_time() - cpu0
        pub.sinks.tick(None)
        return self._finish(end)

    def _release_due(self, now: float, flush, clock) -> None:
        """Every held step whose deadline has passed by ``now`` (as fast as possible: every
        one held; paused: those asked for), released in order; ``flush``: all held."""
        queue, lock, release = self.held.queue, self.held.lock, self.publication.release
        while True:
            reply = None
            with lock:
                if not queue:
                    break
                if not flush:
                    if self.held.paused_at is not None:  # paused: the steps asked for
                        if not self._step_replies:
                            break
                    elif not self.afap and queue[0].deadline > now:
                        break
                head = self.held.released = queue.popleft()
                if head.state and self.held.paused_at is not None and self._step_replies:
                    reply = self._step_replies.popleft()
            release(head, clock)
            if reply is not None:
                try:
                    reply(self.schedule.time_of(head.k))
                except Exception:  # a reply must never take the run down
                    pass

    def _take_frames(self, got: list) -> dict | None:
        """The frames the stepping process sent: steps held (of the present generation),
        answers given, log lines said, its priority; the run's end (returned, where it came)."""
        end = None
        loads, messages = marshal.loads, Frame.MESSAGES
        entries: list[HeldStep] = []  # the steps read in a row, held at once
        for kind, payload in got:
            if kind == messages:
                entry = HeldStep(*loads(payload))
                entry.encoded = payload  # to the recorder as it came
                entries.append(entry)
                continue
            if entries:  # held before what came after them
                self._hold(entries)
                entries = []
            if kind == Frame.ANSWER:
                cid, ack = marshal.loads(payload)
                self.boundaries.answer(cid, json.loads(ack))
            elif kind == Frame.LOG:
                self.log(*marshal.loads(payload))
            elif kind == Frame.PRIORITY:
                self.scheduling.said(json.loads(payload))
            elif kind == Frame.END:
                end = json.loads(payload)
                with self.held.lock:
                    self.held.ended = True
        if entries:
            self._hold(entries)
        return end

    def _hold(self, entries: list[HeldStep]) -> None:
        """Hold the steps that came in a row from the stepping process, in order.

        Each is held or dropped as :meth:`Boundaries.arrived` says (an earlier generation's
        past its boundary), the lock taken once for them all."""
        arrived = self.boundaries.arrived
        with self.held.lock:
            for entry in entries:
                arrived(entry)

    def _finish(self, end: dict | None) -> dict:
        child = self._started()
        if end is None:  # the stepping process died
            child.wait(10)
            self.error = (
                f"the stepping process (pid {child.proc.pid}) ended without finishing "
                f"the run ({exit_words(child.proc.returncode)})"
            )
            self.error_kind = "died"
            self.stop_reason = "error"
            k = self.publication.k_released or 0
            self._stats = {"steps": k, "t": self.schedule.time_of(k)}
        else:
            child.proc.wait(30)
            self._stats = end["stats"]
            self.stop_reason = end.get("stop_reason") or self.stop_reason
            self.error = end.get("error")
            self.error_kind = end.get("error_kind")
        return self.stats()

    def stats(self) -> dict:
        """The stepping process's statistics, with this process's publication figures (the
        latency is measured here, after each step's publishes) and the CPU of both."""
        pub = self.publication
        s = dict(self._stats)
        steps = max(1, int(s.get("steps", 0) or 0))
        if pub.latencies.n:
            s["latency_p50_ms"] = pub.latencies.percentile(50) * 1e3
            s["latency_p99_ms"] = pub.latencies.percentile(99) * 1e3
        if pub.publish_times.n:
            s["publish_time_p50_ms"] = pub.publish_times.percentile(50) * 1e3
            s["publish_time_p99_ms"] = pub.publish_times.percentile(99) * 1e3
        ros = self.ros_cpu
        step_cpu = s.get("cpu_time")
        if ros is not None and step_cpu is not None:
            s["stepping_process_cpu_per_step_us"] = step_cpu / steps * 1e6
            s["ros_process_cpu_per_step_us"] = ros / steps * 1e6
            s["process_cpu_per_step_us"] = (step_cpu + ros) / steps * 1e6
        s["messages"] = pub.messages
        if pub.first is not None and "sim_time" in s and pub.last > pub.first:
            # from the schedule's start to the last release (the steps were computed ahead),
            # the pauses left out
            s["wall_time"] = pub.last - pub.first - self.paused_s
            s["real_time_factor"] = s["sim_time"] / s["wall_time"]
        s["commands_lost"] = self.commands_lost
        s["commands_refused"] = s.get("commands_refused", 0) + self.commands_refused
        s["realtime_priority"] = self.scheduling.got or 0
        if not self.afap:  # the publishing thread is this process's: its slice, not the stepping's
            s["release_slice_ms"] = self.scheduling.slice_granted * 1e3
        for k in (
            "step_time_p50_ms",
            "step_time_p99_ms",
            "publish_time_p50_ms",
            "publish_time_p99_ms",
            "real_time_factor",
            "deadline_misses",
            "step_thread_cpu_per_step_us",
            "process_cpu_per_step_us",
            "commands_accepted",
            "steps",
        ):
            s.setdefault(k, 0 if k in ("deadline_misses", "steps", "commands_accepted") else math.nan)
        return s

    def close(self) -> None:
        """End the stepping process if it is still there (the node is going away)."""
        child = self.child
        if child is None:
            return
        if child.proc.poll() is None:
            self.request_stop("the node is shutting down")
            child.wait(30)
        child.close()
