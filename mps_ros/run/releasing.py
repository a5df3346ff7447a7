"""The node's side of a split run (:class:`SteppingProcess`): the steps its stepping process
(:mod:`mps_ros.run.stepping`) computed, held and released at their deadlines (or as they come, as
fast as possible), to the ROS publishers first and then to the recorder (:class:`Publication`);
the commands taken as they arrive, each at its boundary (:class:`Boundaries`); the stepping
process started, watched and ended (:class:`SteppingChild`). See :mod:`mps_ros.run.stepping` for
the frames, the commands' rules and the faults."""

from __future__ import annotations

import collections
import json
import marshal
import math
import signal
import subprocess
import sys
import threading
import time

from ..os_threads import widen_pipe
from ..wire.pipe import Frame, FrameReader, FrameWriter
from ..wire.topics import BY_KEY
from .commands import COMMAND_INDEX, Command, Gate, RefusalLog, shown
from .metrics import Timings
from .stepping import HOW_TO_ALLOW, ask_fifo, fifo_for_the_others
from .twin import to_json, to_ns


class _Entry:
    """A step (or a command's answers) from the stepping process, waiting for its deadline;
    ``structure`` and ``refusals`` (:meth:`Twin.refusals`): the twin's after it."""

    __slots__ = ("k", "gen", "deadline", "state", "structure", "refusals", "msgs")

    def __init__(self, k, gen, deadline, state, structure, refusals, msgs):
        self.k, self.gen, self.deadline = k, gen, deadline
        self.state, self.structure, self.refusals, self.msgs = state, structure, refusals, msgs


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


