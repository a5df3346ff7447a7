"""Integrators behind one contract (:class:`~mps_core.solvers.base.Solver`), registered by
their scene/CLI name in :data:`SOLVERS`: each class says whether it controls its error
(``adaptive``) and, for a fixed step, its stability limit (``stability_limit``)."""

from collections.abc import Callable
from typing import Any

from numpy.typing import ArrayLike

from .adaptive import AdaptiveSolver, Radau
from .base import Solver
from .dop853 import DOP853
from .linear_acceleration import LinearAcceleration
from .rk4 import RK4
from .rk6 import RK6
from .rk8 import RK8

#: the solvers by their scene/CLI name, in the order the docs list them
SOLVERS: dict[str, type[Solver]] = {
    cls.name: cls for cls in (LinearAcceleration, RK4, RK6, RK8, DOP853, Radau)
}
#: the solvers with error control (the others take the steps they are given)
ADAPTIVE_SOLVERS = tuple(name for name, cls in SOLVERS.items() if cls.adaptive)
#: the fixed-step solvers (they take the steps they are given)
FIXED_STEP_SOLVERS = tuple(name for name, cls in SOLVERS.items() if not cls.adaptive)
#: the fixed-step solvers' stability limits as a share of the shortest period, and how an
#: error message writes them
FIXED_STEP_LIMITS = {
    name: (cls.stability_limit, cls.stability_text)
    for name, cls in SOLVERS.items()
    if cls.stability_limit is not None
}


def make_solver(
    name: str,
    fun: Callable,
    t0: float,
    q0: ArrayLike,
    qd0: ArrayLike,
    current: Any = None,
    *,
    iterations: int = 1,
    rtol: float = 1e-9,
    atol: float = 1e-12,
    scales: ArrayLike | None = None,
    first_step: float | None = None,
    accel: Callable | None = None,
) -> Solver:
    """A solver by its scene/CLI name. ``first_step`` (adaptive solvers): the first internal
    step to try, e.g. the ``step_size`` of the solver this one carries on from. ``accel``: q̈
    alone on floats (see :class:`~mps_core.solvers.base.Solver`)."""
    cls = SOLVERS.get(name)
    if cls is None:
        raise ValueError(f"solver {name!r}: expected one of {', '.join(SOLVERS)}")
    return cls.create(
        fun,
        t0,
        q0,
        qd0,
        current,
        iterations=iterations,
        rtol=rtol,
        atol=atol,
        scales=scales,
        first_step=first_step,
        accel=accel,
    )


__all__ = [
    "Solver",
    "LinearAcceleration",
    "RK4",
    "RK6",
    "RK8",
    "DOP853",
    "AdaptiveSolver",
    "Radau",
    "SOLVERS",
    "ADAPTIVE_SOLVERS",
    "FIXED_STEP_SOLVERS",
    "FIXED_STEP_LIMITS",
    "make_solver",
]
