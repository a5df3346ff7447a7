"""A twin's step as its messages (:class:`StepMessages`): as dicts in the field layout of their
ROS types, for readers and tests, or encoded (CDR), each into a buffer kept from one step to the
next: what the run publishes and records. ``/tf_static`` and ``~/structure`` are latched: each
goes out where it has not yet, or has changed."""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from typing import TYPE_CHECKING

from mps_core.dynamics.reactions import REACTION_COLUMNS

from .topics import FOUNDATION, FRAME_ID, JOINT_NAMES, WRENCHES

if TYPE_CHECKING:
    from .cdr import Preset
    from .frames import TfLayout
    from .markers import MarkerLayout

_RX = {c: i for i, c in enumerate(REACTION_COLUMNS)}
_CLOCK_HEAD = b"\x00\x01\x00\x00"  # CDR, little endian
_time = struct.Struct("<iI").pack


def stamp(t: float) -> dict:
    """builtin_interfaces/Time of a simulated time (s), to the nearest nanosecond."""
    ns = int(round(t * 1e9))
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def _effort(rx) -> list:
    return [rx[_RX["M_motor"]], math.nan, rx[_RX["M_latch"]], rx[_RX["F_stop"]]]


def _wrenches(outputs: tuple[str, ...], solve_reactions: bool) -> tuple:
    if not solve_reactions:
        return ()
    wrenches = WRENCHES if "reactions" in outputs else ()
    if "foundation" in outputs:
        wrenches = (*wrenches, FOUNDATION)
    return wrenches


