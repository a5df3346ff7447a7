"""A tracked run as a recording: ``mps track --out FILE.mcap``.

The entry point ``mcap`` of the group ``mps.track_writers``, which
:mod:`mps_core.track.recording` calls.

The file is the twin's recording (:mod:`mps_ros.recording.recorder`: the same writer, profile,
schemas, channels and metadata records), the messages those the node publishes, estimated:
``/clock``, ``/tf_static`` and ``/tf``, ``/joint_states`` (the efforts from the estimated
reactions), each reaction's and the foundation's WrenchStamped, ``~/structure`` (latched: at
its changes), ``~/events`` (the model's events, JSON), ``/diagnostics`` (the ``tracking`` status
at each of its changes and every second); and beside them (:mod:`mps_ros.wire.track_topics`) the
measurements on ``/press/joint_states`` and ``/press/mode`` at their stamps, the 1-σ of each
estimated topic on ``TOPIC/sigma``, the process force and the load torque, the strokes. No
``~/markers``: the view draws the press from the joint states.

**Time.** A step is an estimate (a measurement taken), at the measurement's stamp (the press's
clock, ns from t = 0). Its reactions are the fixed-lag smoother's for that time, which it gives
``force_lag`` measurements later; the steps the smoother gave no loads for (the last
``force_lag``, and one where the chart restarted its lags) are left out of the estimated topics, so
that every step read back has its joint states and its reactions together.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..wire import diagnostics
from ..wire.cdr import Preset, encoder, generic_encoder, planar_wrench
from ..wire.frames import MSGTYPE as _TF
from ..wire.frames import TfLayout
from ..wire.json_text import to_json
from ..wire.topics import BY_KEY, FOUNDATION, FRAME_ID, JOINT_NAMES, WRENCHES, offered_qos, qos_yaml, resolve
from ..wire.track_topics import (
    LOAD_TORQUE,
    MEASURED_JOINTS,
    MEASURED_MODE,
    PROCESS_FORCE,
    STROKES,
    TRACKING_STATUS,
    sigma,
)
from .recorder import Recorder

if TYPE_CHECKING:
    from mps_core.track.recording import TrackRecording

__all__ = ["write"]

#: the diagnostics period (s of the press's clock)
PERIOD = 1.0
_WRENCH = "geometry_msgs/msg/WrenchStamped"
_JOINTS = "sensor_msgs/msg/JointState"
_STRING = "std_msgs/msg/String"
NAN = math.nan


def _ns(t: float) -> int:
    """Return a time (s) in ns."""
    return int(round(t * 1e9))


def _sec_nsec(t: float) -> tuple[int, int]:
    """Return a time (s) as builtin_interfaces/Time's (sec, nanosec)."""
    return divmod(_ns(t), 1_000_000_000)


def _stamp(t: float) -> dict[str, int]:
    """Return builtin_interfaces/Time of a time (s)."""
    sec, nsec = _sec_nsec(t)
    return {"sec": sec, "nanosec": nsec}


class _Messages:
    """The recording's messages gathered by time, then written in time order."""

    def __init__(self) -> None:
        self.items: list[tuple[int, int, str, str, bytes]] = []

    def add(self, key: str, msgtype: str, msg: dict[str, Any], t: float) -> None:
        """Add one message (topic key, type, message dict) at time ``t`` (s)."""
        self.items.append((_ns(t), len(self.items), key, msgtype, encoder(msgtype)(msg)))

    def add_bytes(self, key: str, msgtype: str, data: bytes, t: float) -> None:
        """Add one message already encoded at time ``t`` (s)."""
        self.items.append((_ns(t), len(self.items), key, msgtype, data))


