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

    def __init__(self, g=(-9.81, 0.0), name: str | None = None):
        super().__init__(name)
        self.g = np.asarray(g, dtype=float)
        if self.g.shape != (2,) or not np.all(np.isfinite(self.g)):
            raise ValueError(f"gravity g: expected two finite numbers (m/s²), got {g!r}")

    def bind(self, mechanism) -> None:
        self._weights = [(b.name, f"G_{b.name}", b.mass * self.g[0], b.mass * self.g[1], b.mass)
                         for b in mechanism.bodies]
        self._forces = [w[:4] for w in self._weights]
        self.acts_on = tuple(w[0] for w in self._weights)
        self._rows_of = None

    def loads(self, t, kin) -> Loads:
        return Loads(forces=self._forces)

    def _row_weights(self, kin) -> np.ndarray:
        """(m_b g_x, m_b g_y) at the rows of the centres of mass in ``kin``'s layout, flattened
        like ``kin.X`` (x0, y0, x1, y1, …); built once per layout."""
        if self._rows_of is not kin.names:
            w = np.zeros(2 * len(kin.names))
            for _, p, fx, fy, _m in self._weights:
                r = kin.names[p]
                w[2 * r] += fx
                w[2 * r + 1] += fy
            self._w, self._rows_of = w, kin.names
        return self._w

    def generalized_force(self, t, kin) -> np.ndarray:
        """Q = Σ_b m_b g·v*_Gb: the virtual work of :meth:`loads`, as one product."""
        return self._row_weights(kin) @ kin.J.reshape(-1, kin.J.shape[-1])

    def potential(self, kin) -> float:
        return -float(self._row_weights(kin) @ kin.X.reshape(-1))
