"""What is due in a run at known simulated times: the commands given for later and the driver's
own control changes (timers). Each is a step boundary: the driver cuts its step there and
applies it at the step's start (:meth:`Simulation.advance_to
<mps_core.run.simulation.Simulation.advance_to>`)."""

from __future__ import annotations

__all__ = ["Schedule"]


class Schedule:
    """A run's commands due later, ``(t, word)``, and its timers, ``(t, name)`` (the disengage
    cylinder's end), each list sorted by time. A checkpoint of the run keeps :meth:`state`."""

    __slots__ = ("commands", "timers")

    def __init__(self, commands=()) -> None:
        self.commands: list[tuple[float, str]] = sorted((float(t), c) for t, c in commands)
        self.timers: list[tuple[float, str]] = []

    def add_command(self, t: float, name: str) -> None:
        self.commands.append((float(t), name))
        self.commands.sort()

    def set_timer(self, t: float, name: str) -> None:
        """The timer ``name`` due at ``t`` (in place of one of that name already set)."""
        self.timers = sorted([(a, b) for a, b in self.timers if b != name] + [(t, name)])

    def until(self, t_next: float) -> float:
        """The earliest of ``t_next``, the next command's time and the next timer's."""
        commands, timers = self.commands, self.timers
        if commands and commands[0][0] < t_next:
            t_next = commands[0][0]
        if timers and timers[0][0] < t_next:
            t_next = timers[0][0]
        return t_next

    def state(self) -> tuple[list, list]:
        """Copies of (commands, timers), for :meth:`set_state`."""
        return list(self.commands), list(self.timers)

    def set_state(self, state: tuple[list, list]) -> None:
        commands, timers = state
        self.commands[:] = commands
        self.timers = list(timers)
