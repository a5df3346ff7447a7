"""The generalized forces of an engine's effects (seed (26)–(29)): Q_i = Σ F·v*_P,i + Σ M·ω*_b,i
over the loads of every effect that applies forces, with the non-conservative ones' share
(their power, the run's work) and the conservative ones' potential energy.

An effect may give its generalized force directly (``generalized_force(t, kin)``, a
:class:`~mps_core.model.effects.base.FastForce`: the same number in fewer operations); it is
used where the effect's class defines it together with its ``loads``. The effects' state, as the
engine's generated code folded it in, is a :class:`~mps_core.model.effects.base.Version` that
any assignment to them (or a change of the list) moves.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Self

from ..codegen.fused_kernels import fingerprint
from ..model.effects.base import FastForce, Version, has_hook, watch_all
from .kinematics import Kinematics, virtual_work

__all__ = ["EffectForces"]


def _owner(cls, name):
    for k in cls.__mro__:
        if name in k.__dict__:
            return k
    return None


def _fast_path(effect):
    """An effect's ``generalized_force(t, kin)`` (:class:`~mps_core.model.effects.base.FastForce`)
    where it has one for the same ``loads`` (a subclass that overrides ``loads`` alone keeps
    the general path)."""
    if not has_hook(effect, FastForce):
        return None
    cls = type(effect)
    gf = _owner(cls, "generalized_force")
    if gf is not None and gf is _owner(cls, "loads"):
        return effect.generalized_force
    return None


class _Effects(list):
    """An engine's effects: a change of the list (an effect added or taken away) moves the
    engine's version, so that no code made for the old list is used."""

    def __init__(self, forces, effects=()):
        super().__init__(effects)
        self._forces = forces

    def _changed(self):
        forces = self._forces
        if forces._paths is not None:
            forces._paths = forces._make_paths()

    def append(self, effect):
        super().append(effect)
        self._changed()

    def extend(self, effects):
        super().extend(effects)
        self._changed()

    def insert(self, i, effect):
        super().insert(i, effect)
        self._changed()

    def remove(self, effect):
        super().remove(effect)
        self._changed()

    def pop(self, i=-1):
        out = super().pop(i)
        self._changed()
        return out

    def clear(self):
        super().clear()
        self._changed()

    def __setitem__(self, i, value):
        super().__setitem__(i, value)
        self._changed()

    def __delitem__(self, i):
        super().__delitem__(i)
        self._changed()

    def __iadd__(self, effects: Iterable) -> Self:  # type: ignore[misc]  # as list's own: += takes any iterable, + a list
        super().extend(effects)
        self._changed()
        return self


class EffectForces:
    """The generalized forces of ``effects`` (bound to ``mechanism`` here).

    ``effects``: the list (a change of it moves ``version``); ``version``: the state of the
    effects and the controls they read, as the engine's generated code folded them in (moved by
    any assignment to them, no other engine's)."""

    def __init__(self, mechanism, effects=()) -> None:
        self._paths: tuple[int, list] | None = None
        self.effects = _Effects(self, effects)
        for e in self.effects:
            e.bind(mechanism)
        self.version = Version()
        self._paths = self._make_paths()
        self._fingerprint_of: tuple | None = None

    def paths(self) -> list:
        """[(fast path or None, effect, conservative)] of the effects that apply forces, in
        order: how :meth:`generalized` calls each (the generated code calls them so)."""
        paths = self._paths
        if paths is None or paths[0] != len(self.effects):
            paths = self._paths = self._make_paths()
        return paths[1]

    def generalized(self, t: float, kin: Kinematics) -> tuple[list, list]:
        """(Q, Q_nc): all the effects' generalized force and the non-conservative ones' share,
        n floats each."""
        paths = self._paths
        if paths is None or paths[0] != len(self.effects):
            paths = self._paths = self._make_paths()
        n = kin.n
        if n == 1:
            q, qc = 0.0, 0.0
            for fast, e, conservative in paths[1]:
                Qe = fast(t, kin) if fast is not None else virtual_work(e.loads(t, kin), kin)
                if Qe is not None:
                    if conservative:
                        qc += Qe[0]
                    else:
                        q += Qe[0]
            return [q + qc], [q]
        if n == 2:
            q0 = q1 = c0 = c1 = 0.0
            for fast, e, conservative in paths[1]:
                Qe = fast(t, kin) if fast is not None else virtual_work(e.loads(t, kin), kin)
                if Qe is not None:
                    if conservative:
                        c0 += Qe[0]
                        c1 += Qe[1]
                    else:
                        q0 += Qe[0]
                        q1 += Qe[1]
            return [q0 + c0, q1 + c1], [q0, q1]
        Q = [0.0] * n
        Qc = [0.0] * n
        for fast, e, conservative in paths[1]:
            Qe = fast(t, kin) if fast is not None else virtual_work(e.loads(t, kin), kin)
            if Qe is not None:
                if conservative:
                    for i in range(n):
                        Qc[i] += Qe[i]
                else:
                    for i in range(n):
                        Q[i] += Qe[i]
        Qnc = list(Q)
        for i in range(n):
            Q[i] += Qc[i]
        return Q, Qnc

    def _make_paths(self) -> tuple[int, list]:
        """(number of effects, [(fast path or None, effect, conservative)]) without the effects
        that apply no force of their own (``applies_forces`` False: a rigid stop, the latch);
        :attr:`version` watches every effect (and moves: the list changed)."""
        watch_all(self.effects, self.version)
        self.version[0] += 1
        return len(self.effects), [
            (_fast_path(e), e, bool(e.conservative))
            for e in self.effects
            if getattr(e, "applies_forces", True)
        ]

    def potential_energy(self, kin: Kinematics) -> float:
        return float(sum(e.potential(kin) for e in self.effects if e.conservative))

    def fingerprint(self):
        """:func:`~mps_core.codegen.fused_kernels.fingerprint` of the effects, made once per state
        of their parameters and controls."""
        version = self.version[0]
        kept = self._fingerprint_of
        if kept is None or kept[0] != version or kept[1] != len(self.effects):
            kept = self._fingerprint_of = (version, len(self.effects), fingerprint(self.effects))
        return kept[2]
