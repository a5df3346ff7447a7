"""``mps view --live``: the running node in a Rerun viewer, as it runs.

A process of its own subscribes to the node's topics (serialized: nothing is deserialized
into Python messages), keeps what arrives, and at the display rate (``hz``, 30 a wall second)
turns what arrived since the last frame into the same columns a recording gives
(:func:`mps_ros.recording.replay.replay_of_messages`) and logs them with the offline view's code
(:func:`mps_ros.view.offline.convert`): the same entities, blueprint and time line (``sim_time``), one
``send_columns`` an entity a frame. The arrows' scale and the drawing's extent are fixed from
the scene beforehand (a live run has no percentile to take); the static parts go with the first
frame. It follows a node started before or after it, and ends at the node's ``run-end`` event,
after ``duration`` wall seconds, or on Ctrl-C / SIGTERM.

Where it goes: a viewer it starts, listening on 127.0.0.1 only (default); ``save``: an .rrd
file; ``connect``: a running viewer's gRPC address (``rerun+http://127.0.0.1:9876/proxy``).

Lag: at each frame the newest simulated time received against the newest one logged; its
maximum over the run is reported (``max_lag_s``), and the frame's own work.
"""

from __future__ import annotations

import bisect
import math
import os
import signal
import socket
import struct
import subprocess
import threading
import time
import uuid
from pathlib import Path
from types import SimpleNamespace

from ..recording.replay import ReplayError, replay_of_messages
from ..wire.drawing import SLIDER
from ..wire.topics import BY_KEY, FOUNDATION, NODE_NAME, WRENCHES, resolve

#: the topics the view reads (the markers are the view's own drawing: not needed)
KEYS = (
    "joint_states",
    *(w.key for w in WRENCHES),
    FOUNDATION.key,
    "~/structure",
    "~/events",
    "~/mode/status",
    "/diagnostics",
)
_STAMPED = {"sensor_msgs/msg/JointState", "geometry_msgs/msg/WrenchStamped"}
#: a frame draws the mechanism at this many of its steps at most (a 1 kHz run gives a 30 Hz
#: view about 33 a frame): a view that has fallen behind thins the drawing, never the plots
DRAW_MAX = 100
_STAMP = struct.Struct("<iI")


def extent_mm(scene) -> tuple[float, float]:
    """The drawing's lowest and highest x along the guide (mm), from the geometry: the slider's
    bottom dead centre to its top stop, the crank's circle, the slider block and a margin."""
    g = scene.geometry
    l1 = g.l1 * 1e3
    h = SLIDER[1] * l1
    low = (g.l2 - g.l3 - g.l1) * 1e3
    top = (g.l1 + g.l2 - g.l3) * 1e3 if scene.x_top is None else scene.x_top * 1e3
    return min(low, -l1) - h - 0.3 * l1, max(top, l1) + h + 0.3 * l1


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class _Inbox:
    """What arrived since the last frame, by topic: (stamp ns, CDR bytes). A step's messages
    come on several topics, each in its own queue: :meth:`take` gives the steps every stamped
    topic has reached and keeps the newer ones for the next frame, so that a step is never cut
    between two frames (its values on one topic would be lost)."""

    def __init__(self, node_name: str):
        self.lock = threading.Lock()
        self.node = node_name
        self.topics = {resolve(k, node_name): BY_KEY[k].msgtype for k in KEYS}
        self.msgs: dict[str, list] = {t: [] for t in self.topics}
        self.last_ns: int | None = None  # the newest simulated time seen
        self.newest: dict[str, int] = {}  # by stamped topic, its newest stamp
        self.ended = False
        self.end_ns: int | None = None  # the run-end event's simulated time
        self.last_arrival = time.monotonic()

    def callback(self, topic: str):
        stamped = self.topics[topic] in _STAMPED
        events = topic == resolve("~/events", self.node)

        def cb(data: bytes):
            if stamped:
                sec, nsec = _STAMP.unpack_from(data, 4)
                t = sec * 1_000_000_000 + nsec
            else:
                t = self.last_ns if self.last_ns is not None else 0
            with self.lock:
                self.msgs[topic].append((t, bytes(data)))
                self.last_arrival = time.monotonic()
                if stamped:
                    self.newest[topic] = t
                    if self.last_ns is None or t > self.last_ns:
                        self.last_ns = t
                if events and b'"run-end"' in data:
                    self.ended = True
                    self.end_ns = _end_ns(data)

        return cb

    def take(self, whole: bool = False) -> dict:
        """The messages of the steps that every stamped topic heard from has reached (all of
        them: ``whole``), by topic; the rest stay for the next take."""
        with self.lock:
            out, self.msgs = self.msgs, {t: [] for t in self.topics}
            if whole or not self.newest:
                return out
            horizon = min(self.newest.values())
            for topic in self.newest:
                msgs = out[topic]
                cut = bisect.bisect_right(msgs, horizon, key=lambda m: m[0])
                if cut < len(msgs):
                    out[topic], self.msgs[topic] = msgs[:cut], msgs[cut:]
        return out


