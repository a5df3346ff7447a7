"""A recording of the twin as a Rerun recording: the mechanism drawn at every step, its reaction
forces as arrows, the time series, the events, and a blueprint that lays them out.

    from mps_ros.recording.replay import read_recording
    from mps_ros.view.offline import save_rrd
    save_rrd(read_recording("run.mcap"), "run.rrd")        # then: rerun --bind 127.0.0.1 run.rrd

It reads recordings (:mod:`mps_ros.recording.replay`), never the core's objects, and never imports rclpy.

**Timeline.** ``sim_time``: the simulated time of each published step (a duration, s).

**Entities.**

* ``mechanism/…`` (2D, millimetres, drawn in the press frame with x up: Rerun's 2D y axis points
  down, so a press point (x, y) is drawn at (y, −x)): ``frame`` (guide rails and axis, the top
  stop's ledges, the bearing at O; static), ``links`` (crank O–A blue, rod A–B orange, rocker
  B–C green), ``slider`` (a block centred on C), ``joints`` (O, A, B, C as points), ``latch``
  (on the slider's side: green, "latch closed (locked)" while the structure is ``locked``; grey,
  "latch open (free)" or "latch open (held)" otherwise), ``reactions/<wrench>`` (an arrow for
  each wrench of :data:`~mps_ros.wire.topics.WRENCHES` that carries a force, at its joint, labelled
  with its magnitude, shown on hover; the guide's on the slider's face, the stop's on its
  ledge) and
  ``reactions/foundation`` (the resultant the frame receives, drawn at the bearing's base below
  O). Arrows share one scale a recording, in the view's title and in
  :attr:`Converted.arrow_scale_n_per_mm`. Positions: A = l1(cos φ, sin φ), C = (x_C, 0),
  B = C + l3(cos ψ, sin ψ), from the joint states and the scene's geometry (its metadata).
* ``plots/<family>/<column>``: the columns of the recording (:mod:`mps_ros.recording.replay`), one plot
  per family (:data:`FAMILIES`); values exactly as recorded, in SI units. ε1 = φ̈ is derived from
  ω1 (a recording has no accelerations). ``plots/crank_speed/events/<kind>``: markers on ω1 at
  each event.
* ``events``: a text log (events, commands received and refused, the run's pacing diagnostics);
  ``state/structure`` and ``state/latch``: state lanes.

**Work.** Everything is logged in columns: one ``send_columns`` call an entity and component
group, whatever the recording's length, and a fixed number of static ``log`` calls (styles,
the frame). :class:`Converted` counts them (``calls``, ``rows``).
"""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import sys
import tempfile
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from mps_core.dynamics.reactions import REACTION_COLUMNS

from ..recording.replay import DERIVED, Replay, ReplayError, read_recording
from ..wire.drawing import BEARING, COLORS, SLIDER, arrow_anchor
from ..wire.topics import FOUNDATION, WRENCHES

TIMELINE = "sim_time"
APPLICATION_ID = "mps"
RERUN_VERSION = "0.41.0"

_MOTOR = next(w for w in WRENCHES if w.name == "motor")


def _named(column: str | None) -> str:
    """Return a wrench's column that the plots name (every one they name exists)."""
    if column is None:
        raise ValueError("a plot names a wrench's column that it does not have")
    return column


def _unit(col: str) -> str:
    return REACTION_COLUMNS.get(col, "").replace("*", "·")