class _Packed:
    """The estimated topics' messages of fixed layout: ``/tf``, the joint states, the wrenches.

    Made as the node makes its own: each layout encoded once, then a message is one ``struct``
    call (:class:`~mps_ros.wire.cdr.Preset`: the bytes of the message dict encoded)."""

    def __init__(self, tf: TfLayout) -> None:
        self._tf = Preset(generic_encoder(_TF), tf.message, tf.nfloats).pack
        self._joints: dict[tuple[int, int, int], Any] = {}

    def tf(self, t: float, values: list) -> bytes:
        """Return ``/tf``'s message at ``t`` with the frames' ``values``."""
        return self._tf(*_sec_nsec(t), values)

    def wrench(self, t: float, frame_id: str, fx: float, fy: float, mz: float) -> bytes:
        """Return a WrenchStamped's bytes at ``t`` (:func:`~mps_ros.wire.cdr.planar_wrench`)."""
        return planar_wrench(*_sec_nsec(t), frame_id, fx, fy, mz)

    def joints(self, t: float, positions: Any, velocities: Any, effort: Any) -> bytes:
        """Return :func:`_joints`'s message, encoded."""
        values = [float(v) for v in (*positions, *velocities, *effort)]
        layout = (len(positions), len(velocities), len(effort))
        pack = self._joints.get(layout)
        if pack is None:
            n_p, n_v, _n_e = layout

            def make(stamp: dict, f: Any) -> dict[str, Any]:
                return _joints(stamp, f[:n_p], f[n_p : n_p + n_v], f[n_p + n_v :])

            pack = self._joints[layout] = Preset(encoder(_JOINTS), make, len(values)).pack
        return pack(*_sec_nsec(t), values)


def write(path: Path, rec: TrackRecording) -> int:
    """Write the tracked run ``rec`` to the MCAP file ``path``; return the messages written.

    The file is written whole: under a temporary name beside it, renamed once finished.
    """
    msgs = _Messages()
    _estimated(msgs, rec)
    _measured(msgs, rec)
    msgs.items.sort(key=lambda m: (m[0], m[1]))
    qos = offered_qos()
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.partial{path.suffix}")
    meta = dict(rec.metadata)
    meta["time"] = "the press's clock: the measurements' stamps, ns from t = 0"
    try:
        with Recorder(
            tmp, scene_name=rec.scene.name, scene_text=rec.scene.text, metadata=meta, file_name=path.name
        ) as recorder:
            channels: dict[str, tuple[str, str]] = {}  # each key's topic and QoS, made once
            for t_ns, _order, key, msgtype, data in msgs.items:
                channel = channels.get(key)
                if channel is None:
                    channel = channels[key] = (resolve(key), qos.get(key) or qos_yaml())
                recorder.write(channel[0], msgtype, data, t_ns, channel[1])
            written = recorder.messages
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return written


