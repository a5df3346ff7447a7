"""The twin's run, without ROS: steps a scene, turns each step into messages, takes commands,
paces, measures, and hands every message to its sinks (the ROS publishers, the MCAP recorder).

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
import json
import math
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace

import numpy as np

from mps_core.dynamics.reactions import REACTION_COLUMNS, compute_reactions, reaction_values
from mps_core.scene.settings import COMMANDS

from ..wire import diagnostics
from ..wire.diagnostics import hardware_id
from ..wire.step_messages import StepMessages, stamp
from ..wire.topics import BY_KEY, OUTPUTS

EXPECTED = "expected one of " + ", ".join(COMMANDS)
#: a word's place in :data:`COMMANDS` (and in :meth:`Twin.refusals`)
COMMAND_INDEX = {word: i for i, word in enumerate(COMMANDS)}

PACINGS = ("realtime", "as_fast_as_possible")


def to_ns(t: float) -> int:
    return int(round(t * 1e9))


def _jsonable(v):
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, (set, tuple)):
        return list(v)
    return str(v)


def to_json(obj) -> str:
    return json.dumps(obj, default=_jsonable, separators=(",", ":"))


def check_outputs(outputs: Iterable[str]) -> tuple[str, ...]:
    out = []
    for o in outputs:
        o = str(o).strip()
        if not o:
            continue
        if o not in OUTPUTS:
            raise ValueError(f"unknown output {o!r}: expected some of {', '.join(OUTPUTS)}")
        if o not in out:
            out.append(o)
    return tuple(out)


class Twin:
    """A scene stepped on a fixed grid, with its messages
    (:class:`~mps_ros.wire.step_messages.StepMessages`).

    ``dt``/``t_end``: override the scene's (None: the scene's); so does ``derivatives`` (the
    scheme of the Lagrange equations' derivatives: ``central``, the seed's finite differences,
    or ``autodiff``, exact). ``scene_commands``: False drops
    the scene's own [[commands]] schedule (an operator sends them instead). ``outputs``: the
    subset of :data:`~mps_ros.wire.topics.OUTPUTS` to produce; the reactions are solved only when
    ``reactions`` or ``foundation`` is among them."""

    def __init__(
        self,
        scene,
        *,
        dt: float | None = None,
        t_end: float | None = None,
        outputs: Iterable[str] = OUTPUTS,
        scene_commands: bool = True,
        markers_hz: float = 30.0,
        markers_scale: float | None = None,
        derivatives: str | None = None,
    ):
        from mps_core import build, load_scene

        if not hasattr(scene, "with_overrides"):
            scene = load_scene(scene)
        # the scene's step unless told (a new t_end alone keeps the step, not the step count)
        scene = scene.with_overrides(dt=dt or scene.dt, t_end=t_end or None, scheme=derivatives or None)
        self._scene_with_commands = scene
        if not scene_commands:
            scene = replace(scene, commands=())
        self.scene = scene
        self.scene_commands = scene_commands
        self.outputs = check_outputs(outputs)
        self.solve_reactions = "reactions" in self.outputs or "foundation" in self.outputs
        self.sim = build(scene)
        if self.solve_reactions and not any(hasattr(o, "impact") for o in self.sim.observers):
            # impulses per joint at each plastic impact, logged as "impulse" events (only the
            # impact hook is used: the twin solves the per-step reactions itself)
            from mps_core.dynamics.reactions import ReactionObserver

            self.sim.observers.append(ReactionObserver(defer_impacts=True))
        self.t0 = self.sim.t
        self.t_end = scene.t_end
        self.n = max(1, int(round((self.t_end - self.t0) / scene.dt)))
        self.dt = (self.t_end - self.t0) / self.n
        self.k = 0
        #: the step's messages, as dicts and encoded, and the latched ones sent
        self.step_messages = StepMessages(
            scene, self.outputs, self.solve_reactions, self.dt, markers_hz, markers_scale
        )
        self._holding = False  # new_events() holds this step's events
        self._refusals: dict[tuple, tuple] = {}  # refusals(), by what they depend on

    def warm_up(self, seconds: float = 1.0, tries: int = 10, trial: float = 0.06) -> None:
        """Do once, before a paced run's clock starts, what its first steps would otherwise do
        on the clock: generate and compile the chart views' kernels and reaction kernels (the
        compiled code is kept by what it depends on, so this twin's first use of a view finds
        it). A copy of the scene, with its own commands, runs ``seconds`` of simulated time;
        then a copy of this run's scene runs them again and, at ``tries`` points spread over
        them, tries each command the machine takes there for ``trial`` simulated seconds and
        comes back (an operator's command meets branches of the effects that the scene's own
        schedule may not: an engage in another phase of the stroke). What the copies meet (an
        error included) stays with them."""
        t_end = min(self.t_end, self.t0 + seconds)
        if t_end <= self.t0:
            return

        def run(copy, n):
            for _ in range(n):
                if copy.done:
                    return
                copy.step()
                copy.state_payloads()
                copy.new_events()

        try:
            copy = Twin(self._scene_with_commands, dt=self.dt, t_end=t_end, outputs=self.outputs)
            run(copy, copy.n)
            copy = Twin(self.scene, dt=self.dt, t_end=min(self.t_end, t_end + trial), outputs=self.outputs)
            if not (tries > 0 and copy.rewindable):
                return
            every = max(1, int(round((t_end - self.t0) / (tries * self.dt))))
            n_trial = max(1, int(round(trial / self.dt)))
            while copy.k + every <= copy.n - n_trial:
                run(copy, every)
                for word in COMMANDS:
                    cp = copy.checkpoint()
                    if copy.command(word)[0]:
                        run(copy, n_trial)
                    copy.restore(cp)
        except Exception:
            pass  # the run itself will meet it, and say so

    # -- stepping -------------------------------------------------------------------------
    @property
    def t(self) -> float:
        return self.sim.t

    @property
    def t_ns(self) -> int:
        """The simulated time in nanoseconds (the messages' stamps)."""
        return to_ns(self.sim.t)

    @property
    def done(self) -> bool:
        return self.k >= self.n

    def time_of(self, k: int) -> float:
        return self.t_end if k == self.n else self.t0 + k * (self.t_end - self.t0) / self.n

    def step(self) -> None:
        self.k += 1
        self.sim.advance_to(self.time_of(self.k))

    # -- steps ahead ----------------------------------------------------------------------
    @property
    def rewindable(self) -> bool:
        """Whether :meth:`checkpoint` works (the simulation's solver and observers allow it)."""
        return self.sim.rewindable

    def checkpoint(self) -> tuple:
        """The twin's state at this step boundary (see :meth:`Simulation.checkpoint`)."""
        m = self.step_messages
        return (self.k, m.structure_sent, m.static_sent, self._holding, self.sim.checkpoint())

    def restore(self, cp: tuple) -> None:
        """Back to a :meth:`checkpoint`: the steps computed since are forgotten."""
        m = self.step_messages
        self.k, m.structure_sent, m.static_sent, self._holding, sim = cp
        self.sim.restore(sim)

    # -- commands -------------------------------------------------------------------------
    def command(self, word: str) -> tuple[bool, str | None]:
        """Apply a command now (at the present step's time) or say why not."""
        from mps_core.run.simulation import CommandRefused

        if self.done:
            return False, "the run has ended"
        try:
            self.sim.command(word)
        except CommandRefused as exc:
            return False, exc.reason
        return True, None

    def refusals(self) -> tuple:
        """Why :meth:`command` would refuse each of the machine's words now, in
        :data:`~mps_core.scene.settings.COMMANDS` order (None: it would apply it): what a step
        carries, so that a command refused at its boundary is answered there without coming
        back to it."""
        key = (self.done, self.sim.structures.command_state())
        got = self._refusals.get(key)
        if got is None:
            got = self._refusals[key] = tuple(self._why_not(w) for w in COMMANDS)
        return got

    def _why_not(self, word: str) -> str | None:
        from mps_core.run.simulation import CommandRefused

        if self.done:
            return "the run has ended"
        try:
            self.sim.check_command(word)
        except CommandRefused as exc:
            return exc.reason
        return None

    # -- messages -------------------------------------------------------------------------
    def reaction_list(self) -> list | None:
        """The reactions of the present state, in :data:`~mps_core.dynamics.reactions.REACTION_COLUMNS`
        order (None unless asked for): the view's reaction kernel where it holds, the general
        Newton–Euler solution elsewhere (the same numbers to round-off)."""
        if not self.solve_reactions:
            return None
        sim = self.sim
        e = sim.solver.current
        fast = reaction_values(
            sim.mechanism, sim.engine.effects, e.view, e.t, e.q.tolist(), e.qd.tolist(), e.qdd.tolist(), e.kin
        )
        if fast is not None:
            return fast[0]
        rx = compute_reactions(
            sim.mechanism, sim.engine.effects, e.view, e.t, e.q, e.qd, e.qdd, kin=e.kin, kernel=False
        )
        return [rx.values[c] for c in REACTION_COLUMNS]

    def reactions(self) -> dict | None:
        """:meth:`reaction_list` by column name."""
        rx = self.reaction_list()
        return None if rx is None else dict(zip(REACTION_COLUMNS, rx))

    def joint_values(self) -> tuple[list, list]:
        """Positions and velocities of :data:`~mps_ros.wire.topics.JOINT_NAMES`."""
        sim = self.sim
        phi, phi_dot, psi, psi_dot, x, x_dot = sim.joint_state()
        kin = sim.solver.current.kin
        xa, ya = kin.xy("A")
        xb, yb = kin.xy("B")
        return ([phi, math.atan2(yb - ya, xb - xa), psi, x], [phi_dot, kin.rate("rod"), psi_dot, x_dot])

    def state_messages(self) -> list[tuple[str, dict]]:
        """The messages of the present step as dicts (topic key, message), in publishing order:
        what :meth:`state_payloads` encodes, for readers and tests. ``~/structure`` is among
        them where the structure differs from the last one :meth:`state_payloads` sent, and
        ``/tf_static`` until it has sent it."""
        return self.step_messages.dicts(self)

    def state_payloads(self) -> list[tuple[str, bytes]]:
        """The messages of the present step, encoded (CDR): (topic key, bytes), in publishing
        order, exactly the bytes of :meth:`state_messages` encoded. Each message's bytes are a
        kept buffer with this step's values packed in; ``~/structure`` goes out when the
        structure changes (and at the first step), ``/tf_static`` at the first step: the node
        offers them latched."""
        return self.step_messages.payloads(self)

    def new_events(self, hold: bool = False) -> list[dict]:
        """The events logged since the last call. They are handed over, not kept: the
        simulation's log is emptied of them (a long run's memory stays flat).

        An impact's event gets its joint impulses here (they are worked out after the step's
        state is out). ``hold``: where this step logged an impact, hand over nothing now and
        everything at the next call, so that the impulses' work falls in the next step's
        spare time instead of this one's (a paced run: an impact's step is already the
        longest). Events keep their order and their own times."""
        events = self.sim.events
        if not events:
            return []
        impacts = any(getattr(ob, "_pending", None) for ob in self.sim.observers)
        if hold and impacts and not self._holding:
            self._holding = True
            return []
        self._holding = False
        for ob in self.sim.observers:
            if hasattr(ob, "resolve"):
                ob.resolve()  # a deferred impact's impulses
            if hasattr(ob, "impacts"):
                ob.impacts.clear()
        ev = list(events)
        del events[:]
        return ev

    def describe(self) -> dict:
        s = self.scene
        return {
            "scene": s.name,
            "origin": s.origin,
            "t0": self.t0,
            "t_end": self.t_end,
            "dt": self.dt,
            "steps": self.n,
            "structure": s.structure,
            "solver": s.solver.name,
            "derivatives": s.solver.scheme,
            "outputs": list(self.outputs),
            "scene_commands": self.scene_commands,
            "commands": [list(c) for c in s.commands],
        }


# -- commands in ----------------------------------------------------------------------------
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
    """The commands of a :class:`Runner`'s run, each taken at the present step boundary
    (:meth:`take`): past the gate, applied to the twin or refused, and answered
    (:meth:`answer`: ``~/mode`` as received, ``~/mode/status``, a log line, its reply); those
    still waiting at the run's end refused (:meth:`refuse_pending`).

    Counted: ``accepted``, ``refused``, ``lost`` (told by the transport: the node's QoS
    events) and ``elsewhere`` (refused, of which as floods, and lost in the node's process,
    where the run steps in a process of its own and its gate answers there: said in
    /diagnostics). ``lines``: the commands' log lines, held back while steps are banked;
    ``refusals``: the refusals' lines, a flood's once a second."""

    def __init__(self, runner: Runner, gate: Gate, log: Callable[[str, str], None]):
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
            r._emit_events(twin.new_events(), t_ns)

    def answer(self, c: Command, word: str, ok: bool, reason, t: float, structure: str) -> None:
        """A command as received, and its answer (``~/mode/status``, the log, its reply)."""
        r = self.runner
        t_ns = to_ns(t)
        r._send("~/mode", r._encode("~/mode")({"data": word}), t_ns, received=True)
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
        r._emit("~/mode/status", {"data": to_json(ack)}, t_ns)
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


# -- the run --------------------------------------------------------------------------------
class Timings:
    """Durations (s) kept as a histogram of 1 % wide bins from 1 µs to 100 s: percentiles to
    1 % and the maximum, in memory that does not grow with the run's length."""

    _LO = 1e-6
    _PER = 1.0 / math.log(1.01)
    _BINS = int(math.log(1e8) * _PER) + 2

    def __init__(self):
        self.counts = [0] * self._BINS
        self.n = 0
        self.max = 0.0

    def add(self, x: float) -> None:
        self.n += 1
        if x > self.max:
            self.max = x
        i = int(math.log(x / self._LO) * self._PER) + 1 if x > self._LO else 0
        self.counts[i if i < self._BINS else self._BINS - 1] += 1

    def percentile(self, p: float) -> float:
        """The p-th percentile (the upper edge of its bin; 0 for no samples)."""
        if not self.n:
            return 0.0
        want = p / 100.0 * self.n
        acc = 0
        for i, c in enumerate(self.counts):
            acc += c
            if acc >= want and c:
                return min(self.max, self._LO * math.exp(i / self._PER))
        return self.max


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


class RunClocks:
    """A run's clocks, from :meth:`start` to :meth:`stop`: the wall clock
    (``time.perf_counter``; a paced run's schedule starts at ``wall_start``, moved on by its
    pauses), the process's CPU, and the CPU of the thread that steps."""

    def __init__(self):
        self.wall_start = 0.0
        self.wall_end = 0.0
        self.cpu_start = 0.0
        self.cpu_end: float | None = None
        self.thread_start = time.thread_time()
        self.thread_cpu: float | None = None

    def start(self) -> None:
        self.wall_start = time.perf_counter()
        self.cpu_start = time.process_time()
        self.thread_start = time.thread_time()

    def stop(self) -> None:
        self.wall_end = time.perf_counter()
        self.cpu_end = time.process_time()
        self.thread_cpu = time.thread_time() - self.thread_start

    def wall(self) -> float:
        """Wall seconds from the start to the stop (to now, before it)."""
        return (self.wall_end or time.perf_counter()) - self.wall_start

    def cpu(self) -> float:
        """The process's CPU seconds from the start to the stop (to now, before it)."""
        return (self.cpu_end if self.cpu_end is not None else time.process_time()) - self.cpu_start

    def thread(self) -> float:
        """The stepping thread's CPU seconds from the start to the stop (to now, before it)."""
        return self.thread_cpu if self.thread_cpu is not None else time.thread_time() - self.thread_start


class Measurements:
    """What a run measures of itself (:meth:`Runner.stats`, /diagnostics): the step times
    (compute: advance + messages), the publish times (a step's messages to the sinks) and, in
    realtime pacing, the latencies (publish done − deadline), as :class:`Timings`; the deadline
    misses, the messages and events sent, the steps recomputed (realtime: computed ahead,
    dropped for a command); ``release_slice``: the releasing thread's scheduler slice (s) as
    granted (realtime; None: the system's); ``window``: the counters the last /diagnostics
    saw."""

    def __init__(self):
        self.step_times = Timings()
        self.publish_times = Timings()
        self.latencies = Timings()
        self.misses = 0
        self.messages = 0
        self.events = 0
        self.steps_recomputed = 0
        self.release_slice: float | None = None
        self.window = diagnostics.Window()


class Runner:
    """Steps a :class:`Twin`, paces it, takes commands from an :class:`Inbox`, and emits every
    message to every sink: ``sink.emit(key, data, t_ns)`` with its CDR bytes (encoded once:
    :meth:`Twin.state_payloads` for the step's messages, :func:`mps_ros.wire.cdr.encoder`
    for the others) and its simulated time in ns; a recorder also gets the commands received,
    ``sink.received(key, data, t_ns)``; ``sink.tick()`` once a step. A sink with
    ``emit_all(msgs)`` gets each step's state in one call instead (``(key, data, t_ns,
    received)`` each, in order; the sink leaves out what it does not take).

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
        sinks=(),
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
        self.sinks = list(sinks)
        self.inbox = inbox if inbox is not None else Inbox()
        self.log = log or (lambda level, text: None)
        self.name = name
        self.commands = RunCommands(self, gate or Gate(), self.log)
        self.measurements = Measurements()
        self.clocks = RunClocks()
        self.stop_reason: str | None = None
        self.error: str | None = None
        self._stop = threading.Event()
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

    def request_stop(self, reason: str) -> None:
        """Ask the loop to end after the step in progress (from a signal handler or thread)."""
        if self.stop_reason is None:
            self.stop_reason = reason
        self._stop.set()
        self.inbox.wake()

    # -- emitting -------------------------------------------------------------------------
    def _encode(self, key: str):
        enc = self._encoders.get(key)
        if enc is None:
            from ..wire.cdr import encoder

            enc = self._encoders[key] = encoder(BY_KEY[key].msgtype)
        return enc

    def _emit(self, key: str, msg: dict, t_ns: int) -> None:
        self._send(key, self._encode(key)(msg), t_ns)

    def _send(self, key: str, data: bytes, t_ns: int, received: bool = False) -> None:
        """One message to every sink (``received``: a command as it came in, to the sinks
        that keep those); while a step is being queued (realtime), to its release instead."""
        if self._staging is not None:
            self._staging.append((key, data, t_ns, received))
            return
        err = None
        if not received:
            self.measurements.messages += 1
        for s in self.sinks:  # every sink gets it, though another one fails
            try:
                if not received:
                    s.emit(key, data, t_ns)
                elif hasattr(s, "received"):
                    s.received(key, data, t_ns)
            except Exception as exc:
                err = err or exc
        if err is not None:
            raise err

    def _emit_events(self, events, t_ns):
        m = self.measurements
        if "events" not in self.twin.outputs:
            m.events += len(events)
            return
        for ev in events:
            m.events += 1
            self._emit("~/events", {"data": to_json(ev)}, t_ns)

    def _publish_step(self, payloads, t_ns):
        """The step's state to every sink, handed over at once (``tick``); then its events,
        whose impulses are worked out now, after the state is out."""
        if self._staging is not None:  # realtime: into the step's release
            self._staging.extend((key, data, t_ns, False) for key, data in payloads)
        else:
            self.measurements.messages += len(payloads)
            msgs = None
            for s in self.sinks:
                emit_all = getattr(s, "emit_all", None)
                if emit_all is not None:  # the step in one call
                    if msgs is None:
                        msgs = [(key, data, t_ns, False) for key, data in payloads]
                    emit_all(msgs)
                else:
                    emit = s.emit
                    for key, data in payloads:
                        emit(key, data, t_ns)
                s.tick(None)
        events = self.twin.new_events()
        if events:
            self._emit_events(events, t_ns)

    def _take_commands(self) -> None:
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

    def _diagnostics(self, t_ns: int) -> None:
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
        statuses += [x.status(self.name, hw) for x in self.sinks if hasattr(x, "status")]
        self._emit("/diagnostics", diagnostics.array(t_ns, statuses), t_ns)

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
            self._encode(k)
        for s in self.sinks:
            if hasattr(s, "prepare"):
                s.prepare(keys)
        if rt.freeze_gc and self.pacing == "realtime":
            import gc

            gc.collect()
            gc.freeze()

    def _begin(self) -> None:
        """The run's start event and the first state, then the commands already waiting."""
        twin = self.twin
        t_ns = twin.t_ns
        self._emit_events(
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
        self._publish_step(twin.state_payloads(), t_ns)
        self._take_commands()

    def _failed(self, exc: Exception) -> None:
        self.error = f"{type(exc).__name__}: {exc}"
        self.stop_reason = "error"
        self.log("error", f"the run stopped at t = {self.twin.t:.6f} s: {self.error}")

    def _end(self) -> None:
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
            lambda: self._emit_events(twin.new_events(), t_ns),
            lambda: self._diagnostics(t_ns),
            lambda: self._emit_events([end], t_ns),
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
            self._begin()
            reply = None
            while not twin.done and not self._stop.is_set():
                if self._paused.is_set():
                    reply = self._hold()
                    if reply is None:
                        continue
                _k, msgs, p0 = self._timed_step(math.inf, clock)  # no deadline: no miss
                t_ns = twin.t_ns
                if msgs is not None:
                    self._publish_step(msgs, t_ns)
                else:
                    self._emit_events(twin.new_events(), t_ns)
                publish_times.add(clock() - p0)
                self._take_commands()
                for s in self.sinks:
                    s.tick(None)
                now = clock()
                if now >= next_diag:
                    next_diag = now + self.period
                    self._diagnostics(t_ns)
                if reply is not None:  # a step taken while paused: said
                    reply, done = None, reply
                    done(twin.t)
        except Exception as exc:
            self._failed(exc)
            raise
        finally:
            self._end()
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
        while self._paused.is_set() and not self._stop.is_set():
            self._take_commands()
            if self._step_replies:
                return self._step_replies.popleft()
            now = time.perf_counter()
            if now >= next_diag and "diagnostics" in self.twin.outputs:
                next_diag = now + self.period
                statuses = [diagnostics.paused(self.name, hw, self.twin.t)]
                statuses += [x.status(self.name, hw) for x in self.sinks if hasattr(x, "status")]
                self._emit("/diagnostics", diagnostics.array(t_ns, statuses), t_ns)
                for s in self.sinks:
                    s.tick(None)
            self.inbox.wait(0.05)

    def _timed_step(self, deadline: float, clock) -> tuple[int, list | None, float]:
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


__all__ = [
    "Twin",
    "Runner",
    "Inbox",
    "Gate",
    "Command",
    "PACINGS",
    "COMMAND_INDEX",
    "stamp",
    "to_ns",
    "to_json",
    "check_outputs",
    "BY_KEY",
]
