"""``mps emulate`` and ``mps track``: a press to follow, and the tracker over its measurements.

    mps emulate SCENE --csv FILE [--t-end S] [--seed N] [--slider] [--motor-torque]
                      [--fault T:KIND ...] [--truth FILE] [--force]
    mps track SCENE (--csv FILE | --recording FILE.mcap|BAG | --against-truth S)
                    [--joints-topic TOPIC] [--mode-topic TOPIC] [--out FILE.csv] [--out FILE.mcap]
                    [--strokes FILE] [--loads] [--prediction jacobian|unscented] [--seed N] [--force]

``mps emulate`` runs SCENE's *truth* (:func:`~mps_core.track.truth.truth_scene`: masses, friction,
part and motor off the nominal) and writes what the press's sensors read
(:mod:`~mps_core.track.measurement_csv`): a 17-bit encoder at 1 kHz with jittered stamps,
optionally the slider's scale and the motor's torque, the mode signals; ``--truth`` writes the
truth's own record beside it. ``mps track`` follows SCENE (the nominal press) over such a file,
or over a recording of the press's topics (:mod:`~mps_core.track.recording_input`: a node's that
followed a press, read in its order), and writes the estimates (one row a measurement taken,
each with its 1-σ, and the ``tracking`` status then: :mod:`~mps_core.track.diagnostics`), the
per-stroke table, and with ``--out FILE.mcap`` a recording of the measured and estimated topics
(:mod:`~mps_core.track.recording`, written by the package registered for it); it prints each
change of the tracking status.
``--against-truth S`` emulates S seconds itself and prints how the estimates compare with
the truth (the tables of docs/tracking.md).
"""

from __future__ import annotations

import argparse
import csv
import math
import signal
import sys
import time
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np

from ..errors import Interrupted
from ..run.progress import Progress
from .diagnostics import TrackingMonitor
from .measurements import Measurement, MeasurementError, ModeSignal, TorqueSensor
from .recording import TrackRecording
from .recording_input import (
    JOINTS_TOPIC,
    MODE_TOPIC,
    Input,
    Tuning,
    in_time_order,
    recording_variances,
    split_inputs,
)
from .settings import PREDICTIONS, SIGNAL_LATENCY, TrackSettings
from .tracker import KEEP_INNOVATIONS, LOAD_COLUMNS, Tracker

if TYPE_CHECKING:
    from .fit_process import CutFits

__all__ = ["register"]

#: the estimates' columns (besides the loads' value and 1-σ with --loads)
ESTIMATE_COLUMNS = (
    "t",
    "structure",
    "phi",
    "phi_sigma",
    "phi_dot",
    "phi_dot_sigma",
    "x_C",
    "x_C_sigma",
    "force",
    "force_sigma",
    "torque",
    "torque_sigma",
    "work",
    "work_sigma",
    "force_smoothed",
    "force_smoothed_sigma",
    "t_force_smoothed",
)


