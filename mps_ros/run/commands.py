"""The commands of a run: as received (:class:`Command`), handed over to the run loop
(:class:`Inbox`), checked (:class:`Gate`), applied at a step boundary and answered
(:class:`RunCommands`), their log lines held back or thinned (:class:`HeldLog`,
:class:`RefusalLog`).
"""

from __future__ import annotations

import collections
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from mps_core.scene.settings import COMMANDS

from ..wire.json_text import to_json
from .twin import to_ns

EXPECTED = "expected one of " + ", ".join(COMMANDS)
#: a word's place in :data:`COMMANDS` (and in :meth:`Twin.refusals`)
COMMAND_INDEX = {word: i for i, word in enumerate(COMMANDS)}


@dataclass
class Command:
    """A command as received: the word, where from (topic, service), an optional reply."""

    word: str
    source: str = "topic"
    reply: Callable[[dict], None] | None = None
    #: when it arrived, on the run's clock (``time.perf_counter``)
    wall: float = field(default_factory=time.perf_counter)


class Inbox:
    """Commands handed over from the ROS callbacks' thread to the run loop, which can wait
    for one (:meth:`wait`)."""

    def __init__(self):
        self._q: collections.deque[Command] = collections.deque()
        self._ready = threading.Event()

    def put(self, cmd: Command) -> None:
        self._q.append(cmd)
        self._ready.set()

    def wake(self) -> None:
        """End a :meth:`wait` now (a stop request)."""
        self._ready.set()

    def wait(self, timeout: float) -> None:
        """Until a command arrives, :meth:`wake` is called, or ``timeout`` (s) passes."""
        if self._ready.wait(timeout):
            self._ready.clear()

    def __bool__(self) -> bool:
        return bool(self._q)

    def drain(self) -> list[Command]:
        out = []
        while True:
            try:
                out.append(self._q.popleft())
            except IndexError:
                return out


class Gate:
    """What a command must pass before the machine sees it: not part of a flood (a token
    bucket over wall time: ``burst`` at once, ``rate`` a second after), not empty, not too
    long, one of the machine's words. What is refused here costs the stepping nothing."""

    MAX_LEN = 64

    def __init__(self, burst: int = 10, rate: float = 20.0, clock=time.monotonic):
        self.burst = max(1, int(burst))
        self.rate = float(rate)
        self.clock = clock
        self.tokens = float(self.burst)
        self.last = clock()
        self.floods = 0  # commands refused as part of a flood

    def check(self, word: str) -> str | None:
        now = self.clock()
        self.tokens = min(self.burst, self.tokens + (now - self.last) * self.rate)
        self.last = now
        if self.tokens < 1.0:
            self.floods += 1
            return (
                f"flood: more than {self.burst} commands at once or {self.rate:g} a second; "
                "this one is dropped"
            )
        self.tokens -= 1.0
        if not word.strip():
            return f"empty command: {EXPECTED}"
        if len(word) > self.MAX_LEN:
            return f"a {len(word)}-character command: {EXPECTED}"
        if word not in COMMANDS:
            return EXPECTED
        return None


def shown(word: str, n: int = 40) -> str:
    return word if len(word) <= n else word[:n] + f"...({len(word)} characters)"


class RefusalLog:
    """The log lines of refused commands: one each, but a flood's once a second with the count
    of those refused since (``say(level, text)`` writes a line)."""

    def __init__(self, say: Callable[[str, str], None]):
        self.say = say
        self.logged = -math.inf  # when a flood's refusal was last logged (wall s)
        self.quiet = 0  # refused as a flood since, not logged

    def refused(self, word: str, source: str, t: float, reason, wall: float) -> None:
        flood = str(reason).startswith("flood")
        if flood and wall - self.logged < 1.0:
            self.quiet += 1
            return
        more = f" ({self.quiet} more refused as a flood before this)" if self.quiet else ""
        self.say("warn", f"refused command {shown(word)!r} ({source}) at t = {t:.6f} s: {reason}{more}")
        self.quiet = 0
        if flood:
            self.logged = wall

    def close(self) -> None:
        """The count of a flood's refusals not logged yet, if any."""
        if self.quiet:
            self.say("warn", f"{self.quiet} more refused as a flood, not logged one by one")
            self.quiet = 0


