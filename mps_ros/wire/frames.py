"""The press's frames, as ``/tf`` and ``/tf_static`` (``tf2_msgs/msg/TFMessage``) give them, so
that RViz2 and Foxglove place the wrenches (stamped ``press_A``, ``press_B``, ``press_C``) and
show the press upright.

::

    press_base  z up (REP-103), fixed
      └─ press  x up along the guide, y across, z out of the plane (contract §2), fixed
           ├─ press_O       the crank bearing O (the press frame's origin), fixed
           ├─ press_A       the crank pin A, every step
           ├─ press_B       the rod–rocker pin B, every step
           ├─ press_C       the rocker–slider pin C, every step
           └─ press_slider  the slider (its pin C, on the guide's axis), every step

The moving frames are parallel to ``press`` (a wrench stamped in one is about its origin, in
the press frame's directions), at the joints' points from the joint states exactly as
:func:`mps_ros.wire.drawing.joint_points` says. ``/tf_static`` is published once, latched;
``/tf`` at every step. :class:`TfLayout` gives the messages and, like
:class:`~mps_ros.wire.markers.MarkerLayout`, the floats that change from one step to the next, so
that a :class:`~mps_ros.wire.cdr.Preset` keeps the encoded ``/tf`` message and packs only those.
"""

from __future__ import annotations

from .drawing import joint_points
from .topics import FRAME_ID

MSGTYPE = "tf2_msgs/msg/TFMessage"
#: the z-up frame above ``press``: the press's x (up the guide) along its z, the press's y
#: along its x, the press's z (out of the plane) along its y
BASE_FRAME = "press_base"
#: ``press`` in ``press_base``: the rotation taking x to z, y to x, z to y (x, y, z, w)
PRESS_IN_BASE = (-0.5, -0.5, -0.5, 0.5)
#: the frames ``/tf`` moves, in order, with the joint each is at (:meth:`TfLayout.at`'s order)
MOVING = (("press_A", "A"), ("press_B", "B"), ("press_C", "C"), ("press_slider", "C"))
#: the fixed frames below ``press``, at their points (press frame, m)
FIXED = (("press_O", (0.0, 0.0)),)


def _transform(stamp: dict, parent: str, child: str, xyz, q=(0.0, 0.0, 0.0, 1.0)) -> dict:
    return {
        "header": {"stamp": stamp, "frame_id": parent},
        "child_frame_id": child,
        "transform": {
            "translation": {"x": float(xyz[0]), "y": float(xyz[1]), "z": float(xyz[2])},
            "rotation": {"x": q[0], "y": q[1], "z": q[2], "w": q[3]},
        },
    }


class TfLayout:
    """The frames of one scene's press (its crank ``l1`` and rocker ``l3``)."""

    def __init__(self, l1: float, l3: float):
        self.l1, self.l3 = float(l1), float(l3)

    @classmethod
    def of_scene(cls, scene) -> TfLayout:
        return cls(scene.geometry.l1, scene.geometry.l3)

    #: the floats of :meth:`values`
    nfloats = 2 * len(MOVING)

    def values(self, phi: float, psi: float, x_c: float) -> list:
        """The moving frames' origins (x, y in the press frame, m), in :data:`MOVING` order,
        from the joint states."""
        pts = joint_points(phi, psi, x_c, self.l1, self.l3)
        return self.at(pts["A"], pts["B"], pts["C"])

    @staticmethod
    def at(a, b, c) -> list:
        """:meth:`values` from the points A, B, C themselves (x, y each: a step's kinematics
        has them, the same to round-off)."""
        return [a[0], a[1], b[0], b[1], c[0], c[1], c[0], c[1]]

    @staticmethod
    def message(stamp: dict, f) -> dict:
        """``/tf`` at ``stamp``: the moving frames at :meth:`values` ``f``."""
        return {
            "transforms": [
                _transform(stamp, FRAME_ID, frame, (f[2 * i], f[2 * i + 1], 0.0))
                for i, (frame, _joint) in enumerate(MOVING)
            ]
        }

    @staticmethod
    def static_message(stamp: dict) -> dict:
        """``/tf_static``: ``press`` in ``press_base``, and the fixed frames in ``press``."""
        return {
            "transforms": [
                _transform(stamp, BASE_FRAME, FRAME_ID, (0.0, 0.0, 0.0), PRESS_IN_BASE),
                *(_transform(stamp, FRAME_ID, frame, (x, y, 0.0)) for frame, (x, y) in FIXED),
            ]
        }


__all__ = ["TfLayout", "MSGTYPE", "BASE_FRAME", "PRESS_IN_BASE", "MOVING", "FIXED"]
