"""Follow a press from its measurements: each taken by the tracker, the estimate's messages out.

:class:`TrackingRun` is the no-ROS half of a node that follows a press (parameter ``track``): a
measurement comes in (its stamp, the crank angle in radians, optionally the slider's position,
and its bytes as received), is recorded as received, updates :class:`~mps_core.track.Tracker` at
its stamp, and the estimate goes out as the simulator's step goes out
(:class:`~mps_ros.wire.step_messages.StepMessages`: ``/clock``, ``/tf``, joint states, reactions,
foundation, structure, markers), plus the 1-σ of each wrench and the process force
(:mod:`mps_ros.wire.track_topics`), and the events the model located. Every message goes
through one :class:`~mps_ros.run.sinks.Fanout`: the ROS publishers and the recording get the same
bytes.

A measurement the tracker rejects (a stamp already seen, out of order, late, a crank jump,
an outlier...) is counted by its reason, said in the log (the first of each reason, then every
hundredth) and reported in ``/diagnostics`` (status ``NAME: tracking input``), as
robot_localization does; a source silent for longer than ``timeout`` wall seconds is counted
(``timeout``) and reported (WARN while it lasts). The node's runner is replaced by this: it
has the runner's few methods the node calls (:meth:`prepare`, :meth:`run`,
:meth:`request_stop`, :meth:`pause`...).
"""

from __future__ import annotations

import gc
import math
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

from mps_core.dynamics.reactions import REACTION_COLUMNS, compute_reactions, reaction_values
from mps_core.errors import MpsError
from mps_core.scene import Scene
from mps_core.track import (
    Encoder,
    Estimate,
    Measurement,
    MeasurementError,
    ModeSignal,
    TorqueSensor,
    Tracker,
    TrackSettings,
)
from mps_core.track.diagnostics import TrackingMonitor
from mps_core.track.fit_process import CutFits
from mps_core.track.tracker import KEEP_INNOVATIONS, LOAD_COLUMNS
from mps_core.track.truth import nominal_scene

from ..wire import diagnostics
from ..wire.cdr import msgdef, planar_wrench, string
from ..wire.diagnostics import hardware_id
from ..wire.json_text import to_json
from ..wire.measured import measurements, ns_seconds
from ..wire.step_messages import StepMessages
from ..wire.topics import BY_KEY, OUTPUTS
from ..wire.track_topics import (
    PROCESS_FORCE,
    PROCESS_FORCE_NOW,
    PROCESS_FRAME,
    RECEIVED_JOINTS,
    RECEIVED_MODE,
    STROKES,
    TRACKING_BY_KEY,
    sigma,
)
from .commands import Inbox, shown
from .metrics import Timings
from .sinks import Fanout, Message

__all__ = ["TrackingRun"]

#: the reasons this run rejects an input for, besides the tracker's (``Tracker.rejected``)
INPUT_REJECTIONS = ("malformed", "timeout")
#: an estimate handed out later than this after its measurement arrived (s) is late: the node
#: does not keep up (issue 46's target: published within 1 ms)
LATE = 1e-3
#: a node behind its press by more than ``max_behind`` publishes again once it is within this (s)
CAUGHT_UP = 0.01
#: the nominal press's first seconds a run takes in a copy of itself before its press's first
#: measurement (:meth:`TrackingRun.warm_up`): press-cycle engages at 8 ms, disengages at 0.435 s
#: and swings free after it within them (with 0.5 s, the free swing's charts were still met
#: for the first time after the disengage, 2 to 6 ms each)
WARM_UP = 1.0


def _ns(t: float) -> int:
    """Return a time (s) in whole nanoseconds."""
    return int(round(t * 1e9))


