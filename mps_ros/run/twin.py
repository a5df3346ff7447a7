"""The twin: a scene stepped on a fixed grid, each step's messages made (plain dicts in the
field layout of their ROS types, or their CDR bytes), commands applied at step boundaries; no
ROS. The :class:`~mps_ros.run.runner.Runner` paces it and hands its messages to the sinks.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import replace

from mps_core.dynamics.reactions import REACTION_COLUMNS, compute_reactions, reaction_values
from mps_core.scene.settings import COMMANDS

from ..wire.step_messages import StepMessages
from ..wire.topics import OUTPUTS


def to_ns(t: float) -> int:
    return int(round(t * 1e9))


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
        from mps_core.scene import Scene

        if not isinstance(scene, Scene):
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
        from mps_core.dynamics.reaction_observer import ReactionObserver

        #: the observers whose impacts' impulses are worked out after a step's state is out
        self._impulses = [o for o in self.sim.observers if isinstance(o, ReactionObserver)]
        if self.solve_reactions and not self._impulses:
            # impulses per joint at each plastic impact, logged as "impulse" events (only the
            # impact hook is used: the twin solves the per-step reactions itself)
            self._impulses.append(ReactionObserver(defer_impacts=True))
            self.sim.observers.append(self._impulses[-1])
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
        #: the evaluation joint_values() last read, with its crank and rocker rates
        self._rates_of: tuple | None = None

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
        e = sim.solver.current
        self._rates_of = (e, phi_dot, psi_dot)
        kin = e.kin
        xa, ya = kin.xy("A")
        xb, yb = kin.xy("B")
        return ([phi, math.atan2(yb - ya, xb - xa), psi, x], [phi_dot, kin.rate("rod"), psi_dot, x_dot])

    def crank_rocker_rates(self) -> tuple[float, float]:
        """Return (φ̇, ψ̇) of the present state.

        Those :meth:`joint_values` read, where it has read this state (a step's
        ``/joint_states``), else the simulation's own (:meth:`Simulation.joint_state`)."""
        e = self.sim.solver.current
        got = self._rates_of
        if got is not None and got[0] is e:
            return got[1], got[2]
        _phi, phi_dot, _psi, psi_dot, _x, _x_dot = self.sim.joint_state()
        return phi_dot, psi_dot

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
        impacts = any(ob.pending for ob in self._impulses)
        if hold and impacts and not self._holding:
            self._holding = True
            return []
        self._holding = False
        for ob in self._impulses:
            ob.resolve()  # a deferred impact's impulses
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


__all__ = ["Twin", "to_ns", "check_outputs"]