#: plot families: (entity name, title, ((column, series name), ...)); the reaction columns come
#: from the wrenches of mps_ros.wire.topics (the joints' forces and moments, the motor's torque, the
#: foundation's resultant), so a name is never written twice
FAMILIES: tuple[tuple[str, str, tuple[tuple[str, str], ...]], ...] = (
    ("crank_angle", "crank angle φ (rad)", (("phi", "φ (rad)"),)),
    ("crank_speed", "crank speed ω1 = φ̇ (rad/s)", (("phi_dot", "ω1 = φ̇ (rad/s)"),)),
    ("crank_acceleration", "crank acceleration ε1 = φ̈ (rad/s², from ω1)", (("phi_ddot", "ε1 = φ̈ (rad/s²)"),)),
    ("rocker_angle", "rocker angle ψ (rad)", (("psi", "ψ (rad)"),)),
    ("slider", "slider position x_C (m)", (("x_C", "x_C (m)"),)),
    (
        "motor",
        f"motor torque on the crank {_MOTOR.torque} (N·m)",
        ((_named(_MOTOR.torque), f"{_MOTOR.torque} (N·m)"),),
    ),
    (
        "joint_forces",
        "joint forces (N)",
        tuple((c, f"{c} ({_unit(c)})") for w in WRENCHES for c in w.force if c is not None),
    ),
    (
        "joint_moments",
        "joint moments (N·m)",
        tuple(
            (_named(w.torque), f"{w.torque} ({_unit(_named(w.torque))})")
            for w in WRENCHES
            if w.torque is not None and w is not _MOTOR
        ),
    ),
    (
        "foundation_force",
        "foundation force (N)",
        (
            (_named(FOUNDATION.force[0]), f"{FOUNDATION.force[0]} (N, along the guide, up)"),
            (_named(FOUNDATION.force[1]), f"{FOUNDATION.force[1]} (N, across)"),
        ),
    ),
    (
        "foundation_moment",
        "foundation moment about O (N·m)",
        ((_named(FOUNDATION.torque), f"{FOUNDATION.torque} (N·m)"),),
    ),
)

#: event kinds marked on ω1, by marker family: (kinds, marker, colour)
MARKERS = {
    "latch": (("latch-closes", "latch-opens"), "diamond", (200, 40, 40)),
    "stop": (("stop-contact", "stop-release"), "square", (150, 60, 200)),
    "command": (("command", "command-refused"), "up", (30, 130, 30)),
    "other": (("change-point", "impulse"), "cross", (120, 120, 120)),
}

_SERIES_COLORS = [
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
    (188, 189, 34),
    (23, 190, 207),
]
LEVELS = {
    "command": "INFO",
    "command-refused": "WARN",
    "latch-closes": "WARN",
    "latch-opens": "INFO",
    "stop-contact": "WARN",
    "stop-release": "INFO",
    "change-point": "INFO",
    "impulse": "WARN",
    "chart": "DEBUG",
    "run-start": "INFO",
    "run-end": "INFO",
    "cylinder-off": "INFO",
}


def rerun_sdk():
    """Import rerun-sdk, or say how to install it (:class:`ReplayError`)."""
    try:
        import rerun as rr
    except ModuleNotFoundError:
        raise ReplayError(
            "the viewer needs rerun-sdk, which is not installed: "
            f"pip install -e '.[view]' (rerun-sdk=={RERUN_VERSION})"
        ) from None
    return rr


@dataclass
class Converted:
    """What a conversion logged: the stream, its blueprint, the work done."""

    recording: object
    blueprint: object
    calls: dict = field(default_factory=lambda: {"send_columns": 0, "log": 0})
    rows: int = 0
    entities: dict = field(default_factory=dict)  # entity -> rows sent
    arrow_scale_n_per_mm: float = math.nan
    steps: int = 0
    drawn_steps: int = 0  # the steps the mechanism was drawn at (draw_every)


