"""The live node's stepping process: the twin stepped in an interpreter of its own.

The node (:mod:`mps_ros.ros.node`) does not step the twin itself. It starts
``python -m mps_ros.run.stepping``, which builds the same :class:`~mps_ros.run.twin.Twin` and uses the
same :class:`~mps_ros.run.runner.Runner`'s parts (the run's start and end messages, events,
diagnostics, commands): it computes steps up to ``lead`` wall seconds ahead of their deadlines,
keeps a checkpoint of every ``_Ahead.EVERY``-th step, and writes each step's messages, already
encoded, down a pipe. The node's process (:mod:`mps_ros.run.releasing`) holds them and publishes
each at its deadline, then hands it to the recorder: its interpreter is not shared with the
stepping, so a step being computed (or a stepping thread that another process preempts while it
holds its interpreter's lock) never holds a publication back, and a step's eleven publishes
never hold a step back.

::

    ROS process (mps_ros.ros.node)                     stepping process (python -m mps_ros.run.stepping)
      executor thread: ~/mode, services: gate,  ── C ──▶  a command at its boundary, numbered
        boundary, refusals answered here
      main thread: holds the steps, publishes   ◀── M ──  each step computed ahead, encoded
        each at its deadline, then records it   ◀── A, L, P, E ── answers, log lines, the end
        │
        ▼ recording process (python -m mps_ros.recording.background)

**Commands.** The wall clock is ``time.perf_counter`` (CLOCK_MONOTONIC), the same in both
processes. A command that arrives at wall time w is taken in the ROS process at once: the gate
(a flood, an empty, overlong or unknown word) answers it there, at its boundary, and the
stepping is not disturbed; every command's boundary (so the answers keep the commands' order)
is the first step whose deadline is not before w + ``command_delay``, among the last released
and those held (the delay leaves the stepping
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
past the last step the node has released (which the node tells it, frame ``RELEASED``); the node
releases each step as it comes. A command is applied at the boundary of the last step released
when it came, the steps held beyond it dropped and computed again, as above: what subscribers
saw before the command is what the run was.

**Frames** (both pipes, :mod:`mps_ros.wire.pipe`): one byte of kind (:class:`Frame`), the
payload's length (u32), the payload. To the stepping process: ``SETTINGS`` (JSON), ``GO`` (the
priority to ask for, JSON), ``COMMAND`` (marshal: reply id or None, word, source, wall, boundary
step, generation), ``REFUSED`` the commands refused here, of which as floods, and lost
(marshal: three counts, for its /diagnostics), ``PAUSE`` (the node deactivated: nothing is
computed ahead, commands are still applied), ``RESUME`` after a pause (marshal: its length in
wall seconds, by which every deadline moves), ``STEP`` one step while paused (the node's
``~/step``), ``RELEASED`` as fast as possible, the last step released (marshal), ``STOP`` (the
reason, UTF-8). From it: ``READY`` (JSON: or the error), ``PRIORITY`` the priority it got
(JSON), ``MESSAGES`` a step or a command's answers (marshal: step, generation, deadline, whether
it holds the step's state, the structure, why the machine would refuse each command word there
(:meth:`Twin.refusals`), its (key, CDR bytes, t_ns, received) messages), ``ANSWER`` a command's
answer for a service (marshal: id, JSON), ``LOG`` a log line (marshal: level, text), ``END`` the
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
import sys
import threading
import time

from mps_core.child_process import die_with_parent

from ..os_threads import widen_pipe

# -- frames -----------------------------------------------------------------------------------
from ..wire.json_text import to_json
from ..wire.pipe import HEAD, Frame, FrameReader, FrameWriter
from .commands import Command

# -- frames -----------------------------------------------------------------------------------
from .runner import Runner
from .twin import Twin

# -- frames -----------------------------------------------------------------------------------
#: the wall seconds over which a realtime run's rate is judged first (the whole run if shorter)
RATE_WINDOW = 1.0
#: a rate below this share of the one real time asks is said (once): the run falls behind
RATE_SHORT = 0.9


def achieved_rate(steps: int, wall: float) -> float:
    """Return the steps a wall second that ``steps`` made in ``wall`` seconds."""
    return steps / wall if wall > 0.0 else math.inf


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
    """The node's pause, as the stepping process knows it: ``paused`` (frame ``PAUSE``);
    ``shift``, the wall seconds the schedule has moved on by for the pauses so far (frame
    ``O``: each pause's length, added as it ends); ``steps``, one token a step asked for while
    paused (frame ``STEP``, the node's ``~/step``)."""

    def __init__(self):
        self.paused = False
        self.shift = 0.0
        self.steps: collections.deque = collections.deque()
        #: as fast as possible: the last step the node has released (frame ``RELEASED``)
        self.released = -1


class _Ahead:
    """The stepping process's loop: the twin stepped up to ``lead`` wall seconds ahead of the
    steps' deadlines, each step's messages written down the pipe as soon as the lead is full
    (or its deadline is near), a checkpoint kept every :attr:`EVERY` steps not yet past, and
    each command applied at the boundary the ROS process chose for it (coming back to the last
    checkpoint at or before it and stepping again to it, or stepping on to it).

    ``afap`` (as fast as possible): no deadlines; the twin steps on while it is fewer than
    :attr:`AHEAD` steps past the last step the node has told it it released (frame
    ``RELEASED``, every :data:`~mps_ros.run.releasing.TOLD_EVERY` steps), the steps written
    :attr:`BATCH` at a time, the checkpoints kept as far back as the node may hold."""

    #: steps written at once at most; a step due within this (wall s) goes at once
    BATCH, NEAR = 16, 0.002
    #: as fast as possible: steps computed past the last one released, at most
    AHEAD = 256
    #: a checkpoint kept every this many steps (and after each command): a command's boundary
    #: between two is reached from the one before it by stepping again (a checkpoint costs
    #: about a sixth of a step; a command comes back up to this less one steps further)
    EVERY = 8
    #: the steps banked are let down to this share of the lead before it is refilled (a burst
    #: of the rest), or to the command delay and :attr:`MARGIN` where that is more (a
    #: command's boundary step is then banked already), but to :attr:`FLOOR` of it at most (a
    #: burst of a fifth of the lead at least)
    LOW, FLOOR, MARGIN = 0.5, 0.8, 0.01

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

    @classmethod
    def refill(cls, lead: float, command_delay: float) -> float:
        """Return the wall seconds of steps computed in one burst, the lead full before it.

        The loop sleeps until the steps banked come down to the low mark (:attr:`LOW` of the
        lead, or the command delay and a margin; at most :attr:`FLOOR` of it), then refills
        the lead. Each wake-up costs the steps that follow it far more than a step in a burst (caches
        and the processor cold after a sleep: the first step about five times a step), so
        the bursts are as long as the steps a command needs banked allow."""
        low = min(cls.FLOOR * lead, max(cls.LOW * lead, command_delay + cls.MARGIN))
        return lead - low

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
            data = b"".join(HEAD.pack(Frame.MESSAGES, len(p)) + p for p in self.pending)
            self.pending = []
            self.due = math.inf
            if not self.out.write(data):
                raise BrokenPipeError("the node's process is gone")

    def run(self) -> None:
        runner, twin, afap = self.runner, self.twin, self.afap
        clock = time.perf_counter
        step = twin.dt / runner.rtf
        ahead = twin.rewindable and (afap or runner.realtime.lead > step)
        lead = runner.realtime.lead if ahead else step
        # checkpoints kept, by step
        keep = (self.AHEAD + self.BATCH + 100) if afap else int(math.ceil(2.0 * lead / step)) + 100
        keep += self.EVERY
        refill = self.refill(lead, runner.realtime.command_delay) if ahead else 0.0
        self._begin(ahead, 0.0 if afap else lead - step)
        next_diag = runner.clocks.wall_start + runner.period
        commands, stop, lines = self.commands, runner.stopping, runner.commands.lines
        # the rate achieved is judged once a wall second has passed (or at the run's end, if
        # sooner), and any time the schedule falls this far behind (wall s): said once
        behind, self.warned = max(0.1, lead), afap
        self.begun = begun = clock()
        judge = begun + RATE_WINDOW
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
                        if lines.held:
                            lines.flush()
                            continue
                        wait += refill
                        self.wake.wait(wait)
                        self.wake.clear()
                        continue
                k, msgs, c1 = runner.timed_step(deadline, clock)
                if (c1 >= judge or c1 > deadline + behind) and not (self.warned or self.hold.paused):
                    judge = math.inf
                    self._judge_rate(k, c1, late=c1 > deadline + behind)
                t_ns = twin.t_ns
                staged = [] if msgs is None else [(key, data, t_ns, False) for key, data in msgs]
                events = twin.new_events(hold=not ahead)
                if events or c1 >= next_diag:  # most steps have neither: no staging for them
                    with runner.staged(staged):
                        runner.emit_events(events, t_ns)
                        if c1 >= next_diag:
                            next_diag = c1 + runner.period
                            runner.publish_diagnostics(t_ns)
                # a step's messages and its events' (none of them a command as received)
                runner.measurements.messages += len(staged)
                if ahead and k % self.EVERY == 0:
                    cps = self.cps
                    cps[k] = twin.checkpoint()
                    while next(iter(cps)) < k - keep:  # in the order they were taken
                        del cps[next(iter(cps))]
                self._entry(k, self.deadline(k) if afap else deadline, msgs is not None, staged)
                if one or len(self.pending) >= self.BATCH or self.due - clock() < self.NEAR:
                    self.flush()
        except Exception as exc:
            runner.failed(exc)
            raise
        finally:
            self._end()

    def _begin(self, ahead: bool, lead: float) -> None:
        """The run's start: its start event, t0's state and the commands already waiting, the
        first entry, due ``lead`` wall seconds from now (the first steps computed meanwhile)."""
        runner, twin = self.runner, self.twin
        runner.prepare()
        runner.clocks.start()
        staged: list = []
        with runner.staged(staged):
            runner.begin()
        self.wall_start = runner.clocks.wall_start = time.perf_counter() + lead
        self.k0 = twin.k
        if ahead:
            self.cps[twin.k] = twin.checkpoint()
        self._entry(twin.k, self.deadline(twin.k), True, staged)
        runner.commands.lines.hold()

    def _end(self) -> None:
        """The run's end, however it ends: what is pending written, the log lines said, the
        run's end event and its last state as the last entry."""
        runner, twin = self.runner, self.twin
        try:
            self.flush()
        except BrokenPipeError:
            pass
        runner.commands.lines.end()
        if not (self.warned or self.hold.paused) and twin.k > self.k0:
            self._judge_rate(twin.k, time.perf_counter(), late=False)
        staged: list = []
        with runner.staged(staged):
            runner.end()
        runner.measurements.messages += sum(1 for m in staged if not m[3])
        self._entry(twin.k, self.deadline(twin.k), False, staged)
        try:
            self.flush()
        except BrokenPipeError:
            pass

    def _judge_rate(self, k: int, now: float, late: bool) -> None:
        """Warn once where the steps so far came slower than real time asks, or ``late``."""
        runner, twin = self.runner, self.twin
        period = twin.dt / runner.rtf
        rate = achieved_rate(k - self.k0, now - self.begun - self.hold.shift)
        if not (late or rate < RATE_SHORT / period):
            return
        self.warned = True
        runner.log(
            "warn",
            f"cannot keep real time: {k - self.k0} steps to t = {twin.t:.6g} s took "
            f"{now - self.begun - self.hold.shift:.3g} wall s, about {rate:.0f} steps a wall "
            f"second where real time needs {1.0 / period:.0f} (a step every "
            f"{period * 1e3:.3g} ms): give a larger dt or a smaller real_time_factor (the run "
            "goes on, behind its schedule)",
        )

    def _command(self, cmd: tuple, ahead: bool) -> None:
        """A command at its boundary ``k`` (the ROS process chose it, dropped the steps it had
        beyond it, and numbered what follows ``gen``)."""
        cid, word, source, wall, k, gen = cmd
        runner, twin = self.runner, self.twin
        if twin.k > k:
            j = max((j for j in self.cps if j <= k), default=None)
            if j is not None:
                runner.measurements.steps_recomputed += twin.k - k
                twin.restore(self.cps[j])
                for j in [j for j in self.cps if j > k]:
                    del self.cps[j]
                self._step_again_to(k, ahead)
        self.gen = gen
        reply = None if cid is None else self._reply(cid)
        staged: list = []
        with runner.staged(staged):
            runner.commands.take([Command(word, source, reply, wall)], gated=True)
        if ahead:
            self.cps[twin.k] = twin.checkpoint()
        self._entry(twin.k, self.deadline(twin.k), False, staged)
        self.flush()

    def _step_again_to(self, k: int, ahead: bool) -> None:
        """From a checkpoint before step ``k`` to ``k`` again, as the loop stepped there (the
        messages and events made as they were, so that the twin is where it was; nothing
        sent: those steps went out already)."""
        twin, every = self.twin, self.runner.every
        while twin.k < k:
            twin.step()
            if twin.k % every == 0 or twin.done:
                twin.state_payloads()
            twin.new_events(hold=not ahead)

    def _reply(self, cid: int):
        def reply(ack):
            self.out.frame(Frame.ANSWER, marshal.dumps((cid, to_json(ack))))

        return reply


class _FromTheNode:
    """What the node's process sends the stepping process after its settings, taken by a
    thread of its own as it comes (see the module's docstring for the frames): the commands
    (for :class:`_Ahead`), go and the priority asked (:attr:`go`, :attr:`asked`), a stop, the
    node's command counts, its pause, its steps asked for while paused and its releases
    (:attr:`hold`); ``pending``: frames that came with the settings."""

    def __init__(self, runner: Runner, reader: FrameReader, pending: list):
        self.runner, self.reader, self.pending = runner, reader, pending
        self.commands: collections.deque = collections.deque()
        self.wake = threading.Event()  # the stepping loop's: something came
        self.hold = Hold()
        self.go = threading.Event()
        self.asked: dict = {}

    def stop(self, reason: str) -> None:
        self.runner.request_stop(reason)
        self.wake.set()

    def take(self, kind: bytes, payload: bytes) -> None:
        hold, runner = self.hold, self.runner
        if kind == Frame.COMMAND:
            self.commands.append(marshal.loads(payload))
        elif kind == Frame.STOP:
            self.stop(payload.decode())
            self.go.set()
        elif kind == Frame.GO:
            self.asked.update(json.loads(payload))
            self.go.set()
        elif kind == Frame.REFUSED:
            runner.commands.elsewhere = marshal.loads(payload)
        elif kind == Frame.PAUSE:
            hold.paused = True
        elif kind == Frame.STEP:
            hold.steps.append(1)
        elif kind == Frame.RELEASED:
            hold.released = marshal.loads(payload)
        elif kind == Frame.RESUME:
            paused = marshal.loads(payload)
            hold.shift += paused
            runner.clocks.wall_start += paused
            hold.paused = False
        self.wake.set()

    def listen(self) -> None:
        """The thread's loop, until the node's end of the pipe closes (a stop)."""
        for kind, payload in self.pending:
            self.take(kind, payload)
        while True:
            got = self.reader.read()
            if not got:  # the node's end of the pipe closed
                self.stop("the node's process ended")
                self.go.set()
                return
            for kind, payload in got:
                self.take(kind, payload)


def serve(fd_in: int = 0, fd_out: int = 1) -> int:
    """The stepping process (``python -m mps_ros.run.stepping``): settings, ready, go, the run,
    its end; see the module's docstring."""
    parent = os.getppid()
    die_with_parent()
    if fd_out == 1:  # the frames keep the pipe; whatever else prints goes to stderr
        fd_out = os.dup(1)
        os.dup2(2, 1)
    out = FrameWriter(fd_out)
    widen_pipe(fd_out)
    reader = FrameReader(fd_in)
    frames = reader.read()
    if not frames or frames[0][0] != Frame.SETTINGS:
        return 2
    spec = json.loads(frames[0][1])
    pending = frames[1:]

    def log(level: str, text: str) -> None:
        out.frame(Frame.LOG, marshal.dumps((level, text)))

    try:
        twin = Twin(spec["scene"], **spec["twin"])
        pacing = "as_fast_as_possible" if spec.get("afap") else "realtime"
        runner = Runner(twin, pacing=pacing, log=log, **spec["runner"])
        runner.prepare()
    except Exception as exc:
        out.frame(Frame.READY, json.dumps({"error": f"{type(exc).__name__}: {exc}"}).encode())
        return 2
    node = _FromTheNode(runner, reader, pending)

    def on_signal(signum, _frame):
        node.stop(signal.Signals(signum).name)

    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, on_signal)
    if os.getppid() != parent:  # the node died before the death signal was asked for
        node.stop("the node's process ended")
    out.frame(
        Frame.READY, json.dumps({"ready": True, "pid": os.getpid(), "rewindable": twin.rewindable}).encode()
    )
    threading.Thread(target=node.listen, name="mps-commands", daemon=True).start()
    node.go.wait()
    prio = int(node.asked.get("priority", 0))
    why = ask_fifo(prio) if prio else None
    if prio and why is None:
        # the commands' thread too: a command waits for no ordinary process on the machine
        fifo_for_the_others(prio)
    # a command waits this long at most for the stepping thread to let go of the interpreter
    # (Python's default: 5 ms, five steps)
    sys.setswitchinterval(2e-4)
    out.frame(
        Frame.PRIORITY, json.dumps({"priority": 0 if (why or not prio) else prio, "refused": why}).encode()
    )
    from ..os_threads import name_thread

    name_thread("mps-step")
    error_kind = None
    try:
        _Ahead(runner, out, node.commands, node.wake, node.hold, afap=bool(spec.get("afap"))).run()
    except Exception as exc:
        from mps_core import MpsError

        error_kind = "simulation" if isinstance(exc, MpsError) else "error"
        if runner.error is None:  # it failed before its loop (its start): said all the same
            runner.failed(exc)
        if error_kind == "error":  # not the simulation's: where it came from
            import traceback

            where = traceback.extract_tb(exc.__traceback__)[-1]
            log("error", f"{type(exc).__name__} at {where.filename}:{where.lineno} in {where.name}")
    stats = runner.stats()
    stats["structure"] = twin.sim.structure
    out.frame(
        Frame.END,
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


if __name__ == "__main__":
    sys.exit(serve())