class Boundaries:
    """The commands of a split run, taken in the node's process as they arrive (any thread),
    each at its boundary: one the gate refuses (a flood, an empty, overlong or unknown word)
    or the machine would refuse there (what the step held there says) is answered here, at no
    cost to the stepping; any other goes to the stepping process with its boundary and a new
    *generation*, the steps held beyond it dropped (and what was already in the pipe of the old
    generation dropped on arrival: :meth:`arrived`). ``run``: the :class:`SteppingProcess`
    whose steps are held (its lock, the steps held and the last released, its pipe)."""

    def __init__(self, run: SteppingProcess, gate: Gate, log):
        from ..wire.cdr import string

        self.run = run
        self.gate = gate
        #: a command takes effect at the first step boundary at least this long (wall s) after
        #: it arrived (see :attr:`~mps_ros.run.runner.RealtimeSettings.command_delay`)
        self.command_delay = float(run.spec["runner"].get("command_delay", 0.0))
        self.commands_refused = 0
        self._string = string
        self._replies: dict[int, object] = {}  # the services' replies, by the id sent on
        self._next_id = 0
        self._gen = 0
        self._limits: dict[int, int] = {}  # an earlier generation: its last valid step
        self._received_gen = 0  # the last generation received
        self._last_boundary = -1  # the step of the last command sent on
        self._held: dict[int, list] = {}  # refusals that follow a command's answers
        #: commands that came while one sent on was unanswered: (command, word, the gate's
        #: refusal or None)
        self._waiting: collections.deque = collections.deque()
        self._refusals = RefusalLog(log)

    def arrived(self, entry: _Entry) -> bool:
        """A step (or a command's answers) from the stepping process, held where it is of
        the present generation or of an earlier one up to that one's boundary (the lock
        held); False where it was dropped."""
        gen = entry.gen
        if not (gen == self._gen or entry.k <= self._limits.get(gen, -1)):
            return False
        queue = self.run._queue
        queue.append(entry)
        if gen > self._received_gen:  # a command's answers
            self._received_gen = gen
            queue.extend(self._held.pop(gen, ()))
        return True

    def answer(self, cid: int, ack: dict) -> None:
        """The stepping process's answer to a command a service sent (any thread)."""
        with self.run._lock:
            reply = self._replies.pop(cid, None)
        if reply is not None:
            try:
                reply(ack)
            except Exception:  # a reply must never take the run down
                pass

    def end(self) -> None:
        """The run has ended: the commands that waited are refused, the services still
        waiting for an answer told so."""
        with self.run._lock:
            self.run._ended = True
            self.take_waiting()
            replies, self._replies = self._replies, {}
        self._refusals.close()
        for reply in replies.values():
            try:
                reply(
                    {
                        "t": math.nan,
                        "command": "",
                        "accepted": False,
                        "reason": "the run has ended",
                        "source": "service",
                        "structure": "",
                    }
                )
            except Exception:
                pass

    def has_waiting(self) -> bool:
        """Whether commands wait for the answer of one sent on."""
        return bool(self._waiting)

    def shift(self, d: float) -> None:
        """The held answers' deadlines moved on by ``d`` wall seconds (a pause ended)."""
        for held in self._held.values():
            for e in held:
                e.deadline += d

    def command(self, cmd: Command) -> None:
        word = cmd.word if isinstance(cmd.word, str) else str(cmd.word)
        with self.run._lock:
            if self.run._paused_at is not None and self.run._released is not None:
                # paused: simulated time holds at the last step released; the command is
                # taken at the next boundary, as if it had come then
                cmd.wall = self.run._released.deadline
            refusal = "the run has ended" if self.run._ended else self.gate.check(word)
            if self._waiting or (refusal is None and self._gen != self._received_gen):
                # a command sent on is still unanswered: this one is taken once it is (what
                # the machine says to it is known then), in the order they came
                self._waiting.append((cmd, word, refusal))
                return
            self._take(cmd, word, refusal)

    def _take(self, cmd: Command, word: str, refusal: str | None) -> None:
        """A command past the gate (``refusal`` None) is answered at its boundary where the
        step held there says that the machine refuses it, else sent on; one the gate refused
        is answered at its boundary (the lock held)."""
        wall = cmd.wall + self.command_delay
        kb = None if refusal is not None else self._step_at(wall)
        if kb is None:
            # at the boundary every command of that wall time has, so that the answers go out
            # in the order the commands came
            self._refuse(cmd, word, refusal or "the run has not started", self._boundary(wall))
            return
        at = self._settled(wall, kb)
        if at is not None and at.refusals[COMMAND_INDEX[word]] is not None:
            # the machine refuses it there: answered as the gate's, the steps stand
            self._refuse(cmd, word, at.refusals[COMMAND_INDEX[word]], at)
            return
        cid = None
        if cmd.reply is not None:
            cid = self._next_id
            self._next_id += 1
            self._replies[cid] = cmd.reply
        queue = self.run._queue
        while queue and queue[-1].k > kb:
            queue.pop()
        self._limits[self._gen] = kb
        self._last_boundary = kb
        self._gen += 1
        self.run.child.out.frame(
            Frame.COMMAND, marshal.dumps((cid, word, cmd.source, cmd.wall, kb, self._gen))
        )

    def take_waiting(self) -> None:
        """The commands that waited for an answer, in order (the lock held), each once the
        step of its boundary is here, until one is sent on; after the run's end, each
        refused."""
        waiting = self._waiting
        while waiting and (self.run._ended or self._gen == self._received_gen):
            cmd, word, refusal = waiting[0]
            if not self.run._ended and refusal is None and not self.run.afap:
                last = self.run._queue[-1] if self.run._queue else self.run._released
                if last is None or last.deadline < cmd.wall + self.command_delay:
                    return  # its boundary's step is still to come
            waiting.popleft()
            self._take(cmd, word, "the run has ended" if self.run._ended else refusal)

    def _step_at(self, wall: float) -> int | None:
        """The first step whose deadline is not before ``wall`` (the lock held), among the
        last released, those held and those still to come (the schedule's; the stepping
        process steps on to it, where it is not there yet); None before the run has started.
        As fast as possible: the last step released."""
        if self.run.afap:
            return None if self.run._released is None else self.run._released.k
        last = self.run._queue[-1] if self.run._queue else self.run._released
        if last is None:
            return None
        grid = self.run.spec.get("grid")
        if last.deadline >= wall or grid is None:
            return self._boundary(wall).k
        n = grid[2]
        return min(n, last.k + max(1, math.ceil((wall - last.deadline) / self._period() - 1e-9)))

    def _settled(self, wall: float, kb: int) -> _Entry | None:
        """The held (or last released) entry that ends step ``kb``, where what it says of the
        machine is what a command there meets (the lock held): no command sent on is still
        unanswered and it is of the present generation; None where that is not known here."""
        if self._gen != self._received_gen:
            return None
        at = self._boundary(wall)
        if at is None or at.k != kb or at.gen != self._gen:
            return None
        return at

    def _period(self) -> float:
        """A step's period on the wall clock (s; 0 where the schedule is not known)."""
        if self.run.spec.get("grid") is None:
            return 0.0
        t0, t_end, n = self.run.spec["grid"]
        return (t_end - t0) / n / float(self.run.spec["runner"].get("real_time_factor", 1.0))

    def _boundary(self, wall: float) -> _Entry | None:
        """The entry a command that arrived at ``wall`` follows (the lock held): the last
        entry of the first step whose deadline is not before ``wall``, among the last released
        and those held; the last of them where none is that late yet. As fast as possible: the
        last step released."""
        if self.run.afap:
            return self.run._released
        at = self.run._released
        d = at.deadline if at is not None and at.deadline >= wall else None
        # held in the order of their deadlines: a command's boundary is near the front
        for e in self.run._queue:
            if d is None:
                at = e
                if e.deadline >= wall:
                    d = e.deadline
            elif e.deadline <= d:
                at = e
            else:
                break
        return at

    def _refuse(self, cmd: Command, word: str, reason: str, at: _Entry | None) -> None:
        """A command the gate refused, answered at its boundary (but never before the answer
        of a command that came earlier: at the boundary of the last one sent on, where that is
        later): its messages go out (and are recorded) right after that step's; the stepping
        is not disturbed."""
        self.commands_refused += 1
        k = at.k if at is not None else 0
        deadline = at.deadline if at is not None else 0.0
        if self._last_boundary > k and at is not None:
            deadline += (self._last_boundary - k) * self._period()
            k = self._last_boundary
        t = self.run._time_of(k)
        structure = at.structure if at is not None else ""
        ack = {
            "t": t,
            "command": shown(word, 64),
            "accepted": False,
            "reason": reason,
            "source": cmd.source,
            "structure": structure,
        }
        t_ns = to_ns(t)
        msgs = [
            ("~/mode", self._string({"data": word}), t_ns, True),
            ("~/mode/status", self._string({"data": to_json(ack)}), t_ns, False),
        ]
        entry = _Entry(
            k, self._gen, deadline, False, structure, at.refusals if at is not None else None, msgs
        )
        queue = self.run._queue
        if self._gen > self._received_gen:
            # a command sent on is being applied: this answer follows that one's
            self._held.setdefault(self._gen, []).append(entry)
        else:
            # after everything held at its step or before (the answers given there included)
            i = next((n for n, e in enumerate(queue) if e.k > k), len(queue))
            queue.insert(i, entry)
        self._refusals.refused(word, cmd.source, t, reason, cmd.wall)
        self.run._tell_counts()
        if cmd.reply is not None:
            try:
                cmd.reply(ack)
            except Exception:
                pass


