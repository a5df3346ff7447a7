"""The effects of a vectorised batch's scenes as parameter arrays, one value a scene
(:mod:`mps_core.run.batch`): their generalized forces and power, their potential energy, and
the loads the reaction kernel takes, for all scenes at once.

The effects vectorised are gravity, the motor, the retention springs, the slider's damper and
the blanking force; every scene of a batch has the same kinds (its group's key). The
kinematics come as :class:`mps_core.run.batch` hands them: positions ``x(row, c)``, analogs
``jac(row, c)`` and angular analogs ``omega(body)``, one array (or a float shared by all) a
number.
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np

from ...model.effects import Blanking, Gravity, Motor, RetentionSprings, SliderDamper


class EffectArrays:
    """The effects of ``lists`` (one list of effects a scene) on the mechanism ``mech``:
    ``rows`` its points' and centres of mass' rows in the kinematics, ``mass`` (scene, body),
    ``structure`` the scenes' (blanking acts in ``locked`` only)."""

    def __init__(self, mech, rows: dict, mass: np.ndarray, structure: str, lists):
        bodies = mech.bodies
        names = [b.name for b in bodies]
        self.m: int | tuple[int, int] = mass.shape[0]  # the shape of one value a scene
        self.structure = structure
        self.com_rows = [rows[f"G_{b.name}"] for b in bodies]
        self.c = rows["C"]
        self.o = rows.get("O")
        self.nb = len(bodies)
        #: the body the effects along the guide act on, at C (springs, damper, blanking)
        self.slider: int | None = names.index("slider") if "slider" in names else None

        def take(cls):
            found = [[e for e in lst if type(e) is cls] for lst in lists]
            return [f[0] for f in found] if all(found) else None

        g = take(Gravity)
        # each body's weight (m g, x and y), one array a component: None without gravity
        self.weight_of = (
            None
            if g is None
            else [[mass[:, b] * np.array([e.g[c] for e in g]) for c in (0, 1)] for b in range(len(bodies))]
        )
        mo = take(Motor)
        self.motor: dict[str, Any] | None = (
            None
            if mo is None
            else {
                "index": names.index(mo[0].body),
                "ratio": np.array([e.ratio for e in mo]),
                "eff": np.array([e.efficiency for e in mo]),
                "wsync": np.array([e.data.omega_sync for e in mo]),
                "mk": np.array([e.data.breakdown_torque for e in mo]),
                "sk": np.array([e.data.breakdown_slip for e in mo]),
                "on": np.array([1.0 if e.enabled else 0.0 for e in mo]),
            }
        )
        if self.motor is not None:  # the torque's factors that no state changes
            mo = self.motor
            mo["gain"] = mo["on"] * mo["ratio"] * mo["eff"]
            mo["2mk"] = 2.0 * mo["mk"]
            mo["sk2"] = mo["sk"] * mo["sk"]
        #: gravity's terms of the generalized forces: (row, component, coordinate, weight),
        #: found at the first evaluation
        self._weighed: list | None = None
        sp = take(RetentionSprings)
        self.springs = (
            None
            if sp is None
            else (np.array([e.k for e in sp]), np.array([e.f0 for e in sp]), np.array([e.x_top for e in sp]))
        )
        da = take(SliderDamper)
        self.damper = None if da is None else np.array([e.c for e in da])
        bl = take(Blanking)
        self.blanking = (
            None
            if bl is None
            else (
                np.array([e.f for e in bl]),
                np.array([e.x_contact for e in bl]),
                np.array([e.pb for e in bl]),
            )
        )
        #: the last evaluation's motor torque and force along x at C (None: no such effect)
        self.at_C: tuple = (None, None)

    def forces(self, kin, v) -> tuple[list, np.ndarray]:
        """Generalized forces (one array, or a number, a coordinate) and the power of the
        non-conservative effects; ``v``: q̇, one array a coordinate. Keeps the motor's torque
        and the force along x at C in :attr:`at_C` for :meth:`loads`."""
        n = len(v)
        Q: list = [0.0] * n
        power = np.zeros(self.m)
        jc = kin.jac(self.c, 0)  # ∂x_C/∂q
        reads_speed = self.damper is not None or self.blanking is not None
        vC = sum(jc[i] * v[i] for i in range(n)) if reads_speed else 0.0  # the slider's speed
        if self.weight_of is not None:
            if self._weighed is None:  # the analogs the kinematics give as numbers 0 are left out
                self._weighed = [
                    (row, cc, i, self.weight_of[b][cc])
                    for b, row in enumerate(self.com_rows)
                    for cc in (0, 1)
                    for i in range(n)
                    if not (isinstance(kin.jac(row, cc)[i], float) and kin.jac(row, cc)[i] == 0.0)
                ]
            for row, cc, i, mg in self._weighed:
                Q[i] = Q[i] + mg * kin.jac(row, cc)[i]
        if self.motor is not None:
            mo = self.motor
            wk = kin.omega(mo["index"])
            w = sum(wk[i] * v[i] for i in range(n))
            s = 1.0 - mo["ratio"] * w / mo["wsync"]
            torque = mo["gain"] * (mo["2mk"] * s * mo["sk"] / (s * s + mo["sk2"]))
            for i in range(n):
                Q[i] = Q[i] + torque * wk[i]
            power += torque * w
        else:
            torque = None
        xC = kin.x(self.c, 0)
        forces = []  # along the guide, at C
        if self.springs is not None:
            k, f0, xt = self.springs
            forces.append(f0 + k * (xt - xC))
        if self.damper is not None:
            f = -self.damper * vC
            forces.append(f)
            power += f * vC
        if self.blanking is not None and self.structure == "locked":
            fmax, xcon, pb = self.blanking
            p = xcon - xC
            on = (vC < 0.0) & (p > 0.0) & (p < pb)
            f = np.where(on, fmax * np.sin(np.pi * np.clip(p, 0.0, None) / pb), 0.0)
            forces.append(f)
            power += f * vC
        for f in forces:
            for i in range(n):
                Q[i] = Q[i] + f * jc[i]
        self.at_C = (torque, sum(forces) if forces else None)
        return Q, power

    def potential(self, kin) -> np.ndarray:
        """The conservative effects' potential energy (gravity, the springs), one a scene."""
        V = np.zeros(self.m)
        if self.weight_of is not None:
            for b, row in enumerate(self.com_rows):
                for cc in (0, 1):
                    V -= self.weight_of[b][cc] * kin.x(row, cc)
        if self.springs is not None:
            k, f0, xt = self.springs
            s = xt - kin.x(self.c, 0)
            V += f0 * s + 0.5 * k * s * s
        return V

    def take(self, scenes: np.ndarray, states: int | None = None) -> EffectArrays:
        """These effects for the scenes ``scenes`` (indices, one a state to evaluate: a scene
        may come many times), their parameters gathered in that order; with ``states``, for
        kinematics of shape (scene, states): the parameters (scene, 1)."""

        def pick(x):
            if isinstance(x, np.ndarray):
                return x[scenes] if states is None else x[scenes, None]
            if isinstance(x, (list, tuple)):
                return type(x)(pick(v) for v in x)
            if isinstance(x, dict):
                return {k: pick(v) for k, v in x.items()}
            return x

        out = copy.copy(self)
        out.m = len(scenes) if states is None else (len(scenes), states)  # its forces' shape
        out.weight_of, out.motor = pick(self.weight_of), pick(self.motor)
        out.springs, out.damper, out.blanking = pick(self.springs), pick(self.damper), pick(self.blanking)
        out.at_C = (None, None)
        out._weighed = None  # its weights gathered
        return out

    def loads(self, kin) -> list:
        """The effects' loads at the last evaluated state as the reaction kernel takes them
        (:class:`~mps_core.codegen.load_sums.LoadSums`): per body the force (x, y) and its
        moment about O, then the frame's own (force x, y, moment about O) and the motor's
        torque; from that evaluation's kinematics ``kin`` and :attr:`at_C`."""
        nb = self.nb
        out: list = [0.0] * (3 * nb + 4)
        o = self.o
        ox, oy = (kin.x(o, 0), kin.x(o, 1)) if o is not None else (0.0, 0.0)

        def add(i: int, x) -> None:  # never in place: an entry may take a larger shape
            out[i] = out[i] + x

        if self.weight_of is not None:
            for b, row in enumerate(self.com_rows):
                fx, fy = self.weight_of[b]
                add(3 * b, fx)
                add(3 * b + 1, fy)
                add(3 * b + 2, (kin.x(row, 0) - ox) * fy - (kin.x(row, 1) - oy) * fx)
        torque, f = self.at_C
        if torque is not None:
            assert self.motor is not None
            k = self.motor["index"]
            add(3 * k + 2, torque)
            add(3 * nb + 2, -torque)  # the stator's
            add(3 * nb + 3, torque)
        if f is not None:  # along x at C on the slider, the frame the opposite
            k = self.slider
            assert k is not None, "a force along the guide with no slider"
            py = kin.x(self.c, 1) - oy
            add(3 * k, f)
            add(3 * k + 2, -py * f)
            add(3 * nb, -f)
            add(3 * nb + 2, py * f)
        return out
