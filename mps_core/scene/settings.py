"""The run settings a scene holds: the solver's, the charts' policy, and the words of the
commands a scene or an operator gives. Plain data: the run layer reads them."""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..solvers import ADAPTIVE_SOLVERS

#: the commands a scene's schedule or an operator may give
COMMANDS = ("engage", "disengage", "stop", "start")


@dataclass(frozen=True)
class ChartPolicy:
    """When to change chart: below ``switch_below`` (if ``switching``); a configuration where no
    chart reaches ``fail_below`` is singular."""

    switching: bool = True
    switch_below: float = 0.5
    fail_below: float = 1e-3


@dataclass(frozen=True)
class SolverSettings:
    name: str = "linear-acceleration"
    scheme: str = "central"
    delta: float = math.radians(0.1)
    iterations: int = 1
    rtol: float = 1e-9
    atol: float = 1e-12
    #: what to do with a fixed step beyond the stability limit of a stiff effect
    stiff: str = "subdivide"
    #: central differences on small charts as scalar kernels (mps_core.codegen.kernels); False: the
    #: engine's array code (the same numbers to round-off, slower; for comparisons)
    kernels: bool = True
    #: where an effect's force law is not smooth (its ``switches``): "locate" ends a step at
    #: every crossing and starts the solver afresh there; "step-over" lets steps straddle them;
    #: "auto": locate with the adaptive solvers (their error estimate assumes a smooth
    #: right-hand side: across a kink it can accept a step far less accurate than asked, e.g.
    #: press-cycle at rtol 1e-9, 5e-6 rad off stepped over, 4e-8 located), step over with the
    #: fixed-step ones (an isolated kink or jump stays within their O(Δt²) error: the linear
    #: acceleration method's order holds; RK4's falls to 2 near one)
    switch_points: str = "auto"
    #: the fixed-step solvers' step where it is not the output interval (None: the same):
    #: shorter, several steps an output; longer, the outputs inside a step from its
    #: interpolant, each evaluated there (event location, commands and charts as ever)
    step: float | None = None

    def described(self) -> dict[str, object]:
        """What a trajectory's ``settings`` say of the solver."""
        return {
            "solver": self.name,
            "scheme": self.scheme,
            "delta": self.delta,
            "iterations": self.iterations,
            "rtol": self.rtol,
            "atol": self.atol,
        }

    def locates_switch_points(self) -> bool:
        if self.switch_points not in SWITCH_POINTS:
            raise ValueError(
                f"switch_points = {self.switch_points!r}: expected one of " + ", ".join(SWITCH_POINTS)
            )
        if self.switch_points == "auto":
            return self.name in ADAPTIVE_SOLVERS
        return self.switch_points == "locate"


#: the choices of :attr:`SolverSettings.switch_points`
SWITCH_POINTS = ("auto", "locate", "step-over")

#: the rules at the held four-bar's change point: "continue" (smooth, on the continuation
#: chart) or "keep-side" (a plastic impact keeps the slider on its side)
CHANGE_POINTS = ("continue", "keep-side")