def register(subparsers: Any) -> None:
    """Add ``emulate`` and ``track`` to the ``mps`` command line."""
    e = subparsers.add_parser("emulate", help="what a press's sensors read: a truth scene run and sampled")
    e.add_argument("scene", help="the nominal press: preset name or scene file (its truth is run)")
    e.add_argument("--csv", metavar="FILE", required=True, help="write the measurements to FILE")
    e.add_argument("--t-end", type=float, default=0.5, metavar="S", help="seconds to run (0.5)")
    e.add_argument("--seed", type=int, default=0, help="the noise's and the jitter's seed")
    e.add_argument("--slider", action="store_true", help="a linear scale on the slider too")
    e.add_argument("--motor-torque", action="store_true", help="the motor's torque too")
    e.add_argument(
        "--fault", action="append", default=[], metavar="T:KIND", help="inject a fault at T s (repeatable)"
    )
    e.add_argument(
        "--signals-late",
        type=float,
        default=0.0,
        metavar="S",
        help="stamp the mode signals S seconds after their commands took effect (a controller's latency)",
    )
    e.add_argument("--truth", metavar="FILE", help="write the truth's record to FILE")
    e.add_argument("--force", action="store_true", help="replace output files that exist")
    e.set_defaults(func=_emulate)

    t = subparsers.add_parser("track", help="follow a press from its measurements (offline)")
    t.add_argument("scene", help="the nominal press: preset name or scene file")
    src = t.add_mutually_exclusive_group(required=True)
    src.add_argument("--csv", metavar="FILE", help="the measurements (mps emulate --csv)")
    src.add_argument(
        "--recording",
        metavar="FILE.mcap|BAG",
        help="the measurements and mode signals of a recording (an MCAP file or a bag directory: "
        "a node's that followed a press), taken in its order",
    )
    src.add_argument(
        "--against-truth", type=float, metavar="S", help="emulate S seconds and compare with the truth"
    )
    t.add_argument(
        "--out",
        metavar="FILE",
        action="append",
        default=[],
        help="FILE.csv: write the estimates; FILE.mcap: write a recording of the measured and estimated "
        "topics, as the node records its own (with the loads); once each",
    )
    t.add_argument(
        "--joints-topic",
        metavar="TOPIC",
        default=JOINTS_TOPIC,
        help=f"--recording: the measurements' sensor_msgs/msg/JointState topic (joint crank, rad; "
        f"optionally slider, m; at the header's stamp) ({JOINTS_TOPIC})",
    )
    t.add_argument(
        "--mode-topic",
        metavar="TOPIC",
        help=f"--recording: the mode signals' std_msgs/msg/String topic, at their log time "
        f"({MODE_TOPIC} where recorded; '' for none)",
    )
    t.add_argument("--strokes", metavar="FILE", help="write the per-stroke table to FILE")
    t.add_argument(
        "--loads",
        action="store_true",
        help="the reactions and foundation load at every step (the smoother's, two steps back, at t_loads)",
    )
    t.add_argument(
        "--sigma-every",
        type=int,
        default=1,
        metavar="N",
        help="the loads' 1-sigma at every N-th measurement (1: at each; the node's track_sigma_every); "
        "the others NaN in --out FILE.csv and left out of a recording's sigma topics",
    )
    t.add_argument("--prediction", choices=PREDICTIONS, default="jacobian", help="how P is predicted")
    t.add_argument(
        "--no-fit-cuts",
        action="store_true",
        help="no stroke's cut fitted whole (its peak force the filter's; docs/tracking.md)",
    )
    t.add_argument(
        "--signal-latency",
        type=float,
        default=None,
        metavar="S",
        help="how late a mode signal may come after its command took effect (s): its command is searched "
        f"for over that window (0: applied at its stamp; {SIGNAL_LATENCY:g} unless a recording records "
        "the node's)",
    )
    t.add_argument("--seed", type=int, default=0, help="--against-truth: the noise's seed")
    t.add_argument(
        "--motor-torque",
        action="store_true",
        help="--against-truth: the emulated press measures its motor's torque too (as mps emulate does)",
    )
    t.add_argument("--force", action="store_true", help="replace output files that exist")
    t.set_defaults(func=_track)


def _nominal(spec: str) -> Any:
    """Return the nominal scene of SPEC (:func:`~mps_core.track.truth.nominal_scene`)."""
    from ..scene import load_scene
    from .truth import nominal_scene

    return nominal_scene(load_scene(spec))


def _faults(specs: list[str]) -> tuple:
    """Return the faults of ``--fault T:KIND`` options."""
    from .truth import FAULTS, Fault, timed_kinds

    return tuple(Fault(t, kind) for t, kind in timed_kinds(specs, "--fault", FAULTS))


