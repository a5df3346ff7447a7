"""The contract of an effect: a small unit that applies forces and torques to the mechanism.

An effect declares the points and bodies it acts on (``acts_on``), is bound once to a mechanism
(names checked, indices cached), and then, for a kinematic state, returns its **loads**: forces at
points of bodies and torques on bodies, in the frame's axes. The engine turns loads into
generalized forces by virtual work, ``Q_i = Σ F·v*_P,i + Σ M·ω*_b,i``; adding an effect never
touches the engine. A conservative effect also gives its potential energy.
"""

from __future__ import annotations

import functools
import weakref
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np


@dataclass
class Loads:
    """What an effect applies, in the frame's axes.

    ``forces``: ``(body, point, Fx, Fy)``, a force on a moving body at one of its points (a
    mechanism point or a centre of mass ``G_<body>``); ``torques``: ``(body, M)``.
    ``frame``: what the same effect applies to the frame (for the foundation load), forces
    ``("frame", point, Fx, Fy)`` and torques ``("frame", M)``; empty where it has no reaction there.
    """

    forces: list = field(default_factory=list)
    torques: list = field(default_factory=list)
    frame: list = field(default_factory=list)


class Version(list):
    """``[n]``: a counter of the state of the effects and controls that an engine (or another
    holder of generated code) reads, moved by every assignment to an attribute of any of
    them (:class:`Watched`). Code generated with their values folded in
    (:mod:`mps_core.codegen.fused_kernels`) holds while it has not moved. Each engine has its
    own: a run's commands never move another run's counter."""

    def __init__(self):
        super().__init__([0])

    # one counter is one object (kept in weak sets): by identity, not by its count
    __eq__ = object.__eq__
    __ne__ = object.__ne__
    __hash__ = object.__hash__  # type: ignore[assignment]


class Watched:
    """Mixin: every assignment to an attribute moves the :class:`Version` counters watching
    the object (:meth:`watch`; held weakly: a counter goes with its holder)."""

    def __setattr__(self, name, value):
        object.__setattr__(self, name, value)
        watchers = self.__dict__.get("_watchers")
        if watchers:
            for version in watchers:
                version[0] += 1

    def watch(self, version: Version) -> None:
        watchers = self.__dict__.get("_watchers")
        if watchers is None:
            watchers = weakref.WeakSet()
            object.__setattr__(self, "_watchers", watchers)
        watchers.add(version)

    def touch(self) -> None:
        """Move the counters watching this object (its state was changed behind
        ``__setattr__``, e.g. restored from a checkpoint)."""
        for version in self.__dict__.get("_watchers") or ():
            version[0] += 1


def watch_all(effects, version: Version) -> None:
    """``version`` watches each effect and the controls each reads."""
    for e in effects:
        if isinstance(e, Watched):
            e.watch(version)
        controls = getattr(e, "controls", None)
        if isinstance(controls, Watched):
            controls.watch(version)


class Effect(Watched):
    """Base class. Subclasses set ``kind`` and implement :meth:`loads`.

    A force law written in plain arithmetic on what ``kin`` gives (comparisons where it
    branches; ``sin``, ``cos``, ``sqrt``, ``tanh`` from :mod:`mps_core.derivatives.tracing`) is traced into
    the engine's generated code (:mod:`mps_core.codegen.fused_kernels`) with its parameters folded in;
    one that does anything else keeps the general path. Parameters are read when the code is
    made: set them by assignment (which moves the :class:`Version` of every engine that reads
    the effect), not in place."""

    kind: str = "effect"
    conservative: bool = False
    #: False for an effect that never applies a force of its own (a rigid stop, the latch: the
    #: structure does their work); the engine leaves it out of Q
    applies_forces: bool = True
    #: True for an effect whose loads do not depend on the state, time or controls (gravity):
    #: a caller may read them once, ``loads(0.0, None)``
    constant_loads: bool = False
    #: True for an effect whose values change between evaluations, in place, without an
    #: assignment (an estimator's unknown inputs): it has ``values`` (a list of floats) and
    #: ``live_loads(t, kin, values)``, its loads at those values. Generated code reads the
    #: list at each call (never folds it in), and is not shared with another engine's
    live: bool = False

    def __init__(self, name: str | None = None):
        self.name = name or self.kind

    #: the points and bodies this effect acts on (names), filled in by :meth:`bind`
    acts_on: tuple[str, ...] = ()

    def bind(self, mechanism) -> None:
        """Check names against the mechanism and cache what :meth:`loads` needs."""

    def loads(self, t: float, kin) -> Loads:
        raise NotImplementedError

    def potential(self, kin) -> float:
        """Potential energy (J) for conservative effects; 0 for the others."""
        return 0.0

    #: the names of the switching functions of this effect's force law: where one of them
    #: crosses zero the law is not smooth in the state (a kink or a jump, e.g. contact begins).
    #: The driver ends a step at every crossing (located on the step's interpolant) and starts
    #: the solver afresh there, so that no step straddles the point: a solver's error estimate
    #: and order assume a smooth right-hand side
    switches: tuple[str, ...] = ()

    def switch_values(self, t: float, kin) -> list:
        """The switching functions' values at a state, in the order of :attr:`switches`:
        continuous in the state while the controls stay as they are (a constant where the law
        has no such point now). A crossing where the law is smooth after all costs a restart,
        nothing else."""
        return []

    #: optional hooks, each a protocol below: :class:`FastForce` (``generalized_force``),
    #: :class:`Stiff` (``stiffness``), :class:`StiffnessBounded` (``stiffness_bound``)

    def power(self, t: float, kin) -> float:
        """Mechanical power (W) this effect delivers to the moving bodies."""
        ld = self.loads(t, kin)
        p = 0.0
        for _body, point, fx, fy in ld.forces:
            vx, vy = kin.vxy(point)
            p += fx * vx + fy * vy
        for body, m in ld.torques:
            p += m * kin.rate(body)
        return float(p)