class _Logger:
    """Logs to one stream and counts the work; ``statics`` False: the static parts (styles,
    the frame) are left out, a later stretch of a live run whose first stretch logged them."""

    def __init__(self, rr, rec, out: Converted, statics: bool = True):
        self.rr, self.rec, self.out, self.statics = rr, rec, out, statics

    def columns(self, path: str, t, columns) -> None:
        """Send columns at times t (s), rounded to the nanosecond (the recording's stamps)."""
        t = np.round(np.asarray(t, dtype=float) * 1e9).astype(np.int64).astype("timedelta64[ns]")
        self.rr.send_columns(
            path, indexes=[self.rr.TimeColumn(TIMELINE, duration=t)], columns=columns, recording=self.rec
        )
        self.out.calls["send_columns"] += 1
        self.out.rows += int(t.size)
        self.out.entities[path] = self.out.entities.get(path, 0) + int(t.size)

    def static(self, path: str, make) -> None:
        """``make()``: the archetype, built only where the static parts are logged."""
        if not self.statics:
            return
        self.rr.log(path, make(), static=True, recording=self.rec)
        self.out.calls["log"] += 1
        self.out.entities.setdefault(path, 0)


# -- geometry ---------------------------------------------------------------------------------
def positions(columns: dict, l1: float, l3: float) -> dict[str, np.ndarray]:
    """Points O, A, B, C (n, 2) in the press frame (m) from the joint states."""
    phi, psi, xc = (np.asarray(columns[c], dtype=float) for c in ("phi", "psi", "x_C"))
    n = phi.size
    O = np.zeros((n, 2))  # noqa: E741 (the paper's point O, the crank bearing)
    A = l1 * np.column_stack([np.cos(phi), np.sin(phi)])
    C = np.column_stack([xc, np.zeros(n)])
    B = C + l3 * np.column_stack([np.cos(psi), np.sin(psi)])
    return {"O": O, "A": A, "B": B, "C": C}


def to_view(p) -> np.ndarray:
    """Press frame (x up, y across; m) to Rerun's 2D view (u right, v down; mm): (y, −x)·1000."""
    p = np.asarray(p, dtype=float)
    return np.stack([p[..., 1] * 1e3, -p[..., 0] * 1e3], axis=-1)


def _changes(values) -> np.ndarray:
    v = np.asarray(values)
    if v.size == 0:
        return np.zeros(0, dtype=int)
    return np.concatenate([[0], np.nonzero(v[1:] != v[:-1])[0] + 1])


def _fmt_force(v: float) -> str:
    a = abs(v)
    if a >= 1e3:
        return f"{v / 1e3:.3g} kN"
    return f"{v:.3g} N"


# -- the conversion ---------------------------------------------------------------------------
def convert(
    rep: Replay,
    *,
    scene=None,
    recording=None,
    application_id: str = APPLICATION_ID,
    arrow_scale: float | None = None,
    extent: tuple | None = None,
    statics: bool = True,
    draw_every: int = 1,
) -> Converted:
    """Log a recording into a Rerun recording stream (a new one unless ``recording`` is given);
    the scene's geometry comes from ``scene`` or else from the recording's metadata.

    A live run is logged a stretch at a time into one stream: ``arrow_scale`` (N/mm) and
    ``extent`` (the drawing's lowest and highest x along the guide, mm) fixed beforehand
    instead of taken from the data, ``statics`` only for the first stretch; ``draw_every``
    > 1 draws the mechanism and the force arrows at every such step only (and the stretch's
    last), the plots and events still at every step (a live view behind the run)."""
    rr = rerun_sdk()
    import rerun.blueprint as rrb

    scene = scene if scene is not None else rep.scene
    if scene is None:
        raise ReplayError(
            f"{rep.path}: the recording holds no scene (metadata record "
            "'scene'), so its geometry is unknown: give one with --scene SCENE"
        )
    if recording is None:
        rid = uuid.uuid5(uuid.NAMESPACE_URL, "mps-recording:" + (rep.digest or str(rep.path)))
        recording = rr.RecordingStream(application_id, recording_id=str(rid))
    cols = rep.columns
    t = cols["t"]
    n = t.size
    g = scene.geometry
    out = Converted(recording, None, steps=n)
    log = _Logger(rr, recording, out, statics)

    pts = positions(cols, g.l1, g.l3)
    view = {k: to_view(v) for k, v in pts.items()}
    drawn: Any = rep
    dcols, dt_, dpts, dview = cols, t, pts, view
    if draw_every > 1 and n > 2:
        idx = np.unique(np.r_[np.arange(0, n, int(draw_every)), n - 1])
        dcols = {
            c: (v[idx] if isinstance(v, np.ndarray) and v.shape[:1] == (n,) else v) for c, v in cols.items()
        }
        drawn = SimpleNamespace(columns=dcols)
        dt_ = t[idx]
        dpts = {k: v[idx] for k, v in pts.items()}
        dview = {k: v[idx] for k, v in view.items()}
    out.drawn_steps = dt_.size
    bounds = _mechanism(rr, log, drawn, scene, dt_, dview, extent)
    out.arrow_scale_n_per_mm = _reactions(rr, log, dcols, dt_, dpts, scene, arrow_scale)
    _plots(rr, log, cols, t)
    _events(rr, log, rep, t)
    out.blueprint = blueprint(rrb, bounds, out.arrow_scale_n_per_mm, rep)
    return out