def _emulate(args: argparse.Namespace) -> int:
    """Run ``mps emulate``."""
    from ..files.outputs import check_outputs, written_whole
    from .measurement_csv import write_measurements
    from .truth import Sensors, run_truth, truth_scene

    check_outputs({"--csv": args.csv, "--truth": args.truth}, inputs=[args.scene], force=args.force)
    if not (math.isfinite(args.signals_late) and 0.0 <= args.signals_late <= 1.0):
        raise MeasurementError("--signals-late", args.signals_late, "a time in [0, 1] s")
    nominal = _nominal(args.scene)
    sensors = Sensors(slider=args.slider, motor_torque=args.motor_torque)
    progress = Progress(0.0, args.t_end, label="mps emulate")
    with _Stop() as stop:  # a first signal ends the emulation where it is: what it made is written
        print(
            f"emulating {args.t_end:.6g} s of {args.scene}'s truth (Ctrl-C: stop, and write what was made)",
            file=sys.stderr,
        )
        try:
            run = run_truth(
                truth_scene(nominal),
                args.t_end,
                sensors=sensors,
                faults=_faults(args.fault),
                seed=args.seed,
                progress=progress,
                stop=lambda: stop.signal is not None,
            )
        finally:
            progress.done()
        modes = [ModeSignal(m.t + args.signals_late, m.command) for m in run.modes]
        written = []
        with written_whole(args.csv) as tmp, tmp.open("w") as fh:
            rows = write_measurements(fh, run.measurements, modes)
        said = f"{len(run.measurements)} measurements, {len(run.modes)} mode signals"
        print(f"wrote {rows} rows ({said}) to {args.csv}")
        written.append(str(args.csv))
        if args.truth:
            with written_whole(args.truth) as tmp, tmp.open("w") as fh:
                _write_truth(fh, run)
            print(f"wrote {len(run.t)} rows of the truth to {args.truth}")
            written.append(str(args.truth))
    if stop.signal is not None:
        reached = float(run.t[-1])
        short = reached < args.t_end - 1e-9
        kept = f"{', '.join(written)} written, " + (
            f"the emulation to t = {reached:.6g} s of {args.t_end:.6g}" if short else "the emulation whole"
        )
        raise Interrupted(stop.signal, kept)
    return 0


def _write_truth(fh: TextIO, run: Any) -> None:
    """Write the truth's record on its fine grid as CSV (``mps emulate --truth``)."""
    w = csv.writer(fh, lineterminator="\n")
    w.writerow(["t", "phi", "phi_dot", "x_C", "force", "F_found_x", "F_found_y", "locked"])
    columns = (run.t, run.phi, run.phi_dot, run.x_C, run.force, run.foundation_x, run.foundation_y)
    for *row, locked in zip(*columns, run.locked):
        w.writerow([repr(float(v)) for v in row] + [str(int(locked))])


def _track(args: argparse.Namespace) -> int:
    """Run ``mps track``."""
    from ..files.outputs import check_outputs

    if args.sigma_every < 1:
        raise MeasurementError("--sigma-every", args.sigma_every, "a whole number of measurements, 1 or more")
    if args.sigma_every != 1 and args.against_truth is not None:
        raise MeasurementError(
            "--sigma-every", args.sigma_every, "1 with --against-truth (its loads' 1-sigma at each)"
        )
    args.out, args.out_recording = _outs(args.out)
    check_outputs(
        {"--out": args.out, "--out (recording)": args.out_recording, "--strokes": args.strokes},
        inputs=[args.scene, args.csv, args.recording],
        force=args.force,
    )
    nominal = _nominal(args.scene)
    if args.against_truth is not None:
        return _against_truth(args, nominal)
    fits = None
    if not args.no_fit_cuts:  # on the second core, started now: it makes its model meanwhile
        from .fit_process import CutFits

        fits = CutFits(nominal, TrackSettings(), lambda level, text: print(text, file=sys.stderr))
        fits.start()
    with _Stop() as stop:  # through the writing too: a first signal there lets it finish
        try:
            tracker, rows, cpu, monitor, recording = _follow_inputs(args, nominal, fits, stop)
        finally:
            if fits is not None:
                fits.close()
        partial = where = None
        if stop.signal is not None and len(cpu) < stop.total:
            reached = f"t = {tracker.t:.6g} s" if tracker.started else "the first measurement"
            where = f"followed to {reached}, {len(cpu)} of {stop.total} measurements"
            partial = f"{where}: interrupted ({stop.signal})"
        written = _write(args, tracker, rows, partial)
        if recording is not None:
            from .recording import write_recording

            recording.events = tracker.take_events()
            recording.statuses = list(monitor.events)
            recording.strokes = list(tracker.strokes.strokes)
            if partial is not None:
                recording.metadata["partial"] = partial
            n = write_recording(args.out_recording, recording)
            print(f"wrote {n} messages ({len(recording.steps)} estimates) to {args.out_recording}")
            written.append(str(args.out_recording))
        _summary(tracker, cpu, monitor)
    if stop.signal is not None:
        files = ", ".join(written)
        if partial is None:
            done = f"{files} written whole" if files else "nothing asked to be written"
            kept = f"{done} (the signal came after the last measurement)"
        else:
            kept = (
                f"{files} written, marked partial ({where})"
                if files
                else f"nothing asked to be written ({where})"
            )
        raise Interrupted(stop.signal, kept)
    return 0


