"""A node's run settings from its parameters (:class:`RunConfig`): the twin, the runner's pacing,
the runner or the stepping process, the real-time priority asked for."""

from __future__ import annotations

from typing import TYPE_CHECKING, TypeAlias

from mps_core import MpsError

from ..run.commands import Gate, Inbox
from ..run.runner import Runner
from ..run.twin import Twin
from ..wire.diagnostics import hardware_id
from .parameters import NodeSettings, ParameterError

if TYPE_CHECKING:
    from ..run.releasing import SteppingProcess
    from ..run.tracking import TrackingRun

#: a node's run: stepped in this process, or in a stepping process of its own, or following a
#: press from its measurements
NodeRun: TypeAlias = "Runner | SteppingProcess | TrackingRun"


class RunConfig:
    """A run's settings from the node's parameters (read and checked): the twin, the runner's
    pacing, whether the twin steps in a process of its own, and the runner (or the stepping
    process) that steps it. The same for every run of the node (a reset's too)."""

    def __init__(self, settings: NodeSettings, name: str):
        self.settings = settings
        #: the node's fully qualified name, without its leading slash (its diagnostics' name)
        self.name = name

    def twin(self) -> Twin:
        """The scene's twin, new (:class:`ParameterError` where the scene cannot be loaded)."""
        p = self.settings
        try:
            return Twin(p.scene, **self._twin_settings())
        except (MpsError, OSError, ValueError) as exc:
            raise ParameterError(f"scene {p.scene!r}: {exc}") from None

    def _twin_settings(self) -> dict:
        p = self.settings
        return dict(
            dt=p.dt or None,
            t_end=p.t_end or None,
            outputs=p.outputs,
            scene_commands=p.scene_commands,
            markers_hz=p.markers_hz,
            markers_scale=p.markers_scale,
            derivatives=p.derivatives or None,
        )

    def splits(self, twin: Twin) -> bool:
        """Whether ``twin`` steps in a process of its own (:mod:`mps_ros.run.stepping`): asked for
        (``stepping_process``), in realtime pacing or where the twin can come back to a step."""
        p = self.settings
        return p.stepping_process and (p.pacing == "realtime" or twin.rewindable)

    def pacing(self) -> dict:
        """The runner's settings from the parameters, the same in the node's process and in a
        stepping process of its own."""
        p = self.settings
        return dict(
            real_time_factor=p.real_time_factor,
            lead=p.lead,
            command_delay=p.command_delay,
            release_period=p.release_period,
            release_slice=p.release_slice,
            freeze_gc=True,
            publish_every=p.publish_every,
            diagnostics_period=p.diagnostics_period,
            name=self.name,
        )

    def gate(self) -> Gate:
        return Gate(self.settings.command_burst, self.settings.command_rate)

    def runner(self, twin: Twin, sink, inbox: Inbox, log) -> Runner:
        """The runner that steps ``twin`` in this process, publishing through ``sink``."""
        p = self.settings
        return Runner(
            twin,
            sinks=[sink],
            pacing=p.pacing,
            inbox=inbox,
            gate=self.gate(),
            log=log,
            **self.pacing(),
        )

    def stepping_process(self, twin: Twin, sink, log) -> SteppingProcess:
        """The stepping process that steps the scene of ``twin`` (not started), its releases
        published through ``sink``."""
        from ..run.releasing import SteppingProcess

        p = self.settings
        spec = {
            "scene": p.scene,
            "twin": dict(self._twin_settings(), outputs=list(p.outputs)),
            "runner": self.pacing(),
            "grid": [twin.t0, twin.t_end, twin.n],
            "hardware_id": hardware_id(twin.scene.name),
            "afap": p.pacing != "realtime",
        }
        return SteppingProcess(spec, sink, log, self.gate(), realtime_priority(p))


def realtime_priority(p: NodeSettings) -> int:
    """The SCHED_FIFO priority the run asks for: ``realtime_priority`` in realtime pacing; none
    as fast as possible (no deadlines to keep: it never takes a core from the others)."""
    return p.realtime_priority if p.pacing == "realtime" else 0
