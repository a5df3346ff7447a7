"""The sinks of a run that are not ROS: the recording (:class:`RecordingSink`)."""

from __future__ import annotations

from pathlib import Path

from ..recording.recorder import Recorder
from ..wire.topics import BY_KEY, NODE_NAME, resolve


class RecordingSink:
    """A :class:`~mps_ros.run.runner.Runner` sink that records every message under its full topic
    name (``names``: key -> topic, e.g. from the node's publishers; default: the node's default
    names) with the QoS it was offered with (``qos``: key -> YAML)."""

    def __init__(
        self,
        recorder: Recorder,
        names: dict | None = None,
        qos: dict | None = None,
        node: str = NODE_NAME,
        log=None,
    ):
        self.rec = recorder
        self.names = names or {}
        self.qos = qos or {}
        self.node = node
        self._ids: dict = {}  # key -> the recorder's channel id (emit_all)
        #: ``log(level, text)``: where the recording's failure is said (once); None: raised
        self.log = log
        #: why the recording stopped (the disk full...); the run goes on without it
        self.failure: str | None = None
        self.dropped = 0  # messages not recorded since it stopped
        #: the simulated time (s) of the messages that could not be written
        self.failed_at: float | None = None
        self._t_ns = 0

    def _failed(self, exc: Exception) -> None:
        if self.log is None:
            raise exc
        self.failure = str(exc)
        self.failed_at = self._t_ns * 1e-9
        path = getattr(self.rec, "path", None)
        self.log(
            "error",
            f"recording stopped at t = {self._t_ns * 1e-9:.6g} s: {exc}; the run "
            "goes on without it; the file keeps the whole chunks written before"
            + (
                f" (complete it with `mps recover {path} OUT.mcap` where there is room)"
                if path is not None
                else ""
            ),
        )

    def _topic(self, key):
        name = self.names.get(key)
        if name is None:
            name = self.names[key] = resolve(key, self.node)
        return name

    def prepare(self, keys) -> None:
        """Register the channels of ``keys`` now (schemas and channels head the file)."""
        for key in keys:
            self.rec.channel(self._topic(key), BY_KEY[key].msgtype, self.qos.get(key))

    def emit(self, key, data, t_ns):
        if self.failure is not None:
            self.dropped += 1
            return
        self._t_ns = t_ns
        try:
            self.rec.write(self._topic(key), BY_KEY[key].msgtype, data, t_ns, self.qos.get(key))
        except OSError as exc:
            self._failed(exc)

    received = emit

    def emit_all(self, msgs) -> None:
        """A released step's messages, ``(key, data, t_ns, received)`` each, in order: the
        commands as received are recorded like the others (:meth:`received` is :meth:`emit`).
        A recorder with ``write_steps`` takes the list as it is."""
        if self.failure is not None:
            self.dropped += len(msgs)
            return
        write_steps = getattr(self.rec, "write_steps", None)
        if write_steps is None:
            for key, data, t_ns, _received in msgs:
                self.emit(key, data, t_ns)
            return
        if msgs:
            self._t_ns = msgs[0][2]
        ids = self._ids
        try:
            for key, _data, _t, _r in msgs:
                if key not in ids:  # a key met for the first time: its channel first
                    ids[key] = self.rec.channel(self._topic(key), BY_KEY[key].msgtype, self.qos.get(key))
            write_steps(msgs, ids)
        except OSError as exc:
            self._failed(exc)

    def tick(self, deadline: float | None = None):
        if self.failure is not None:
            return
        try:
            self.rec.tick()
        except OSError as exc:
            self._failed(exc)

    def status(self, name: str, hardware: str) -> dict:
        """The recording's /diagnostics status (:func:`mps_ros.wire.diagnostics.recording`): the
        file's bytes on disk so far (the chunks written), the messages handed to it."""
        from ..wire.diagnostics import recording

        path = Path(getattr(self.rec, "path", ""))
        try:
            parts = list(path.glob("*.mcap")) if path.is_dir() else [path]
            size = sum(p.stat().st_size for p in parts)
        except OSError:
            parts, size = [], 0
        return recording(
            name, hardware, path, size, self.rec.messages, self.failure, self.dropped, files=len(parts)
        )


__all__ = ["RecordingSink"]