class _Stop:
    """Ctrl-C (SIGINT) or SIGTERM while ``mps track`` follows its measurements or writes what it
    followed: the first stops the following before the next measurement (what was followed is
    written, marked partial) and lets the writing finish; a second ends the command at once (an
    output not finished is not written). A signal ignored where the command started (a
    background job's SIGINT) stays ignored; off the main thread nothing is taken."""

    def __init__(self) -> None:
        #: the first signal's name, once one came
        self.signal: str | None = None
        #: the measurements there were to follow
        self.total = 0
        self._old: dict[int, Any] = {}

    def __enter__(self) -> _Stop:
        import threading

        if threading.current_thread() is not threading.main_thread():
            return self  # signals are the main thread's to take
        for s in (signal.SIGINT, signal.SIGTERM):
            if signal.getsignal(s) is not signal.SIG_IGN:
                self._old[s] = signal.signal(s, self._on)
        return self

    def _on(self, signum: int, _frame: object) -> None:
        name = signal.Signals(signum).name
        if self.signal is not None:
            raise Interrupted(name)
        self.signal = name

    def __exit__(self, *exc: object) -> None:
        for s, handler in self._old.items():
            signal.signal(s, handler)


def _follow_inputs(
    args: argparse.Namespace, nominal: Any, fits: CutFits | None, stop: _Stop | None = None
) -> tuple:
    """Follow the press of ``--csv`` or ``--recording`` (its cuts fitted by ``fits`` where given;
    stopped by ``stop``'s signal where one comes); return the tracker, the estimates' rows, the
    CPU of each measurement, the tracking status and the recording gathered (None unless asked
    for)."""
    inputs, measurements, modes, tuning = _inputs(args)
    if stop is not None:
        stop.total = len(measurements)
    tracker = Tracker(nominal, _settings(args, bool(modes), tuning))
    tracker.keep_innovations = KEEP_INNOVATIONS  # a long recording: the status reads them as they come
    args.loads = args.loads or args.out_recording is not None
    monitor = TrackingMonitor()
    recording = None
    if args.out_recording is not None:
        recording = TrackRecording(nominal, measurements=measurements, modes=modes)
        recording.metadata = {
            "source": "mps track",
            "measurements": str(args.csv or args.recording),
            "prediction": args.prediction,
        }
    if fits is not None:
        fits.attach(tracker)
    span = f", {measurements[-1].t - measurements[0].t:.6g} s of the press" if measurements else ""
    print(
        f"following {len(measurements)} measurements{span} (Ctrl-C: stop, and write what was followed)",
        file=sys.stderr,
    )
    rows, cpu = _follow(tracker, inputs, args.loads, monitor, recording, fits, stop, args.sigma_every)
    if fits is not None:
        fits.finish(tracker)
    return tracker, rows, cpu, monitor, recording


def _outs(outs: list[str]) -> tuple[str | None, str | None]:
    """Return the estimates' CSV and the recording among the ``--out`` files (None where not asked)."""
    csv_out = [o for o in outs if not o.lower().endswith(".mcap")]
    mcap_out = [o for o in outs if o.lower().endswith(".mcap")]
    for kind, given in (("FILE.csv (the estimates)", csv_out), ("FILE.mcap (a recording)", mcap_out)):
        if len(given) > 1:
            raise MeasurementError("--out", ", ".join(given), f"at most one {kind}")
    return (csv_out[0] if csv_out else None), (mcap_out[0] if mcap_out else None)