class SteppingChild:
    """The stepping process itself (``python -m mps_ros.run.stepping``), from the node's side:
    started with its settings (``spec``), ready once it has built its twin and its kernels
    (:meth:`wait_ready`), its frames written (``out``) and read (``reader``), its end waited
    for (:meth:`wait`) and its pipes closed (:meth:`close`)."""

    def __init__(self, spec: dict):
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "mps_ros.run.stepping"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            bufsize=0,
        )
        self.out = FrameWriter(self.proc.stdin.fileno())
        widen_pipe(self.proc.stdin.fileno())
        self.reader = FrameReader(self.proc.stdout.fileno())
        self.out.frame(Frame.SETTINGS, json.dumps(spec).encode())
        self.pid: int | None = None

    def wait_ready(self, log) -> None:
        """Until it says it is ready (its log lines said meanwhile); OSError with its reason
        where it ended or failed first."""
        while True:
            got = self.reader.read()
            if not got:
                self.proc.wait(10)
                raise OSError(
                    f"the stepping process ended before it was ready ({_exit_words(self.proc.returncode)})"
                )
            for kind, payload in got:
                if kind == Frame.LOG:
                    log(*marshal.loads(payload))
                elif kind == Frame.READY:
                    reply = json.loads(payload)
                    if not reply.get("ready"):
                        self.proc.wait(10)
                        raise OSError(reply.get("error", "the stepping process failed"))
                    self.pid = reply["pid"]
                    return

    def wait(self, timeout: float) -> None:
        """Until it has ended; killed where it has not within ``timeout`` s."""
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(10)

    def close(self) -> None:
        for f in (self.proc.stdin, self.proc.stdout):
            try:
                f.close()
            except OSError:
                pass


