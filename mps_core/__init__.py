"""mps_core: the partial-system engine, the press mechanism, its effects, solvers and scenes.

Pure Python on numpy and scipy; no ROS. The entry point for library users::

    from mps_core import load_scene, simulate
    traj = simulate("paper")            # a preset name, a path, or a Scene
    traj.phi, traj.phi_dot, traj.phi_ddot, traj.T, traj.V

The names below are imported when first used (as scipy's subpackages are): a process that
needs one module of the package (the recording process needs the file formats) does not pay
for the engine, scipy and the scenes.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from .version import __version__

#: each public name and the module it comes from
_FROM = {
    "sweep": ".analysis.sweep",
    "ChartBreakdown": ".errors",
    "MpsError": ".errors",
    "NumericalError": ".errors",
    "SceneError": ".errors",
    "SimulationError": ".errors",
    "SingularConfiguration": ".errors",
    "build": ".run.build",
    "simulate": ".run.build",
    "Simulation": ".run.simulation",
    "Trajectory": ".run.trajectory",
    "Scene": ".scene",
    "load_scene": ".scene",
    "preset_names": ".scene",
    "scene_from_dict": ".scene",
    "scene_from_text": ".scene",
    "ChartPolicy": ".scene.settings",
    "SolverSettings": ".scene.settings",
}

if TYPE_CHECKING:
    from .analysis.sweep import sweep
    from .errors import (
        ChartBreakdown,
        MpsError,
        NumericalError,
        SceneError,
        SimulationError,
        SingularConfiguration,
    )
    from .run.build import build, simulate
    from .run.simulation import Simulation
    from .run.trajectory import Trajectory
    from .scene import Scene, load_scene, preset_names, scene_from_dict, scene_from_text
    from .scene.settings import ChartPolicy, SolverSettings


def __getattr__(name: str) -> Any:
    where = _FROM.get(name)
    if where is None:
        raise AttributeError(f"module 'mps_core' has no attribute {name!r}")
    value = getattr(importlib.import_module(where, __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_FROM))


__all__ = [
    "simulate",
    "build",
    "sweep",
    "load_scene",
    "scene_from_dict",
    "scene_from_text",
    "preset_names",
    "Scene",
    "Simulation",
    "SolverSettings",
    "ChartPolicy",
    "Trajectory",
    "MpsError",
    "SceneError",
    "SimulationError",
    "ChartBreakdown",
    "SingularConfiguration",
    "NumericalError",
    "__version__",
]