def _estimated(msgs: _Messages, rec: TrackRecording) -> None:
    """Add the estimated topics: each step with its loads, the events, statuses and strokes."""
    tf = TfLayout.of_scene(rec.scene)
    packed = _Packed(tf)
    structure = None
    next_diagnostics = -math.inf
    first = True
    for step in rec.steps:
        loads = rec.loads.get(step.t)
        if loads is None:
            continue
        t, e = step.t, step.estimate
        msgs.add("/clock", "rosgraph_msgs/msg/Clock", {"clock": _stamp(t)}, t)
        if first:
            msgs.add("/tf_static", "tf2_msgs/msg/TFMessage", tf.static_message(_stamp(t)), t)
            first = False
        phi, _rod, psi, x_c = step.positions
        msgs.add_bytes("/tf", _TF, packed.tf(t, tf.values(phi, psi, x_c)), t)
        value = {c: v for c, (v, _s) in loads.items()}
        sd = {c: s for c, (_v, s) in loads.items()}
        effort = [value["M_motor"], NAN, value["M_latch"], value["F_stop"]]
        msgs.add_bytes("joint_states", _JOINTS, packed.joints(t, step.positions, step.velocities, effort), t)
        pos_sd = (e["phi_sigma"], NAN, NAN, e["x_C_sigma"])
        vel_sd = (e["phi_dot_sigma"], NAN, NAN, NAN)
        msgs.add_bytes(sigma("joint_states"), _JOINTS, packed.joints(t, pos_sd, vel_sd, []), t)
        with_sigma = not math.isnan(sd["F_found_x"])  # the loads' 1-σ at this step (mps track --sigma-every)
        for w in (*WRENCHES, FOUNDATION):
            for key, of in ((w.key, value), (sigma(w.key), sd)) if with_sigma else ((w.key, value),):
                fx, fy = (0.0 if c is None else float(of[c]) for c in w.force)
                mz = 0.0 if w.torque is None else float(of[w.torque])
                msgs.add_bytes(key, _WRENCH, packed.wrench(t, w.frame_id, fx, fy, mz), t)
        if step.structure != structure:
            structure = step.structure
            msgs.add("~/structure", _STRING, {"data": structure}, t)
        t_f = e["t_force_smoothed"]
        msgs.add_bytes(
            PROCESS_FORCE.key, _WRENCH, packed.wrench(t_f, "press_C", e["force_smoothed"], 0.0, 0.0), t
        )
        msgs.add_bytes(
            sigma(PROCESS_FORCE.key),
            _WRENCH,
            packed.wrench(t_f, "press_C", e["force_smoothed_sigma"], 0.0, 0.0),
            t,
        )
        msgs.add_bytes(LOAD_TORQUE.key, _WRENCH, packed.wrench(t, FRAME_ID, 0.0, 0.0, e["torque"]), t)
        msgs.add_bytes(
            sigma(LOAD_TORQUE.key), _WRENCH, packed.wrench(t, FRAME_ID, 0.0, 0.0, e["torque_sigma"]), t
        )
        if t >= next_diagnostics:
            _status(msgs, rec, step.status, t)
            next_diagnostics = t + PERIOD
    for change in rec.statuses:
        _status(msgs, rec, change, change.t)
    for ev in rec.events:
        msgs.add("~/events", _STRING, {"data": to_json(ev)}, float(ev.get("t", 0.0)))
    for s in rec.strokes:
        if math.isfinite(s.t_end):
            msgs.add(STROKES.key, _STRING, {"data": to_json(s.row())}, s.t_end)


def _joints(stamp: dict[str, int], positions: Any, velocities: Any, effort: Any) -> dict[str, Any]:
    """Return a JointState of the twin's joints."""
    return {
        "header": {"stamp": stamp, "frame_id": FRAME_ID},
        "name": list(JOINT_NAMES),
        "position": [float(v) for v in positions],
        "velocity": [float(v) for v in velocities],
        "effort": [float(v) for v in effort],
    }


def _status(msgs: _Messages, rec: TrackRecording, status: Any, t: float) -> None:
    """Add the tracking status on /diagnostics at ``t``."""
    st = diagnostics.tracking(status, TRACKING_STATUS, diagnostics.hardware_id(rec.scene.name))
    msgs.add("/diagnostics", BY_KEY["/diagnostics"].msgtype, diagnostics.array(_ns(t), [st]), t)


def _measured(msgs: _Messages, rec: TrackRecording) -> None:
    """Add the measurements, one JointState a stamp, and the mode signals."""
    by_stamp: dict[float, dict[str, float]] = {}
    for m in rec.measurements:
        by_stamp.setdefault(m.t, {})[m.kind] = m.value
    for t, got in sorted(by_stamp.items()):
        names = ["crank"] + (["slider"] if "slider_position" in got else [])
        pos = [got.get("crank_angle", NAN)] + ([got["slider_position"]] if len(names) > 1 else [])
        vel = [got["crank_rate"]] + [NAN] * (len(names) - 1) if "crank_rate" in got else []
        eff = [got["motor_torque"]] + [NAN] * (len(names) - 1) if "motor_torque" in got else []
        msg = {
            "header": {"stamp": _stamp(t), "frame_id": FRAME_ID},
            "name": names,
            "position": pos,
            "velocity": vel,
            "effort": eff,
        }
        msgs.add(MEASURED_JOINTS.key, MEASURED_JOINTS.msgtype, msg, t)
    for s in rec.modes:
        msgs.add(MEASURED_MODE.key, MEASURED_MODE.msgtype, {"data": s.command}, s.t)
