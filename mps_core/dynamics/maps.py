"""What the engine's evaluations of one mechanism reuse, built once per engine
(:mod:`mps_core.dynamics.engine`).

The centres of mass and the rotating bodies' link vectors are linear in the points'
coordinates, so one matrix ``M`` maps the points' coordinates (x0, y0, x1, y1, …) to all named
points, centres of mass and link vectors; with it the rows by name, the bodies' masses and
inertias, and the weights of the mass matrix A = U diag(w) Uᵀ. The generated code reads the same
numbers as one frozen :class:`~mps_core.codegen.emitter.Tables` (:attr:`MechanismMaps.tables`).
"""

from __future__ import annotations

import numpy as np

from ..codegen.emitter import Tables

__all__ = ["MechanismMaps"]


class MechanismMaps:
    """The maps of one ``mechanism``.

    ``point_names``: its points, in the order of the position function's outputs; ``names``:
    every named row (the points, then ``G_<body>`` for each centre of mass) by its number;
    ``body_index``: the bodies by name; ``mass``, ``inertia``: by body; ``rot``: the rotating
    bodies' numbers; ``MT``, ``offset``: see :meth:`_build`; ``npoints`` (named rows),
    ``npts`` (points), ``nrot`` (rotating bodies): counts; ``weights``: the weights of U's rows
    [v*_G (x, y per body); ω*_rot] in A = U diag(w) Uᵀ; ``point_slots``: (point, row of x, row
    of y) in the points' matrix."""

    def __init__(self, mechanism) -> None:
        bodies = mechanism.bodies
        self.point_names = list(mechanism.points)
        self.names = {p: k for k, p in enumerate(self.point_names)}
        for b in bodies:
            self.names[f"G_{b.name}"] = len(self.names)
        self.body_index = {b.name: k for k, b in enumerate(bodies)}
        self.mass = np.array([b.mass for b in bodies])
        self.inertia = np.array([b.inertia for b in bodies])
        self.rot = [k for k, b in enumerate(bodies) if b.rotates]
        self._build(mechanism)
        #: what the generated code reads of the mechanism (:mod:`mps_core.codegen.emitter`)
        self.tables = Tables(
            point_names=tuple(self.point_names),
            names=self.names,
            body_index=self.body_index,
            mass=self.mass,
            inertia=self.inertia,
            rot=tuple(self.rot),
            MT=self.MT,
            offset=self.offset,
            fixed_points=tuple(getattr(mechanism, "fixed_points", ())),
        )

    def _build(self, mech) -> None:
        """The map from the points' coordinates (x0, y0, x1, y1, …) to, in pairs (x, y): the
        named points and centres of mass (pairs 0 … NP−1), the rotating bodies' link vectors
        toward − origin (pairs NP … NP+nrot−1), and a pair (Σ of everything, 0) that makes a
        non-finite position show in one number. Kept transposed (``MT``), so that a result's
        last axis is x, y, x, y, …: viewed as complex numbers x + iy, an angular analog is
        ω* = (r × v*)/|r|² = Im(v*/r) in one division. ``offset``: the centres of mass'
        constant offsets (None: all zero)."""
        names = self.names
        npts = len(self.point_names)
        NP = len(names)
        nrot = len(self.rot)
        M = np.zeros((2 * NP + 2 * nrot + 2, 2 * npts))
        offset = np.zeros((NP, 2))
        for k in range(npts):
            M[2 * k, 2 * k] = M[2 * k + 1, 2 * k + 1] = 1.0
        for b in mech.bodies:
            r = 2 * names[f"G_{b.name}"]
            o = 2 * names[b.origin]
            a, c = b.com
            if b.toward is None:
                M[r, o] = M[r + 1, o + 1] = 1.0
                offset[r // 2] = (a, c)
                continue
            t = 2 * names[b.toward]
            al, be = a / b.length, c / b.length
            # G = P_o + al (P_t − P_o) + be n(P_t − P_o), n(x, y) = (−y, x)   (Body.com_of)
            M[r, o] += 1.0 - al
            M[r, t] += al
            M[r, t + 1] -= be
            M[r, o + 1] += be
            M[r + 1, o + 1] += 1.0 - al
            M[r + 1, t + 1] += al
            M[r + 1, t] += be
            M[r + 1, o] -= be
        for j, k in enumerate(self.rot):
            b = mech.bodies[k]
            r = 2 * NP + 2 * j
            o, t = 2 * names[b.origin], 2 * names[b.toward]
            M[r, t] += 1.0
            M[r, o] -= 1.0
            M[r + 1, t + 1] += 1.0
            M[r + 1, o + 1] -= 1.0
        M[-2, :] = 1.0
        self.MT = np.ascontiguousarray(M.T)
        self.offset = offset.reshape(-1) if np.any(offset != 0.0) else None
        self.npoints, self.npts, self.nrot = NP, npts, nrot
        nbody = len(mech.bodies)
        # weights of U's rows [v*_G (x, y per body); ω*_rot]: A = U diag(w) Uᵀ
        self.weights = np.concatenate((np.repeat(self.mass, 2), self.inertia[self.rot]))
        self.rot_all = self.rot == list(range(nbody))
        self.rot_idx = np.array(self.rot, dtype=int)
        self.point_slots = [(p, 2 * k, 2 * k + 1) for k, p in enumerate(self.point_names)]

    def omega_rows(self, Wr, n):
        """(nbody, n) angular analogs from the rotating bodies' (n, nrot)."""
        if self.rot_all:
            return Wr.T
        W = np.zeros((len(self.mass), n))
        W[self.rot_idx] = Wr.T
        return W