def _take(subs, stop: threading.Event, period: float = 0.002) -> None:
    """Take what has arrived on each subscription (serialized) and hand it to its callback,
    every ``period`` wall seconds until ``stop``: a loop of rclpy's take, without an executor's
    machinery a message (which, at eleven topics of 1 kHz, cost more than a core here and let
    the middleware's queues overflow)."""
    while not stop.is_set():
        for sub, cb in subs:
            handle = sub.handle
            with handle:
                while True:
                    got = handle.take_message(sub.msg_type, True)
                    if got is None:
                        break
                    try:
                        cb(got[0])
                    except Exception:  # a message the view cannot read: not the run's end
                        pass
        stop.wait(period)


def _end_ns(data: bytes) -> int | None:
    """The simulated time (ns) of a ``run-end`` event's message (CDR std_msgs/String)."""
    import json

    try:
        text = bytes(data[8:]).rstrip(b"\x00").decode()
        return round(float(json.loads(text)["t"]) * 1e9)
    except (ValueError, KeyError, TypeError):
        return None


def run_live(
    *,
    scene,
    node_name: str = NODE_NAME,
    save=None,
    connect: str | None = None,
    spawn: bool = True,
    duration: float | None = None,
    hz: float = 30.0,
    arrow_scale_n_per_m: float = 2e6,
    log=None,
) -> dict:
    """Follow the node ``node_name`` (see the module's doc); returns the figures of the run:
    frames, steps logged, the last simulated time logged, ``max_lag_s``, frame work p50/max."""
    import rclpy

    from .offline import rerun_sdk

    if log is None:

        def log(text):
            print(text, flush=True)

    if not (hz > 0):
        raise ReplayError(f"--hz {hz!r}: expected a positive number of frames a second")
    if save is None and connect is None:
        from .offline import no_display

        no_display()  # before anything is started
    rr = rerun_sdk()

    scale = arrow_scale_n_per_m / 1e3  # N per mm
    extent = extent_mm(scene)
    _warm_up(rr, scene, node_name, scale, extent)
    rec, viewer = _open_sink(rr, scene, extent, scale, save, connect)
    rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    stop = threading.Event()
    old = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    node = rclpy.create_node(f"mps_view_live_{os.getpid()}")
    inbox = _Inbox(node_name)
    subs = _subscribe(node, inbox)
    taking = threading.Event()
    taker = threading.Thread(target=_take, args=(subs, taking), name="mps-view-take", daemon=True)
    taker.start()
    log(
        f"following {resolve('joint_states', node_name)}: "
        + (f"saving to {save}" if save is not None else f"streaming to {connect or 'a viewer on 127.0.0.1'}")
    )
    out = _Frames(node_name, scene, rec, scale, extent)
    try:
        max_lag = _follow(inbox, out, taker, stop, 1.0 / hz, duration)
    finally:
        taking.set()
        taker.join(timeout=10.0)
        if not taker.is_alive():  # rclpy: never destroy what another thread takes from
            node.destroy_node()
        rclpy.try_shutdown()
        for s, h in old.items():
            signal.signal(s, h)
        rec.flush()
        rr.disconnect(recording=rec)
    return _figures(out, max_lag, viewer)


