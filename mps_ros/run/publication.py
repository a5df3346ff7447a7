"""The steps of a split run released: published, recorded and measured (:class:`Publication`)."""

from __future__ import annotations

from typing import Any

from ..wire.topics import BY_KEY
from .boundaries import HeldStep
from .metrics import Timings
from .sinks import Fanout, Sink
from .twin import to_ns


class Publication:
    """The steps released (:meth:`release`): each published (``sink.emit_all``: the ROS
    publishers) and then recorded (``sinks``: the recorder; one that fails is said once and
    dropped, and the run steps on), measured (publish times and, paced, the latency after its
    deadline; the messages published; ``first``, the schedule's start, and ``last``, the
    last release), and the recording's /diagnostics status said once a diagnostics period and
    at once where it has stopped (:meth:`recording_status`), published and recorded after the
    step's messages."""

    def __init__(self, spec: dict, sink, log):
        self.spec = spec
        self.afap = bool(spec.get("afap"))
        self.sink = sink
        #: the others: the recorder; one that fails is dropped (:meth:`_sink_failed`)
        self.sinks = Fanout(on_failure=self._sink_failed)
        self._k_releasing = 0  # the step being released (said with a sink's failure)
        self._said = False  # a sink's failure, first seen at the step being released
        self.log = log
        self.latencies = Timings()
        self.publish_times = Timings()
        self.messages = 0
        self.first: float | None = None  # the schedule's start (wall s)
        self.last = 0.0  # the last release (wall s)
        self.k_released: int | None = None
        self.failure: str | None = None  # why the recording stopped, where it did
        self.next_status = 0.0  # the recording's next status (wall s)
        self.diagnostics_encoder: Any = None  # set in prepare
        #: the statuses' name prefix (the node's) and hardware_id
        self.named = (spec["runner"].get("name", "press_twin"), spec.get("hardware_id", "mps"))

    def prepare(self) -> None:
        """The sinks' channels; the recording status's encoder."""
        keys = [t.key for t in BY_KEY.values() if not t.output or t.output in self.spec["twin"]["outputs"]]
        self.sinks.prepare(keys)
        if "diagnostics" in self.spec["twin"]["outputs"]:
            from ..wire.cdr import encoder

            # the recording's status: its encoder made now, not at the first release (a
            # quarter of a second here, holding this interpreter's lock)
            self.diagnostics_encoder = encoder(BY_KEY["/diagnostics"].msgtype)

    def release(self, head: HeldStep, clock) -> None:
        msgs = head.msgs
        p0 = clock()
        self.messages += self.sink.emit_all(msgs)
        p1 = clock()
        if self.first is None:
            self.first = head.deadline
        self.last = p1
        self.k_released = head.k
        if head.state:
            self.publish_times.add(p1 - p0)
            if not self.afap:
                late = p1 - head.deadline
                self.latencies.add(late if late > 0.0 else 0.0)
        self._k_releasing = head.k
        self._said = False
        encoded = head.encoded
        if encoded is None:
            self.sinks.emit_all(msgs)
        else:  # the recorder takes the step as the stepping process encoded it
            self.sinks.emit_encoded(msgs, encoded)
        self.sinks.tick(head.deadline)
        said = self._said
        if self.failure is None:
            for s in self.sinks.sinks:  # a plain loop: no generator made each step
                if s.failure:
                    self.failure = s.failure
                    said = True
                    break
        if said or p1 >= self.next_status:
            self.next_status = p1 + float(self.spec["runner"].get("diagnostics_period", 1.0))
            self.recording_status(msgs)

    def _sink_failed(self, sink: Sink, exc: Exception) -> None:
        """A sink that raised: said once, dropped (the run steps on without it)."""
        self.log("error", f"recording failed at step {self._k_releasing}: {type(exc).__name__}: {exc}")
        if self.failure is None:
            self.failure = f"{type(exc).__name__}: {exc}"
            self._said = True

    def stale(self, now: float, t: float | None) -> None:
        """Paused: the diagnostics say so (pacing STALE, the recording's status), once a
        diagnostics period, stamped ``t``, the time of the step released last (None: none
        was); published and recorded."""
        self.next_status = now + float(self.spec["runner"].get("diagnostics_period", 1.0))
        if "diagnostics" not in self.spec["twin"]["outputs"] or t is None:
            return
        from ..wire import diagnostics

        name, hw = self.named
        self.statuses_out(
            [diagnostics.paused(name, hw, t)] + self.sinks.statuses(name, hw),
            to_ns(t),
        )

    def recording_status(self, msgs: list) -> None:
        """The recording's /diagnostics status (:func:`mps_ros.wire.diagnostics.recording`), once a
        diagnostics period and at once where it has stopped, stamped with the step released:
        published and recorded (where the recording goes on) after the step's messages. None
        where the run publishes no diagnostics or records nothing."""
        if "diagnostics" not in self.spec["twin"]["outputs"]:
            return
        from ..wire import diagnostics

        name, hw = self.named
        statuses = self.sinks.statuses(name, hw)
        if self.failure is not None and not any(x["level"] == diagnostics.ERROR for x in statuses):
            # the sink itself gave up (dropped): its failure said all the same
            statuses.append(diagnostics.recording(name, hw, "", 0, 0, self.failure))
        if statuses:
            self.statuses_out(statuses, msgs[0][2] if msgs else 0)

    def statuses_out(self, statuses: list, t_ns: int) -> None:
        """A /diagnostics message of ``statuses`` (stamped ``t_ns``) after the step released:
        published, and recorded where the recording goes on."""
        from ..wire.diagnostics import array

        out = [("/diagnostics", self.diagnostics_encoder(array(t_ns, statuses)), t_ns, False)]
        self.messages += self.sink.emit_all(out)
        for s in self.sinks:
            if s.failure is None:
                s.emit_all(out)
                s.tick(None)
