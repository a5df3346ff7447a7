"""mps_core: the partial-system engine, the press mechanism, its effects, solvers and scenes.

Pure Python on numpy and scipy; no ROS. The entry point for library users::

    from mps_core import load_scene, simulate
    traj = simulate("paper")            # a preset name, a path, or a Scene
    traj.phi, traj.phi_dot, traj.phi_ddot, traj.T, traj.V
"""

from __future__ import annotations

from .errors import (ChartBreakdown, MpsError, NumericalError, SceneError, SimulationError,
                     SingularConfiguration)
from .scene import Scene, load_scene, preset_names, scene_from_dict, scene_from_text
from .simulation import ChartPolicy, Simulation, SolverSettings
from .trajectory import Trajectory



def _version() -> str:
    """The installed distribution's version: pyproject.toml's, the one place it is written
    (from that file itself where the tree runs without being installed)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("mps")
    except PackageNotFoundError:
        import tomllib
        from pathlib import Path

        text = (Path(__file__).resolve().parents[1] / "pyproject.toml").read_text()
        return tomllib.loads(text)["project"]["version"]


__version__ = _version()


def build(scene: Scene | str) -> Simulation:
    """A ready-to-run simulation of a scene (a Scene, a preset name or a path)."""
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    mech = scene.mechanism()
    observers = []
    if scene.reactions:
        from .reactions import ReactionObserver

        observers.append(ReactionObserver())
    return Simulation(mech, scene.structure, scene.build_effects(mech), scene.initial_state(mech),
                      solver=scene.solver, charts=scene.charts, commands=scene.commands,
                      observers=observers, change_point=scene.change_point)


def simulate(scene: Scene | str, **overrides) -> Trajectory:
    """Run a scene to its end; keyword overrides as :meth:`Scene.with_overrides`."""
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    if overrides:
        scene = scene.with_overrides(**overrides)
    traj = build(scene).run(scene.t_end, scene.dt)
    traj.settings["scene"] = scene.name
    return traj


__all__ = ["simulate", "build", "load_scene", "scene_from_dict", "scene_from_text",
           "preset_names", "Scene", "Simulation", "SolverSettings", "ChartPolicy", "Trajectory",
           "MpsError", "SceneError", "SimulationError", "ChartBreakdown", "SingularConfiguration",
           "NumericalError", "__version__"]
