"""Where a run's messages go: the contract of a sink (:class:`Sink`), the one fan-out to a
run's sinks (:class:`Fanout`), and the recording (:class:`RecordingSink`). The ROS publishers'
sink is :class:`~mps_ros.ros.endpoints.RosSink`."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import Protocol

from ..recording.recorder import Message, RecordingWriter
from ..wire.topics import NODE_NAME, resolve
from ..wire.track_topics import msgtype

__all__ = ["Fanout", "Message", "RecordingSink", "Sink"]


class Sink(Protocol):
    """Where a run's messages go. A run hands each sink every message, a step's (and each
    other message's) in one :meth:`emit_all` call, in order: ``(key, CDR bytes, t_ns,
    received)`` each, ``received`` marking a command as it came in (kept by a recording, not
    published again). Subclass it for the defaults: no channels to prepare, nothing to do at a
    step's end, no status."""

    #: handed each step at its deadline (the ROS publishers); False: after it, off that path
    #: (the recorder)
    live: bool = False
    #: why the sink stopped taking messages (the run goes on without it); None while it takes
    #: them
    failure: str | None = None

    def prepare(self, keys: Sequence[str]) -> None:
        """Make ready for the topics of ``keys`` before the run's clock starts."""
        return None

    def emit_all(self, msgs: Sequence[Message]) -> int | None:
        """Take messages in order; return how many went out where that is counted."""
        ...

    def emit_encoded(self, msgs: Sequence[Message], encoded: bytes) -> None:
        """Take a step's messages as :meth:`emit_all` does, with ``encoded``: the stepping
        process's marshal of the step (:class:`~mps_ros.run.boundaries.HeldStep`'s fields,
        ``msgs`` the last), for a sink that hands them to another process as they are."""
        self.emit_all(msgs)

    def tick(self, deadline: float | None = None) -> None:
        """Do what is due at a step's end (``deadline``: the step's, paced; else None)."""
        return None

    def status(self, name: str, hardware: str) -> dict | None:
        """Return the sink's /diagnostics status, or None where it has none."""
        return None


class Fanout:
    """A run's sinks, each handed every message in turn. ``on_failure(sink, exc)``: a sink
    that raises is dropped and this told, and the others go on; None: every sink still gets
    the messages, and the first error is raised after."""

    def __init__(
        self, sinks: Iterable[Sink] = (), on_failure: Callable[[Sink, Exception], None] | None = None
    ):
        self.sinks: list[Sink] = list(sinks)
        self.on_failure = on_failure

    def __iter__(self) -> Iterator[Sink]:
        return iter(self.sinks)

    def __len__(self) -> int:
        return len(self.sinks)

    def append(self, sink: Sink) -> None:
        """Add ``sink`` after the others."""
        self.sinks.append(sink)

    def split(self) -> tuple[Fanout, Fanout]:
        """Return the live sinks and the others, each as a fan-out of its own."""
        return (
            Fanout([s for s in self.sinks if s.live], self.on_failure),
            Fanout([s for s in self.sinks if not s.live], self.on_failure),
        )

    def _failed(self, sink: Sink, exc: Exception) -> None:
        self.sinks = [s for s in self.sinks if s is not sink]
        assert self.on_failure is not None
        self.on_failure(sink, exc)

    def prepare(self, keys: Sequence[str]) -> None:
        """Make every sink ready for the topics of ``keys``."""
        for s in self.sinks:
            s.prepare(keys)

    def emit_all(self, msgs: Sequence[Message]) -> None:
        """Hand ``msgs`` to every sink."""
        self._each(lambda s: s.emit_all(msgs))

    def emit_encoded(self, msgs: Sequence[Message], encoded: bytes) -> None:
        """Hand a step's ``msgs`` to every sink, with ``encoded`` (:meth:`Sink.emit_encoded`)."""
        self._each(lambda s: s.emit_encoded(msgs, encoded))

    def _each(self, call: Callable[[Sink], object]) -> None:
        """Call ``call`` on every sink, the fan-out's policy for a sink that raises."""
        if self.on_failure is not None:
            for s in list(self.sinks):
                try:
                    call(s)
                except Exception as exc:  # dropped and said; the others go on
                    self._failed(s, exc)
            return
        err = None
        for s in self.sinks:  # every sink gets them, though another one fails
            try:
                call(s)
            except Exception as exc:
                err = err or exc
        if err is not None:
            raise err

    def tick(self, deadline: float | None = None) -> None:
        """Tell every sink that a step has ended."""
        if self.on_failure is not None:
            for s in list(self.sinks):
                try:
                    s.tick(deadline)
                except Exception as exc:
                    self._failed(s, exc)
            return
        for s in self.sinks:
            s.tick(deadline)

    def statuses(self, name: str, hardware: str) -> list[dict]:
        """Return the sinks' /diagnostics statuses, those that have one."""
        out = []
        for s in self.sinks:
            st = s.status(name, hardware)
            if st is not None:
                out.append(st)
        return out