def _stamp(t_ns: int) -> dict:
    """Return builtin_interfaces/Time of ``t_ns``."""
    return {"sec": t_ns // 1_000_000_000, "nanosec": t_ns % 1_000_000_000}


def _percentile_ms(timings: Timings, q: float) -> float:
    """Return the ``q``-th percentile of ``timings`` in ms (to 1 %; NaN where empty)."""
    return timings.percentile(q) * 1e3 if timings.n else math.nan


class _Estimated:
    """The tracker's present estimate, as :class:`StepMessages` reads a twin's step."""

    def __init__(self, tracker: Tracker, solve_reactions: bool) -> None:
        self.tracker = tracker
        self.solve_reactions = solve_reactions
        self.k = 0
        self.rx: list | None = None

    @property
    def sim(self) -> Any:
        """Return the tracker's run (its present state is the estimate's mean)."""
        return self.tracker.sim

    def reaction_list(self) -> list | None:
        """Return the reactions at the estimate, in REACTION_COLUMNS order (None unless asked for)."""
        return self.rx

    def compute_reactions(self) -> None:
        """Solve the reactions at the estimate (the estimated process force and load torque acting)."""
        if not self.solve_reactions:
            self.rx = None
            return
        sim = self.tracker.sim
        e = sim.solver.current
        fast = reaction_values(
            sim.mechanism, sim.engine.effects, e.view, e.t, e.q.tolist(), e.qd.tolist(), e.qdd.tolist(), e.kin
        )
        if fast is not None:
            self.rx = list(fast[0])
            return
        rx = compute_reactions(sim.mechanism, sim.engine.effects, e.view, e.t, e.q, e.qd, e.qdd, kin=e.kin)
        self.rx = [float(rx.values[c]) for c in REACTION_COLUMNS]

    def joint_values(self) -> tuple[list, list]:
        """Return the positions and velocities of the joints (crank, rod, rocker, slider)."""
        sim = self.tracker.sim
        phi, phi_dot, psi, psi_dot, x, x_dot = sim.joint_state()
        kin = sim.solver.current.kin
        xa, ya = kin.xy("A")
        xb, yb = kin.xy("B")
        return ([phi, math.atan2(yb - ya, xb - xa), psi, x], [phi_dot, kin.rate("rod"), psi_dot, x_dot])


class TrackingRun:
    """Follow a press: measurements in (:meth:`measurement`, :meth:`mode`), the estimate's messages out.

    ``scene``: the nominal press (:func:`nominal_scene` is applied). ``outputs``: what of
    :data:`~mps_ros.wire.topics.OUTPUTS` goes out at each measurement taken. ``encoder``: the
    crank encoder (its variance is the angle's); ``slider_variance``: the slider scale's (m²);
    ``torque_sensor``: the motor torque's (where the measurements carry it).
    ``sigma_every``: the loads' 1-σ (``KEY/sigma``) computed and published every this many
    estimates (they cost 2n more evaluations and 2n + 3 reaction solves each: a stated decimation where the
    machine cannot keep up). ``timeout``: wall seconds without a measurement reported as a
    timeout. ``late_after``: an estimate out later than this (s) after its measurement arrived
    is counted late and reported (WARN: the node does not keep up). ``max_behind``: a
    measurement taken this many seconds (> 0) after its arrival updates the tracker but its
    estimate is not published, nor those after it until one is taken within
    :data:`CAUGHT_UP` of its arrival (counted, said, WARN: the node catches up with its press;
    0: every estimate published however late). ``clock``: the wall clock
    the inputs' arrival and sending times are on (s). ``log(level, text)``: where rejections
    and timeouts are said. ``fit_elsewhere``: the cuts fitted in a process of their own
    (:mod:`~mps_core.track.fit_process`: the node's, so that a fit holds no measurement up; the
    strokes the same), not where the measurements are taken; :meth:`close` ends it.
    """

    def __init__(
        self,
        scene: Scene,
        sinks: Fanout,
        *,
        name: str = "press_twin",
        outputs: Sequence[str] = OUTPUTS,
        settings: TrackSettings | None = None,
        encoder: Encoder | None = None,
        slider_variance: float = 1e-12 + 1e-12 / 12.0,
        torque_sensor: TorqueSensor | None = None,
        sigma_every: int = 1,
        timeout: float = 0.05,
        late_after: float = LATE,
        max_behind: float = 0.0,
        clock: Callable[[], float] = time.monotonic,
        diagnostics_period: float = 1.0,
        markers_hz: float = 30.0,
        markers_scale: float | None = None,
        log: Callable[[str, str], None] | None = None,
        freeze_gc: bool = False,
        fit_elsewhere: bool = False,
    ) -> None:
        if not (isinstance(sigma_every, int) and sigma_every >= 1):
            raise MeasurementError("track_sigma_every", sigma_every, "an integer >= 1")
        if not (timeout > 0.0 and math.isfinite(timeout)):
            raise MeasurementError("track_timeout", timeout, "a positive number of seconds")
        self.scene = nominal_scene(scene)
        self.sinks = sinks
        self.name = name
        self.outputs = tuple(outputs)
        self.tracker = Tracker(self.scene, settings)
        #: what a copy of this run is made with (:meth:`warm_up`), beside the scene
        self._made: dict[str, Any] = {
            "outputs": tuple(outputs),
            "settings": settings,
            "encoder": encoder,
            "slider_variance": slider_variance,
            "torque_sensor": torque_sensor,
            "timeout": timeout,
            "markers_hz": markers_hz,
            "markers_scale": markers_scale,
        }
        # a press followed for days: the tracking status reads the innovations as they come,
        # a late signal's search the last few; the older are dropped
        self.tracker.keep_innovations = KEEP_INNOVATIONS
        self.log = log or (lambda level, text: None)
        #: the cuts fitted in a process of their own, not where the measurements are taken
        #: (None: fitted here, where the tracker fits them at all)
        self.fits: CutFits | None = None
        if fit_elsewhere and self.tracker.settings.fit_cuts:
            self.fits = CutFits(self.scene, self.tracker.settings, self.log)
            self.fits.attach(self.tracker)
        #: whether the press still moves as the model says (the ``NAME: tracking`` status)
        self.monitor = TrackingMonitor()
        self.encoder = encoder or Encoder()
        self.slider_variance = float(slider_variance)
        self.torque_sensor = torque_sensor or TorqueSensor()
        self._torque_said = False
        self._found_said = 0  # the mode signals searched for, said
        self._restarts_said = 0  # the model's runs started again, said
        #: the crank's and the slider's acquisitions counted so far (said at the first and every 100th)
        self._acquired_said: Counter[str] = Counter()
        self._prepared = False  # prepare() done (once: its warm-up takes about 1 s)
        #: once prepared, the objects made so far are frozen out of the garbage collector's
        #: passes (``gc.freeze``, a process-wide choice: the node's), as a simulating run's are
        #: (:attr:`~mps_ros.run.runner.RealtimeSettings.freeze_gc`)
        self.freeze_gc = bool(freeze_gc)
        self.sigma_every = sigma_every
        self.timeout = float(timeout)
        self.late_after = float(late_after)
        self.max_behind = float(max_behind)
        self.clock = clock
        self.period = float(diagnostics_period)
        solve = "reactions" in self.outputs or "foundation" in self.outputs
        self.step = _Estimated(self.tracker, solve)
        self.messages = StepMessages(
            self.scene, self.outputs, solve, 1e-3, markers_hz=markers_hz, markers_scale=markers_scale
        )
        self.hardware = hardware_id(self.scene.name)
        #: inputs this run rejected itself (malformed, timeout), beside the tracker's
        self.input_rejected: Counter[str] = Counter()
        self.received = 0  # measurements received (messages)
        self.estimates = 0  # estimates published (one a measurement message taken)
        #: CPU (s, this thread's) from a measurement's arrival to its estimate handed out (a
        #: histogram: a run of days keeps no more than a run of seconds)
        self.cpu = Timings()
        #: wall seconds from a measurement's arrival to its estimate handed to every sink
        self.delay = Timings()
        #: the press's clock on the wall clock: the least (sent - stamp) of the measurements
        self._offset = math.inf
        #: the process's CPU time (s) at the first measurement and after the last estimate:
        #: what following costs the whole process (executor, publishers, recording) a measurement
        self._process_cpu: list[float] = []
        #: estimates handed out more than :data:`LATE` after their measurement arrived
        self.late = 0
        #: measurements taken but their estimate not published: more than ``max_behind`` late
        self.skipped = 0
        #: strokes finished and published on ``~/strokes``
        self.strokes = 0
        self._catching_up = False
        self.stop_reason: str | None = None
        #: why the run failed and of what kind (a node's run says; this one ends without)
        self.error: str | None = None
        self.error_kind: str | None = None
        self.commands_lost = 0
        #: the node's mode commands (``~/mode``, ``~/engage``...): refused, answered
        self.inbox = Inbox()
        #: called as :meth:`run` starts (the node's source subscribes then) and as it ends
        #: (the source stops taking measurements then)
        self.on_start: Callable[[], None] | None = None
        self.on_end: Callable[[], None] | None = None
        #: set when the run is asked to stop
        self.stopping = threading.Event()
        self._lock = threading.Lock()
        self._last_arrival: float | None = None
        self._silent = False
        self._window = diagnostics.Window()
        self._said: Counter[str] = Counter()

    # -- the node's runner, as far as the node calls it ------------------------------------
    def prepare(self) -> None:
        """Make the sinks ready for the topics of the estimates and the inputs.

        The recording's channels are registered as their first messages come (a channel is in
        the file where its topic has messages), but their types' definitions are read now: the
        first measurement would otherwise wait for rosbags' type store (in process, the first
        measurement took 82 ms before, 11.5 ms after). Then :meth:`warm_up` (about 1 s), and
        the garbage collector's freeze where :attr:`freeze_gc`: a full collection that scanned
        every object the process had made held a measurement up for 39–48 ms in process
        (press-cycle with its slider scale and signals). The node calls it as the run is made
        and again as it starts: the second call does nothing.
        """
        if self._prepared:
            return
        self._prepared = True
        for msgtype in sorted({t.msgtype for t in (*BY_KEY.values(), *TRACKING_BY_KEY.values())}):
            msgdef(msgtype)
        self.sinks.prepare([])
        if self.fits is not None:
            self.fits.start()  # the worker makes its model meanwhile
        self.warm_up()
        if self.freeze_gc:
            gc.collect()
            gc.freeze()

    def warm_up(self, seconds: float = WARM_UP) -> None:
        """Take the nominal press's own first ``seconds`` in a copy of this run.

        The copy's messages go nowhere: its crank, slider scale and motor's torque read, its mode
        signals given at their times, the loads' 1-σ at every estimate. The code the run meets
        (the model's in each structure it goes through, the reactions', the messages' encoders) is
        then made before the press's first measurement waits for it; the run itself is left as it
        was. In process, press-cycle with its slider scale and signals: measurements that took
        over 2 ms went from 12, 6, 6 and 33 ms in the first 30 and 2 to 6 ms at ten after the
        disengage to 3.1 ms at the first and 2.4 ms once; the warm-up took 1.15 s.
        """
        from mps_core.track import Sensors, run_truth

        motor = self.tracker.motor is not None
        try:
            sensors = Sensors(slider=True, motor_torque=motor)
            press = run_truth(self.scene, seconds, sensors=sensors, fine_dt=2e-4)
            # the cuts fitted as this run fits them: here, or not at all (their code is then
            # the fitting process's)
            fit_here = self.fits is None and self.tracker.settings.fit_cuts
            made = dict(self._made, settings=replace(self.tracker.settings, fit_cuts=fit_here))
            copy = TrackingRun(self.scene, Fanout([]), sigma_every=1, clock=self.clock, **made)
            copy.take_all(press.measurements, press.modes, self.clock() - press.measurements[0].t)
        except (MpsError, ArithmeticError, ValueError, IndexError) as exc:
            # a scene whose own run cannot go so far: its code is made as the press's
            # measurements come, as without the warm-up
            self.log("warn", f"tracking: the warm-up on the nominal press stopped ({exc}); the run goes on")

    def take_all(
        self, measurements: Sequence[Measurement], modes: Sequence[ModeSignal], offset: float
    ) -> int:
        """Take measurements and mode signals as a press sends them; return the messages taken.

        No middleware: the measurements of one stamp make one message (the crank's, the
        slider's, the motor's torque), sent at its stamp plus ``offset`` on :attr:`clock` and
        arriving as it is taken; a mode signal goes before the first message at or after its
        time, sent at its time plus ``offset`` (a benchmark's plain loop, a warm-up, a test).
        """
        by_t: dict[float, dict[str, float]] = {}
        for m in measurements:
            by_t.setdefault(m.t, {})[m.kind] = m.value
        signals = sorted(modes, key=lambda s: s.t)
        taken = 0
        for t in sorted(by_t):
            while signals and signals[0].t <= t:
                s = signals.pop(0)
                self.mode(s.command, b"", s.t + offset)
            v = by_t[t]
            angle, slider, torque = v.get("crank_angle"), v.get("slider_position"), v.get("motor_torque")
            taken += self.measurement(t, angle, slider, b"", self.clock(), t + offset, torque)
        return taken

    def close(self) -> None:
        """End what the run started beside it: the cuts' fitting process."""
        if self.fits is not None:
            self.fits.close()

    def request_stop(self, reason: str) -> None:
        """End :meth:`run` (``reason``: why, said at the run's end)."""
        if self.stop_reason is None:
            self.stop_reason = reason
        self.stopping.set()
        self.inbox.wake()

    def resume(self) -> None:
        """Do nothing: a tracking run is never paused."""

    def pause(self) -> str:
        """Refuse: a run that follows a press goes at the press's pace."""
        return "a node following a press (track) cannot pause: the press does not"

    def step_paused(self, reply: Callable[[float], None]) -> str:
        """Refuse: there is no step to take without a measurement."""
        return "a node following a press (track) steps at its measurements"

    def run(self) -> dict:
        """Watch the source until stopped: a silence over the timeout said, ``/diagnostics`` once a period."""
        if self.on_start is not None:
            self.on_start()
        next_diag = time.monotonic() + self.period
        while not self.stopping.is_set():
            self.inbox.wait(min(self.timeout / 2.0, self.period))
            self.answer_commands()
            if self.stopping.is_set():
                break
            now = self.clock()
            self.watch(now)
            if now >= next_diag:
                next_diag = now + self.period
                self.publish_diagnostics()
        if self.on_end is not None:
            self.on_end()
        self.finish_fits()
        self.publish_diagnostics()
        return self.stats()

    def finish_fits(self) -> None:
        """Wait for the cuts' fits still out and publish the strokes they held back."""
        if self.fits is None:
            return
        with self._lock:
            self.fits.finish(self.tracker)
            msgs = self._strokes()
            if msgs:
                self.sinks.emit_all(msgs)

    def watch(self, now: float) -> None:
        """Count and say a silence of the source longer than the timeout (once a silence)."""
        with self._lock:
            last = self._last_arrival
            if last is None or self._silent or now - last <= self.timeout:
                return
            self._silent = True
            self.input_rejected["timeout"] += 1
        self.log(
            "warn",
            f"tracking: no measurement for {now - last:.3g} s (timeout {self.timeout:g} s); "
            f"the estimate holds at t = {self.tracker.t:.6f} s",
        )

    def answer_commands(self) -> None:
        """Refuse the node's mode commands, each answered on ``~/mode/status`` (and to its caller).

        The press's mode comes from its controller (``track_mode``), not from the node's
        commands.
        """
        for cmd in self.inbox.drain():
            with self._lock:
                ack = {
                    "t": self.tracker.t,
                    "command": shown(cmd.word, 64),
                    "accepted": False,
                    "reason": "the node follows a press (track): its mode comes from the press (track_mode)",
                    "source": cmd.source,
                    "structure": self.tracker.sim.structure,
                }
                t_ns = _ns(self.tracker.t)
                self.sinks.emit_all([("~/mode/status", string({"data": to_json(ack)}), t_ns, False)])
            self.log("warn", f"refused command {ack['command']!r}: {ack['reason']}")
            if cmd.reply is not None:
                cmd.reply(ack)

    # -- the inputs ----------------------------------------------------------------------
    def measurement(
        self,
        t: float,
        angle: float | None,
        slider: float | None,
        raw: bytes,
        arrival: float,
        sent: float | None = None,
        torque: float | None = None,
    ) -> bool:
        """Take one measurement message: record it, update the tracker at stamp ``t``, publish the estimate.

        ``angle``: the crank angle (rad; None: the message has none, rejected as
        ``malformed``), ``slider``: the slider's position (m) or None; ``raw``: the message's
        bytes as received; ``arrival``: when it came (``clock``), ``sent``: when its publisher
        sent it (``clock``; None: ``arrival``); ``torque``: the motor's torque on the crank (N·m)
        or None. Return whether the tracker took it.
        """
        cpu0 = time.thread_time()
        if not self._process_cpu:
            self._process_cpu = [time.process_time(), time.process_time()]
        with self._lock:
            self.received += 1
            self._last_arrival = self.clock()  # taken now: a silence is the source's, not a queue's
            self._silent = False
            if math.isfinite(t):
                self._offset = min(self._offset, (arrival if sent is None else sent) - t)
            t_ns = _ns(t) if math.isfinite(t) else 0
            self.sinks.emit_all([(RECEIVED_JOINTS.key, raw, t_ns, True)])
            if angle is None:
                self._reject("malformed", t, "no crank angle (a joint named crank, or a single position)")
                return False
            if torque is not None and self.tracker.motor is None:
                torque = None  # left out, said once: the press sends it with every measurement
                if not self._torque_said:
                    self._torque_said = True
                    self.log(
                        "warn",
                        "tracking: the press's measurements carry the motor's torque (the crank's "
                        "effort) and the scene has no motor: the torque is not taken",
                    )
            ms = measurements(
                t, angle, slider, torque, self.encoder.variance, self.slider_variance, self.torque_sensor
            )
            tr = self.tracker
            taken = False
            for m in ms:
                before = Counter(tr.rejected)
                if tr.update(m):
                    taken = True
                    continue
                new = tr.rejected - before
                for reason in new:
                    self._say(reason, t, m)
            if self.fits is not None:
                self.fits.submit(tr)
                self.fits.poll(tr)
            self._say_found()
            if tr.restarted > self._restarts_said:
                self._restarts_said = tr.restarted
                self.log(
                    "warn",
                    f"tracking: at t = {t:.6f} s the model's run failed and started again in the scene's "
                    f"initial structure at the crank measured ({tr.restarted} so far; tracker-restart)",
                )
            gap = tr.rejected["gap"] - self._said["gap"]
            if gap > 0:
                self._say("gap", t, ms[0])
            self._say_acquired(
                "crank",
                tr.acquired,
                t,
                "the model off it by more than its covariance allows",
                "the first measurement, after a gap, or latch open after angles rejected running",
            )
            self._say_acquired(
                "slider", tr.slider_acquired, t, "", "latch open after its positions rejected running"
            )
            est = tr.estimate()  # one for the status, the stroke table and the messages
            self._watch_machine(ms[0], est)
            if not taken:
                return False
            behind = self.clock() - arrival
            if 0.0 < self.max_behind < behind:
                self._catching_up = True
            elif behind <= min(self.max_behind, CAUGHT_UP):
                self._catching_up = False
            if self._catching_up:  # taken, not published, until the node is within CAUGHT_UP again
                self._publish(est, full=False)
                self.skipped += 1
                if self.skipped == 1 or self.skipped % 1000 == 0:
                    self.log(
                        "warn",
                        f"tracking: behind the press by over {self.max_behind:g} s: the estimate at "
                        f"t = {t:.6f} s taken, not published ({self.skipped} so far)",
                    )
                self._process_cpu[1] = time.process_time()
                return True
            self._publish(est)
            self.cpu.add(time.thread_time() - cpu0)
            delay = self.clock() - arrival
            self.delay.add(delay)
            if delay > self.late_after:
                self.late += 1
            self._process_cpu[1] = time.process_time()
            return True

    def _watch_machine(self, m: Measurement, est: Estimate) -> None:
        """Give the tracking status the tracker after ``m`` (estimate ``est``); say each new level."""
        before = self.monitor.status.level
        status = self.monitor.observe(self.tracker, m, est)
        if status.level != before:
            self.log({"OK": "info", "WARN": "warn"}.get(status.level, "error"), status.line())

    def mode(self, command: str, raw: bytes, sent: float) -> None:
        """Take one mode signal (``engage``, ``disengage``): record it, apply it at its time.

        A String has no stamp, and the executor takes it in no set order with the measurements:
        its time is when it was sent (``clock``) on the press's clock (less the least
        sent-stamp offset of the measurements so far), or the estimate's time before any
        measurement. Where the estimate is past it, it applies at once. It applies at the time
        it is recorded at, to the nanosecond: tracked again from the recording
        (``mps track --recording``), it gives the same estimates.
        """
        with self._lock:
            t = sent - self._offset if math.isfinite(self._offset) else self.tracker.t
            t_ns = _ns(max(t, 0.0))
            t = ns_seconds(t_ns)
            self.sinks.emit_all([(RECEIVED_MODE.key, raw, t_ns, True)])
            try:
                signal = ModeSignal(t, command.strip())
            except MeasurementError as exc:
                self._reject("malformed", self.tracker.t, str(exc))
                return
            self.tracker.mode(signal)
            self.log(
                "info",
                f"tracking: mode signal {signal.command} at t = {signal.t:.6f} s (the estimate at "
                f"t = {self.tracker.t:.6f} s)",
            )
            self._say_found()

    def _say_acquired(self, what: str, n: int, t: float, how: str, when: str) -> None:
        """Say that ``what`` (the crank, the slider) was acquired again at ``t``.

        Said where it was since the last call and its count ``n`` is the first or a hundredth; the
        line is made only then (the call comes with every measurement).
        """
        if n > self._acquired_said[what]:
            self._acquired_said[what] = n
            if n == 1 or n % 100 == 0:
                self.log(
                    "info",
                    f"tracking: at t = {t:.6f} s the {what} acquired again"
                    + (f", {how}" if how else "")
                    + f" ({n} so far: {when})",
                )

    def _say_found(self) -> None:
        """Say where the commands of the mode signals searched for since the last call were found."""
        timing, tr = self.tracker.timing, self.tracker
        if timing is None or timing.searched == self._found_said:
            return
        new = min(timing.searched - self._found_said, len(timing.found))  # the last ``new`` of them
        for signal, shift, searched, tried, cpu in list(timing.found)[len(timing.found) - new :]:
            where = (
                f"found {1e3 * shift:.2f} ms before it (searched over {1e3 * timing.latency:g} ms: "
                f"{tried} hypotheses, {1e3 * cpu:.1f} ms of CPU holding the measurements up)"
                if searched
                else f"kept {1e3 * shift:.2f} ms before it, unsearched (nothing measured to search with)"
            )
            self.log(
                "info",
                f"tracking: mode signal {signal.command} at t = {signal.t + tr.origin:.6f} s: "
                f"its command {where}",
            )
        self._found_said = timing.searched

    def _reject(self, reason: str, t: float, why: str) -> None:
        """Count and say an input this run rejects itself."""
        self.input_rejected[reason] += 1
        n = self.input_rejected[reason]
        if n == 1 or n % 100 == 0:
            self.log("warn", f"tracking: measurement at t = {t:.6f} s rejected ({reason}, {n} so far): {why}")

    def _say(self, reason: str, t: float, m: Measurement) -> None:
        """Say a rejection of the tracker's (the first of its reason, then every hundredth)."""
        n = self.tracker.rejected[reason]
        self._said[reason] = n
        if n == 1 or n % 100 == 0:
            what = (
                f"a gap over {self.tracker.settings.timeout:g} s before it (taken)"
                if reason == "gap"
                else f"{m.kind} {m.value:.6g} rejected"
            )
            self.log(
                "warn",
                f"tracking: measurement at t = {t:.6f} s: {reason} ({n} so far): {what}; "
                f"the estimate is at t = {self.tracker.t:.6f} s",
            )

    # -- the estimate out ----------------------------------------------------------------
    def _publish(self, est: Estimate, full: bool = True) -> None:
        """Hand the messages of estimate ``est`` to every sink, then the events (only those: not ``full``)."""
        tr = self.tracker
        step = self.step
        msgs: list[Message]
        if not full:
            tr.observe_stroke(None, est)
            events = tr.take_events()
            msgs = self._strokes()
            if events and "events" in self.outputs:
                t_ns = _ns(tr.t)
                msgs.extend(("~/events", string({"data": to_json(ev)}), t_ns, False) for ev in events)
            if msgs:
                self.sinks.emit_all(msgs)
            return
        step.compute_reactions()
        t_ns = _ns(tr.t)
        msgs = [(k, d, t_ns, False) for k, d in self.messages.payloads(step, tr.t)]
        st = _stamp(t_ns)
        msgs.append((PROCESS_FORCE_NOW.key, _wrench(st, PROCESS_FRAME, est.force, 0.0, 0.0), t_ns, False))
        msgs.append(
            (sigma(PROCESS_FORCE_NOW.key), _wrench(st, PROCESS_FRAME, est.force_sigma, 0.0, 0.0), t_ns, False)
        )
        st_s = _stamp(_ns(est.t_force_smoothed))
        msgs.append(
            (
                PROCESS_FORCE.key,
                _wrench(st_s, PROCESS_FRAME, est.force_smoothed, 0.0, 0.0),
                t_ns,
                False,
            )
        )
        msgs.append(
            (
                sigma(PROCESS_FORCE.key),
                _wrench(st_s, PROCESS_FRAME, est.force_smoothed_sigma, 0.0, 0.0),
                t_ns,
                False,
            )
        )
        loads = None
        if self.messages.wrenches and self.estimates % self.sigma_every == 0:
            loads = tr.loads(step.reaction_list())  # the reactions solved for the messages above
            for w in self.messages.wrenches:
                fx, fy = (0.0 if c is None else _sigma(loads, c) for c in w.force)
                mz = 0.0 if w.torque is None else _sigma(loads, w.torque)
                msgs.append((sigma(w.key), _wrench(st, w.frame_id, fx, fy, mz), t_ns, False))
        # the foundation's peak a stroke from loads computed at every estimate only
        tr.observe_stroke(loads if self.sigma_every == 1 else None, est)
        msgs.extend(self._strokes())
        events = tr.take_events()
        if events and "events" in self.outputs:
            msgs.extend(("~/events", string({"data": to_json(ev)}), t_ns, False) for ev in events)
        self.sinks.emit_all(msgs)
        self.sinks.tick(None)
        self.estimates += 1
        step.k += 1

    def _strokes(self) -> list[Message]:
        """Return the strokes finished since the last call as ``~/strokes`` messages.

        A JSON object each, stamped with the stroke's end; taken off the tracker's table (a
        long run keeps none). A stroke whose cut's fit is out holds it and those after it back.
        """
        done = self.tracker.strokes.strokes
        held = next((i for i, s in enumerate(done) if s.fit_pending), None)
        if held is not None:
            done = done[:held]
        msgs: list[Message] = [
            (STROKES.key, string({"data": to_json(s.row())}), _ns(s.t_end), False) for s in done
        ]
        self.strokes += len(done)
        del self.tracker.strokes.strokes[: len(done)]
        return msgs

    # -- what it says ----------------------------------------------------------------------
    def rejected(self) -> dict[str, int]:
        """Return every rejection so far by reason: the tracker's and this run's own."""
        out = dict(self.tracker.rejected)
        out.update(self.input_rejected)
        return out

    def stats(self) -> dict:
        """Return the run's figures: inputs, estimates, rejections, CPU and delay a measurement (ms)."""
        cpu, delay = self.cpu, self.delay
        out: dict[str, Any] = {
            "t": self.tracker.t,
            "received": self.received,
            "estimates": self.estimates,
            "rejected": sum(self.rejected().values()) - self.tracker.rejected["gap"],
            "cpu_p50_ms": _percentile_ms(cpu, 50),
            "cpu_p99_ms": _percentile_ms(cpu, 99),
            "delay_p50_ms": _percentile_ms(delay, 50),
            "delay_p99_ms": _percentile_ms(delay, 99),
            "delay_max_ms": delay.max * 1e3 if delay.n else math.nan,
            "process_cpu_ms": (
                (self._process_cpu[1] - self._process_cpu[0]) * 1e3 / max(self.received - 1, 1)
                if self._process_cpu
                else math.nan
            ),
            "sigma_every": self.sigma_every,
            "late": self.late,
            "skipped": self.skipped,
        }
        out.update({f"rejected_{k.replace('-', '_')}": v for k, v in sorted(self.rejected().items())})
        return out

    def summary(self) -> str:
        """Return the run's last line: how it ended, its inputs, its rejections, its CPU and delay."""
        s = self.stats()
        why = self.stop_reason or "end"
        rej = ", ".join(f"{k} {v}" for k, v in sorted(self.rejected().items())) or "none"
        return (
            f"tracking run {'ended' if why == 'end' else 'stopped (' + why + ')'} at t = {s['t']:.6g} s: "
            f"{s['received']} measurements received, {s['estimates']} estimates published, rejected: {rej}; "
            f"CPU a measurement p50 {s['cpu_p50_ms']:.3g} ms, p99 {s['cpu_p99_ms']:.3g} ms (the process's "
            f"{s['process_cpu_ms']:.3g} ms); published after "
            f"its arrival p50 {s['delay_p50_ms']:.3g} ms, p99 {s['delay_p99_ms']:.3g} ms, max "
            f"{s['delay_max_ms']:.3g} ms, {s['late']} estimates over "
            f"{self.late_after * 1e3:g} ms, {s['skipped']} taken but not published (over "
            f"{self.max_behind:g} s behind); loads' 1-sigma every "
            f"{self.sigma_every} estimate(s)"
        )

    def status(self) -> dict:
        """Return the ``NAME: tracking input`` status.

        WARN where inputs were rejected since the last status, or the source is silent.
        """
        rej = self.rejected()
        gaps = rej.pop("gap", 0)
        total = sum(rej.values())
        new = self._window.since(
            rejected=total, estimates=self.estimates, late=self.late, skipped=self.skipped
        )
        level = diagnostics.OK
        msg = f"{self.estimates} estimates from {self.received} measurements, {total} rejected"
        if new["skipped"]:
            level = diagnostics.WARN
            msg = (
                f"behind the press: {new['skipped']} estimates not published since the last report "
                f"(taken over {self.max_behind:g} s after their measurement arrived); " + msg
            )
        if new["late"]:
            level = diagnostics.WARN
            msg = (
                f"cannot keep up: {new['late']} of {new['estimates']} estimates out more than "
                f"{self.late_after * 1e3:g} ms after their measurement arrived since the last report "
                f"(track_sigma_every {self.sigma_every}: raise it to compute the loads' 1-sigma less often); "
                + msg
            )
        if new["rejected"]:
            level = diagnostics.WARN
            msg = f"{new['rejected']} rejected since the last report; " + msg
        if self._silent:
            level = diagnostics.WARN
            msg = f"no measurement for over {self.timeout:g} s; " + msg
        values: dict[str, Any] = {
            "estimates": self.estimates,
            "received": self.received,
            "gaps": gaps,
            "late estimates": self.late,
            "estimates not published": self.skipped,
        }
        values.update({f"rejected {k}": v for k, v in sorted(rej.items())})
        s = self.stats()
        for k in (
            "cpu_p50_ms",
            "cpu_p99_ms",
            "delay_p50_ms",
            "delay_p99_ms",
            "delay_max_ms",
        ):
            values[k] = s[k]
        return diagnostics.status(level, f"{self.name}: tracking input", msg, self.hardware, values)

    def statuses(self) -> list[dict]:
        """Return the run's own statuses: its inputs' and the machine's (``NAME: tracking``)."""
        return [
            self.status(),
            diagnostics.tracking(self.monitor.status, f"{self.name}: tracking", self.hardware),
        ]

    def publish_diagnostics(self) -> None:
        """Hand ``/diagnostics`` (the tracking input's status and the sinks') to every sink."""
        if "diagnostics" not in self.outputs:
            return
        from ..wire.cdr import encoder

        with self._lock:
            t_ns = _ns(self.tracker.t)
            statuses = [*self.statuses(), *self.sinks.statuses(self.name, self.hardware)]
            data = encoder("diagnostic_msgs/msg/DiagnosticArray")(diagnostics.array(t_ns, statuses))
            self.sinks.emit_all([("/diagnostics", data, t_ns, False)])


def _wrench(st: dict, frame_id: str, fx: float, fy: float, mz: float) -> bytes:
    """Return a WrenchStamped's bytes at stamp ``st``: force (fx, fy, 0), torque (0, 0, mz)."""
    return planar_wrench(st["sec"], st["nanosec"], frame_id, fx, fy, mz)


def _sigma(loads: dict[str, tuple[float, float]], column: str) -> float:
    """Return a load's 1-σ (0 for a column the tracker does not estimate)."""
    return float(loads[column][1]) if column in LOAD_COLUMNS else 0.0