def _frame(rr, log, l1, w, h, x_top, lo, hi) -> float:
    """The press's frame, static: the guide's rails and axis over ``lo`` to ``hi`` (mm along
    the guide), the bearing at O, the top stop's ledges; the rails' distance from the axis."""
    rail = w + 0.1 * l1
    strips = [
        np.array([[-rail, -lo], [-rail, -hi]]),
        np.array([[rail, -lo], [rail, -hi]]),
        np.array([[0.0, -lo], [0.0, -hi]]),
    ]  # the rails, the guide's axis
    labels = ["guide", "", ""]
    colors = [COLORS["frame"], COLORS["frame"], (205, 205, 205)]
    # the bearing at O: a triangle under O in the press frame (towards −x)
    b = BEARING * l1
    strips.append(np.array([[0, 0], [-b, b], [b, b], [0, 0]]))
    labels.append("")
    colors.append(COLORS["frame"])
    if x_top is not None:
        # two ledges on the rails that the slider's top face meets at x_C = x_top
        v = -(x_top + h)
        strips += [np.array([[-rail - 0.25 * l1, v], [-w, v]]), np.array([[w, v], [rail + 0.25 * l1, v]])]
        labels += ["", "top stop"]
        colors += [(60, 60, 60), (60, 60, 60)]
    log.static(
        "mechanism/frame",
        lambda: rr.LineStrips2D(strips, colors=colors, labels=labels, radii=[-1.0] * len(strips)),
    )
    return rail


