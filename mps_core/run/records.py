"""What a run records: its work counts (:class:`WorkCounts`)."""

from __future__ import annotations

__all__ = ["WorkCounts"]


class WorkCounts:
    """A run's work beyond its engine's counts: the right-hand sides and steps of the solvers it
    has replaced (a new solver at every restart: an event's cut, a change of chart, a command)
    and the switching points of the effects' force laws crossed (a step ended at each). A
    checkpoint of the run keeps :meth:`state`."""

    __slots__ = ("solver_evaluations", "steps", "switch_points")

    def __init__(self) -> None:
        self.solver_evaluations = 0
        self.steps = 0
        self.switch_points = 0

    def retire(self, solver) -> None:
        """Count the work of a solver the run replaces."""
        self.solver_evaluations += solver.nfev
        self.steps += solver.nsteps

    def counts(self, engine_counts: dict, solver) -> dict:
        """The trajectory's counts: the engine's, and the solvers' with the present one."""
        counts = dict(engine_counts)
        counts["solver_evaluations"] = self.solver_evaluations + solver.nfev
        counts["steps"] = self.steps + solver.nsteps
        counts["switch_points"] = self.switch_points
        return counts

    def state(self) -> tuple[int, int, int]:
        """(solver evaluations, steps, switch points), for :meth:`set_state`."""
        return self.solver_evaluations, self.steps, self.switch_points

    def set_state(self, state: tuple[int, int, int]) -> None:
        self.solver_evaluations, self.steps, self.switch_points = state
