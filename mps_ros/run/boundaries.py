"""The commands of a split run, each taken at its boundary in the node's process
(:class:`Boundaries`), the steps held there (:class:`HeldStep`, :class:`HeldSteps`) and the
run's schedule (:class:`Schedule`)."""

from __future__ import annotations

import collections
import marshal
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass

from ..wire.json_text import to_json
from .commands import COMMAND_INDEX, Command, Gate, RefusalLog, shown
from .twin import to_ns


class HeldStep:
    """A step (or a command's answers) from the stepping process, waiting for its deadline;
    ``structure`` and ``refusals`` (:meth:`Twin.refusals`): the twin's after it; ``encoded``:
    the frame it came in (its marshal, ``msgs`` the last item), handed to the recorder as it
    is; None for one made here."""

    __slots__ = ("k", "gen", "deadline", "state", "structure", "refusals", "msgs", "encoded")

    def __init__(self, k, gen, deadline, state, structure, refusals, msgs, encoded=None):
        self.k, self.gen, self.deadline = k, gen, deadline
        self.state, self.structure, self.refusals, self.msgs = state, structure, refusals, msgs
        self.encoded = encoded


class HeldSteps:
    """The steps a split run holds for their deadlines, shared by the node's releasing loop
    and its commands: read or change them with :attr:`lock` held."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        #: the steps (and commands' answers) held, in the order of their deadlines
        self.queue: collections.deque[HeldStep] = collections.deque()
        #: the last one released
        self.released: HeldStep | None = None
        #: the stepping process has said its end
        self.ended = False
        #: paused (the node inactive) since this wall time (s); None while it runs
        self.paused_at: float | None = None

    def last(self) -> HeldStep | None:
        """Return the last step held, or the last released where none is held."""
        return self.queue[-1] if self.queue else self.released


@dataclass(frozen=True)
class Schedule:
    """A split run's steps in time: ``grid`` (t0, t_end, the number of steps; None where not
    known), their pace and whether they go out as fast as possible."""

    grid: tuple[float, float, int] | None
    real_time_factor: float = 1.0
    afap: bool = False

    @classmethod
    def of(cls, spec: dict) -> Schedule:
        """Return the schedule of a stepping process's settings."""
        grid = spec.get("grid")
        return cls(
            None if grid is None else (float(grid[0]), float(grid[1]), int(grid[2])),
            float(spec["runner"].get("real_time_factor", 1.0)),
            bool(spec.get("afap")),
        )

    def time_of(self, k: int) -> float:
        """Return step ``k``'s simulated time (NaN where the grid is not known)."""
        if self.grid is None:
            return math.nan
        t0, t_end, n = self.grid
        return t_end if k == n else t0 + k * (t_end - t0) / n

    def period(self) -> float:
        """Return a step's period on the wall clock (s; 0 where the grid is not known)."""
        if self.grid is None:
            return 0.0
        t0, t_end, n = self.grid
        return (t_end - t0) / n / self.real_time_factor


