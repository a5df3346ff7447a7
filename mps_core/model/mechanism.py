"""What the engine needs to know of a mechanism, and nothing about presses.

A mechanism is

* named **points** (joints and other places where forces act), whose positions are closed-form
  functions of the free generalized coordinates of a **chart**;
* **bodies**: mass, moment of inertia about the centre of mass, and how the centre of mass and the
  body's angle follow from two of its points;
* **observables**: physical coordinates (the angle of a link, a point's x) that charts use as their
  coordinates and that trajectories report whatever the current chart;
* **charts**: sets of coordinates with closed-form positions, each regular on part of the
  configuration space; several charts cover the places where one of them degenerates;
* **structures**: which observables are frozen (a latch, a stop) and so which charts apply.

Position functions take a list of coordinate values (numpy arrays, floats or
:class:`~mps_core.derivatives.jet.Jet`) and return ``{point: (x, y)}``; they are written with
numpy ufuncs so that one call evaluates a whole stencil (arrays) or exact derivatives (jets).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..derivatives.jet import Jet, seed

TWO_PI = 2.0 * math.pi

#: the name of the fixed frame (the press body) as a body in joints and loads
FRAME = "frame"


def unwrap_to(angle: float, reference: float) -> float:
    """The angle equal to ``angle`` modulo 2π that lies nearest to ``reference``."""
    return angle + TWO_PI * round((reference - angle) / TWO_PI)


@dataclass(frozen=True)
class Body:
    """A rigid body placed by two of the mechanism's points.

    The body frame has its origin at point ``origin``, its first axis e toward point ``toward`` and
    its second axis n = e turned by +90°. The centre of mass is ``origin + com[0]·e + com[1]·n``
    (metres). ``toward=None`` makes a body that only translates (e = x axis, no rotation).
    ``length`` is the constant distance origin→toward.
    """

    name: str
    mass: float
    inertia: float
    origin: str
    toward: str | None = None
    length: float = 0.0
    com: tuple[float, float] = (0.0, 0.0)

    @property
    def rotates(self) -> bool:
        return self.toward is not None

    def com_of(self, pose: Mapping[str, tuple]):
        """Centre of mass (x, y) from a pose; works on arrays and jets alike."""
        px, py = pose[self.origin]
        a, b = self.com
        if self.toward is None:
            return px + a, py + b
        qx, qy = pose[self.toward]
        al, be = a / self.length, b / self.length
        rx, ry = qx - px, qy - py
        return px + al * rx - be * ry, py + al * ry + be * rx


@dataclass(frozen=True)
class Observable:
    """A physical coordinate: the angle of the vector P→Q from x (``kind='angle'``) or a point's
    x or y (``kind='x'``/``'y'``)."""

    name: str
    kind: str
    points: tuple[str, ...]

    @property
    def is_angle(self) -> bool:
        return self.kind == "angle"

    def value(self, pose) -> float:
        if self.kind == "angle":
            (px, py), (qx, qy) = pose[self.points[0]], pose[self.points[1]]
            return math.atan2(float(qy) - float(py), float(qx) - float(px))
        x, y = pose[self.points[0]]
        return float(x if self.kind == "x" else y)

    def jet(self, pose_jets, n: int) -> Jet:
        """This observable as a jet, from a pose of jets."""
        if self.kind == "angle":
            (px, py), (qx, qy) = pose_jets[self.points[0]], pose_jets[self.points[1]]
            return Jet.arctan2(_as_jet(qy - py, n), _as_jet(qx - px, n))
        x, y = pose_jets[self.points[0]]
        return _as_jet(x if self.kind == "x" else y, n)


def _as_jet(v, n: int) -> Jet:
    return v if isinstance(v, Jet) else Jet.constant(v, n)


@dataclass(frozen=True)
class Chart:
    """A set of generalized coordinates with closed-form positions.

    ``positions(q)`` takes a list with one value per coordinate and returns ``{point: (x, y)}``.
    It raises :class:`~mps_core.errors.ChartDomainError` where no real configuration exists.
    ``regularity(pose)`` is a number in [0, 1], 1 far from the chart's singularity and 0 on it
    (of the order of the sine of the angle whose vanishing makes the chart degenerate).
    ``owns(pose)`` says whether a configuration lies on this chart's branch (assembly).
    """

    name: str
    coordinates: tuple[Observable, ...]
    positions: Callable[[Sequence], dict]
    regularity: Callable[[Mapping], float]
    owns: Callable[[Mapping], bool]
    scales: tuple[float, ...]
    #: structures that may use this chart (None: every structure whose frozen coordinates it has)
    only_in: tuple[str, ...] | None = None
    #: optional: the same positions on floats, one argument per coordinate, returned flat
    #: ``(x, y)`` per point in the mechanism's ``points`` order; the engine's scalar kernels
    #: use it (math's functions on one number cost a fraction of numpy's)
    flat: Callable[..., tuple] | None = None

    @property
    def size(self) -> int:
        return len(self.coordinates)


@dataclass(frozen=True)
class Joint:
    """A joint's reaction: what ``receiver`` gets from ``giver`` (which gets the opposite).

    ``components`` is a subset of ``("x", "y", "m")``: force components in the frame's axes,
    applied at ``point``, and a moment about z. ``columns`` names each component's value.
    ``requires``: the frozen coordinate that makes this joint carry load (``"psi"``: latch
    closed, ``"x_C"``: slider held at its stop); ``None``: always present.
    """

    name: str
    point: str | None
    receiver: str
    giver: str
    components: tuple[str, ...]
    columns: tuple[str, ...]
    requires: str | None = None
    meaning: str = ""


@dataclass(frozen=True)
class Structure:
    """A structure of the mechanism: the observables it freezes and their values."""

    name: str
    frozen: Mapping[str, float] = field(default_factory=dict)


class ChartView:
    """A chart with some coordinates frozen: the free coordinates the engine integrates."""

    def __init__(self, chart: Chart, frozen: Mapping[str, float] | None = None):
        frozen = dict(frozen or {})
        names = [c.name for c in chart.coordinates]
        for k in frozen:
            if k not in names:
                raise ValueError(f"chart {chart.name} has no coordinate {k!r} to freeze")
        self.chart = chart
        self.frozen = frozen
        self.free = tuple(i for i, c in enumerate(chart.coordinates) if c.name not in frozen)
        self.coordinates = tuple(chart.coordinates[i] for i in self.free)
        self.scales = np.array([chart.scales[i] for i in self.free], dtype=float)
        self.n = len(self.free)
        self._template = [frozen.get(c.name) for c in chart.coordinates]
        fz = "".join(f",{k}={v:g}" for k, v in frozen.items())
        self.name = chart.name + (f"[{fz[1:]}]" if fz else "")
        self._identity = all(i == k for k, i in enumerate(self.free)) and not frozen
        self._index = {c.name: k for k, c in enumerate(self.coordinates)}

    def full(self, q: Sequence) -> list:
        if self._identity:
            return list(q)
        out = list(self._template)
        for k, i in enumerate(self.free):
            out[i] = q[k]
        return out

    def positions(self, q: Sequence) -> dict:
        return self.chart.positions(self.full(q))

    def regularity(self, pose) -> float:
        return float(self.chart.regularity(pose))

    def owns(self, pose) -> bool:
        return bool(self.chart.owns(pose))

    def coordinate_index(self, name: str) -> int | None:
        return self._index.get(name)

    # -- exact state transfer -------------------------------------------------------------
    def pose_jets(self, q, qd) -> dict:
        """Positions as jets at q along q̇: exact analogs, velocities, convective accelerations.

        The last few states' jets are kept: an impact or a change of structure asks for the
        same state several times (jets are values: nothing changes them; each call gets a dict
        of its own)."""
        q = np.asarray(q, float)
        qd = np.asarray(qd, float)
        key = (q.tobytes(), qd.tobytes())
        cache = self.__dict__.setdefault("_jets_cache", {})
        hit = cache.get(key)
        if hit is None:
            hit = self.positions(seed(q, qd))
            if len(cache) >= 4:  # the oldest goes (pop: a view may serve two threads)
                cache.pop(next(iter(cache), None), None)
            cache[key] = hit
        return dict(hit)

    def state_from(self, pose_jets, reference: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
        """This view's (q, q̇) for a configuration given as jets (from any chart).

        Angles are unwrapped to lie nearest to ``reference`` (the same observables' current
        values), so that coordinates stay continuous across a change of chart.
        """
        n = next(iter(_jets(pose_jets)), None)
        n = n.grad.shape[-1] if n is not None else 1
        q = np.empty(self.n)
        qd = np.empty(self.n)
        for k, obs in enumerate(self.coordinates):
            j = obs.jet(pose_jets, n)
            v = float(j.val)
            if obs.is_angle and obs.name in reference:
                v = unwrap_to(v, reference[obs.name])
            q[k] = v
            qd[k] = float(j.d1)
        return q, qd


def _jets(pose):
    for x, y in pose.values():
        if isinstance(x, Jet):
            yield x
        if isinstance(y, Jet):
            yield y


class Mechanism:
    """Base class of a mechanism: subclasses set the attributes below."""

    points: tuple[str, ...] = ()
    bodies: tuple[Body, ...] = ()
    observables: Mapping[str, Observable] = {}
    charts: tuple[Chart, ...] = ()
    structures: Mapping[str, Structure] = {}
    #: points whose positions are fixed in the frame (their analogs are zero)
    fixed_points: tuple[str, ...] = ()
    #: joints whose reactions Newton–Euler per body solves for (mps_core.dynamics.reactions)
    joints: tuple[Joint, ...] = ()

    def views(self, structure: str | Structure) -> list[ChartView]:
        """Every chart usable in a structure, with that structure's coordinates frozen. The
        views are made once a structure and shared by every simulation of this mechanism (a
        view holds nothing a run changes: its kept jets are values of a state)."""
        s = self.structures[structure] if isinstance(structure, str) else structure
        key = (s.name, tuple(sorted(s.frozen.items())))
        made = self.__dict__.setdefault("_views", {})
        out = made.get(key)
        if out is None:
            out = []
            for chart in self.charts:
                names = {c.name for c in chart.coordinates}
                if chart.only_in is not None and s.name not in chart.only_in:
                    continue
                if all(k in names for k in s.frozen):
                    out.append(ChartView(chart, s.frozen))
            out = made[key] = tuple(out)
        return list(out)

    def body(self, name: str) -> Body:
        for b in self.bodies:
            if b.name == name:
                return b
        raise KeyError(name)