def _inputs(args: argparse.Namespace) -> tuple[list[Input], list[Measurement], list[ModeSignal], Tuning]:
    """Return the tracker's inputs in the order it takes them, the measurements and mode signals
    among them, of ``--csv`` or ``--recording``, and the tuning it records (a CSV's: the defaults)."""
    if args.recording is not None:
        from .recording_input import RecordedTopics, read_recording_inputs

        mode = MODE_TOPIC if args.mode_topic is None else (args.mode_topic or None)
        topics = RecordedTopics(args.joints_topic, mode, mode_required=args.mode_topic is not None)
        inputs = read_recording_inputs(args.recording, topics)
        return (inputs, *split_inputs(inputs), inputs.tuning)
    if args.joints_topic != JOINTS_TOPIC or args.mode_topic is not None:
        given = "--joints-topic" if args.joints_topic != JOINTS_TOPIC else "--mode-topic"
        raise MeasurementError(
            given,
            args.joints_topic if given == "--joints-topic" else args.mode_topic,
            "--recording FILE with it (a CSV names no topics)",
        )
    from .measurement_csv import read_measurements

    # the crank's, the slider's and the torque's as the node takes them (one press, one set of sensors)
    variances: dict[str, float | Callable[[float], float]] = {
        **recording_variances(),
        "crank_rate": 1e-4,
        "motor_torque": TorqueSensor().variance,
    }
    measurements, modes = read_measurements(args.csv, variances)
    return in_time_order(measurements, modes), measurements, modes, Tuning()


def _follow(
    tracker: Tracker,
    inputs: Iterable[Input],
    loads: bool,
    monitor: TrackingMonitor,
    recording: TrackRecording | None = None,
    fits: CutFits | None = None,
    stop: _Stop | None = None,
    sigma_every: int = 1,
) -> tuple[list[dict], np.ndarray]:
    """Run the tracker over the measurements and mode signals in their order, watched by
    ``monitor`` (and gathered into ``recording``), its cuts fitted by ``fits`` where given, up
    to the end or to ``stop``'s signal; return the estimates' rows and the CPU time of each
    measurement taken (this process's). ``loads``: the smoother's loads at each measurement,
    their 1-σ at every ``sigma_every``-th (the strokes' own foundation peak from them where that
    is each, as the node's)."""
    inputs = list(inputs)
    times = [m.t for m in inputs]
    progress = Progress(min(times, default=0.0), max(times, default=0.0), label="mps track")
    rows: list[dict] = []
    cpu: list[float] = []
    for m in inputs:
        if stop is not None and stop.signal is not None:
            break
        progress(m.t)
        if isinstance(m, ModeSignal):
            tracker.mode(m)
            continue
        c0 = time.process_time()
        taken = tracker.update(m)
        if fits is not None:
            fits.submit(tracker)
            fits.poll(tracker)
        smoothed = tracker.smoothed_loads(sigma=len(cpu) % sigma_every == 0) if loads else None
        est = tracker.estimate()  # one for the stroke table, the status and the row
        tracker.observe_stroke(None if smoothed is None or sigma_every != 1 else smoothed[1], est)
        status = monitor.observe(tracker, m, est)
        cpu.append(time.process_time() - c0)
        if recording is not None and smoothed is not None:
            recording.add_loads(*smoothed)
        if taken:
            row: dict[str, Any] = {c: getattr(est, c) for c in ESTIMATE_COLUMNS}
            row["tracking"] = status.level
            if smoothed is not None:
                row["t_loads"] = smoothed[0]
                for name, (v, s) in smoothed[1].items():
                    row[name], row[name + "_sigma"] = v, s
            rows.append(row)
            if recording is not None:
                recording.add(tracker, {k: v for k, v in row.items() if isinstance(v, float)}, status)
    progress.done()
    return rows, np.asarray(cpu)


def _write(
    args: argparse.Namespace, tracker: Tracker, rows: list[dict], partial: str | None = None
) -> list[str]:
    """Write the estimates (``--out``) and the per-stroke table (``--strokes``); return the files
    written. ``partial``: the following stopped short (why and where), said in each file's last
    line (``# partial: ...``, as ``mps run`` marks its CSV)."""
    from ..files.outputs import written_whole

    written = []
    note = "" if partial is None else f"# partial: {partial}\n"
    if args.out:
        columns = [*ESTIMATE_COLUMNS, "tracking"]
        if args.loads:
            columns += ["t_loads"] + [c + s for c in LOAD_COLUMNS for s in ("", "_sigma")]
        with written_whole(args.out) as tmp, tmp.open("w") as fh:
            _table(fh, columns, rows)
            fh.write(note)
        print(f"wrote {len(rows)} estimates to {args.out}")
        written.append(str(args.out))
    if args.strokes:
        strokes = [s.row() for s in tracker.strokes.strokes]
        with written_whole(args.strokes) as tmp, tmp.open("w") as fh:
            _table(fh, list(strokes[0]) if strokes else ["stroke"], strokes)
            fh.write(note)
        print(f"wrote {len(strokes)} strokes to {args.strokes}")
        written.append(str(args.strokes))
    return written