class Publication:
    """The steps released (:meth:`release`): each published (``sink.emit_all``: the ROS
    publishers) and then recorded (``sinks``: the recorder; one that fails is said once and
    dropped, and the run steps on), measured (publish times and, paced, the latency after its
    deadline; the messages published; ``first``, the schedule's start, and ``last``, the
    last release), and the recording's /diagnostics status said once a diagnostics period and
    at once where it has stopped (:meth:`recording_status`), published and recorded after the
    step's messages."""

    def __init__(self, spec: dict, sink, log):
        self.spec = spec
        self.afap = bool(spec.get("afap"))
        self.sink = sink
        self.sinks: list = []  # the others: the recorder
        self.log = log
        self.latencies = Timings()
        self.publish_times = Timings()
        self.messages = 0
        self.first: float | None = None  # the schedule's start (wall s)
        self.last = 0.0  # the last release (wall s)
        self.k_released: int | None = None
        self.failure: str | None = None  # why the recording stopped, where it did
        self.next_status = 0.0  # the recording's next status (wall s)
        self.diagnostics_encoder = None
        #: the statuses' name prefix (the node's) and hardware_id
        self.named = (spec["runner"].get("name", "press_twin"), spec.get("hardware_id", "mps"))

    def prepare(self) -> None:
        """The sinks' channels; the recording status's encoder."""
        keys = [t.key for t in BY_KEY.values() if not t.output or t.output in self.spec["twin"]["outputs"]]
        for s in self.sinks:
            if hasattr(s, "prepare"):
                s.prepare(keys)
        if "diagnostics" in self.spec["twin"]["outputs"]:
            from ..wire.cdr import encoder

            # the recording's status: its encoder made now, not at the first release (a
            # quarter of a second here, holding this interpreter's lock)
            self.diagnostics_encoder = encoder(BY_KEY["/diagnostics"].msgtype)

    def release(self, head: _Entry, clock) -> None:
        msgs = head.msgs
        p0 = clock()
        self.messages += self.sink.emit_all(msgs)
        p1 = clock()
        if self.first is None:
            self.first = head.deadline
        self.last = p1
        self.k_released = head.k
        if head.state:
            self.publish_times.add(p1 - p0)
            if not self.afap:
                late = p1 - head.deadline
                self.latencies.add(late if late > 0.0 else 0.0)
        said = False  # the recording's failure, first seen at this step
        for s in self.sinks:
            try:
                s.emit_all(msgs)
                s.tick(head.deadline)
            except Exception as exc:  # a sink that fails: said once, dropped, step on
                self.log("error", f"recording failed at step {head.k}: {type(exc).__name__}: {exc}")
                self.sinks = [x for x in self.sinks if x is not s]
                if self.failure is None:
                    self.failure = f"{type(exc).__name__}: {exc}"
                    said = True
            else:
                if self.failure is None and getattr(s, "failure", None):
                    self.failure = s.failure
                    said = True
        if said or p1 >= self.next_status:
            self.next_status = p1 + float(self.spec["runner"].get("diagnostics_period", 1.0))
            self.recording_status(msgs)

    def stale(self, now: float, t: float | None) -> None:
        """Paused: the diagnostics say so (pacing STALE, the recording's status), once a
        diagnostics period, stamped ``t``, the time of the step released last (None: none
        was); published and recorded."""
        self.next_status = now + float(self.spec["runner"].get("diagnostics_period", 1.0))
        if "diagnostics" not in self.spec["twin"]["outputs"] or t is None:
            return
        from ..wire import diagnostics

        name, hw = self.named
        self.statuses_out(
            [diagnostics.paused(name, hw, t)]
            + [s.status(name, hw) for s in self.sinks if hasattr(s, "status")],
            to_ns(t),
        )

    def recording_status(self, msgs: list) -> None:
        """The recording's /diagnostics status (:func:`mps_ros.wire.diagnostics.recording`), once a
        diagnostics period and at once where it has stopped, stamped with the step released:
        published and recorded (where the recording goes on) after the step's messages. None
        where the run publishes no diagnostics or records nothing."""
        if "diagnostics" not in self.spec["twin"]["outputs"]:
            return
        from ..wire import diagnostics

        name, hw = self.named
        statuses = [s.status(name, hw) for s in self.sinks if hasattr(s, "status")]
        if self.failure is not None and not any(x["level"] == diagnostics.ERROR for x in statuses):
            # the sink itself gave up (dropped): its failure said all the same
            statuses.append(diagnostics.recording(name, hw, "", 0, 0, self.failure))
        if statuses:
            self.statuses_out(statuses, msgs[0][2] if msgs else 0)

    def statuses_out(self, statuses: list, t_ns: int) -> None:
        """A /diagnostics message of ``statuses`` (stamped ``t_ns``) after the step released:
        published, and recorded where the recording goes on."""
        from ..wire.diagnostics import array

        out = [("/diagnostics", self.diagnostics_encoder(array(t_ns, statuses)), t_ns, False)]
        self.messages += self.sink.emit_all(out)
        for s in self.sinks:
            if getattr(s, "failure", None) is None:
                s.emit_all(out)
                s.tick(None)


