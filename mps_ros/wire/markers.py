"""The press as ``visualization_msgs/MarkerArray`` (``~/markers``), for RViz2 and Foxglove's 3D
panel, live or from a recording: the guide and the top stop, the crank, rod and rocker as lines
in their colours of the Rerun view, the slider block, the joints, the latch and its state, and
the reaction forces and the foundation resultant as arrows to one stated scale.

Everything is in the frame ``press`` (x up along the guide, y across, z out of the plane;
metres), stamped with the step's simulated time. Namespaces: ``frame``, ``links``, ``slider``,
``joints``, ``latch``, and ``reactions/<wrench> (1 m = N N)`` for the arrows (the scale in
the name: a force F is an arrow F/N metres long). Points come from the joint states and the scene's
geometry exactly as :func:`mps_ros.wire.drawing.joint_points` says.

:class:`MarkerLayout` gives the message from the step's values (:meth:`MarkerLayout.message`) and
the floats that change from one step to the next in the order the message takes them
(:meth:`MarkerLayout.values`), so that a :class:`~mps_ros.wire.cdr.Preset` keeps the encoded
message and packs only those.
"""

from __future__ import annotations

from mps_core.dynamics.reactions import REACTION_COLUMNS

from .drawing import COLORS, SLIDER, arrow_anchor, joint_points, latch_point
from .topics import FOUNDATION, FRAME_ID, WRENCHES

MSGTYPE = "visualization_msgs/msg/MarkerArray"
#: Marker types and action used here
ARROW, CUBE, SPHERE, LINE_LIST, SPHERE_LIST, TEXT = 0, 1, 2, 5, 7, 9
ADD = 0

#: default arrow scale: newtons a metre of arrow (press-cycle's forces of some 10 kN come out
#: about one crank radius long)
N_PER_M = 2e6


def _rgba(rgb, a: float = 1.0) -> dict:
    return {"r": rgb[0] / 255.0, "g": rgb[1] / 255.0, "b": rgb[2] / 255.0, "a": float(a)}


def _p(x: float, y: float, z: float = 0.0) -> dict:
    return {"x": float(x), "y": float(y), "z": float(z)}


_Q0 = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}


