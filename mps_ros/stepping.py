"""The live node's stepping process: the twin stepped in an interpreter of its own.

The node (:mod:`mps_ros.node`) does not step the twin itself. It starts
``python -m mps_ros.stepping``, which builds the same :class:`~mps_ros.twin.Twin` and uses the
same :class:`~mps_ros.twin.Runner`'s parts (the run's start and end messages, events,
diagnostics, commands): it computes steps up to ``lead`` wall seconds ahead of their deadlines,
keeps a checkpoint of each, and writes each step's messages, already encoded, down a pipe. The
node's process holds them and publishes each at its deadline, then hands it to the recorder: its
interpreter is not shared with the stepping, so a step being computed (or a stepping thread that
another process preempts while it holds its interpreter's lock) never holds a publication back,
and a step's eleven publishes never hold a step back.

::

    ROS process (mps_ros.node)                     stepping process (python -m mps_ros.stepping)
      executor thread: ~/mode, services: gate,  ── C ──▶  a command at its boundary, numbered
        boundary, refusals answered here
      main thread: holds the steps, publishes   ◀── M ──  each step computed ahead, encoded
        each at its deadline, then records it   ◀── A, L, P, E ── answers, log lines, the end
        │
        ▼ recording process (python -m mps_ros.recording)

**Commands.** The wall clock is ``time.perf_counter`` (CLOCK_MONOTONIC), the same in both
processes. A command that arrives at wall time w is taken in the ROS process at once: the gate
(a flood, an empty, overlong or unknown word) answers it there, at the boundary of w, and the
stepping is not disturbed; any other's boundary is the first step whose deadline is not before
w + ``command_delay``, among the last released and those held (the delay leaves the stepping
process time to redo the steps after it, whose first cost more: the command's events, charts
met for the first time). Where the step held there says that the machine would refuse it
(an ``engage`` while engaging; each step carries :meth:`Twin.refusals`), it is answered there
too and the stepping is not disturbed: only a command the machine takes costs steps redone.
(One that comes while a command sent on is still unanswered waits for that answer, a few
milliseconds, and is taken then, in the order they came.) Otherwise the steps held beyond
it are dropped, the steps that follow are numbered with a new *generation*, and the command
goes to the stepping process with its boundary and generation: that process comes back to the
boundary's checkpoint (or steps on to it), applies the command there and computes on. Whatever
it had sent of the old generation beyond the boundary is dropped on arrival. So the run is the
one that stepped in time, as in one process, and what the node publishes is what it records,
byte for byte, in the same order.

**As fast as possible** (where the twin can come back to a step) the same two processes
pipeline the run: the stepping process steps on while it is fewer than ``_Ahead.AHEAD`` steps
past the last step the node has released (which the node tells it, frame ``K``); the node
releases each step as it comes. A command is applied at the boundary of the last step released
when it came, the steps held beyond it dropped and computed again, as above: what subscribers
saw before the command is what the run was.

**Frames** (both pipes): one byte of kind, the payload's length (u32), the payload. To the
stepping process: ``I`` its settings (JSON), ``G`` go (the priority to ask for, JSON), ``C`` a
command (marshal: reply id or None, word, source, wall, boundary step, generation), ``N`` the
commands refused here, of which as floods, and lost (marshal: three counts, for its
/diagnostics), ``Z`` pause (the node deactivated: nothing is computed ahead, commands are still
applied), ``O`` go on after a pause (marshal: its length in wall seconds, by which every
deadline moves), ``T`` one step while paused (the node's ``~/step``), ``K`` as fast as
possible, the last step released (marshal), ``S`` stop (the reason, UTF-8). From it: ``R``
ready (JSON: or the error), ``P`` the priority it got (JSON), ``M`` a step or a command's
answers (marshal: step, generation, deadline, whether it holds the step's
state, the structure, why the machine would refuse each command word there
(:meth:`Twin.refusals`), its (key, CDR bytes, t_ns, received) messages), ``A`` a command's
answer for a service (marshal: id, JSON), ``L`` a log line (marshal: level, text), ``E`` the
run's end (JSON: statistics, stop reason, error).

**Faults.** The stepping process asks the system for SIGTERM when the node's process dies
(``PR_SET_PDEATHSIG``) and stops as on a stop frame when its pipe closes. Where the stepping
process dies (a SIGKILL), the node reads the end of its pipe, releases what it holds at its
deadlines, says so in one line, finishes the recording and exits nonzero.
"""

from __future__ import annotations

import collections
import json
import marshal
import math
import os
import signal
import struct
import subprocess
import sys
import threading
import time

from .os_threads import widen_pipe
from .topics import BY_KEY
from .twin import COMMAND_INDEX, Command, Gate, RefusalLog, Runner, Timings, Twin, shown, to_json, to_ns