def _mechanism(rr, log, rep, scene, t, view, extent=None) -> tuple:
    cols = rep.columns
    g = scene.geometry
    n = t.size
    l1 = g.l1 * 1e3
    w = SLIDER[0] * l1  # slider half width (across), mm
    h = SLIDER[1] * l1  # slider half height (along), mm
    xc = np.asarray(cols["x_C"], float) * 1e3
    x_top = None if scene.x_top is None else scene.x_top * 1e3
    if extent is not None:
        lo, hi = extent
    else:
        lo = min(float(np.nanmin(xc)), -l1) - h - 0.3 * l1
        hi = max(float(np.nanmax(xc)), x_top if x_top is not None else -math.inf) + h + 0.3 * l1
    rail = _frame(rr, log, l1, w, h, x_top, lo, hi)
    # Static styles never carry a component that is sent in time: a static value would hide
    # the temporal one (Rerun's rule), so they are logged with from_fields.
    # links: crank O-A, rod A-B, rocker B-C at every step
    seg = np.stack(
        [
            np.stack([view["O"], view["A"]], 1),
            np.stack([view["A"], view["B"]], 1),
            np.stack([view["B"], view["C"]], 1),
        ],
        axis=1,
    )  # (n, 3, 2, 2)
    log.static(
        "mechanism/links",
        lambda: rr.LineStrips2D.from_fields(
            colors=[COLORS["crank"], COLORS["rod"], COLORS["rocker"]],
            labels=["crank", "rod", "rocker"],
            show_labels=False,
            radii=[-3.0, -3.0, -3.0],
            draw_order=15.0,
        ),
    )
    log.columns(
        "mechanism/links", t, rr.LineStrips2D.columns(strips=seg.reshape(-1, 2, 2)).partition(np.full(n, 3))
    )
    # the slider: a block centred on C
    log.static(
        "mechanism/slider",
        lambda: rr.Boxes2D.from_fields(
            half_sizes=[[w, h]], colors=[COLORS["slider"]], radii=[-1.5], draw_order=5.0
        ),
    )
    log.columns("mechanism/slider", t, rr.Boxes2D.columns(centers=view["C"]))
    # joints
    log.static(
        "mechanism/joints",
        lambda: rr.Points2D.from_fields(
            labels=["O", "A", "B", "C"], colors=[COLORS["joint"]] * 4, radii=[-4.0] * 4, draw_order=40.0
        ),
    )
    jp = np.stack([view["O"], view["A"], view["B"], view["C"]], axis=1)
    log.columns(
        "mechanism/joints", t, rr.Points2D.columns(positions=jp.reshape(-1, 2)).partition(np.full(n, 4))
    )
    # the latch (rocker to slider), on the slider's side: closed while the structure is
    # locked; its label also names the structure
    st = np.asarray(cols.get("structure", np.full(n, "")), dtype=str)
    log.static("mechanism/latch", lambda: rr.Points2D.from_fields(radii=[-6.0], draw_order=30.0))
    log.columns("mechanism/latch", t, rr.Points2D.columns(positions=view["C"] + np.array([-w, 0.0])))
    ch = _changes(st)
    log.columns(
        "mechanism/latch",
        t[ch],
        rr.Points2D.columns(
            colors=[COLORS["latch_closed"] if s == "locked" else COLORS["latch_open"] for s in st[ch]],
            labels=[
                ("latch closed" if s == "locked" else "latch open") + (f" ({s})" if s else "") for s in st[ch]
            ],
        ),
    )
    allp = np.concatenate([v for v in view.values()])
    umin = min(float(np.nanmin(allp[:, 0])), -rail) - 0.6 * l1
    umax = max(float(np.nanmax(allp[:, 0])), rail) + 0.6 * l1
    vmin = min(float(np.nanmin(allp[:, 1])), -hi) - 0.6 * l1
    vmax = max(float(np.nanmax(allp[:, 1])), -lo) + 0.6 * l1
    return (umin, umax), (vmin, vmax)


def _arrow_origin(name, point, pts, l1, x_top, n) -> np.ndarray:
    """Where a wrench's arrow starts at every step (view, mm; :func:`drawing.arrow_anchor`),
    from the press frame's points ``pts`` (n, 2 each)."""
    base, dx, dy = arrow_anchor(name, point, l1, x_top)
    p = np.tile([dx, dy], (n, 1)) if base is None else pts[base] + np.array([dx, dy])
    return to_view(p)


