"""The nominal press's model as a tracker runs it: its process load left out, the unknown inputs in.

:class:`NominalModel` makes the model's runs a tracker follows a press with
(:class:`~mps_core.track.tracker.Tracker`) and those a cut's fit runs
(:class:`~mps_core.track.cut_fit.CutFitter`): the nominal scene's mechanism and effects but its
process loads (:data:`PROCESS_EFFECTS`: the process force is estimated), the unknown inputs'
effect of its own (:class:`~mps_core.track.unknown_inputs.UnknownInputs`), its solver on the
tracker's derivative scheme, no commands (they come as mode signals).
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Any

from ..run.simulation import Simulation
from ..solvers import ADAPTIVE_SOLVERS
from .settings import TrackSettings
from .unknown_inputs import UnknownInputs

if TYPE_CHECKING:
    from ..scene import Scene

__all__ = ["PROCESS_EFFECTS", "NominalModel"]

#: the process loads a tracker's model leaves out (the unknown input stands for them)
PROCESS_EFFECTS = ("blanking",)


class NominalModel:
    """The model of ``scene`` a tracker runs (see the module), its effects and runs its own."""

    def __init__(self, scene: Scene, settings: TrackSettings) -> None:
        self.scene = scene
        self.mechanism = mech = scene.mechanism()
        effects = [e for e in scene.build_effects(mech) if e.kind not in PROCESS_EFFECTS]
        #: the unknown inputs' effect (its values follow the state)
        self.inputs = UnknownInputs()
        effects.append(self.inputs)
        self.effects = effects
        self.motor = next((e for e in effects if e.kind == "motor"), None)
        solver = replace(scene.solver, scheme=settings.derivatives)
        if solver.name not in ADAPTIVE_SOLVERS and solver.step is None:
            solver = replace(solver, step=2e-3)  # a gap in the measurements: 2 ms steps at most
        self.solver = solver
        #: the parameters of the process loads the scene names
        self.process_params = [dict(e.params) for e in scene.effects if e.kind in PROCESS_EFFECTS]

    def new_run(
        self, initial: tuple, t0: float, structure: str | None = None, controls: dict | None = None
    ) -> Simulation:
        """Return a run from ``initial`` (view, q, q̇) at ``t0``.

        In the scene's initial structure, or in ``structure`` with the controls ``controls``
        (:meth:`controls_of` a run's).
        """
        scene = self.scene
        sim = Simulation(
            self.mechanism,
            structure or scene.structure,
            self.effects,
            initial,
            solver=self.solver,
            charts=scene.charts,
            t0=t0,
            change_point=scene.change_point,
        )
        if controls is not None:
            vars(sim.controls).update(controls)
            sim.controls.touch()
            e = sim.solver.current
            sim.restart_at(e.q, e.qd)  # its evaluation under these controls
        return sim

    def view(self, structure: str, name: str) -> Any:
        """Return the chart view of ``structure`` named ``name``."""
        for v in self.mechanism.views(structure):
            if v.name == name:
                return v
        raise KeyError(f"no chart view {name!r} in structure {structure!r}")

    @staticmethod
    def controls_of(sim: Simulation) -> dict[str, Any]:
        """Return a run's controls as plain values (what :meth:`new_run` takes)."""
        return {k: v for k, v in vars(sim.controls).items() if not k.startswith("_") and k != "structure"}
