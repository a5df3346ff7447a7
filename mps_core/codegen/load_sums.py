"""The known loads of a reaction kernel (:mod:`.reaction_kernels`), summed as floats: per body the
force and its moment about O of every effect's forces and torques, the frame's own entries and
the motor's torque (:class:`LoadSums`), by the effects' ``loads`` one by one or by those sums
traced into generated code (:func:`traced_sums`), the effects' parameters and controls folded in."""

from __future__ import annotations

import math

from ..derivatives.tracing import BranchChanged, Tape, Traced
from ..model.effects.base import Version, watch_all
from .emitter import inline_once, live_lines, load
from .fused_kernels import emit_tape, fingerprint, input_slot, live_inputs


class LoadSums:
    """The known loads a reaction kernel takes, as floats: per body (in the mechanism's order)
    the force (x, y) and the moment about O of every effect's forces and torques on it; then
    the frame's own entries (force x, y, moment about O) and the motor's torque. The general
    path's sums, taken with the step's kinematics (``kin``'s positions).

    Made once per list of effects: effects that apply no force of their own (a rigid stop, the
    latch) are left out, and the loads of effects whose loads do not depend on the state
    (``constant_loads``, e.g. gravity) are read once."""

    def __init__(self, effects, mechanism):
        self.bodies = {b.name: k for k, b in enumerate(mechanism.bodies)}
        self.nb = nb = len(self.bodies)
        #: the state of the effects and their controls (moved by any assignment to them)
        self.version = Version()
        watch_all(effects, self.version)
        self.effects = []
        self.constant = []  # (point, body row, fx, fy) of constant forces
        base = [0.0] * (3 * nb + 4)
        for e in effects:
            if not getattr(e, "applies_forces", True):
                continue
            if getattr(e, "constant_loads", False):
                ld = e.loads(0.0, None)
                for body, point, fx, fy in ld.forces:
                    if not isinstance(point, str):
                        raise ValueError(f"effect {e.name!r}: constant loads at named points only")
                    self.constant.append((point, 3 * self.bodies[body], float(fx), float(fy)))
                for body, mz in ld.torques:
                    base[3 * self.bodies[body] + 2] += mz
                if ld.frame:
                    raise ValueError(f"effect {e.name!r}: constant loads on the frame")
                continue
            self.effects.append((e, e.kind == "motor"))
        for _p, k, fx, fy in self.constant:
            base[k] += fx
            base[k + 1] += fy
        self.base = base
        self._names = None  # the kinematics' names the rows below are read from
        self._rows = None
        #: the sums as generated code per number of coordinates (:func:`traced_sums`):
        #: [functions, most recent first], for the effects' state ``_traced_at``; kept per
        #: state of their parameters and controls (a command, a change of structure, and back)
        self._traced: dict = {}
        self._traced_at = -1
        self._by_state: dict = {}
        self._traces = 0

    def _refresh(self) -> None:
        """The traced sums of the effects' present state (parameters and controls)."""
        if self._traced_at != self.version[0]:
            self._traced_at = self.version[0]
            state = fingerprint([e for e, _motor in self.effects])
            if state is None:
                self._traced = {}
            else:
                if len(self._by_state) > 64:
                    self._by_state.clear()
                self._traced = self._by_state.setdefault(state, {})

    def first(self, n: int):
        """The traced sums for n coordinates that held last (``fn(t, xl, jl, wl, vl)``), or
        None where there is none yet."""
        self._refresh()
        made = self._traced.get(n)
        return made[0] if made else None

    def __call__(self, t: float, kin) -> list:
        """The sums at a state: by generated code where it holds (the same operations on the
        same numbers of ``kin``), else :meth:`sums`."""
        xl, jl, wl = kin._xl, kin._jl, kin._wl
        if xl is not None and jl is not None and wl is not None:
            self._refresh()
            vl = kin._vl if kin._vl is not None else kin._v()
            made = self._traced.get(kin.n)
            if made is None and self._traces < 64:
                self._traces += 1
                fn = traced_sums(self, t, kin)
                made = self._traced[kin.n] = [fn] if fn is not None else []
            for k, fn in enumerate(made or ()):
                try:
                    out = fn(t, xl, jl, wl, vl)
                except (BranchChanged, ArithmeticError, ValueError):
                    continue
                if k:  # a later branch held: it goes first next time
                    assert made is not None  # k > 0: made has entries
                    made.insert(0, made.pop(k))
                return out
            if made and len(made) < 6 and self._traces < 64:  # another branch of a law
                self._traces += 1
                fn = traced_sums(self, t, kin)
                if fn is not None:
                    made.insert(0, fn)
        return self.sums(t, kin)

    def sums(self, t: float, kin, live: dict | None = None) -> list:
        """The sums by the effects' ``loads``, one by one (the general path); ``live``: a
        ``live`` effect's values to take its loads at (by the effect), where given (a trace's)."""
        out = self.base[:]
        names = kin.names
        if self._rows is None or self._names is not names:
            self._names = names
            self._rows = [(2 * names[p], k, fx, fy) for p, k, fx, fy in self.constant]
            self._o = 2 * names["O"] if "O" in names else None
        xl = kin._xl if kin._xl is not None else kin._lists()[0]
        r = self._o
        ox, oy = (xl[r], xl[r + 1]) if r is not None else (0.0, 0.0)
        for r, k, fx, fy in self._rows:
            out[k + 2] += (xl[r] - ox) * fy - (xl[r + 1] - oy) * fx
        fr = 3 * self.nb
        bodies = self.bodies
        for e, motor in self.effects:
            ld = e.live_loads(t, kin, live[e]) if live is not None and e in live else e.loads(t, kin)
            # a force at a point (a name or (x, y)) into slots k (x), k + 1 (y), k + 2 (M_O)
            for body, point, fx, fy in ld.forces:
                k = 3 * bodies[body]
                px, py = _arm(point, names, xl, ox, oy)
                out[k] += fx
                out[k + 1] += fy
                out[k + 2] += px * fy - py * fx
            for body, mz in ld.torques:
                out[3 * bodies[body] + 2] += mz
                if motor:
                    out[fr + 3] += mz
            for entry in ld.frame:
                if len(entry) == 4:
                    _, point, fx, fy = entry
                    px, py = _arm(point, names, xl, ox, oy)
                    out[fr] += fx
                    out[fr + 1] += fy
                    out[fr + 2] += px * fy - py * fx
                else:
                    out[fr + 2] += entry[1]
        return out