def _reactions(rr, log, cols, t, pts, scene, scale=None) -> float:
    """Arrows of the joint forces and the foundation resultant; returns the scale (N/mm): the
    one given, or else the 99th percentile force drawn 1.6 l1 long."""
    n = t.size
    arrows = []
    for w in (*WRENCHES, FOUNDATION):
        fx, fy = w.force
        if fx is None and fy is None:
            continue
        if any(c is not None and c not in cols for c in (fx, fy)):
            continue
        F = np.column_stack(
            [
                np.zeros(n) if fx is None else np.asarray(cols[fx], float),
                np.zeros(n) if fy is None else np.asarray(cols[fy], float),
            ]
        )
        at = _arrow_origin(w.name, w.point, pts, scene.geometry.l1, scene.x_top, n)
        arrows.append((w, F, at))
    if not arrows:
        return math.nan
    length = 1.6 * scene.geometry.l1 * 1e3  # the 99th percentile force: 1.6 l1 long
    if scale is None:
        mags = np.concatenate([np.hypot(F[:, 0], F[:, 1]) for _, F, _ in arrows])
        mags = mags[np.isfinite(mags)]
        ref = float(np.percentile(mags, 99)) if mags.size else 0.0
        if not ref > 0:
            ref = 1.0
        scale = ref / length  # N per mm
    ref = scale * length
    for w, F, at in arrows:
        vec = to_view(F) / 1e3 / scale  # to_view multiplies by 1000
        mag = np.hypot(F[:, 0], F[:, 1])
        name = "foundation" if w is FOUNDATION else f"F_{w.name}"
        labels = np.where(
            mag > 0.02 * ref, np.array([f"{name} {_fmt_force(m)}" for m in mag], dtype=object), ""
        )
        color = COLORS["foundation"] if w is FOUNDATION else COLORS["force"]
        path = f"mechanism/reactions/{w.name}"
        # the magnitude is each arrow's label, shown on hover (not drawn: the joints' labels
        # would lie on top of each other)
        log.static(
            path,
            lambda color=color: rr.Arrows2D.from_fields(
                colors=[color], radii=[-1.5], show_labels=False, draw_order=20.0
            ),
        )
        log.columns(path, t, rr.Arrows2D.columns(origins=at, vectors=vec, labels=list(labels)))
    return scale


def _plots(rr, log, cols, t) -> None:
    for fam, _title, series in FAMILIES:
        k = 0
        for col, name in series:
            if col not in cols:
                continue
            y = np.asarray(cols[col], dtype=float)
            path = f"plots/{fam}/{col}"
            color = _SERIES_COLORS[k % len(_SERIES_COLORS)]
            log.static(
                path, lambda name=name, color=color: rr.SeriesLines(names=name, colors=[color], widths=[1.5])
            )
            log.columns(path, t, rr.Scalars.columns(scalars=y))
            k += 1


def describe_event(ev: dict) -> str:
    """One line for a person: what happened."""
    k = ev.get("kind", "?")
    if k == "command":
        return f"command {ev.get('command')!s} (structure {ev.get('structure')})"
    if k == "command-refused":
        return f"command {ev.get('command')!s} refused: {ev.get('reason')}"
    if k in ("latch-closes", "stop-contact", "latch-opens", "stop-release"):
        what = {
            "latch-closes": "latch closes",
            "latch-opens": "latch opens",
            "stop-contact": "slider hits its top stop",
            "stop-release": "slider leaves its top stop",
        }[k]
        s = f"{what}: {ev.get('from')} -> {ev.get('to')}"
        if ev.get("energy_lost"):
            s += f", kinetic energy lost {ev['energy_lost']:.4g} J"
        if ev.get("impulse"):
            s += f", impulse {ev['impulse']:.4g} {ev.get('impulse_unit', '')}".rstrip()
        return s
    if k == "chart":
        return f"chart {ev.get('from')} -> {ev.get('to')}"
    if k == "cylinder-off":
        return f"{str(ev.get('effect', 'cylinder')).replace('_', ' ')} stops acting"
    if k == "change-point":
        return f"change point passed ({ev.get('choice', '')})"
    if k == "impulse":
        imp = ev.get("impulses_Ns", {})
        big = sorted(imp.items(), key=lambda kv: -abs(kv[1]))[:3]
        return "impulses: " + ", ".join(f"{a} {b:.4g} N*s" for a, b in big)
    if k == "run-start":
        return (
            f"run start: scene {ev.get('scene')}, {ev.get('steps')} steps of "
            f"{ev.get('dt')} s, solver {ev.get('solver')}, pacing {ev.get('pacing')}"
        )
    if k == "run-end":
        s = f"run end ({ev.get('reason')}, {ev.get('steps')} steps)"
        return s + (f": {ev['error']}" if ev.get("error") else "")
    rest = {a: b for a, b in ev.items() if a not in ("t", "kind")}
    return f"{k} {rest}" if rest else str(k)