def _table(fh: TextIO, columns: list[str], rows: list[dict]) -> None:
    """Write rows as CSV under a header of ``columns``."""
    w = csv.DictWriter(fh, fieldnames=columns, lineterminator="\n", extrasaction="ignore")
    w.writeheader()
    for r in rows:
        w.writerow({k: (repr(float(v)) if isinstance(v, float) else v) for k, v in r.items()})


def _summary(tracker: Tracker, cpu: np.ndarray, monitor: TrackingMonitor | None = None) -> None:
    """Print what was taken and rejected, the CPU a measurement, the tracking status's changes
    and the per-stroke table."""
    rejected = ", ".join(f"{k} {v}" for k, v in sorted(tracker.rejected.items())) or "none"
    print(f"measurements: {tracker.accepted} taken; rejected or reported: {rejected}")
    if len(cpu):
        us = cpu * 1e6
        print(
            f"CPU per measurement: median {np.median(us):.0f} us, p99 {np.percentile(us, 99):.0f} us, "
            f"max {us.max():.0f} us ({len(cpu)} measurements)"
        )
    if tracker.acquired:
        print(
            f"the crank acquired again {tracker.acquired} times, the model off it by more than its "
            "covariance allowed (the first measurement, after a gap, or latch open after angles "
            "rejected running)"
        )
    if tracker.inferred:
        said = ", ".join(f"{name} {n}" for name, n in sorted(tracker.inferred.items()))
        print(f"modes followed from the slider scale (no mode signal): {said}")
    if tracker.slider_acquired:
        print(
            f"the slider acquired again {tracker.slider_acquired} times, latch open after its positions "
            "rejected running"
        )
    if tracker.cuts_fitted or tracker.cuts_unfitted or tracker.cuts_without_part:
        print(
            f"cuts fitted whole: {tracker.cuts_fitted}"
            + (f", {tracker.cuts_unfitted} not (the filter's peak kept)" if tracker.cuts_unfitted else "")
            + (f", {tracker.cuts_without_part} with no part's work" if tracker.cuts_without_part else "")
            + (f"; the part: {_part_line(tracker)}" if tracker.cuts_fitted else "")
        )
    if tracker.restarted:
        print(
            f"the model's run started again {tracker.restarted} times (its state had no configuration "
            "to go on from: see the tracker-restart events)"
        )
    timing = tracker.timing
    if timing is not None and timing.shifts:
        said = ", ".join(f"{1e3 * d:.2f}" for d in timing.shifts[:8]) + (
            " ..." if len(timing.shifts) > 8 else ""
        )
        print(
            f"mode signals: {timing.searched}, their commands found (ms before their stamps) {said} "
            f"({timing.tried} hypotheses tried"
            + (
                f", the longest search {1e3 * max(f.cpu for f in timing.found):.1f} ms of CPU"
                if timing.tried
                else ""
            )
            + ")"
        )
    if tracker.motor_measured:
        est = tracker.estimate()
        print(
            f"the motor's torque: {100 * est.motor_scale:+.2f} ± {100 * est.motor_scale_sigma:.2f} % "
            "off its catalogue's characteristic"
        )
    if monitor is not None:
        changes = [s for s in monitor.events if s.level != "OK"]
        if not changes:
            print(f"tracking OK throughout ({monitor.status.message})")
        for change in monitor.events[1:] if changes else ():
            print(f"t = {change.t:.4f} s: {change.line()}")
    print("stroke  peak force (kN)  (the filter's)      work (J)         peak foundation (kN)  tracking")
    for s in tracker.strokes.strokes:
        found = "-"
        if math.isfinite(s.peak_foundation):
            found = f"{s.peak_foundation / 1e3:7.2f} ± {s.peak_foundation_sigma / 1e3:5.2f}"
        filtered = f"{s.filter_peak_force / 1e3:7.2f} ± {s.filter_peak_force_sigma / 1e3:5.2f}"
        print(
            f"{s.index:6d}  {s.peak_force / 1e3:7.2f} ± {s.peak_force_sigma / 1e3:5.2f}  "
            f"({filtered if s.fit is not None else 'the same':>16})   "
            f"{s.work:6.2f} ± {s.work_sigma:5.2f}   {found:<18}  {s.tracking}"
        )