class RecordingSink(Sink):
    """A :class:`~mps_ros.run.runner.Runner` sink that records every message under its full topic
    name (``names``: key -> topic, e.g. from the node's publishers; default: the node's default
    names) with the QoS it was offered with (``qos``: key -> YAML)."""

    def __init__(
        self,
        recorder: RecordingWriter,
        names: dict | None = None,
        qos: dict | None = None,
        node: str = NODE_NAME,
        log: Callable[[str, str], None] | None = None,
    ):
        self.rec = recorder
        #: the recorder's hand-over of a step as the stepping process encoded it, where it has one
        self._write_encoded = getattr(recorder, "write_encoded", None)
        self.names = names or {}
        self.qos = qos or {}
        self.node = node
        self._ids: dict = {}  # key -> the recorder's channel (emit_all)
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
        path = self.rec.path
        self.log(
            "error",
            f"recording stopped at t = {self._t_ns * 1e-9:.6g} s: {exc}; the run "
            "goes on without it; the file keeps the whole chunks written before"
            + (f" (complete it with `mps recover {path} OUT.mcap` where there is room)" if path else ""),
        )

    def _topic(self, key):
        name = self.names.get(key)
        if name is None:
            name = self.names[key] = resolve(key, self.node)
        return name

    def prepare(self, keys) -> None:
        """Register the channels of ``keys`` now (schemas and channels head the file)."""
        for key in keys:
            self.rec.channel(self._topic(key), msgtype(key), self.qos.get(key))

    def emit_all(self, msgs: Sequence[Message]) -> None:
        """Record a step's messages, ``(key, data, t_ns, received)`` each, in order: the
        commands as received are recorded like the others."""
        if self.failure is not None:
            self.dropped += len(msgs)
            return
        self._record(msgs, lambda ids: self.rec.write_steps(msgs, ids))

    def emit_encoded(self, msgs: Sequence[Message], encoded: bytes) -> None:
        """Record a step's messages as :meth:`emit_all` does; a recorder in a process of its
        own (:meth:`~mps_ros.recording.background.BackgroundRecorder.write_encoded`) is handed
        ``encoded``, the stepping process's marshal of the step, instead of the messages: they
        go on as they came, not marshalled again."""
        write = self._write_encoded
        if write is None or self.failure is not None:
            self.emit_all(msgs)
            return
        self._record(msgs, lambda ids: write(encoded, len(msgs), ids))

    def _record(self, msgs: Sequence[Message], write: Callable[[dict], None]) -> None:
        """Register the channels of keys met for the first time, then ``write(ids)`` the step."""
        if msgs:
            self._t_ns = msgs[0][2]
        ids = self._ids
        try:
            for key, _data, _t, _r in msgs:
                if key not in ids:  # a key met for the first time: its channel first
                    ids[key] = self.rec.channel(self._topic(key), msgtype(key), self.qos.get(key))
            write(ids)
        except OSError as exc:
            self._failed(exc)

    def tick(self, deadline: float | None = None) -> None:
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

        path = Path(self.rec.path)
        try:
            parts = list(path.glob("*.mcap")) if path.is_dir() else [path]
            size = sum(p.stat().st_size for p in parts)
        except OSError:
            parts, size = [], 0
        return recording(
            name, hardware, path, size, self.rec.messages, self.failure, self.dropped, files=len(parts)
        )
