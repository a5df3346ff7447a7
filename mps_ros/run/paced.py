"""Realtime pacing in one process (the node's ``stepping_process:=false``): a
:class:`~mps_ros.run.runner.Runner`'s twin stepped ahead by its thread, each step released at its
deadline by a thread of its own (:class:`PacedInProcess`). The node's default steps in a
process of its own instead (:mod:`mps_ros.run.stepping`, :mod:`mps_ros.run.releasing`)."""

from __future__ import annotations

import collections
import math
import threading
import time

from mps_core.scene.settings import COMMANDS

from ..os_threads import name_thread, short_slice
from .sinks import Fanout


class _Release:
    """A step's messages waiting for their deadline (realtime pacing): ``msgs`` as
    (key, bytes, t_ns, received), ``state``: they include the step's state; ``cp``: the
    twin's checkpoint after the step (to come back to for a command); ``structure`` and
    ``refusals`` (:meth:`Twin.refusals`): the twin's after the step."""

    __slots__ = ("k", "t_ns", "deadline", "msgs", "state", "cp", "structure", "refusals")

    def __init__(self, k, t_ns, deadline, msgs, state, cp, structure="", refusals=None):
        self.k, self.t_ns, self.deadline = k, t_ns, deadline
        self.msgs, self.state, self.cp = msgs, state, cp
        self.structure, self.refusals = structure, refusals