def traced_sums(sums: LoadSums, t: float, kin):
    """``fn(t, xl, jl, wl, vl) -> list``: :meth:`LoadSums.sums` traced at (t, ``kin``) into
    generated code reading the kinematics' lists by index, the effects' parameters and the
    controls folded in, their comparisons guards (a failed one raises
    :class:`~mps_core.derivatives.tracing.BranchChanged`); None where a law cannot be traced.
    A ``live`` effect's values are read at each call from its list (``_live{j}[k]``), as the
    fused functions read them (:mod:`.fused_kernels`)."""
    tape = Tape()
    slots: list[str] = []
    slot = input_slot(tape, slots)
    vl = kin._vl if kin._vl is not None else kin._v()
    tl = {
        name: [slot(f"{name}[{i}]", x) for i, x in enumerate(values)]
        for name, values in (("xl", kin._xl), ("jl", kin._jl), ("wl", kin._wl), ("vl", vl))
    }
    tkin = type(kin)(
        slot("t", t),
        None,
        None,
        kin.names,
        bodies=kin.bodies,
        lists=(tl["xl"], tl["jl"], tl["wl"]),
        v=tl["vl"],
    )
    lives: dict[str, list] = {}
    live: dict = {}
    for e, _motor in sums.effects:
        if getattr(e, "live", False):
            live[e] = live_inputs(e, slot, lives)
    try:
        out = sums.sums(tkin.t, tkin, live)
        values = [x.value if isinstance(x, Traced) else float(x) for x in out]
        if not all(math.isfinite(v) for v in values):
            return None
    except Exception:
        return None
    nodes = tuple(x.index if isinstance(x, Traced) else float(x) for x in out)
    key = ("load sums", tape.key(), tuple(slots), nodes)
    return load(
        key,
        lambda: _sums_source(tape, slots, nodes),
        "<load sums>",
        None,
        "",
        {"tanh": math.tanh, "_Branch": BranchChanged, **lives},
    )


def _sums_source(tape, slots, nodes) -> str:
    """Write the traced load sums' code (:func:`traced_sums`): the tape, and the sums (``nodes``:
    their nodes or constants) returned."""
    body: list = []
    code = emit_tape(body, tape, slots)
    items = [code(x) if isinstance(x, int) else repr(x) for x in nodes]
    ret = f"    return [{', '.join(items)}]"
    return "def kernel(t, xl, jl, wl, vl):\n" + "\n".join(inline_once(live_lines(body, ret) + [ret])) + "\n"


def _arm(point, names, xl, ox, oy) -> tuple[float, float]:
    """A point (a name or (x, y)) relative to O."""
    if point.__class__ is str:
        r = 2 * names[point]
        return xl[r] - ox, xl[r + 1] - oy
    return float(point[0]) - ox, float(point[1]) - oy


__all__ = ["LoadSums", "traced_sums"]