class Boundaries:
    """The commands of a split run, taken in the node's process as they arrive (any thread),
    each at its boundary: one the gate refuses (a flood, an empty, overlong or unknown word)
    or the machine would refuse there (what the step held there says) is answered here, at no
    cost to the stepping; any other goes to the stepping process with its boundary and a new
    *generation*, the steps held beyond it dropped (and what was already in the pipe of the old
    generation dropped on arrival: :meth:`arrived`). ``held``: the steps held (shared with the
    releasing loop); ``schedule``: their times; ``send_command(payload)``: a command on to the
    stepping process (the payload of :attr:`~mps_ros.wire.pipe.Frame.COMMAND`);
    ``counts_changed()``: the refusals counted here have changed (the stepping process's
    /diagnostics say them)."""

    def __init__(
        self,
        held: HeldSteps,
        schedule: Schedule,
        gate: Gate,
        log: Callable[[str, str], None],
        send_command: Callable[[bytes], None],
        counts_changed: Callable[[], None],
        command_delay: float = 0.0,
    ):
        from ..wire.cdr import string

        self.held = held
        self.schedule = schedule
        self.gate = gate
        self.send_command = send_command
        self.counts_changed = counts_changed
        #: a command takes effect at the first step boundary at least this long (wall s) after
        #: it arrived (see :attr:`~mps_ros.run.runner.RealtimeSettings.command_delay`)
        self.command_delay = float(command_delay)
        self.commands_refused = 0
        self._string = string
        self._replies: dict[int, Callable[[dict], None]] = {}  # the services' replies, by the id sent on
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

    def arrived(self, entry: HeldStep) -> bool:
        """A step (or a command's answers) from the stepping process, held where it is of
        the present generation or of an earlier one up to that one's boundary (the lock
        held); False where it was dropped."""
        gen = entry.gen
        if not (gen == self._gen or entry.k <= self._limits.get(gen, -1)):
            return False
        queue = self.held.queue
        queue.append(entry)
        if gen > self._received_gen:  # a command's answers
            self._received_gen = gen
            queue.extend(self._held.pop(gen, ()))
        return True

    def answer(self, cid: int, ack: dict) -> None:
        """The stepping process's answer to a command a service sent (any thread)."""
        with self.held.lock:
            reply = self._replies.pop(cid, None)
        if reply is not None:
            try:
                reply(ack)
            except Exception:  # a reply must never take the run down
                pass

    def end(self) -> None:
        """The run has ended: the commands that waited are refused, the services still
        waiting for an answer told so."""
        with self.held.lock:
            self.held.ended = True
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
        with self.held.lock:
            if self.held.paused_at is not None and self.held.released is not None:
                # paused: simulated time holds at the last step released; the command is
                # taken at the next boundary, as if it had come then
                cmd.wall = self.held.released.deadline
            refusal = "the run has ended" if self.held.ended else self.gate.check(word)
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
        queue = self.held.queue
        while queue and queue[-1].k > kb:
            queue.pop()
        self._limits[self._gen] = kb
        self._last_boundary = kb
        self._gen += 1
        self.send_command(marshal.dumps((cid, word, cmd.source, cmd.wall, kb, self._gen)))

    def take_waiting(self) -> None:
        """The commands that waited for an answer, in order (the lock held), each once the
        step of its boundary is here, until one is sent on; after the run's end, each
        refused."""
        waiting = self._waiting
        while waiting and (self.held.ended or self._gen == self._received_gen):
            cmd, word, refusal = waiting[0]
            if not self.held.ended and refusal is None and not self.schedule.afap:
                last = self.held.last()
                if last is None or last.deadline < cmd.wall + self.command_delay:
                    return  # its boundary's step is still to come
            waiting.popleft()
            self._take(cmd, word, "the run has ended" if self.held.ended else refusal)

    def _step_at(self, wall: float) -> int | None:
        """The first step whose deadline is not before ``wall`` (the lock held), among the
        last released, those held and those still to come (the schedule's; the stepping
        process steps on to it, where it is not there yet); None before the run has started.
        As fast as possible: the last step released."""
        if self.schedule.afap:
            return None if self.held.released is None else self.held.released.k
        last = self.held.last()
        if last is None:
            return None
        grid = self.schedule.grid
        if last.deadline >= wall or grid is None:
            at = self._boundary(wall)
            return None if at is None else at.k
        n = grid[2]
        return min(n, last.k + max(1, math.ceil((wall - last.deadline) / self.schedule.period() - 1e-9)))

    def _settled(self, wall: float, kb: int) -> HeldStep | None:
        """The held (or last released) entry that ends step ``kb``, where what it says of the
        machine is what a command there meets (the lock held): no command sent on is still
        unanswered and it is of the present generation; None where that is not known here."""
        if self._gen != self._received_gen:
            return None
        at = self._boundary(wall)
        if at is None or at.k != kb or at.gen != self._gen:
            return None
        return at

    def _boundary(self, wall: float) -> HeldStep | None:
        """The entry a command that arrived at ``wall`` follows (the lock held): the last
        entry of the first step whose deadline is not before ``wall``, among the last released
        and those held; the last of them where none is that late yet. As fast as possible: the
        last step released."""
        if self.schedule.afap:
            return self.held.released
        at = self.held.released
        d = at.deadline if at is not None and at.deadline >= wall else None
        # held in the order of their deadlines: a command's boundary is near the front
        for e in self.held.queue:
            if d is None:
                at = e
                if e.deadline >= wall:
                    d = e.deadline
            elif e.deadline <= d:
                at = e
            else:
                break
        return at

    def _refuse(self, cmd: Command, word: str, reason: str, at: HeldStep | None) -> None:
        """A command the gate refused, answered at its boundary (but never before the answer
        of a command that came earlier: at the boundary of the last one sent on, where that is
        later): its messages go out (and are recorded) right after that step's; the stepping
        is not disturbed."""
        self.commands_refused += 1
        k = at.k if at is not None else 0
        deadline = at.deadline if at is not None else 0.0
        if self._last_boundary > k and at is not None:
            deadline += (self._last_boundary - k) * self.schedule.period()
            k = self._last_boundary
        t = self.schedule.time_of(k)
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
        entry = HeldStep(
            k, self._gen, deadline, False, structure, at.refusals if at is not None else None, msgs
        )
        queue = self.held.queue
        if self._gen > self._received_gen:
            # a command sent on is being applied: this answer follows that one's
            self._held.setdefault(self._gen, []).append(entry)
        else:
            # after everything held at its step or before (the answers given there included)
            i = next((n for n, e in enumerate(queue) if e.k > k), len(queue))
            queue.insert(i, entry)
        self._refusals.refused(word, cmd.source, t, reason, cmd.wall)
        self.counts_changed()
        if cmd.reply is not None:
            try:
                cmd.reply(ack)
            except Exception:
                pass