def _events(rr, log, rep: Replay, t) -> None:
    rows = []  # (t, level, text)
    for ev in rep.events:
        try:
            te = float(ev.get("t"))
        except (TypeError, ValueError):
            continue
        rows.append((te, LEVELS.get(ev.get("kind"), "INFO"), describe_event(ev)))
    for te, word in rep.commands:
        rows.append((te, "INFO", f"received command {word!r}"))
    for ack in rep.acks:
        if not ack.get("accepted", True):
            rows.append(
                (float(ack["t"]), "WARN", f"refused command {ack.get('command')!r}: {ack.get('reason')}")
            )
    for te, level, name, msg in rep.diagnostics:
        rows.append((te, "WARN" if level else "DEBUG", f"{name}: {msg}"))
    rows.sort(key=lambda r: r[0])
    if rows:
        log.columns(
            "events",
            [r[0] for r in rows],
            rr.TextLog.columns(text=[r[2] for r in rows], level=[r[1] for r in rows]),
        )
    # markers on ω1
    w = np.asarray(rep.columns["phi_dot"], float)
    for fam, (kinds, marker, color) in MARKERS.items():
        times = np.array(
            [float(ev["t"]) for ev in rep.events if ev.get("kind") in kinds and _finite(ev.get("t"))]
        )
        if times.size == 0:
            continue
        path = f"plots/crank_speed/events/{fam}"
        log.static(
            path,
            lambda fam=fam, marker=marker, color=color: rr.SeriesPoints(
                names=f"{fam} events", markers=[marker], colors=[color], marker_sizes=[6.0]
            ),
        )
        log.columns(path, times, rr.Scalars.columns(scalars=np.interp(times, t, w)))
    # state lanes: the structure, the latch
    st = np.asarray(rep.columns.get("structure", np.full(t.size, "")), dtype=str)
    ch = _changes(st)
    if ch.size and st[0] != "":
        log.columns("state/structure", t[ch], rr.StateChange.columns(state=list(st[ch])))
        closed = np.where(st == "locked", "latch closed", "latch open")
        ch = _changes(closed)
        log.columns("state/latch", t[ch], rr.StateChange.columns(state=list(closed[ch])))


def _finite(v) -> bool:
    try:
        return math.isfinite(float(v))
    except (TypeError, ValueError):
        return False


def blueprint(rrb, bounds, scale, rep: Replay):
    (u0, u1), (v0, v1) = bounds
    title = "mechanism (x up, mm)"
    if math.isfinite(scale):
        title += f", forces 1 mm = {scale:.3g} N"
    mech = rrb.Spatial2DView(
        origin="mechanism",
        name=title,
        visual_bounds=rrb.VisualBounds2D(x_range=[u0, u1], y_range=[v0, v1]),
        background=(255, 255, 255),
    )
    plots = [
        rrb.TimeSeriesView(origin=f"plots/{fam}", name=title_)
        for fam, title_, series in FAMILIES
        if any(c in rep.columns for c, _ in series)
    ]
    # the mechanism alone in a tall column (its swept area is taller than wide), the plots and
    # under them the structure's lanes and the events
    below = rrb.Horizontal(
        rrb.StateTimelineView(origin="state", name="structure and latch"),
        rrb.TextLogView(origin="events", name="events"),
        column_shares=[1, 1.6],
    )
    right = rrb.Vertical(rrb.Grid(*plots, grid_columns=2), below, row_shares=[7, 2.2])
    return rrb.Blueprint(
        rrb.Horizontal(mech, right, column_shares=[0.75, 2]),
        rrb.TimePanel(timeline=TIMELINE, state="collapsed", play_state="paused"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.BlueprintPanel(state="collapsed"),
        collapse_panels=False,
    )


# -- files and the viewer ---------------------------------------------------------------------
def save_rrd(rep: Replay, path, *, scene=None) -> Converted:
    """Convert and write ``path`` (.rrd) with its blueprint; returns the work done."""
    rr = rerun_sdk()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rid = uuid.uuid5(uuid.NAMESPACE_URL, "mps-recording:" + (rep.digest or str(rep.path)))
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=str(rid))
    # the blueprint depends on the data (bounds, scale): the stream buffers what is logged
    # until its sink is set, then hands it all over
    out = convert(rep, scene=scene, recording=rec)
    rr.save(path, default_blueprint=out.blueprint, recording=rec)
    rec.flush()
    rr.disconnect(recording=rec)
    return out