def _follow(
    inbox: _Inbox,
    out: _Frames,
    taker: threading.Thread,
    stop: threading.Event,
    period: float,
    duration: float | None,
) -> float:
    """A frame every ``period`` wall seconds, of what ``inbox`` took since the last one, until
    the run's end (its last steps logged, or a quiet second after it), ``duration`` wall
    seconds or ``stop``: the largest lag of the view behind the node (simulated s)."""
    log_frame = out.log
    max_lag = 0.0
    t_start = time.monotonic()
    nxt = time.monotonic()
    while not stop.is_set():
        nxt += period
        time.sleep(max(0.0, nxt - time.monotonic()))
        if not taker.is_alive():
            raise ReplayError("the view stopped taking the node's messages")
        ended = inbox.ended
        log_frame(inbox.take())
        newest, last_logged = inbox.last_ns, out.last_logged
        if newest is not None and last_logged is not None:
            max_lag = max(max_lag, newest * 1e-9 - last_logged)
        if ended:
            # the run's end came on its own topic: the steps still on their way (other
            # topics, other queues) are taken too, up to the end's time or a quiet second
            reached = inbox.end_ns is None or (
                last_logged is not None and round(last_logged * 1e9) >= inbox.end_ns
            )
            if reached:
                break
            if time.monotonic() - inbox.last_arrival > 1.0:
                log_frame(inbox.take(whole=True))  # what a topic never completed
                break
        if duration is not None and time.monotonic() - t_start >= duration:
            log_frame(inbox.take(whole=True))
            break
    return max_lag