def along_x(f: float, kin, point: str):
    """The generalized force of a force f along x at a point: f·∂x/∂q, n floats."""
    jx = kin.jac(point)[0]
    return [f * j for j in jx]


def stiffness_x(k: float, kin, point: str):
    """The generalized stiffness k·(∂x/∂q)ᵀ(∂x/∂q) of a spring along x at a point (n × n)."""
    jx = kin.jac(point)[0]
    return [[k * a * b for b in jx] for a in jx]


def stiffness_x_bound(k: float, mechanism, point: str) -> float | None:
    """An upper bound on ω² of K v = ω² A v for K = k·(∂x/∂q)ᵀ(∂x/∂q), a spring along x at a
    point (:func:`stiffness_x`), in every configuration and chart: k/M, with M the mass of the
    bodies whose centre of mass is that point. The mass matrix is a sum of Gram matrices, so
    A ≥ M·J_Pᵀ J_P ≥ M·(∂x/∂q)ᵀ(∂x/∂q), hence (∂x/∂q)·A⁻¹·(∂x/∂q) ≤ 1/M and
    ω²_max ≤ trace(A⁻¹K) ≤ k/M. None where no body has its centre of mass at the point."""
    m = 0.0
    for b in mechanism.bodies:
        a, c = b.com
        if (b.origin == point and a == 0.0 and c == 0.0) or (
            b.toward == point and b.length > 0.0 and a == b.length and c == 0.0
        ):
            m += b.mass
    return k / m if m > 0.0 else None


def vector2(value, field_name: str) -> np.ndarray:
    v = np.asarray(value, dtype=float)
    if v.shape != (2,):
        raise ValueError(f"{field_name}: expected two numbers (x, y), got {value!r}")
    return v


# -- an effect's optional hooks ------------------------------------------------------------------
@runtime_checkable
class FastForce(Protocol):
    """``generalized_force(t, kin)``: the virtual work of the effect's loads as n floats (None
    for none), the same number as the engine's sum over the loads in fewer operations. Used
    where the class defines it together with its :meth:`Effect.loads` (a subclass that
    overrides ``loads`` alone keeps the general path)."""

    def generalized_force(self, t: float, kin) -> list | None: ...


@runtime_checkable
class Stiff(Protocol):
    """``stiffness(kin)``: the effect's generalized stiffness at a state, n × n, or None (none
    there); the driver keeps a fixed step within the stability limit it sets."""

    def stiffness(self, kin) -> list | None: ...


@runtime_checkable
class StiffnessBounded(Protocol):
    """``stiffness_bound(mechanism)``: an upper bound on the largest ω² of K v = ω² A v for
    this effect's K alone, valid in every configuration and chart (None: no bound known). The
    driver's stability check skips its per-step work for steps safely within the bounds'
    limit (:class:`mps_core.run.stability.StepStability`)."""

    def stiffness_bound(self, mechanism) -> float | None: ...


@functools.lru_cache(maxsize=256)
def _class_has(cls: type, hook: type) -> bool:
    return issubclass(cls, hook)


def has_hook(effect, hook: type) -> bool:
    """Whether an effect's class implements an optional hook (:class:`FastForce`,
    :class:`Stiff`, :class:`StiffnessBounded`): the protocol's check, once per class (a
    protocol's ``isinstance`` costs tens of µs, a run's build asks it for every effect)."""
    return _class_has(effect.__class__, hook)