_HEAD = struct.Struct("<cI")


# -- frames -----------------------------------------------------------------------------------
class FrameWriter:
    """Frames to a file descriptor, one writer at a time (the threads of a process share it)."""

    def __init__(self, fd: int):
        self.fd = fd
        self._lock = threading.Lock()
        self.broken = False

    def frame(self, kind: bytes, payload: bytes) -> bool:
        return self.write(_HEAD.pack(kind, len(payload)) + payload)

    def write(self, data: bytes) -> bool:
        """Whole frames at once (False: the other side is gone)."""
        with self._lock:
            if self.broken:
                return False
            view = memoryview(data)
            try:
                while view:
                    view = view[os.write(self.fd, view) :]
            except OSError:  # the other side is gone
                self.broken = True
                return False
        return True


class FrameReader:
    """Whole frames from a file descriptor: :meth:`read` blocks until at least one has come
    (an empty list: the other side closed its end)."""

    def __init__(self, fd: int):
        self.fd = fd
        self._buf = bytearray()

    def read(self) -> list[tuple[bytes, bytes]]:
        buf = self._buf
        while True:
            got = []
            pos = 0
            n_buf = len(buf)
            while n_buf - pos >= 5:
                kind, n = _HEAD.unpack_from(buf, pos)
                if n_buf - pos - 5 < n:
                    break
                got.append((kind, bytes(buf[pos + 5 : pos + 5 + n])))
                pos += 5 + n
            if pos:
                del buf[:pos]
            if got:
                return got
            try:
                chunk = os.read(self.fd, 1 << 20)
            except InterruptedError:
                continue
            if not chunk:
                return []
            buf.extend(chunk)


# -- real-time scheduling ---------------------------------------------------------------------
HOW_TO_ALLOW = (
    "to allow it, raise the user's rtprio limit (ulimit -r 99, or a line "
    "'@realtime - rtprio 99' in /etc/security/limits.conf with the user in group "
    "realtime) or grant CAP_SYS_NICE; see docs/ros.md, 'Real-time scheduling'"
)