def rerun_executable() -> str | None:
    """The ``rerun`` viewer installed with rerun-sdk (beside this Python), or on PATH."""
    here = Path(sys.executable).parent / ("rerun.exe" if os.name == "nt" else "rerun")
    if here.exists():
        return str(here)
    return shutil.which("rerun")


def spawn_viewer(rrd: Path) -> subprocess.Popen:
    """Open ``rrd`` in a new native viewer that listens on the loopback interface only."""
    exe = rerun_executable()
    if exe is None:
        raise ReplayError(
            "no rerun viewer found (pip install -e '.[view]'); the .rrd can be "
            f"opened later with: rerun --bind 127.0.0.1 {rrd}"
        )
    cmd = [exe, "--bind", "127.0.0.1", "--port", "auto", str(rrd)]
    return subprocess.Popen(cmd, start_new_session=True)


def view(path, *, save=None, spawn: bool = True, scene=None, log=print) -> tuple[Path, Converted]:
    """``mps view``: read a recording, write its .rrd (``save``, or a temporary file) and open
    the viewer unless ``spawn`` is False."""
    import time

    if spawn:
        no_display()
    c0 = time.perf_counter()
    rep = read_recording(path)
    c1 = time.perf_counter()
    for w in rep.warnings:
        log(f"note: {w}")
    if save is None:
        if not spawn:
            raise ReplayError("--no-spawn without --save: nothing to do (give --save FILE.rrd)")
        save = Path(tempfile.mkdtemp(prefix="mps-view-")) / (Path(path).stem + ".rrd")
    out = save_rrd(rep, save, scene=scene)
    c2 = time.perf_counter()
    log(
        f"{path}: {out.steps} steps, {len(rep.events)} events; read in {c1 - c0:.2f} s, "
        f"converted in {c2 - c1:.2f} s ({out.calls['send_columns']} column sends, "
        f"{out.calls['log']} static logs, {out.rows} rows)"
    )
    log(f"wrote {save}")
    if spawn:
        viewer = spawn_viewer(Path(save))
        try:  # a viewer that cannot start ends at once: say so, not "opened"
            code = viewer.wait(1.5)
        except subprocess.TimeoutExpired:
            code = None
        if code is not None:
            raise ReplayError(
                f"the viewer ended at once (exit status {code}); the recording "
                f"is saved in {save}: open it with rerun --bind 127.0.0.1 {save}"
            )
        log(f"opened the viewer on {save} (listening on 127.0.0.1 only)")
    return Path(save), out


def no_display() -> None:
    """ReplayError where a native viewer has no display to open on (Linux without DISPLAY or
    WAYLAND_DISPLAY), before any work is done."""
    if sys.platform.startswith("linux") and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    ):
        raise ReplayError(
            "no display to open the viewer on (DISPLAY and WAYLAND_DISPLAY are "
            "unset): give --save FILE.rrd --no-spawn and open the file where "
            "there is one"
        )


__all__ = [
    "convert",
    "save_rrd",
    "view",
    "spawn_viewer",
    "positions",
    "to_view",
    "blueprint",
    "describe_event",
    "Converted",
    "FAMILIES",
    "MARKERS",
    "TIMELINE",
    "RERUN_VERSION",
    "DERIVED",
]