class PacedInProcess:
    """A :class:`~mps_ros.run.runner.Runner`'s realtime run in its own process: the steps, their
    releases and the commands at their boundaries (see :meth:`run`). ``runner``: the run's
    twin, sinks, inbox, settings and counters."""

    #: steps queued ahead: no step is begun closer than this (wall s) to the next release's
    #: deadline (at most half a step's period)
    RELEASE_GUARD = 3e-4

    def __init__(self, runner):
        self.runner = runner
        twin, rt = runner.twin, runner.realtime
        #: a step's period on the wall clock
        self.step = step = twin.dt / runner.rtf
        #: steps are computed ahead of their deadlines (a command comes back to a checkpoint)
        self.ahead = ahead = twin.rewindable and rt.lead > step
        self.lead = rt.lead if ahead else step
        # the steps and the releases share the interpreter: a step is not begun this close
        # to a release's deadline, or while one is going out, when steps are queued ahead
        self.guard = min(self.RELEASE_GUARD, 0.5 * step)
        #: a full lead: the stepping thread sleeps until this much of it is spent
        self.refill = 0.2 * self.lead if ahead else 0.0
        #: the sinks each step goes to at its deadline (the ROS publishers), and after it
        #: (the recorder)
        self.live, self.later = runner.sinks.split()
        self._queue: collections.deque[_Release] = collections.deque()
        self._cond = threading.Condition()
        self._released: _Release  # the last released (set at the start)
        self._flush = self._ahead_done = self._releasing = False
        self._released_steps: collections.deque[_Release] = collections.deque()
        # a release goes out this long after the deadline of the first step it sends
        self._release_delay = max(0.0, rt.release_period - step)

    def run(self) -> dict:
        """Realtime pacing. The stepping thread (this one) computes steps up to ``lead``
        seconds of wall time ahead of their deadlines and queues each step's messages with a
        checkpoint of the twin; a releasing thread hands each step's messages to the live
        sinks (``sink.live``: the ROS publishers) once its deadline has passed (at most
        ``release_period`` less one period after it: the steps due at a wake-up go out
        together), and the stepping thread then hands the released steps to the other sinks
        (the recorder) in its spare time. A
        step that costs more than the period (an impact, a chart change, the machine busy for
        a moment) is absorbed by the steps computed ahead instead of coming out late. A
        command that arrives at wall time w is applied at the first step boundary whose
        deadline is not before w + ``command_delay`` (one the gate refuses is answered at that
        boundary too, so that the answers keep the commands' order, and changes nothing):
        the twin comes back to that step's checkpoint (the steps
        computed beyond it are dropped, never released) and goes on from there with the
        command. Nothing is released before its deadline, so what the sinks get is what a run
        that stepped in time would have given them."""
        r = self.runner
        r.prepare()
        r.clocks.start()
        releaser = threading.Thread(
            target=self._release_loop, args=(self.live,), name=f"{r.name}-release", daemon=True
        )
        next_diag = r.clocks.wall_start + r.period
        try:
            self._start(releaser)
            self._step_ahead(next_diag)
        except Exception as exc:
            r.failed(exc)
            raise
        finally:
            self._end(releaser)
        return r.stats()

    def _start(self, releaser: threading.Thread) -> None:
        """The run's start, t0's state and the commands already waiting, queued to go out at
        the schedule's start; with steps computed ahead, that is once the first of them are
        (the schedule's first steps would otherwise find none banked). The releasing thread
        started; with steps computed ahead, the commands' log lines held back from now on."""
        r = self.runner
        twin = r.twin
        first = _Release(twin.k, twin.t_ns, 0.0, [], True, None, twin.sim.structure, twin.refusals())
        with r.staged(first.msgs):
            r.begin()
        r.clocks.wall_start = first.deadline = time.perf_counter() + (self.lead - self.step)
        if self.ahead:
            first.cp = twin.checkpoint()
        self._queue.append(first)
        self._released = first
        releaser.start()
        if self.ahead:
            r.commands.lines.hold()

    def _step_ahead(self, next_diag: float) -> None:
        """The stepping thread's loop, to the run's end or a stop: the released steps handed
        to the other sinks, the commands taken as they come, each step computed and queued
        once its deadline is within the lead (the commands' log lines said where it is full)."""
        r = self.runner
        twin, clocks, inbox, stop, lines = r.twin, r.clocks, r.inbox, r.stopping, r.commands.lines
        clock = time.perf_counter
        queue, cond, released, later = self._queue, self._cond, self._released_steps, self.later
        ahead, lead, guard, refill = self.ahead, self.lead, self.guard, self.refill
        delay = self._release_delay
        t0, rtf = twin.t0, r.rtf
        while not twin.done and not stop.is_set():
            if released:
                self._hand_over(released, later)
            if inbox:
                self._commands_ahead(ahead)
                continue
            deadline = clocks.wall_start + (twin.time_of(twin.k + 1) - t0) / rtf
            wait = deadline - lead - clock()
            if wait > 0.0:
                if lines.held:
                    lines.flush()
                    continue
                # a full lead: sleep until a part of it is spent, then refill it in a
                # burst of steps (one wake-up for several steps)
                wait += refill
                inbox.wait(wait if wait < 0.05 else 0.05)
                continue
            if ahead and queue:
                with cond:
                    while (
                        (self._releasing or (queue and queue[0].deadline + delay - clock() < guard))
                        and not stop.is_set()
                        and not inbox
                    ):
                        cond.wait(0.002)
            next_diag = self._step_queued(deadline, ahead, next_diag)

    def _step_queued(self, deadline: float, ahead: bool, next_diag: float) -> float:
        """One step computed and queued for its release (its messages, events, the
        diagnostics where due, its checkpoint); the next diagnostics' time."""
        r = self.runner
        twin, queue, cond = r.twin, self._queue, self._cond
        k, msgs, c1 = r.timed_step(deadline, time.perf_counter)
        t_ns = twin.t_ns
        entry = _Release(k, t_ns, deadline, [], msgs is not None, None, twin.sim.structure, twin.refusals())
        if msgs is not None:
            entry.msgs.extend((key, data, t_ns, False) for key, data in msgs)
        with r.staged(entry.msgs):
            # no time ahead: an impact's impulses wait for the next step's spare time
            r.emit_events(twin.new_events(hold=not ahead), t_ns)
            if c1 >= next_diag:
                next_diag = c1 + r.period
                r.publish_diagnostics(t_ns)
        if ahead:
            entry.cp = twin.checkpoint()
        with cond:
            # the releasing thread waits for its head's deadline, which a step queued behind
            # it does not move: it is woken only where it has none
            idle = not queue
            queue.append(entry)
            if idle:
                cond.notify_all()
        return next_diag

    def _end(self, releaser: threading.Thread) -> None:
        """The run's end, however it ends: the releasing thread lets go of what is queued (at
        once, where the run was stopped) and ends, the last released steps handed over, the
        log lines said, the run's end."""
        r, cond = self.runner, self._cond
        with cond:
            self._ahead_done = True
            self._flush = r.stopping.is_set() or r.error is not None
            cond.notify_all()
        if releaser.is_alive():
            releaser.join()
        self._hand_over(self._released_steps, self.later)
        r.commands.lines.end()
        r.end()

    def _release_loop(self, live: Fanout) -> None:
        """The releasing thread: each queued step's messages to the live sinks once its
        deadline has passed: woken ``_release_delay`` after the first queued step's deadline,
        it sends that step and every one queued behind it whose deadline has passed by then
        (one wake-up for them all); then each step goes to the stepping thread for the other
        sinks."""
        r = self.runner
        # named for top -H and /proc; a short scheduler slice, so that the subscribers'
        # threads its messages wake preempt it less often (Linux 6.12 on; elsewhere not)
        name_thread("mps-release")
        m = r.measurements
        ask = r.realtime.release_slice
        m.release_slice = ask if ask and short_slice(ask) else None
        clock = time.perf_counter
        queue, cond, released = self._queue, self._cond, self._released_steps
        delay = self._release_delay
        due = -math.inf  # the wake-up's time: the steps due by then go out now
        while True:
            with cond:
                while True:
                    if queue:
                        head = queue[0]
                        if head.deadline > due and not self._flush:
                            now = clock()
                            left = head.deadline + delay - now
                            if left > 0.0:
                                cond.wait(left)
                                continue
                            due = now
                        queue.popleft()
                        self._released = head
                        self._releasing = True
                        break
                    elif self._ahead_done:
                        return
                    else:
                        cond.wait()
            p0 = clock()
            n = 0
            try:
                msgs = head.msgs
                for _key, _data, _t, received in msgs:
                    if not received:
                        n += 1
                live.emit_all(msgs)
                live.tick(head.deadline)
            except Exception as exc:  # a sink that fails ends the run, never hangs it
                if r.error is None:
                    r.error = f"{type(exc).__name__}: {exc}"
                    r.log("error", f"publishing failed at t = {head.t_ns * 1e-9:.6f} s: {r.error}")
                r.request_stop("error")
            p1 = clock()
            m.messages += n
            released.append(head)
            with cond:
                self._releasing = False
                cond.notify_all()
            if head.state:
                m.publish_times.add(p1 - p0)
                late = p1 - head.deadline
                m.latencies.add(late if late > 0.0 else 0.0)

    @staticmethod
    def _hand_over(released: collections.deque, sinks: Fanout) -> None:
        """Released steps to the sinks that are not live (the recorder), in order."""
        while released:
            entry = released.popleft()
            sinks.emit_all(entry.msgs)
            sinks.tick(entry.deadline)

    def _boundary(self, wall: float, ahead: bool) -> _Release:
        """The release a command that arrived at ``wall`` follows (call with the queue's
        lock held): the first step whose deadline is not before ``wall`` (its last release:
        the step's, or a command's applied there), among the last one released and those
        queued after it; the last one computed where nothing can be rewound."""
        queue = self._queue
        last = queue[-1] if queue else self._released
        if not ahead:
            return last
        steps = (self._released, *queue)
        d = next((e.deadline for e in steps if e.deadline >= wall), None)
        return last if d is None else [e for e in steps if e.deadline <= d][-1]

    def _commands_ahead(self, ahead: bool) -> None:
        """Apply the commands waiting, each at its step boundary (see :meth:`run`). One
        the gate refuses (a flood, an empty or overlong word), or the machine would refuse at
        its boundary (the step's :attr:`_Release.refusals`), changes nothing: its answer is
        queued right after its boundary and the steps computed beyond it stand. Any other comes
        back to its boundary's checkpoint, drops the steps beyond it, and is applied there."""
        r = self.runner
        twin, queue, cond, commands = r.twin, self._queue, self._cond, r.commands
        for c in r.inbox.drain():
            word = c.word if isinstance(c.word, str) else str(c.word)
            refusal = commands.gate.check(word)
            with cond:
                # every command at the boundary of its wall time and the delay, so that the
                # answers go out in the order the commands came
                at = self._boundary(c.wall + r.realtime.command_delay, ahead)
                if refusal is None:
                    refusal = at.refusals[COMMANDS.index(word)]
                    if refusal is None:
                        last = queue[-1] if queue else self._released
                        while queue and queue[-1] is not at:
                            queue.pop()
            if refusal is not None:
                entry = _Release(at.k, at.t_ns, at.deadline, [], False, at.cp, at.structure, at.refusals)
                with r.staged(entry.msgs):
                    commands.answer(c, word, False, refusal, twin.time_of(at.k), at.structure)
                with cond:
                    # right after its boundary and the answers given there (or first, where
                    # that went out meanwhile)
                    i = next((n for n, e in enumerate(queue) if e is at), -1) + 1
                    while i < len(queue) and queue[i].k == at.k:
                        i += 1
                    queue.insert(i, entry)
                    cond.notify_all()
                continue
            if at is not last:
                r.measurements.steps_recomputed += last.k - at.k
                twin.restore(at.cp)
            entry = _Release(twin.k, twin.t_ns, at.deadline, [], False, None)
            with r.staged(entry.msgs):
                commands.take([c], gated=True)
            entry.structure, entry.refusals = twin.sim.structure, twin.refusals()
            if ahead:
                entry.cp = twin.checkpoint()
            with cond:
                queue.append(entry)
                cond.notify_all()