class Scheduling:
    """The real-time scheduling of a split run: ``priority``, the SCHED_FIFO priority asked
    for the stepping process and this process's publishing thread (0: none); this process's
    scheduling for the run (:meth:`apply`); what the stepping process said it got
    (:meth:`said`; ``got``: the run's ``realtime_priority``)."""

    def __init__(self, priority: int, log):
        self.priority = int(priority)
        self.log = log
        self.got: int | None = None
        self.refused_here: str | None = None  # why SCHED_FIFO was refused this process
        #: the publishing thread's scheduler slice as granted (s; 0: none, the system's own)
        self.slice_granted = 0.0

    def apply(self, release_slice: float) -> None:
        """This process's scheduling for the run: SCHED_FIFO where asked and allowed (its
        other threads one below), else a short slice (``release_slice`` s; 0: none) for the
        publishing thread; the objects made so far frozen out of the collector's passes."""
        import gc

        from ..os_threads import name_thread, short_slice

        if self.priority:
            self.refused_here = ask_fifo(self.priority)
            if not self.refused_here:
                # the rest of this process one below: never ahead of the releases, never
                # behind an ordinary process while holding what the releases need
                fifo_for_the_others(max(1, self.priority - 1))
        if not self.priority or self.refused_here:
            # under the fair scheduler: a short slice, so that this thread, woken at each
            # deadline, preempts a busy neighbour at once (Linux 6.12 on; elsewhere nothing)
            if release_slice and short_slice(release_slice):
                self.slice_granted = release_slice
        name_thread("mps-publish")
        # what the node made so far (rclpy, the publishers, the scene) out of the collector's
        # passes: a full collection during the run scans only what the run made since
        gc.collect()
        gc.freeze()

    def said(self, got: dict) -> None:
        """What the stepping process said of its priority (frame ``PRIORITY``), logged."""
        prio = self.priority
        if not prio:
            return
        why = got.get("refused") or self.refused_here
        if why is None:
            self.got = prio
            self.log("info", f"stepping process and publishing thread: SCHED_FIFO, priority {prio}")
        else:
            self.got = 0
            self.log(
                "warn",
                f"realtime_priority {prio}: SCHED_FIFO refused here ({why}); "
                f"stepping at normal priority; {HOW_TO_ALLOW}",
            )


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
    ``publication``, the steps released, published and recorded (:class:`Publication`);
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
        self._lock = threading.Lock()  # the held steps, the generation, the replies
        self._queue: collections.deque[_Entry] = collections.deque()
        self._released: _Entry | None = None
        self._stats: dict = {}
        self._prepared = False
        self._ended = False
        self._paused_at: float | None = None  # paused (the node inactive) since (wall s)
        self.paused_s = 0.0  # wall seconds paused so far
        #: the replies of the steps asked for while paused (~/step), in order
        self._step_replies: collections.deque = collections.deque()
        #: the commands, each at its boundary
        self.boundaries = Boundaries(self, gate, log)

    @property
    def sinks(self) -> list:
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

    def _time_of(self, k: int) -> float:
        tw = self.spec.get("grid")
        if tw is None:
            return math.nan
        t0, t_end, n = tw
        return t_end if k == n else t0 + k * (t_end - t0) / n

    def pause(self) -> str | None:
        """Hold the run (the node's lifecycle: deactivate): nothing more is released or
        computed ahead, simulated time holds at the last step released; commands are still
        taken (at the next boundary). None, or why not."""
        with self._lock:
            if self._ended:
                return "the run has ended"
            if self._paused_at is None:
                self._paused_at = time.perf_counter()
                self.child.out.frame(Frame.PAUSE, b"")
        return None

    def step_paused(self, reply) -> str | None:
        """One step while paused (the node's ``~/step``): the next step held is released, or
        the stepping process computes one; ``reply(t)`` once it is out. None, or why not."""
        with self._lock:
            if self._ended:
                return "the run has ended"
            if self._paused_at is None:
                return "the node is active: ~/step takes a step while it is deactivated"
            self._step_replies.append(reply)
            if len(self._step_replies) > sum(1 for e in self._queue if e.state):
                self.child.out.frame(Frame.STEP, b"")
        return None

    def resume(self) -> None:
        """Go on after :meth:`pause`: every deadline (held, and in the stepping process) moves
        on by the time since the pause (or since the deadline of the last step taken with
        ``~/step``, where that is later)."""
        with self._lock:
            if self._paused_at is None:
                return
            since = self._paused_at
            if self._released is not None and self._released.deadline > since:
                since = self._released.deadline
            d = time.perf_counter() - since
            self._paused_at = None
            self.paused_s += d
            for e in self._queue:
                e.deadline += d
            self.boundaries.shift(d)
            self.child.out.frame(Frame.RESUME, marshal.dumps(d))

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
        out, reader, pub = self.child.out, self.child.reader, self.publication
        out.frame(Frame.GO, json.dumps({"priority": self.scheduling.priority}).encode())
        cpu0 = time.process_time()
        clock = time.perf_counter
        fd = reader.fd
        queue, lock, boundaries = self._queue, self._lock, self.boundaries
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
            if self.afap and self._released is not None and self._released.k != told:
                # the stepping process steps on up to _Ahead.AHEAD past it
                told = self._released.k
                out.frame(Frame.RELEASED, marshal.dumps(told))
            if self._paused_at is not None and now >= pub.next_status:
                released = self._released
                pub.stale(now, None if released is None else self._time_of(released.k))
            if (end is not None or eof) and not queue:
                break
            if eof:
                if queue:
                    wait = queue[0].deadline - clock()
                    if wait > 0:
                        time.sleep(min(wait, 0.05))
                continue
            if self._paused_at is not None:
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
        for s in pub.sinks:
            s.tick(None)
        return self._finish(end)

    def _release_due(self, now: float, flush, clock) -> None:
        """Every held step whose deadline has passed by ``now`` (as fast as possible: every
        one held; paused: those asked for), released in order; ``flush``: all held."""
        queue, lock, release = self._queue, self._lock, self.publication.release
        while True:
            reply = None
            with lock:
                if not queue:
                    break
                if not flush:
                    if self._paused_at is not None:  # paused: the steps asked for
                        if not self._step_replies:
                            break
                    elif not self.afap and queue[0].deadline > now:
                        break
                head = self._released = queue.popleft()
                if head.state and self._paused_at is not None and self._step_replies:
                    reply = self._step_replies.popleft()
            release(head, clock)
            if reply is not None:
                try:
                    reply(self._time_of(head.k))
                except Exception:  # a reply must never take the run down
                    pass

    def _take_frames(self, got: list) -> dict | None:
        """The frames the stepping process sent: steps held (of the present generation),
        answers given, log lines said, its priority; the run's end (returned, where it came)."""
        end = None
        for kind, payload in got:
            if kind == Frame.MESSAGES:
                entry = _Entry(*marshal.loads(payload))
                with self._lock:
                    self.boundaries.arrived(entry)
            elif kind == Frame.ANSWER:
                cid, ack = marshal.loads(payload)
                self.boundaries.answer(cid, json.loads(ack))
            elif kind == Frame.LOG:
                self.log(*marshal.loads(payload))
            elif kind == Frame.PRIORITY:
                self.scheduling.said(json.loads(payload))
            elif kind == Frame.END:
                end = json.loads(payload)
                with self._lock:
                    self._ended = True
        return end

    def _finish(self, end: dict | None) -> dict:
        child = self.child
        if end is None:  # the stepping process died
            child.wait(10)
            self.error = (
                f"the stepping process (pid {child.proc.pid}) ended without finishing "
                f"the run ({_exit_words(child.proc.returncode)})"
            )
            self.error_kind = "died"
            self.stop_reason = "error"
            k = self.publication.k_released or 0
            self._stats = {"steps": k, "t": self._time_of(k)}
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
        ros = getattr(self, "ros_cpu", None)
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


def _exit_words(code: int | None) -> str:
    if code is None:
        return "still running"
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit status {code}"