class StepMessages:
    """The messages of a :class:`~mps_ros.run.twin.Twin`'s present step, in publishing order: as
    dicts (:meth:`dicts`) or encoded (:meth:`payloads`). It holds the topics' layouts
    (``frames``: ``/tf``; ``markers``: ``~/markers``, every ``marker_every`` steps, at about
    ``markers_hz``; ``wrenches``), the kept buffers each step's values are packed into, and what
    of the latched messages has gone out (``static_sent``: ``/tf_static``;
    ``structure_sent``: the last ``~/structure``), which a checkpoint of the twin keeps."""

    def __init__(
        self,
        scene,
        outputs: tuple[str, ...],
        solve_reactions: bool,
        dt: float,
        markers_hz: float = 30.0,
        markers_scale: float | None = None,
    ):
        self.outputs = outputs
        self.solve_reactions = solve_reactions
        self.wrenches = _wrenches(outputs, solve_reactions)
        # ~/markers at a display rate: every so many steps, never more often than the steps
        if not (markers_hz > 0 and math.isfinite(markers_hz)):
            raise ValueError(f"markers_hz {markers_hz!r}: expected a positive number")
        self.marker_every = max(1, int(round(1.0 / (markers_hz * dt))))
        self.markers: MarkerLayout | None = None
        if "markers" in outputs:
            from .markers import N_PER_M, MarkerLayout

            self.markers = MarkerLayout.of_scene(
                scene, self.wrenches or (), N_PER_M if markers_scale is None else markers_scale
            )
        self._marker_presets: dict = {}
        self.frames: TfLayout | None = None
        if "tf" in outputs:
            from .frames import TfLayout

            self.frames = TfLayout.of_scene(scene)
        self._tf: Callable[..., bytes] | None = None  # /tf's kept buffer (payloads)
        self.structure_sent: str | None = None
        self.static_sent = False  # /tf_static has gone out
        self._js: Preset | None = None  # the per-step messages' kept buffers (payloads)
        self._wr: list = []

    def _frame_values(self, sim) -> list:
        assert self.frames is not None  # called where /tf is published
        kin = sim.solver.current.kin
        return self.frames.at(kin.xy("A"), kin.xy("B"), kin.xy("C"))

    def _marker_values(self, sim, rx) -> list:
        assert self.markers is not None  # called where the markers are published
        phi, _, psi, _, x_c, _ = sim.joint_state()
        return self.markers.values(phi, psi, x_c, rx)

    def dicts(self, twin) -> list[tuple[str, dict]]:
        """``twin``'s present step as (topic key, message dict): see
        :meth:`~mps_ros.run.twin.Twin.state_messages`."""
        out: list[tuple[str, dict]] = []
        o = self.outputs
        sim = twin.sim
        t = sim.t
        st = stamp(t)
        if "clock" in o:
            out.append(("/clock", {"clock": st}))
        if self.frames is not None:
            if not self.static_sent:
                out.append(("/tf_static", self.frames.static_message(st)))
            out.append(("/tf", self.frames.message(st, self._frame_values(sim))))
        rx = twin.reaction_list()
        if "joint_states" in o:
            pos, vel = twin.joint_values()
            effort = _effort(rx) if rx is not None else []
            out.append(
                (
                    "joint_states",
                    {
                        "header": {"stamp": st, "frame_id": FRAME_ID},
                        "name": list(JOINT_NAMES),
                        "position": [float(v) for v in pos],
                        "velocity": [float(v) for v in vel],
                        "effort": [float(v) for v in effort],
                    },
                )
            )
        for w in self.wrenches:
            fx, fy = (0.0 if c is None else float(rx[_RX[c]]) for c in w.force)
            mz = 0.0 if w.torque is None else float(rx[_RX[w.torque]])
            out.append(
                (
                    w.key,
                    {
                        "header": {"stamp": st, "frame_id": w.frame_id},
                        "wrench": {
                            "force": {"x": fx, "y": fy, "z": 0.0},
                            "torque": {"x": 0.0, "y": 0.0, "z": mz},
                        },
                    },
                )
            )
        if "structure" in o and sim.structure != self.structure_sent:
            out.append(("~/structure", {"data": sim.structure}))
        if self.markers is not None and twin.k % self.marker_every == 0:
            out.append(("~/markers", self.markers.message(st, self._marker_values(sim, rx), sim.structure)))
        return out

    def _make_presets(self) -> Preset:
        from .cdr import Preset, joint_state, wrench_stamped

        effort = 4 if self.solve_reactions else 0

        def js(st, f):
            return {
                "header": {"stamp": st, "frame_id": FRAME_ID},
                "name": list(JOINT_NAMES),
                "position": f[0:4],
                "velocity": f[4:8],
                "effort": f[8 : 8 + effort],
            }

        def wrench(frame_id):
            def make(st, f):
                return {
                    "header": {"stamp": st, "frame_id": frame_id},
                    "wrench": {
                        "force": {"x": f[0], "y": f[1], "z": 0.0},
                        "torque": {"x": 0.0, "y": 0.0, "z": f[2]},
                    },
                }

            return make

        self._js = Preset(joint_state, js, 8 + effort)
        self._wr = [
            (
                w.key,
                Preset(
                    wrench_stamped,
                    wrench(w.frame_id),
                    3,
                    take=[None if c is None else _RX[c] for c in (*w.force, w.torque)],
                ).pack,
            )
            for w in self.wrenches
        ]
        return self._js

    def payloads(self, twin, t: float | None = None) -> list[tuple[str, bytes]]:
        """``twin``'s present step as (topic key, CDR bytes), the latched messages marked sent:
        see :meth:`~mps_ros.run.twin.Twin.state_payloads`; stamped ``t`` (s) where given, else
        with its run's time."""
        js = self._js if self._js is not None else self._make_presets()
        o = self.outputs
        sim = twin.sim
        ns = int(round((sim.t if t is None else t) * 1e9))
        sec, nsec = ns // 1_000_000_000, ns % 1_000_000_000
        out = []
        if "clock" in o:
            out.append(("/clock", _CLOCK_HEAD + _time(sec, nsec)))
        if self.frames is not None:
            if self._tf is None:
                from .cdr import Preset, generic_encoder
                from .frames import MSGTYPE

                self._tf = Preset(generic_encoder(MSGTYPE), self.frames.message, self.frames.nfloats).pack
            if not self.static_sent:
                from .cdr import generic_encoder
                from .frames import MSGTYPE

                self.static_sent = True
                out.append(
                    (
                        "/tf_static",
                        generic_encoder(MSGTYPE)(self.frames.static_message({"sec": sec, "nanosec": nsec})),
                    )
                )
            out.append(("/tf", self._tf(sec, nsec, self._frame_values(sim))))
        rx = twin.reaction_list()
        if "joint_states" in o:
            pos, vel = twin.joint_values()
            vals = pos + vel
            if rx is not None:
                vals += _effort(rx)
            out.append(("joint_states", js.pack(sec, nsec, vals)))
        for key, pack in self._wr:
            out.append((key, pack(sec, nsec, rx)))
        if "structure" in o:
            s = sim.structure
            if s != self.structure_sent:
                from .cdr import string

                self.structure_sent = s
                out.append(("~/structure", string({"data": s})))
        if self.markers is not None and twin.k % self.marker_every == 0:
            s = sim.structure
            preset = self._marker_presets.get(s)
            if preset is None:
                from .cdr import Preset, generic_encoder
                from .markers import MSGTYPE

                layout = self.markers
                preset = self._marker_presets[s] = Preset(
                    generic_encoder(MSGTYPE), lambda st, f: layout.message(st, f, s), layout.nfloats
                )
            out.append(("~/markers", preset.pack(sec, nsec, self._marker_values(sim, rx))))
        return out