def _part_line(tracker: Tracker) -> str:
    """Return the last fitted cut's part: its contact and breakthrough depth."""
    fit = next((s.fit for s in reversed(tracker.strokes.strokes) if s.fit is not None), None)
    if fit is None:
        return "its strokes not closed yet"
    return (
        f"contact at x_C = {1e3 * fit.contact:.3f} ± {1e3 * fit.contact_sigma:.3f} mm, breaking through "
        f"{1e3 * fit.depth:.3f} ± {1e3 * fit.depth_sigma:.3f} mm below (the last stroke's)"
    )


def _settings(args: argparse.Namespace, signals: bool, tuning: Tuning | None = None) -> TrackSettings:
    """Return the tracker's settings of ``mps track``'s arguments (``signals``: whether mode signals come).

    ``tuning``: a recording's own (the node's parameters it records), where it has them; the
    signals' latency as given (``--signal-latency``) before the recording's.
    """
    tuning = tuning or Tuning()
    latency = args.signal_latency
    if latency is None:
        latency = SIGNAL_LATENCY if tuning.signal_latency is None else tuning.signal_latency
    if not (math.isfinite(latency) and 0.0 <= latency <= 0.1):
        raise MeasurementError("--signal-latency", latency, "a time in [0, 0.1] s")
    return tuning.settings(
        prediction=args.prediction, signal_latency=latency if signals else 0.0, fit_cuts=not args.no_fit_cuts
    )


def _against_truth(args: argparse.Namespace, nominal: Any) -> int:
    """Emulate the truth, follow it, and print how the estimates compare with it."""
    from .evaluation import follow, nis_inside, truth_strokes
    from .truth import Sensors, run_truth, truth_scene

    sensors = Sensors(motor_torque=args.motor_torque)
    progress = Progress(0.0, args.against_truth, label="mps track: the truth")  # on a terminal only
    try:
        truth = run_truth(
            truth_scene(nominal), args.against_truth, sensors=sensors, seed=args.seed, progress=progress
        )
    finally:
        progress.done()
    tracker = Tracker(nominal, _settings(args, bool(truth.modes)))
    f = follow(tracker, truth, loads=args.loads)
    _summary(tracker, np.asarray(f.cpu))
    print(
        f"consistency: NEES inside its 95 % bound {f.nees_inside():.3f}, NIS {nis_inside(tracker):.3f}; "
        f"1-sigma covers the truth {f.coverage():.3f}"
        + (
            f"; foundation RMS error {100 * f.foundation_rms_fraction():.2f} % of its peak"
            if args.loads
            else ""
        )
    )
    true = truth_strokes(truth)
    print(
        "stroke  peak force err (%)  (the filter's, %)  (truth's peak step average, %)  work err (%)  "
        "peak foundation err (%)  (the filter's, %)   (complete strokes)"
    )
    for s in tracker.strokes.strokes:
        t = true.get(s.index)
        if t is None or not t["complete"]:
            continue
        found = 100 * (s.peak_foundation / t["peak_foundation_N"] - 1)
        found_filter = math.nan
        if args.loads:
            found_filter = 100 * (s.filter_peak_foundation / t["peak_foundation_N"] - 1)
        resolvable = 100 * (t["peak_step_average_N"] / t["peak_force_N"] - 1)
        print(
            f"{s.index:6d}  {100 * (s.peak_force / t['peak_force_N'] - 1):+18.2f}  "
            f"{100 * (s.filter_peak_force / t['peak_force_N'] - 1):+17.1f}  {resolvable:+30.1f}  "
            f"{100 * (s.work / t['work_J'] - 1):+12.1f}  {found:+22.1f}  {found_filter:+17.1f}"
        )
    if tracker.fallbacks:
        print(f"unscented prediction: {tracker.fallbacks} steps by the Jacobian", file=sys.stderr)
    return 0
