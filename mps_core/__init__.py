"""mps_core: the partial-system engine, the press mechanism, its effects, solvers and scenes.

Pure Python on numpy and scipy; no ROS. The entry point for library users::

    from mps_core import load_scene, simulate
    traj = simulate("paper")            # a preset name, a path, or a Scene
    traj.phi, traj.phi_dot, traj.phi_ddot, traj.T, traj.V
"""

from __future__ import annotations

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
from .version import __version__

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