def _figures(out: _Frames, max_lag: float, viewer) -> dict:
    """The figures of the run the view followed (:func:`run_live`'s answer)."""
    work = sorted(out.work)
    return {
        "frames": out.frames,
        "steps": out.steps,
        "drawn_steps": out.drawn,
        "thinned_frames": out.thinned,
        "last_t": out.last_logged,
        "max_lag_s": max_lag,
        "frame_work_p50_s": work[len(work) // 2] if work else math.nan,
        "frame_work_max_s": work[-1] if work else math.nan,
        "viewer_pid": viewer.pid if viewer is not None else None,
    }


def _open_sink(rr, scene, extent, scale, save, connect):
    """The recording stream and where it goes (a file, a viewer at ``connect``, or a viewer
    spawned on loopback), its blueprint sent before the first frame, so that that frame costs
    what any does: (the stream, the spawned viewer or None)."""
    import rerun.blueprint as rrb

    from .offline import FAMILIES, blueprint

    rec = rr.RecordingStream("mps", recording_id=str(uuid.uuid4()))
    viewer = None
    every = SimpleNamespace(columns={c: None for _, _, series in FAMILIES for c, _ in series})
    bp = blueprint(rrb, _bounds(scene, extent), scale, every)
    if save is not None:
        try:
            rr.save(Path(save), default_blueprint=bp, recording=rec)
        except (OSError, RuntimeError) as exc:
            raise ReplayError(f"--save {save}: cannot write it ({exc})") from None
    elif connect is not None:
        rr.connect_grpc(connect, default_blueprint=bp, recording=rec)
    else:
        viewer, url = _spawn()
        rr.connect_grpc(url, default_blueprint=bp, recording=rec)
    return rec, viewer


def _subscribe(node, inbox) -> list:
    """The view's subscriptions to the node's topics (the structure latched), raw, each
    with its inbox callback: [(subscription, callback)]."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    from ..ros.endpoints import MSG_CLASSES

    qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2000, reliability=ReliabilityPolicy.RELIABLE)
    latched = QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=1,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )
    subs = []
    for topic, msgtype in inbox.topics.items():
        cb = inbox.callback(topic)
        sub = node.create_subscription(
            MSG_CLASSES[msgtype], topic, cb, latched if topic.endswith("/structure") else qos, raw=True
        )
        subs.append((sub, cb))
    return subs


class _Frames:
    """The frames logged so far: each a batch of the node's messages converted and logged to
    the stream (:meth:`log`), with its counts and work."""

    def __init__(self, node_name, scene, rec, scale, extent):
        self.node_name, self.scene, self.rec, self.scale, self.extent = node_name, scene, rec, scale, extent
        self.frames = self.steps = self.drawn = self.thinned = 0
        self.last_logged: float | None = None
        self.work: list[float] = []

    def log(self, got: dict) -> None:
        from .offline import convert

        w0 = time.perf_counter()
        rep = replay_of_messages("live", got, self.node_name)
        if rep is None or not len(rep):
            return
        # behind the run (a frame holding more steps than DRAW_MAX): the mechanism drawn at
        # every k-th step, the plots and events at every one
        k = max(1, math.ceil(len(rep) / DRAW_MAX))
        c = convert(
            rep,
            scene=self.scene,
            recording=self.rec,
            arrow_scale=self.scale,
            extent=self.extent,
            statics=self.frames == 0,
            draw_every=k,
        )
        self.frames += 1
        self.steps += len(rep)
        self.drawn += c.drawn_steps
        self.thinned += k > 1
        self.last_logged = float(rep.columns["t"][-1])
        self.work.append(time.perf_counter() - w0)


def _warm_up(rr, scene, node_name, scale, extent) -> None:
    """Do once, before following, what the first frame would otherwise do on the clock (the
    viewer library's and numpy's first calls): three steps of the scene, converted into a
    stream that is dropped."""
    from ..run.twin import Twin
    from .offline import convert

    tw = Twin(scene, t_end=3 * scene.dt)
    msgs: dict = {}
    while True:
        for key, data in tw.state_payloads():
            msgs.setdefault(resolve(key, node_name), []).append((round(tw.t * 1e9), data))
        if tw.done:
            break
        tw.step()
    rec = rr.RecordingStream("mps-warm-up")  # no sink: kept in memory, dropped
    rep = replay_of_messages("warm-up", msgs, node_name)
    if rep is None:  # no joint states among the outputs: nothing drawn to warm up
        return
    for statics in (True, False):
        convert(rep, scene=scene, recording=rec, arrow_scale=scale, extent=extent, statics=statics)


def _bounds(scene, extent):
    """The mechanism panel's bounds (view mm): across, the guide's rails and the crank's
    circle; along, the drawing's extent."""
    g = scene.geometry
    l1 = g.l1 * 1e3
    across = max(g.l1 + g.l3, (SLIDER[0] + 0.35) * g.l1) * 1e3 + 0.6 * l1
    lo, hi = extent
    return (-across, across), (-hi - 0.3 * l1, -lo + 0.3 * l1)


def _spawn():
    """A native viewer listening on 127.0.0.1 only; (process, its gRPC address)."""
    from .offline import rerun_executable

    exe = rerun_executable()
    if exe is None:
        raise ReplayError("no rerun viewer found (pip install -e '.[view]'); use --save FILE.rrd")
    port = _free_port()
    proc = subprocess.Popen([exe, "--bind", "127.0.0.1", "--port", str(port)], start_new_session=True)
    time.sleep(1.0)
    return proc, f"rerun+http://127.0.0.1:{port}/proxy"


__all__ = ["run_live", "extent_mm", "KEYS"]
