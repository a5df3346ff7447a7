"""A scene built into a ready-to-run simulation, and run to its end."""

from __future__ import annotations

from typing import Any

from ..scene import Scene, load_scene
from .simulation import Simulation
from .trajectory import Trajectory


def build(scene: Scene | str) -> Simulation:
    """A ready-to-run simulation of a scene (a Scene, a preset name or a path)."""
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    mech = scene.mechanism()
    observers = []
    if scene.reactions:
        from ..dynamics.reaction_observer import ReactionObserver

        observers.append(ReactionObserver())
    return Simulation(
        mech,
        scene.structure,
        scene.build_effects(mech),
        scene.initial_state(mech),
        solver=scene.solver,
        charts=scene.charts,
        commands=scene.commands,
        observers=observers,
        change_point=scene.change_point,
    )


def simulate(scene: Scene | str, **overrides: Any) -> Trajectory:
    """Run a scene to its end; keyword overrides as :meth:`Scene.with_overrides`."""
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    if overrides:
        scene = scene.with_overrides(**overrides)
    traj = build(scene).run(scene.t_end, scene.dt)
    traj.settings["scene"] = scene.name
    return traj