class MarkerLayout:
    """The markers of one scene: its geometry (``l1``, ``l3``, ``x_top``), the arrows it
    draws (the wrenches with a force, of those the run publishes; none without reactions)
    and their scale ``n_per_m``."""

    def __init__(self, l1: float, l3: float, x_top: float | None, *, arrows=(), n_per_m: float = N_PER_M):
        if not (n_per_m > 0):
            raise ValueError(f"markers scale {n_per_m!r}: expected a positive number of N/m")
        self.l1, self.l3, self.x_top = float(l1), float(l3), x_top
        self.n_per_m = float(n_per_m)
        #: (wrench, joint or None, dx, dy) of each arrow
        self.arrows = [
            (w, *arrow_anchor(w.name, w.point, self.l1, x_top))
            for w in arrows
            if any(c is not None for c in w.force)
        ]
        at = {c: i for i, c in enumerate(REACTION_COLUMNS)}
        self._cols = {w.name: tuple(None if c is None else at[c] for c in w.force) for w, *_ in self.arrows}
        #: each arrow's namespace: its wrench and the scale
        self.namespaces = [f"reactions/{w.name} (1 m = {self.n_per_m:g} N)" for w, *_ in self.arrows]

    @classmethod
    def of_scene(cls, scene, wrenches=(*WRENCHES, FOUNDATION), n_per_m: float = N_PER_M):
        g = scene.geometry
        return cls(g.l1, g.l3, scene.x_top, arrows=wrenches, n_per_m=n_per_m)

    # -- the floats of a step ---------------------------------------------------------------
    def values(self, phi: float, psi: float, x_c: float, rx=None) -> list:
        """The floats that change, in the order :meth:`message` takes them: the links' A, A, B,
        B and C's x; the joints' A, B and C's x; the slider's, the latch's and its label's x;
        then each arrow's start and end. ``rx``: the reactions, a list in
        :data:`~mps_core.dynamics.reactions.REACTION_COLUMNS` order (None: every arrow of zero
        length)."""
        pts = joint_points(phi, psi, x_c, self.l1, self.l3)
        (ax, ay), (bx, by) = pts["A"], pts["B"]
        out = [ax, ay, ax, ay, bx, by, bx, by, x_c, ax, ay, bx, by, x_c, x_c, x_c, x_c]
        s = 1.0 / self.n_per_m
        for w, base, dx, dy in self.arrows:
            x0, y0 = (dx, dy) if base is None else (pts[base][0] + dx, pts[base][1] + dy)
            fx = fy = 0.0
            if rx is not None:
                cx, cy = self._cols[w.name]
                fx = 0.0 if cx is None else rx[cx]
                fy = 0.0 if cy is None else rx[cy]
            out += [x0, y0, x0 + fx * s, y0 + fy * s]
        return out

    @property
    def nfloats(self) -> int:
        return 17 + 4 * len(self.arrows)

    # -- the message --------------------------------------------------------------------------
    def message(self, stamp: dict, f, structure: str) -> dict:
        """The MarkerArray at ``stamp`` from :meth:`values` ``f``, with the latch drawn for
        ``structure``."""
        l1 = self.l1
        head = {"stamp": stamp, "frame_id": FRAME_ID}
        w, h = SLIDER[0] * l1, SLIDER[1] * l1
        markers = []

        def marker(ns, mid, mtype, **kw):
            markers.append(_marker(head, ns, mid, mtype, **kw))

        # the frame: the guide's rails, its axis, the bearing at O, the top stop's ledges
        lo, hi = -l1 - h - 0.3 * l1, l1 + (self.x_top or l1) + h + 0.3 * l1
        rail = w + 0.1 * l1
        lines = [(lo, -rail), (hi, -rail), (lo, rail), (hi, rail), (0.0, 0.0), (-0.35 * l1, 0.0)]
        if self.x_top is not None:
            x = self.x_top + h
            lines += [(x, -rail - 0.25 * l1), (x, -w), (x, w), (x, rail + 0.25 * l1)]
        marker("frame", 0, LINE_LIST, scale=(0.04 * l1, 0.0, 0.0), color=COLORS["frame"], points=lines)
        # the links: crank O-A, rod A-B, rocker B-C, each in its colour
        marker(
            "links",
            0,
            LINE_LIST,
            scale=(0.12 * l1, 0.0, 0.0),
            color=COLORS["crank"],
            points=[(0.0, 0.0), (f[0], f[1]), (f[2], f[3]), (f[4], f[5]), (f[6], f[7]), (f[8], 0.0)],
            colors=[COLORS["crank"]] * 2 + [COLORS["rod"]] * 2 + [COLORS["rocker"]] * 2,
        )
        marker(
            "joints",
            0,
            SPHERE_LIST,
            scale=(0.2 * l1, 0.2 * l1, 0.2 * l1),
            color=COLORS["joint"],
            points=[(0.0, 0.0), (f[9], f[10]), (f[11], f[12]), (f[13], 0.0)],
        )
        marker(
            "slider", 0, CUBE, position=(f[14], 0.0), scale=(2 * h, 2 * w, 0.1 * l1), color=COLORS["slider"]
        )
        closed = structure == "locked"
        ly = latch_point(0.0, l1)[1]
        marker(
            "latch",
            0,
            SPHERE,
            position=(f[15], ly),
            scale=(0.3 * l1,) * 3,
            color=COLORS["latch_closed" if closed else "latch_open"],
        )
        marker(
            "latch",
            1,
            TEXT,
            position=(f[16], ly - 0.9 * l1),
            scale=(0.0, 0.0, 0.3 * l1),
            color=COLORS["joint"],
            text=("latch closed" if closed else "latch open") + f" ({structure})",
        )
        for i, (wr, *_anchor) in enumerate(self.arrows):
            x0, y0, x1, y1 = f[17 + 4 * i : 21 + 4 * i]
            marker(
                self.namespaces[i],
                0,
                ARROW,
                scale=(0.06 * l1, 0.12 * l1, 0.15 * l1),
                color=COLORS["foundation" if wr is FOUNDATION else "force"],
                points=[(x0, y0), (x1, y1)],
            )
        return {"markers": markers}


def _marker(
    head: dict,
    ns: str,
    mid: int,
    mtype: int,
    *,
    position=(0.0, 0.0),
    scale=(1.0, 1.0, 1.0),
    color=(0, 0, 0),
    points=(),
    colors=(),
    text="",
) -> dict:
    """One visualization_msgs/Marker (ADD, never expiring) in the field layout of its type."""
    return {
        "header": head,
        "ns": ns,
        "id": mid,
        "type": mtype,
        "action": ADD,
        "pose": {"position": _p(*position), "orientation": dict(_Q0)},
        "scale": _p(*scale),
        "color": _rgba(color),
        "lifetime": {"sec": 0, "nanosec": 0},
        "frame_locked": False,
        "points": [_p(*p) for p in points],
        "colors": [_rgba(c) for c in colors],
        "texture_resource": "",
        "texture": {
            "header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""},
            "format": "",
            "data": b"",
        },
        "uv_coordinates": [],
        "text": text,
        "mesh_resource": "",
        "mesh_file": {"filename": "", "data": b""},
        "mesh_use_embedded_materials": False,
    }


__all__ = ["MarkerLayout", "MSGTYPE", "N_PER_M"]