class HeldLog:
    """A run's log (``log(level, text)``), whose lines may be held back and said later: in
    realtime pacing with steps banked, the commands' lines are said when the lead is full (a
    line through rclpy's logger costs about 0.6 ms: not in the steps after a command)."""

    def __init__(self, log: Callable[[str, str], None]):
        self.log = log
        #: the lines held back (None: each is said at once)
        self.held: list | None = None

    def say(self, level: str, text: str) -> None:
        if self.held is not None:
            self.held.append((level, text))
        else:
            self.log(level, text)

    def hold(self) -> None:
        """From now on, each line held back until :meth:`flush`."""
        self.held = []

    def flush(self) -> None:
        """The lines held back, said."""
        held = self.held
        if held:
            self.held = []
            for level, text in held:
                self.log(level, text)

    def end(self) -> None:
        """The lines held back said, and each line said at once from now on."""
        self.flush()
        self.held = None


class RunCommands:
    """The commands of a :class:`~mps_ros.run.runner.Runner`'s run (``runner``), each taken
    at the present step boundary (:meth:`take`): past the gate, applied to the twin or refused,
    and answered (:meth:`answer`: ``~/mode`` as received, ``~/mode/status``, a log line, its reply); those
    still waiting at the run's end refused (:meth:`refuse_pending`).

    Counted: ``accepted``, ``refused``, ``lost`` (told by the transport: the node's QoS
    events) and ``elsewhere`` (refused, of which as floods, and lost in the node's process,
    where the run steps in a process of its own and its gate answers there: said in
    /diagnostics). ``lines``: the commands' log lines, held back while steps are banked;
    ``refusals``: the refusals' lines, a flood's once a second."""

    def __init__(self, runner, gate: Gate, log: Callable[[str, str], None]):
        self.runner = runner
        self.gate = gate
        self.lines = HeldLog(log)
        self.refusals = RefusalLog(self.lines.say)
        self.accepted = 0
        self.refused = 0
        self.lost = 0
        self.elsewhere = (0, 0, 0)

    def take(self, cmds: list[Command], gated: bool = False) -> None:
        """Apply ``cmds`` at the present step boundary, each answered on ``~/mode/status`` and
        by its reply (``gated``: they passed the gate already)."""
        r = self.runner
        twin = r.twin
        t = twin.t
        t_ns = to_ns(t)
        for c in cmds:
            word = c.word if isinstance(c.word, str) else str(c.word)
            reason = None if gated else self.gate.check(word)
            if reason is None:
                ok, reason = twin.command(word.strip())
            else:
                ok = False
            self.answer(c, word, ok, reason, t, twin.sim.structure)
            # a command's event (and what it set off) goes out at once, before the next
            # command's answer
            r.emit_events(twin.new_events(), t_ns)

    def answer(self, c: Command, word: str, ok: bool, reason, t: float, structure: str) -> None:
        """A command as received, and its answer (``~/mode/status``, the log, its reply)."""
        r = self.runner
        t_ns = to_ns(t)
        r.send("~/mode", r.encoder("~/mode")({"data": word}), t_ns, received=True)
        ack = {
            "t": t,
            "command": shown(word, 64),
            "accepted": ok,
            "reason": reason,
            "source": c.source,
            "structure": structure,
        }
        if ok:
            self.accepted += 1
            self.lines.say("info", f"command {word.strip()!r} ({c.source}) applied at t = {t:.6f} s")
        else:
            self.refused += 1
            self.refusals.refused(word, c.source, t, reason, c.wall)
        r.emit("~/mode/status", {"data": to_json(ack)}, t_ns)
        if c.reply is not None:
            try:
                c.reply(ack)
            except Exception:  # a reply must never take the run down
                pass

    def refuse_pending(self, reason: str) -> None:
        """Answer commands still waiting (the run is over): refused, never silently lost."""
        twin = self.runner.twin
        for c in self.runner.inbox.drain():
            ack = {
                "t": twin.t,
                "command": shown(str(c.word), 64),
                "accepted": False,
                "reason": reason,
                "source": c.source,
                "structure": twin.sim.structure,
            }
            self.refused += 1
            self.lines.log("warn", f"refused command {shown(str(c.word))!r} ({c.source}): {reason}")
            if c.reply is not None:
                try:
                    c.reply(ack)
                except Exception:
                    pass


__all__ = ["Command", "Inbox", "Gate", "RunCommands", "HeldLog", "RefusalLog", "COMMAND_INDEX", "shown"]
