"""A run's energy account: the work ``W`` of the non-conservative effects, the impact losses
``E_impact`` and the potential energy ``V`` of the conservative ones.

``W`` is integrated per step by the trapezoid rule on the effects' power at the step's ends
(the power at the last accepted step's end is kept, so each step computes it once); impact
losses accumulate as the structure layer's impacts report them. The balance
``T + V − (T0 + V0) − W + E_impact`` closes to the integration error.
"""

from __future__ import annotations

__all__ = ["EnergyAccount"]


class EnergyAccount:
    """The energy bookkeeping of one run, over its scene's effects.

    ``work`` (W, J) and ``impact_loss`` (E_impact, J) are the run's totals so far, ``power_now``
    the non-conservative effects' power at the last accepted step's end (W). A checkpoint of
    the run keeps :meth:`state`."""

    __slots__ = ("_nc", "_potentials", "work", "impact_loss", "power_now")

    def __init__(self, effects) -> None:
        self._nc = [e for e in effects if not e.conservative]
        self._potentials = [e.potential for e in effects if e.conservative]
        self.work = 0.0
        self.impact_loss = 0.0
        self.power_now = 0.0

    def power(self, e) -> float:
        """The non-conservative effects' power at evaluation ``e`` (W)."""
        if e.Q_nc is not None:
            # Σ F·v + M·ω of the non-conservative loads is their virtual work along q̇
            p = 0.0
            for a, b in zip(e.Q_nc, e.kin._v()):
                p += a * b
            return p
        p = 0.0
        for eff in self._nc:
            p += eff.power(e.t, e.kin)
        return p

    def potential(self, kin) -> float:
        """V: the engine's ``potential_energy`` (the conservative effects' sum, in their order)
        over the list of those effects kept here (a test holds the two equal)."""
        v = 0
        for potential in self._potentials:
            v += potential(kin)
        return float(v)

    def state(self) -> tuple[float, float, float]:
        """(W, E_impact, power now), for :meth:`set_state`."""
        return self.work, self.impact_loss, self.power_now

    def set_state(self, state: tuple[float, float, float]) -> None:
        self.work, self.impact_loss, self.power_now = state
