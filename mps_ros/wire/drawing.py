"""The press as it is drawn, defined once for every view of it (the Rerun view of a recording,
the live ``~/markers``): the links' colours, the slider's and the bearing's sizes, where each
reaction's arrow starts. Press frame (x up along the guide, y across; metres); pure Python.
"""

from __future__ import annotations

import math

#: the drawing's slider half width (across, y) and half height (along, x), and the bearing's
#: size, in units of l1
SLIDER = (0.45, 0.5)
BEARING = 0.35

COLORS = {
    "crank": (31, 119, 180),
    "rod": (255, 127, 14),
    "rocker": (44, 160, 44),
    "slider": (140, 140, 150),
    "frame": (90, 90, 90),
    "joint": (20, 20, 20),
    "latch_closed": (20, 170, 60),
    "latch_open": (170, 170, 170),
    "force": (214, 39, 40),
    "foundation": (148, 103, 189),
}


def joint_points(phi: float, psi: float, x_c: float, l1: float, l3: float) -> dict:
    """O, A, B, C (x, y) in the press frame from the joint states: A = l1(cos φ, sin φ),
    C = (x_C, 0), B = C + l3(cos ψ, sin ψ)."""
    return {
        "O": (0.0, 0.0),
        "A": (l1 * math.cos(phi), l1 * math.sin(phi)),
        "B": (x_c + l3 * math.cos(psi), l3 * math.sin(psi)),
        "C": (x_c, 0.0),
    }


def arrow_anchor(name: str, point: str, l1: float, x_top: float | None) -> tuple[str | None, float, float]:
    """Where a wrench's arrow starts, as (joint or None, dx, dy): that joint's point moved by
    (dx, dy), or the fixed point (dx, dy) (press frame, m). At its joint, except where several
    would overlap: the guide's force on the slider's face against the rail, the stop's on its
    ledge, the foundation resultant at the bearing's base below O."""
    if name == "stop" and x_top is not None:
        return None, x_top + SLIDER[1] * l1, 0.5 * (SLIDER[0] + SLIDER[0] + 0.1 + 0.25) * l1
    if name == "guide":
        return "C", 0.0, SLIDER[0] * l1
    if name == "foundation":
        return None, -BEARING * l1, 0.0
    return point, 0.0, 0.0


def latch_point(x_c: float, l1: float) -> tuple[float, float]:
    """The latch (rocker to slider), on the slider's side."""
    return (x_c, -SLIDER[0] * l1)
