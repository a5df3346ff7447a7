"""Integrators behind one contract (:class:`~mps_core.solvers.base.Solver`)."""

from .adaptive import AdaptiveSolver
from .base import Solver
from .dop853 import DOP853
from .linear_acceleration import LinearAcceleration
from .rk4 import RK4
from .rk6 import RK6
from .rk8 import RK8

SOLVERS = ("linear-acceleration", "rk4", "rk6", "rk8", "dop853", "radau")


def make_solver(name: str, fun, t0, q0, qd0, current=None, *, iterations=1, rtol=1e-9,
                atol=1e-12, scales=None, first_step=None, accel=None):
    """A solver by its scene/CLI name. ``first_step`` (adaptive solvers): the first internal
    step to try, e.g. the ``step_size`` of the solver this one carries on from. ``accel``: q̈
    alone on floats (see :class:`~mps_core.solvers.base.Solver`)."""
    if name == "linear-acceleration":
        return LinearAcceleration(fun, t0, q0, qd0, current, iterations=iterations,
                                  accel=accel)
    if name == "rk4":
        return RK4(fun, t0, q0, qd0, current, accel=accel)
    if name == "rk6":
        return RK6(fun, t0, q0, qd0, current, accel=accel)
    if name == "rk8":
        return RK8(fun, t0, q0, qd0, current, accel=accel)
    if name == "dop853":
        return DOP853(fun, t0, q0, qd0, current, rtol=rtol, atol=atol, scales=scales,
                      first_step=first_step, accel=accel)
    if name == "radau":
        return AdaptiveSolver(fun, t0, q0, qd0, current, method=name, rtol=rtol, atol=atol,
                              scales=scales, first_step=first_step)
    raise ValueError(f"solver {name!r}: expected one of {', '.join(SOLVERS)}")


__all__ = ["Solver", "LinearAcceleration", "RK4", "RK6", "RK8", "DOP853", "AdaptiveSolver", "SOLVERS", "make_solver"]
