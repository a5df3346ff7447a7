"""``mps record``: the node's recording made without ROS, the same runner writing the same
messages (:func:`record`)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from ..recording.background import BackgroundRecorder
from ..recording.recorder import Recorder
from ..wire.topics import DEPTH, offered_qos
from .sinks import Message, RecordingSink, Sink


def record(
    scene,
    out,
    *,
    dt=None,
    t_end=None,
    outputs=None,
    publish_every: int = 1,
    pacing: str = "as_fast_as_possible",
    real_time_factor: float = 1.0,
    scene_commands: bool = True,
    flush_period: float = 1.0,
    log=None,
    stop_on_signals: bool = True,
    background: bool = True,
    compression: str = "zstd",
    progress: bool = False,
    max_bytes: int = 0,
    max_s: float = 0.0,
    file_name: str = "",
) -> tuple[Path, dict, dict]:
    """The node's recording made without ROS: run ``scene`` with the scene's own commands and
    write every message the node would publish to ``out``; ``background``: written by a
    :class:`BackgroundRecorder` (another process), else in this one; ``progress``: a progress
    line on standard error where it is a terminal (:class:`~mps_core.run.progress.Progress`);
    ``compression``: the chunks' (``zstd``, ``lz4``, ``none``); ``out`` a bag directory (not
    ending in ``.mcap``): its files split at ``max_bytes`` or ``max_s`` (:class:`Recorder`);
    ``file_name``: the name ``out`` is renamed to once finished, for its rosbag2 record.
    Returns (path, stats, counts); the stats say why the run stopped (``stop_reason``), and
    where the recording could not be written, why and from when (``recording_failure``,
    ``recording_failed_at``)."""
    import signal

    from ..wire.topics import OUTPUTS
    from .runner import Runner
    from .twin import Twin

    twin = Twin(scene, dt=dt, t_end=t_end, outputs=outputs or OUTPUTS, scene_commands=scene_commands)
    from mps_core.run.progress import Progress

    shown = Progress(twin.t0, twin.t_end, label=twin.scene.name, quiet=not progress)
    rec = (BackgroundRecorder if background else Recorder)(
        out,
        scene_name=twin.scene.name,
        scene_text=twin.scene.text,
        metadata=run_metadata(twin, "mps record", pacing, real_time_factor, publish_every),
        flush_period=flush_period,
        compression=compression,
        max_bytes=max_bytes,
        max_s=max_s,
        file_name=file_name,
    )

    def recording_failed(_level, _text):  # a recording that cannot be written ends the run
        runner.request_stop("recording-failed")

    sink = RecordingSink(rec, qos=offered_qos(DEPTH), log=recording_failed)
    watch = _WatchSink(twin, shown)
    runner = Runner(
        twin,
        sinks=[sink, watch],
        pacing=pacing,
        real_time_factor=real_time_factor,
        publish_every=publish_every,
        log=log,
    )
    old = {}
    if stop_on_signals:

        def stop(signum, _frame):
            runner.request_stop(signal.Signals(signum).name)

        for sig in (signal.SIGINT, signal.SIGTERM):
            old[sig] = signal.signal(sig, stop)
    failed = True

    def outcome(stats: dict) -> dict:
        """``stats`` with why the run stopped, the recording's failure and the run's step."""
        stats["stop_reason"] = runner.stop_reason or "end"
        stats["recording_failure"] = sink.failure
        stats["recording_failed_at"] = sink.failed_at
        stats["fastest_rates"] = watch.fastest
        solver = twin.sim.settings
        stats["solver"] = solver.name
        stats["solver_step"] = solver.step if solver.step is not None else twin.dt
        return stats

    try:
        stats = runner.run()
        failed = False
    except BaseException as exc:  # what the run did up to its error, for the caller to say
        exc.record_stats = outcome({"t": twin.t, "steps": twin.k})  # type: ignore[attr-defined]
        raise
    finally:
        shown.done()
        try:
            rec.finish()
        except OSError as exc:
            # the file could not be finished: what failed is said already (the recording's
            # failure, or the run's error on its way out), or it failed only now (the disk
            # filled with the last messages handed over): the recording's failure at the end
            if not failed and sink.failure is None:
                sink.failure, sink.failed_at = str(exc), twin.t
        finally:
            for sig, h in old.items():
                signal.signal(sig, h)
    return rec.path, outcome(stats), rec.counts()


class _WatchSink(Sink):
    """A run's sink that shows how far the run has got and keeps its fastest crank and rocker
    rates (for the coarse-step warning), at each step's tick."""

    def __init__(self, twin, progress):
        self.twin, self.progress = twin, progress
        #: the largest |phi_dot| and |psi_dot| so far (rad/s)
        self.fastest = [0.0, 0.0]

    def emit_all(self, msgs: Sequence[Message]) -> None:
        pass

    def tick(self, deadline: float | None = None) -> None:
        twin = self.twin
        self.progress(twin.t)
        phi_dot, psi_dot = twin.crank_rocker_rates()  # the step's /joint_states read them already
        fastest = self.fastest
        if abs(phi_dot) > fastest[0]:
            fastest[0] = abs(phi_dot)
        if abs(psi_dot) > fastest[1]:
            fastest[1] = abs(psi_dot)


def run_metadata(twin, source, pacing, rtf, publish_every) -> dict:
    """Return the ``mps`` metadata record of a run of ``twin`` (the recording's settings)."""
    d = twin.describe()
    return {
        "source": source,
        "scene_origin": d["origin"],
        "t0_s": repr(d["t0"]),
        "t_end_s": repr(d["t_end"]),
        "dt_s": repr(d["dt"]),
        "steps": str(d["steps"]),
        "solver": d["solver"],
        "derivatives": d["derivatives"],
        "outputs": ",".join(d["outputs"]),
        "scene_commands": str(d["scene_commands"]).lower(),
        "pacing": pacing,
        "real_time_factor": repr(float(rtf)),
        "publish_every": str(int(publish_every)),
        "time": "simulated, ns from t = 0",
    }


__all__ = ["record", "run_metadata"]