def ask_fifo(priority: int) -> str | None:
    """Put the calling thread under SCHED_FIFO at ``priority`` (threads it starts after
    inherit it). None where granted, else why not (the system's words)."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (AttributeError, OSError) as exc:
        return f"{type(exc).__name__}: {exc}"
    return None


def fifo_for_the_others(priority: int) -> int:
    """Put every other thread of this process (rclpy's executor, the middleware's: receiving,
    events, sending) under SCHED_FIFO at ``priority``; how many took it. One of them holding a
    lock that a real-time thread waits for (the interpreter's, a writer's) is then not kept
    off the processor by ordinary processes for a scheduler slice (milliseconds); they sleep
    but for their short work."""
    me = threading.get_native_id()
    done = 0
    try:
        tids = [int(n) for n in os.listdir("/proc/self/task")]
    except OSError:
        return 0
    for tid in tids:
        if tid == me:
            continue
        try:
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
            done += 1
        except (AttributeError, OSError):
            pass
    return done


# -- the stepping process's side --------------------------------------------------------------
class Hold:
    """The node's pause, as the stepping process knows it: ``paused`` (frame ``Z``);
    ``shift``, the wall seconds the schedule has moved on by for the pauses so far (frame
    ``O``: each pause's length, added as it ends); ``steps``, one token a step asked for while
    paused (frame ``T``, the node's ``~/step``)."""

    def __init__(self):
        self.paused = False
        self.shift = 0.0
        self.steps: collections.deque = collections.deque()
        #: as fast as possible: the last step the node has released (frame ``K``)
        self.released = -1


class _Ahead:
    """The stepping process's loop: the twin stepped up to ``lead`` wall seconds ahead of the
    steps' deadlines, each step's messages written down the pipe as soon as the lead is full
    (or its deadline is near), a checkpoint kept for each step not yet past, and each command
    applied at the boundary the ROS process chose for it (coming back to that step's
    checkpoint, or stepping on to it).

    ``afap`` (as fast as possible): no deadlines; the twin steps on while it is fewer than
    :attr:`AHEAD` steps past the last step the node has released (frame ``K``), the steps
    written :attr:`BATCH` at a time, a checkpoint kept for each step the node may still hold."""

    #: steps written at once at most; a step due within this (wall s) goes at once
    BATCH, NEAR = 16, 0.002
    #: as fast as possible: steps computed past the last one released, at most
    AHEAD = 256

    def __init__(
        self,
        runner: Runner,
        out: FrameWriter,
        commands,
        wake: threading.Event,
        hold: Hold | None = None,
        afap: bool = False,
    ):
        self.runner, self.twin, self.out = runner, runner.twin, out
        self.commands, self.wake = commands, wake
        self.hold = hold or Hold()
        self.afap = afap
        self.gen = 0
        self.cps: dict[int, tuple] = {}
        self.pending: list[bytes] = []
        self.due = math.inf  # the earliest deadline among the pending steps

    def deadline(self, k: int) -> float:
        if self.afap:
            return 0.0  # none: the node releases each step as it comes
        tw = self.twin
        return self.wall_start + self.hold.shift + (tw.time_of(k) - tw.t0) / self.runner.rtf

    def _entry(self, k: int, deadline: float, state: bool, msgs: list) -> None:
        twin = self.twin
        self.pending.append(
            marshal.dumps((k, self.gen, deadline, state, twin.sim.structure, twin.refusals(), msgs))
        )
        if deadline < self.due and not self.afap:
            self.due = deadline

    def flush(self) -> None:
        if self.pending:
            data = b"".join(_HEAD.pack(b"M", len(p)) + p for p in self.pending)
            self.pending = []
            self.due = math.inf
            if not self.out.write(data):
                raise BrokenPipeError("the node's process is gone")

    def run(self) -> None:
        runner, twin, afap = self.runner, self.twin, self.afap
        clock = time.perf_counter
        step = twin.dt / runner.rtf
        ahead = twin.rewindable and (afap or runner.lead > step)
        lead = runner.lead if ahead else step
        # checkpoints kept, by step
        keep = (self.AHEAD + self.BATCH + 100) if afap else int(math.ceil(2.0 * lead / step)) + 100
        refill = 0.2 * lead if ahead else 0.0
        runner.prepare()
        runner._start_clocks()
        staged: list = []
        runner._staging = staged
        runner._begin()
        runner._staging = None
        self.wall_start = runner.wall_start = clock() + (0.0 if afap else lead - step)
        self.k0 = twin.k
        if ahead:
            self.cps[twin.k] = twin.checkpoint()
        self._entry(twin.k, self.deadline(twin.k) if afap else self.wall_start, True, staged)
        runner._later_logs = []
        next_diag = runner.wall_start + runner.period
        commands, stop = self.commands, runner._stop
        # a schedule this far behind (wall s) is said once: the run cannot keep real time
        behind, warned = max(0.1, lead), False
        try:
            while not twin.done and not stop.is_set():
                if commands and twin.k >= commands[0][4]:
                    self._command(commands.popleft(), ahead)
                    continue
                one = False  # a step asked for while paused
                if self.hold.paused:  # the node is inactive: nothing computed ahead
                    if not self.hold.steps:
                        self.flush()
                        self.wake.wait(0.05)
                        self.wake.clear()
                        continue
                    self.hold.steps.popleft()
                    one = True
                deadline = self.deadline(twin.k + 1)
                if afap:
                    if not one and twin.k - self.hold.released >= self.AHEAD:
                        self.flush()  # as far ahead as the node may hold: it releases first
                        self.wake.wait(0.05)
                        self.wake.clear()
                        continue
                    deadline = math.inf  # no deadline: no miss
                elif not commands and not one:
                    wait = deadline - lead - clock()
                    if wait > 0.0:
                        self.flush()
                        if runner._later_logs:
                            runner._flush_logs()
                            continue
                        wait += refill
                        self.wake.wait(wait if wait < 0.05 else 0.05)
                        self.wake.clear()
                        continue
                k, msgs, c1 = runner._timed_step(deadline, clock)
                if c1 > deadline + behind and not warned:
                    warned = True
                    self._say_behind(k, c1 - deadline)
                t_ns = to_ns(twin.t)
                staged = [] if msgs is None else [(key, data, t_ns, False) for key, data in msgs]
                runner._staging = staged
                runner._emit_events(twin.new_events(hold=not ahead), t_ns)
                if c1 >= next_diag:
                    next_diag = c1 + runner.period
                    runner._diagnostics(t_ns)
                runner._staging = None
                runner.messages += sum(1 for m in staged if not m[3])
                if ahead:
                    self.cps[k] = twin.checkpoint()
                    self.cps.pop(k - keep, None)
                self._entry(k, self.deadline(k) if afap else deadline, msgs is not None, staged)
                if one or len(self.pending) >= self.BATCH or self.due - clock() < self.NEAR:
                    self.flush()
        except Exception as exc:
            runner._failed(exc)
            raise
        finally:
            runner._staging = None
            try:
                self.flush()
            except BrokenPipeError:
                pass
            runner._flush_logs()
            runner._later_logs = None
            staged = []
            runner._staging = staged
            try:
                runner._end()
            finally:
                runner._staging = None
            runner.messages += sum(1 for m in staged if not m[3])
            self._entry(twin.k, self.deadline(twin.k), False, staged)
            try:
                self.flush()
            except BrokenPipeError:
                pass

    def _say_behind(self, k: int, late: float) -> None:
        """One warning: the steps cost more than their period (the run goes on, late)."""
        runner, twin = self.runner, self.twin
        period = twin.dt / runner.rtf
        steps = max(1, k - self.k0)
        rate = steps / (steps * period + late)
        runner.log(
            "warn",
            f"cannot keep real time: step {k} (t = {twin.t:.6g} s) came "
            f"{late * 1e3:.0f} ms after its deadline; the node makes about "
            f"{rate:.0f} steps a wall second where real time needs "
            f"{1.0 / period:.0f} (a step every {period * 1e3:.3g} ms): give a "
            "larger dt or a smaller real_time_factor (the run goes on, behind "
            "its schedule)",
        )

    def _command(self, cmd: tuple, ahead: bool) -> None:
        """A command at its boundary ``k`` (the ROS process chose it, dropped the steps it had
        beyond it, and numbered what follows ``gen``)."""
        cid, word, source, wall, k, gen = cmd
        runner, twin = self.runner, self.twin
        if twin.k > k:
            cp = self.cps.get(k)
            if cp is not None:
                runner.steps_recomputed += twin.k - k
                twin.restore(cp)
                for j in [j for j in self.cps if j > k]:
                    del self.cps[j]
        self.gen = gen
        reply = None if cid is None else self._reply(cid)
        staged: list = []
        runner._staging = staged
        try:
            runner._take_commands([Command(word, source, reply, wall)], gated=True)
        finally:
            runner._staging = None
        if ahead:
            self.cps[twin.k] = twin.checkpoint()
        self._entry(twin.k, self.deadline(twin.k), False, staged)
        self.flush()

    def _reply(self, cid: int):
        def reply(ack):
            self.out.frame(b"A", marshal.dumps((cid, to_json(ack))))

        return reply


def _set_parent_death_signal() -> None:
    """SIGTERM to this process when the process that started it dies (Linux)."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def serve(fd_in: int = 0, fd_out: int = 1) -> int:
    """The stepping process (``python -m mps_ros.stepping``): settings, ready, go, the run,
    its end; see the module's docstring."""
    parent = os.getppid()
    _set_parent_death_signal()
    if fd_out == 1:  # the frames keep the pipe; whatever else prints goes to stderr
        fd_out = os.dup(1)
        os.dup2(2, 1)
    out = FrameWriter(fd_out)
    widen_pipe(fd_out)
    reader = FrameReader(fd_in)
    frames = reader.read()
    if not frames or frames[0][0] != b"I":
        return 2
    spec = json.loads(frames[0][1])
    pending = frames[1:]

    def log(level: str, text: str) -> None:
        out.frame(b"L", marshal.dumps((level, text)))

    try:
        twin = Twin(spec["scene"], **spec["twin"])
        pacing = "as_fast_as_possible" if spec.get("afap") else "realtime"
        runner = Runner(twin, pacing=pacing, log=log, **spec["runner"])
        runner.prepare()
    except Exception as exc:
        out.frame(b"R", json.dumps({"error": f"{type(exc).__name__}: {exc}"}).encode())
        return 2
    commands: collections.deque = collections.deque()
    wake = threading.Event()
    hold = Hold()

    def stop(reason: str) -> None:
        runner.request_stop(reason)
        wake.set()

    def on_signal(signum, _frame):
        stop(signal.Signals(signum).name)

    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, on_signal)
    if os.getppid() != parent:  # the node died before the death signal was asked for
        stop("the node's process ended")
    out.frame(b"R", json.dumps({"ready": True, "pid": os.getpid(), "rewindable": twin.rewindable}).encode())
    go = threading.Event()
    asked: dict = {}

    def take(kind, payload) -> None:
        if kind == b"C":
            commands.append(marshal.loads(payload))
            wake.set()
        elif kind == b"S":
            stop(payload.decode())
            go.set()
        elif kind == b"G":
            asked.update(json.loads(payload))
            go.set()
        elif kind == b"N":
            runner.elsewhere = marshal.loads(payload)
        elif kind == b"Z":
            hold.paused = True
            wake.set()
        elif kind == b"T":
            hold.steps.append(1)
            wake.set()
        elif kind == b"K":
            hold.released = marshal.loads(payload)
            wake.set()
        elif kind == b"O":
            paused = marshal.loads(payload)
            hold.shift += paused
            runner.wall_start += paused
            hold.paused = False
            wake.set()

    def listen() -> None:
        for kind, payload in pending:
            take(kind, payload)
        while True:
            got = reader.read()
            if not got:  # the node's end of the pipe closed
                stop("the node's process ended")
                go.set()
                return
            for kind, payload in got:
                take(kind, payload)

    threading.Thread(target=listen, name="mps-commands", daemon=True).start()
    go.wait()
    prio = int(asked.get("priority", 0))
    why = ask_fifo(prio) if prio else None
    if prio and why is None:
        # the commands' thread too: a command waits for no ordinary process on the machine
        fifo_for_the_others(prio)
    # a command waits this long at most for the stepping thread to let go of the interpreter
    # (Python's default: 5 ms, five steps)
    sys.setswitchinterval(2e-4)
    out.frame(b"P", json.dumps({"priority": 0 if (why or not prio) else prio, "refused": why}).encode())
    from .os_threads import name_thread

    name_thread("mps-step")
    error_kind = None
    try:
        _Ahead(runner, out, commands, wake, hold, afap=bool(spec.get("afap"))).run()
    except Exception as exc:
        from mps_core import MpsError

        error_kind = "simulation" if isinstance(exc, MpsError) else "error"
    stats = runner.stats()
    stats["structure"] = twin.sim.structure
    out.frame(
        b"E",
        json.dumps(
            {
                "stats": stats,
                "stop_reason": runner.stop_reason,
                "error": runner.error,
                "error_kind": error_kind,
            },
            default=str,
        ).encode(),
    )
    return 0


# -- the ROS process's side -------------------------------------------------------------------
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


class SteppingProcess:
    """The ROS process's side of a split run, with what the node needs of a
    :class:`~mps_ros.twin.Runner` (``prepare``, ``run``, ``request_stop``, ``stats``,
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
    publishing thread (0: none)."""

    def __init__(self, spec: dict, sink, log, gate: Gate, priority: int = 0):
        from .cdr import string

        self.spec = spec
        #: as fast as possible: each step released as it comes, a command applied at the
        #: boundary of the last step released (the steps held beyond it computed again)
        self.afap = bool(spec.get("afap"))
        self.sink = sink
        self.sinks: list = []  # the others: the recorder
        self.log = log
        self.gate = gate
        self.priority = int(priority)
        #: a command takes effect at the first step boundary at least this long (wall s) after
        #: it arrived (see :attr:`Runner.command_delay`)
        self.command_delay = float(spec["runner"].get("command_delay", 0.0))
        self.inbox = ForwardingInbox(self)
        self.stop_reason: str | None = None
        self.error: str | None = None
        self.error_kind: str | None = None
        self._lost = 0
        self.commands_refused = 0
        self.pid: int | None = None
        self.priority_got: int | None = None
        self.latencies = Timings()
        self.publish_times = Timings()
        self.messages = 0
        self.k_released: int | None = None
        self.structure = ""
        self._string = string
        self._proc: subprocess.Popen | None = None
        self._replies: dict[int, object] = {}
        self._next_id = 0
        self._lock = threading.Lock()  # the held steps, the generation, the replies
        self._out: FrameWriter | None = None
        self._reader: FrameReader | None = None
        self._queue: collections.deque[_Entry] = collections.deque()
        self._released: _Entry | None = None
        self._gen = 0
        self._limits: dict[int, int] = {}  # an earlier generation: its last valid step
        self._received_gen = 0  # the last generation received
        self._last_boundary = -1  # the step of the last command sent on
        self._held: dict[int, list] = {}  # refusals that follow a command's answers
        #: commands that came while one sent on was unanswered: (command, word, the gate's
        #: refusal or None)
        self._waiting: collections.deque = collections.deque()
        self._stats: dict = {}
        self._refusals = RefusalLog(log)
        self._prepared = False
        self._first: float | None = None  # the schedule's start (wall s)
        self._last = 0.0  # the last release (wall s)
        self._ended = False
        self._this_refused: str | None = None
        self._failure: str | None = None  # why the recording stopped, where it did
        self._next_status = 0.0  # the recording's next status (wall s)
        self._paused_at: float | None = None  # paused (the node inactive) since (wall s)
        self.paused_s = 0.0  # wall seconds paused so far
        #: the replies of the steps asked for while paused (~/step), in order
        self._step_replies: collections.deque = collections.deque()
        self._diagnostics_encoder = None
        #: the statuses' name prefix (the node's) and hardware_id
        self._named = (spec["runner"].get("name", "press_twin"), spec.get("hardware_id", "mps"))

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
        if self._out is not None:
            self._out.frame(b"N", marshal.dumps((self.commands_refused, self.gate.floods, self._lost)))

    # -- start ------------------------------------------------------------------------------
    def prepare(self) -> None:
        """Start the stepping process and wait until it has built its twin and its kernels
        (raises OSError with its reason where it could not); the sinks' channels."""
        if self._prepared:
            return
        self._prepared = True
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "mps_ros.stepping"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            bufsize=0,
        )
        self._out = FrameWriter(self._proc.stdin.fileno())
        widen_pipe(self._proc.stdin.fileno())
        self._reader = FrameReader(self._proc.stdout.fileno())
        self._out.frame(b"I", json.dumps(self.spec).encode())
        keys = [t.key for t in BY_KEY.values() if not t.output or t.output in self.spec["twin"]["outputs"]]
        for s in self.sinks:
            if hasattr(s, "prepare"):
                s.prepare(keys)
        if "diagnostics" in self.spec["twin"]["outputs"]:
            from .cdr import encoder

            # the recording's status: its encoder made now, not at the first release (a
            # quarter of a second here, holding this interpreter's lock)
            self._diagnostics_encoder = encoder(BY_KEY["/diagnostics"].msgtype)
        while True:
            got = self._reader.read()
            if not got:
                self._proc.wait(10)
                raise OSError(
                    f"the stepping process ended before it was ready ({_exit_words(self._proc.returncode)})"
                )
            for kind, payload in got:
                if kind == b"L":
                    self.log(*marshal.loads(payload))
                elif kind == b"R":
                    reply = json.loads(payload)
                    if not reply.get("ready"):
                        self._proc.wait(10)
                        raise OSError(reply.get("error", "the stepping process failed"))
                    self.pid = reply["pid"]
                    return

    # -- commands and stops (any thread) ------------------------------------------------------
    def command(self, cmd: Command) -> None:
        word = cmd.word if isinstance(cmd.word, str) else str(cmd.word)
        with self._lock:
            if self._paused_at is not None and self._released is not None:
                # paused: simulated time holds at the last step released; the command is
                # taken at the next boundary, as if it had come then
                cmd.wall = self._released.deadline
            refusal = "the run has ended" if self._ended else self.gate.check(word)
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
            self._refuse(cmd, word, refusal or "the run has not started", self._boundary(cmd.wall))
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
        queue = self._queue
        while queue and queue[-1].k > kb:
            queue.pop()
        self._limits[self._gen] = kb
        self._last_boundary = kb
        self._gen += 1
        self._out.frame(b"C", marshal.dumps((cid, word, cmd.source, cmd.wall, kb, self._gen)))

    def _take_waiting(self) -> None:
        """The commands that waited for an answer, in order (the lock held), each once the
        step of its boundary is here, until one is sent on; after the run's end, each
        refused."""
        waiting = self._waiting
        while waiting and (self._ended or self._gen == self._received_gen):
            cmd, word, refusal = waiting[0]
            if not self._ended and refusal is None and not self.afap:
                last = self._queue[-1] if self._queue else self._released
                if last is None or last.deadline < cmd.wall + self.command_delay:
                    return  # its boundary's step is still to come
            waiting.popleft()
            self._take(cmd, word, "the run has ended" if self._ended else refusal)

    def _step_at(self, wall: float) -> int | None:
        """The first step whose deadline is not before ``wall`` (the lock held), among the
        last released, those held and those still to come (the schedule's; the stepping
        process steps on to it, where it is not there yet); None before the run has started.
        As fast as possible: the last step released."""
        if self.afap:
            return None if self._released is None else self._released.k
        last = self._queue[-1] if self._queue else self._released
        if last is None:
            return None
        grid = self.spec.get("grid")
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
        if self.spec.get("grid") is None:
            return 0.0
        t0, t_end, n = self.spec["grid"]
        return (t_end - t0) / n / float(self.spec["runner"].get("real_time_factor", 1.0))

    def _boundary(self, wall: float) -> _Entry | None:
        """The entry a command that arrived at ``wall`` follows (the lock held): the last
        entry of the first step whose deadline is not before ``wall``, among the last released
        and those held; the last of them where none is that late yet. As fast as possible: the
        last step released."""
        if self.afap:
            return self._released
        at = self._released
        d = at.deadline if at is not None and at.deadline >= wall else None
        # held in the order of their deadlines: a command's boundary is near the front
        for e in self._queue:
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
        t = self._time_of(k)
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
        queue = self._queue
        if self._gen > self._received_gen:
            # a command sent on is being applied: this answer follows that one's
            self._held.setdefault(self._gen, []).append(entry)
        else:
            # after everything held at its step or before (the answers given there included)
            i = next((n for n, e in enumerate(queue) if e.k > k), len(queue))
            queue.insert(i, entry)
        self._refusals.refused(word, cmd.source, t, reason, cmd.wall)
        self._tell_counts()
        if cmd.reply is not None:
            try:
                cmd.reply(ack)
            except Exception:
                pass

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
                self._out.frame(b"Z", b"")
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
                self._out.frame(b"T", b"")
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
            for held in self._held.values():
                for e in held:
                    e.deadline += d
            self._out.frame(b"O", marshal.dumps(d))

    def request_stop(self, reason: str) -> None:
        if self.stop_reason is None:
            self.stop_reason = reason
        if self._out is not None:
            self._out.frame(b"S", reason.encode())

    # -- the run ----------------------------------------------------------------------------
    def run(self) -> dict:
        """Go; release each step at its deadline until the stepping process's end (or its
        death: :attr:`error` says so)."""
        self.prepare()
        import gc

        from .os_threads import name_thread, short_slice

        if self.priority:
            self._this_refused = ask_fifo(self.priority)
            if not self._this_refused:
                # the rest of this process one below: never ahead of the releases, never
                # behind an ordinary process while holding what the releases need
                fifo_for_the_others(max(1, self.priority - 1))
        if not self.priority or self._this_refused:
            # under the fair scheduler: a short slice, so that this thread, woken at each
            # deadline, preempts a busy neighbour at once (Linux 6.12 on; elsewhere nothing)
            ask = self.spec["runner"].get("release_slice", 1e-4)
            if ask:
                short_slice(ask)
        name_thread("mps-publish")
        # what the node made so far (rclpy, the publishers, the scene) out of the collector's
        # passes: a full collection during the run scans only what the run made since
        gc.collect()
        gc.freeze()
        self._out.frame(b"G", json.dumps({"priority": self.priority}).encode())
        cpu0 = time.process_time()
        clock = time.perf_counter
        fd = self._reader.fd
        queue, lock = self._queue, self._lock
        end = None
        eof = False
        told = -1  # as fast as possible: the last step released that the stepping process knows of
        if self.afap:
            self._first = clock()  # the run's start: the first step goes out as it comes
        import select

        while True:
            # a run stopped early lets go of what it holds at once
            flush = end is not None and (end.get("stop_reason") or end.get("error"))
            now = clock()
            while True:  # every held step whose deadline has passed
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
                self._release(head, clock)
                if reply is not None:
                    try:
                        reply(self._time_of(head.k))
                    except Exception:  # a reply must never take the run down
                        pass
            if self.afap and self._released is not None and self._released.k != told:
                # the stepping process steps on up to _Ahead.AHEAD past it
                told = self._released.k
                self._out.frame(b"K", marshal.dumps(told))
            if self._paused_at is not None and now >= self._next_status:
                self._stale(now)
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
            got = self._reader.read()
            if not got:
                eof = True
                continue
            for kind, payload in got:
                if kind == b"M":
                    k, gen, deadline, state, structure, refusals, msgs = marshal.loads(payload)
                    with lock:
                        if gen == self._gen or k <= self._limits.get(gen, -1):
                            queue.append(_Entry(k, gen, deadline, state, structure, refusals, msgs))
                            if gen > self._received_gen:  # a command's answers
                                self._received_gen = gen
                                queue.extend(self._held.pop(gen, ()))
                elif kind == b"A":
                    cid, ack = marshal.loads(payload)
                    with lock:
                        reply = self._replies.pop(cid, None)
                    if reply is not None:
                        try:
                            reply(json.loads(ack))
                        except Exception:  # a reply must never take the run down
                            pass
                elif kind == b"L":
                    self.log(*marshal.loads(payload))
                elif kind == b"P":
                    self._priority_said(json.loads(payload))
                elif kind == b"E":
                    end = json.loads(payload)
                    with lock:
                        self._ended = True
            if self._waiting:
                with lock:
                    self._take_waiting()
        with lock:
            self._ended = True
            self._take_waiting()
        self.ros_cpu = time.process_time() - cpu0
        for s in self.sinks:
            s.tick(None)
        return self._finish(end)

    def _release(self, head: _Entry, clock) -> None:
        msgs = head.msgs
        p0 = clock()
        self.messages += self.sink.emit_all(msgs)
        p1 = clock()
        if self._first is None:
            self._first = head.deadline
        self._last = p1
        self.k_released, self.structure = head.k, head.structure
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
                if self._failure is None:
                    self._failure = f"{type(exc).__name__}: {exc}"
                    said = True
            else:
                if self._failure is None and getattr(s, "failure", None):
                    self._failure = s.failure
                    said = True
        if said or p1 >= self._next_status:
            self._next_status = p1 + float(self.spec["runner"].get("diagnostics_period", 1.0))
            self._recording_status(msgs)

    def _stale(self, now: float) -> None:
        """Paused: the diagnostics say so (pacing STALE, the recording's status), once a
        diagnostics period, stamped with the step released last; published and recorded."""
        self._next_status = now + float(self.spec["runner"].get("diagnostics_period", 1.0))
        if "diagnostics" not in self.spec["twin"]["outputs"] or self._released is None:
            return
        from . import diagnostics

        name, hw = self._named
        t = self._time_of(self._released.k)
        self._statuses_out(
            [diagnostics.paused(name, hw, t)]
            + [s.status(name, hw) for s in self.sinks if hasattr(s, "status")],
            to_ns(t),
        )

    def _recording_status(self, msgs: list) -> None:
        """The recording's /diagnostics status (:func:`mps_ros.diagnostics.recording`), once a
        diagnostics period and at once where it has stopped, stamped with the step released:
        published and recorded (where the recording goes on) after the step's messages. None
        where the run publishes no diagnostics or records nothing."""
        if "diagnostics" not in self.spec["twin"]["outputs"]:
            return
        from . import diagnostics

        name, hw = self._named
        statuses = [s.status(name, hw) for s in self.sinks if hasattr(s, "status")]
        if self._failure is not None and not any(x["level"] == diagnostics.ERROR for x in statuses):
            # the sink itself gave up (dropped): its failure said all the same
            statuses.append(diagnostics.recording(name, hw, "", 0, 0, self._failure))
        if statuses:
            self._statuses_out(statuses, msgs[0][2] if msgs else 0)

    def _statuses_out(self, statuses: list, t_ns: int) -> None:
        """A /diagnostics message of ``statuses`` (stamped ``t_ns``) after the step released:
        published, and recorded where the recording goes on."""
        from .diagnostics import array

        out = [("/diagnostics", self._diagnostics_encoder(array(t_ns, statuses)), t_ns, False)]
        self.messages += self.sink.emit_all(out)
        for s in self.sinks:
            if getattr(s, "failure", None) is None:
                s.emit_all(out)
                s.tick(None)

    def _priority_said(self, got: dict) -> None:
        prio = self.priority
        if not prio:
            return
        why = got.get("refused") or self._this_refused
        if why is None:
            self.priority_got = prio
            self.log("info", f"stepping process and publishing thread: SCHED_FIFO, priority {prio}")
        else:
            self.priority_got = 0
            self.log(
                "warn",
                f"realtime_priority {prio}: SCHED_FIFO refused here ({why}); "
                f"stepping at normal priority; {HOW_TO_ALLOW}",
            )

    def _finish(self, end: dict | None) -> dict:
        proc = self._proc
        self._refusals.close()
        if end is None:  # the stepping process died
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(10)
            self.error = (
                f"the stepping process (pid {proc.pid}) ended without finishing "
                f"the run ({_exit_words(proc.returncode)})"
            )
            self.error_kind = "died"
            self.stop_reason = "error"
            k = self.k_released or 0
            self._stats = {"steps": k, "t": self._time_of(k)}
        else:
            proc.wait(30)
            self._stats = end["stats"]
            self.stop_reason = end.get("stop_reason") or self.stop_reason
            self.error = end.get("error")
            self.error_kind = end.get("error_kind")
        with self._lock:
            replies, self._replies = self._replies, {}
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
        return self.stats()

    def stats(self) -> dict:
        """The stepping process's statistics, with this process's publication figures (the
        latency is measured here, after each step's publishes) and the CPU of both."""
        s = dict(self._stats)
        steps = max(1, int(s.get("steps", 0) or 0))
        if self.latencies.n:
            s["latency_p50_ms"] = self.latencies.percentile(50) * 1e3
            s["latency_p99_ms"] = self.latencies.percentile(99) * 1e3
        if self.publish_times.n:
            s["publish_time_p50_ms"] = self.publish_times.percentile(50) * 1e3
            s["publish_time_p99_ms"] = self.publish_times.percentile(99) * 1e3
        ros = getattr(self, "ros_cpu", None)
        step_cpu = s.get("cpu_time")
        if ros is not None and step_cpu is not None:
            s["stepping_process_cpu_per_step_us"] = step_cpu / steps * 1e6
            s["ros_process_cpu_per_step_us"] = ros / steps * 1e6
            s["process_cpu_per_step_us"] = (step_cpu + ros) / steps * 1e6
        s["messages"] = self.messages
        if self._first is not None and "sim_time" in s and self._last > self._first:
            # from the schedule's start to the last release (the steps were computed ahead),
            # the pauses left out
            s["wall_time"] = self._last - self._first - self.paused_s
            s["real_time_factor"] = s["sim_time"] / s["wall_time"]
        s["commands_lost"] = self.commands_lost
        s["commands_refused"] = s.get("commands_refused", 0) + self.commands_refused
        s["realtime_priority"] = self.priority_got or 0
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
        proc = self._proc
        if proc is None:
            return
        if proc.poll() is None:
            self.request_stop("the node is shutting down")
            try:
                proc.wait(30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(10)
        for f in (proc.stdin, proc.stdout):
            try:
                f.close()
            except OSError:
                pass


def _exit_words(code: int | None) -> str:
    if code is None:
        return "still running"
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit status {code}"


if __name__ == "__main__":
    sys.exit(serve())
