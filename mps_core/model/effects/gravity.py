"""Gravity on every body's centre of mass."""

from __future__ import annotations

import numpy as np

from .base import Effect, Loads


class Gravity(Effect):
    """Uniform gravity ``g`` (m/s², frame axes) on each body's centre of mass.

    Potential energy ``V = −Σ m_b g·r_Gb``; the frame receives nothing directly (the weights reach
    it through the joints, which the reactions account for).
    """

    kind = "gravity"
    conservative = True
    constant_loads = True

    def __init__(self, g=(-9.81, 0.0), name: str | None = None):
        super().__init__(name)
        self.g = np.asarray(g, dtype=float)
        if self.g.shape != (2,) or not np.all(np.isfinite(self.g)):
            raise ValueError(f"gravity g: expected two finite numbers (m/s²), got {g!r}")

    def bind(self, mechanism) -> None:
        self._weights = [
            (b.name, f"G_{b.name}", b.mass * float(self.g[0]), b.mass * float(self.g[1]), b.mass)
            for b in mechanism.bodies
        ]
        self._forces = [w[:4] for w in self._weights]
        self.acts_on = tuple(w[0] for w in self._weights)
        self._com = [(p, fx, fy) for _, p, fx, fy, _m in self._weights]

    def loads(self, t, kin) -> Loads:
        return Loads(forces=self._forces)

    def generalized_force(self, t, kin) -> list:
        """Q = Σ_b m_b g·v*_Gb: the virtual work of :meth:`loads`."""
        return kin.weighted_analogs(self._com)

    def potential(self, kin) -> float:
        pose = kin.pose  # built once per state (the driver reads it every step)
        v = 0.0
        for p, fx, fy in self._com:
            x, y = pose[p]
            v -= fx * x + fy * y
        return v
