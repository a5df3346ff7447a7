"""The press's executive mechanism: crank 1 (O–A), rod 2 (A–B), rocker 3 (C–B), slider 4 (C).

Frame: origin at the crank bearing O, x along the slider guide pointing up, y across it. The slider's
point C runs on the x axis. Observables: φ (angle of O→A), ψ (angle of C→B), x_C, θ2 (angle of A→B).

Charts (each with closed-form positions, contract §2):

``phi-psi+`` / ``phi-psi-``
    (φ, ψ), the seed's chart, with assembly σ = ±1:
    x_B = l1 cos φ + σ √(l2² − (l3 sin ψ − l1 sin φ)²). Degenerates where the rod AB stands
    across the guide (the square root's argument reaches zero). Regularity |x_B − x_A| / l2.
``phi-xc+`` / ``phi-xc-``
    (φ, x_C), B from the intersection of the circles (A, l2) and (C, l3), on the side κ = ±1 of
    A→C. Degenerates where rod and rocker are in line. Regularity |sin ∠ABC|.
``psi-xc+`` / ``psi-xc-``
    (ψ, x_C), A from the intersection of the circles (O, l1) and (B, l2). Degenerates where crank
    and rod are in line. Regularity |sin ∠OAB|.

``phi-xc~+`` / ``phi-xc~-`` (``held`` only, and only at the change point x_top = l1 + l2 − l3)
    The smooth continuation through the change-point configuration: (φ, x_C) with B on the side
    κ = ±sign(sin(φ/2)) of A→C, so that B changes side each time the crank passes φ = 0 (mod 2π),
    where O, A, C, B lie on the x axis and the two assemblies meet. On this path the four-bar's
    positions are smooth (the rocker swings to ψ > 0 on alternate turns); the chart has no
    singularity in ``held`` at that ground length (regularity 1).

Structures (contract §5): ``free`` (nothing frozen), ``locked`` (ψ frozen at ψ_lock, the latch
closed), and, where a top stop x_top is given, ``held`` (x_C frozen at x_top).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from ..derivatives.jet import value_of
from ..errors import ChartDomainError, SceneError
from .mechanism import FRAME, Body, Chart, ChartView, Joint, Mechanism, Observable, Structure

PHI = Observable("phi", "angle", ("O", "A"))
PSI = Observable("psi", "angle", ("C", "B"))
X_C = Observable("x_C", "x", ("C",))
THETA2 = Observable("theta2", "angle", ("A", "B"))


@dataclass(frozen=True)
class PressGeometry:
    """Link lengths (m): crank l1 = |OA|, rod l2 = |AB|, rocker l3 = |CB|."""

    l1: float = 0.015
    l2: float = 0.040
    l3: float = 0.030

    def __post_init__(self):
        for name in ("l1", "l2", "l3"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise SceneError(f"mechanism.{name}_mm", v, "a positive length")


@dataclass(frozen=True)
class BodyData:
    """Mass (kg), moment of inertia about the centre of mass (kg·m²), and the centre of mass in
    the body frame (m): along the body's first axis and across it (see :class:`Body`)."""

    mass: float
    inertia: float
    com: tuple[float, float] | None = None


#: The seed's bodies (contract §3): centres of mass of crank at A, rod at B, rocker and slider at C.
#: the press's moving bodies, in the order of its bodies
BODY_NAMES = ("crank", "rod", "rocker", "slider")

SEED_BODIES = {
    "crank": BodyData(4.6, 0.034),
    "rod": BodyData(20.0, 0.036),
    "rocker": BodyData(18.0, 0.0441),
    "slider": BodyData(100.0, 0.0),
}

# Body frames: origin point, point the first axis points to, and the seed's centre of mass.
_FRAMES = {
    "crank": ("O", "A", "l1", lambda g: (g.l1, 0.0)),
    "rod": ("A", "B", "l2", lambda g: (g.l2, 0.0)),
    "rocker": ("C", "B", "l3", lambda g: (0.0, 0.0)),
    "slider": ("C", None, None, lambda g: (0.0, 0.0)),
}


def _domain(chart: str, arg, what: str):
    v = value_of(arg)
    ok = v > 0.0 if isinstance(v, float) else bool((np.asarray(v) > 0.0).all())
    if not ok:
        raise ChartDomainError(chart, f"{what} has no real solution here")


def _positive(chart: str, arg: float, what: str):
    if not arg > 0.0:
        raise ChartDomainError(chart, f"{what} has no real solution here")


def _sign(x: float) -> float:
    return 1.0 if x > 0.0 else (-1.0 if x < 0.0 else 0.0)


#: the operations a chart's formulas use: on arrays and jets (``positions``), or on floats
#: (``flat``, the engine's scalar kernels: math's functions cost a fraction of numpy's on one
#: number); the same formulas either way
_ARRAYS = SimpleNamespace(
    cos=np.cos,
    sin=np.sin,
    sqrt=np.sqrt,
    domain=_domain,
    sign=lambda x: np.sign(np.asarray(value_of(x))),
    sqrt_touching=lambda x: _sqrt_touching(x),
)
_FLOATS = SimpleNamespace(
    cos=math.cos,
    sin=math.sin,
    sqrt=math.sqrt,
    domain=_positive,
    sign=_sign,
    sqrt_touching=lambda x: math.sqrt(x) if x > 0.0 else 0.0,
)


def _cross(ax, ay, bx, by):
    return ax * by - ay * bx


def _sqrt_touching(x):
    """√x for an argument that touches zero (a double root): the jet's derivatives stay finite by
    taking them from the plain value where x = 0 exactly (the branch's tangent is then set by the
    sign flip of the continuation)."""
    from ..derivatives.jet import Jet

    if isinstance(x, Jet):
        v = np.asarray(x.val)
        if np.all(v > 0.0):
            return x.sqrt()
        return Jet(np.sqrt(np.maximum(v, 0.0)), x.grad * 0.0, x.d1 * 0.0, x.d2 * 0.0)
    return np.sqrt(np.maximum(x, 0.0))


#: the press's joints (contract §7); a mechanism may provide its own as ``mechanism.joints``
PRESS_JOINTS: tuple[Joint, ...] = (
    Joint(
        "F_O",
        "O",
        FRAME,
        "crank",
        ("x", "y"),
        ("F_O_x", "F_O_y"),
        meaning="force the frame receives from the crank at O",
    ),
    Joint(
        "F_A",
        "A",
        "crank",
        "rod",
        ("x", "y"),
        ("F_A_x", "F_A_y"),
        meaning="force the crank receives from the rod at A",
    ),
    Joint(
        "F_B",
        "B",
        "rod",
        "rocker",
        ("x", "y"),
        ("F_B_x", "F_B_y"),
        meaning="force the rod receives from the rocker at B",
    ),
    Joint(
        "F_C",
        "C",
        "slider",
        "rocker",
        ("x", "y"),
        ("F_C_x", "F_C_y"),
        meaning="force the slider receives from the rocker at C",
    ),
    Joint(
        "N_guide",
        "C",
        FRAME,
        "slider",
        ("y",),
        ("N_guide",),
        meaning="force along y the frame receives from the slider through the guide, at C",
    ),
    Joint(
        "M_guide",
        None,
        FRAME,
        "slider",
        ("m",),
        ("M_guide",),
        meaning="moment the frame receives from the slider through the guide",
    ),
    Joint(
        "M_latch",
        None,
        "slider",
        "rocker",
        ("m",),
        ("M_latch",),
        requires="psi",
        meaning="moment the slider receives from the rocker through the closed latch",
    ),
    Joint(
        "F_stop",
        "C",
        FRAME,
        "slider",
        ("x",),
        ("F_stop",),
        requires="x_C",
        meaning="force along x the frame receives from the slider at the top stop, at C",
    ),
)


class PressMechanism(Mechanism):
    points = ("O", "A", "B", "C")
    fixed_points = ("O",)
    joints = PRESS_JOINTS
    observables = {o.name: o for o in (PHI, PSI, X_C, THETA2)}

    def __init__(
        self,
        geometry: PressGeometry | None = None,
        bodies: dict | None = None,
        psi_lock: float = 0.0,
        x_top: float | None = None,
    ):
        g = geometry or PressGeometry()
        self.geometry = g
        data = dict(SEED_BODIES)
        data.update(bodies or {})
        self.bodies = tuple(self._body(name, data[name]) for name in BODY_NAMES)
        self.psi_lock = float(psi_lock)
        self.x_top = None if x_top is None else float(x_top)
        structures = {"free": Structure("free"), "locked": Structure("locked", {"psi": psi_lock})}
        if x_top is not None:
            structures["held"] = Structure("held", {"x_C": float(x_top)})
        self.structures = structures
        self.charts = (
            tuple(self._phi_psi(s) for s in (1, -1))
            + tuple(self._phi_xc(k) for k in (1, -1))
            + tuple(self._psi_xc(k) for k in (1, -1))
        )
        if self.at_change_point:
            self.charts += tuple(self._phi_xc(k, continuation=True) for k in (1, -1))

    @property
    def at_change_point(self) -> bool:
        """x_top equals l1 + l2 − l3 (to 1e-12 m): the held four-bar is a change-point linkage."""
        g = self.geometry
        return self.x_top is not None and abs(self.x_top - (g.l1 + g.l2 - g.l3)) < 1e-12

    # -- bodies ---------------------------------------------------------------------------
    def _body(self, name: str, d: BodyData) -> Body:
        origin, toward, lname, seed_com = _FRAMES[name]
        length = getattr(self.geometry, lname) if lname else 0.0
        com = d.com if d.com is not None else seed_com(self.geometry)
        return Body(
            name, float(d.mass), float(d.inertia), origin, toward, length, (float(com[0]), float(com[1]))
        )

    # -- charts ---------------------------------------------------------------------------
    def _phi_psi(self, sigma: int) -> Chart:
        l1, l2, l3 = self.geometry.l1, self.geometry.l2, self.geometry.l3
        name = "phi-psi" + ("+" if sigma > 0 else "-")

        def core(m, phi, psi):
            ax, ay = l1 * m.cos(phi), l1 * m.sin(phi)
            by = l3 * m.sin(psi)
            dy = by - ay
            arg = l2 * l2 - dy * dy
            m.domain(name, arg, "x_B (rod across the guide)")
            bx = ax + sigma * m.sqrt(arg)
            return ax, ay, bx, by, bx - l3 * m.cos(psi)

        def positions(q):
            ax, ay, bx, by, cx = core(_ARRAYS, *q)
            return {"O": (0.0, 0.0), "A": (ax, ay), "B": (bx, by), "C": (cx, 0.0)}

        def flat(phi, psi, cos=math.cos, sin=math.sin, sqrt=math.sqrt):
            # core's formulas written out on floats (a test holds them equal)
            ax, ay = l1 * cos(phi), l1 * sin(phi)
            by = l3 * sin(psi)
            dy = by - ay
            arg = l2 * l2 - dy * dy
            if not arg > 0.0:
                _positive(name, arg, "x_B (rod across the guide)")
            bx = ax + sigma * sqrt(arg)
            return (0.0, 0.0, ax, ay, bx, by, bx - l3 * cos(psi), 0.0)

        def regularity(pose):
            return abs(pose["B"][0] - pose["A"][0]) / l2

        def owns(pose):
            return sigma * (pose["B"][0] - pose["A"][0]) > 0.0

        return Chart(name, (PHI, PSI), positions, regularity, owns, (1.0, 1.0), flat=flat)

    def _phi_xc(self, kappa: int, continuation: bool = False) -> Chart:
        l1, l2, l3 = self.geometry.l1, self.geometry.l2, self.geometry.l3
        name = ("phi-xc~" if continuation else "phi-xc") + ("+" if kappa > 0 else "-")

        def core(m, phi, xc):
            k = kappa * m.sign(m.sin(0.5 * phi)) if continuation else kappa
            ax, ay = l1 * m.cos(phi), l1 * m.sin(phi)
            dx, dy = xc - ax, -ay
            d2 = dx * dx + dy * dy
            m.domain(name, d2, "the distance AC")
            d = m.sqrt(d2)
            a = (l2 * l2 - l3 * l3 + d2) / (2.0 * d)
            h2 = l2 * l2 - a * a
            if continuation:
                # h² touches zero at the change point: rounding below zero is no domain error
                h = m.sqrt_touching(h2)
            else:
                m.domain(name, h2, "B (rod and rocker in line)")
                h = m.sqrt(h2)
            ux, uy = dx / d, dy / d
            return ax, ay, ax + a * ux - k * h * uy, ay + a * uy + k * h * ux

        def positions(q):
            ax, ay, bx, by = core(_ARRAYS, *q)
            return {"O": (0.0, 0.0), "A": (ax, ay), "B": (bx, by), "C": (q[1], 0.0)}

        def flat(phi, xc, cos=math.cos, sin=math.sin, sqrt=math.sqrt):
            # core's formulas written out on floats, on the functions given (so that the
            # exact kernels can trace them; a test holds them equal)
            ax, ay = l1 * cos(phi), l1 * sin(phi)
            dx, dy = xc - ax, -ay
            d2 = dx * dx + dy * dy
            if not d2 > 0.0:
                _positive(name, d2, "the distance AC")
            d = sqrt(d2)
            a = (l2 * l2 - l3 * l3 + d2) / (2.0 * d)
            h2 = l2 * l2 - a * a
            ux, uy = dx / d, dy / d
            if continuation:
                # the branch's sign flips with sin(φ/2); h² touches zero at the change point
                s = sin(0.5 * phi)
                k = kappa * (1.0 if s > 0.0 else (-1.0 if s < 0.0 else 0.0))
                h = sqrt(h2) if h2 > 0.0 else 0.0
                return (0.0, 0.0, ax, ay, ax + a * ux - k * h * uy, ay + a * uy + k * h * ux, xc, 0.0)
            if not h2 > 0.0:
                _positive(name, h2, "B (rod and rocker in line)")
            h = kappa * sqrt(h2)
            return (0.0, 0.0, ax, ay, ax + a * ux - h * uy, ay + a * uy + h * ux, xc, 0.0)

        def regularity(pose):
            if continuation:
                return 1.0
            (ax, ay), (bx, by), (cx, cy) = pose["A"], pose["B"], pose["C"]
            return abs(_cross(ax - bx, ay - by, cx - bx, cy - by)) / (l2 * l3)

        def owns(pose):
            (ax, ay), (bx, by), (cx, cy) = pose["A"], pose["B"], pose["C"]
            c = _cross(cx - ax, cy - ay, bx - ax, by - ay)
            if continuation:
                return kappa * _sign(math.sin(0.5 * math.atan2(ay, ax))) * c >= 0.0
            return kappa * c > 0.0

        return Chart(
            name,
            (PHI, X_C),
            positions,
            regularity,
            owns,
            (1.0, l1),
            only_in=("held",) if continuation else None,
            flat=flat,
        )

    def _psi_xc(self, kappa: int) -> Chart:
        l1, l2, l3 = self.geometry.l1, self.geometry.l2, self.geometry.l3
        name = "psi-xc" + ("+" if kappa > 0 else "-")

        def core(m, psi, xc):
            bx, by = xc + l3 * m.cos(psi), l3 * m.sin(psi)
            d2 = bx * bx + by * by
            m.domain(name, d2, "the distance OB")
            d = m.sqrt(d2)
            a = (l1 * l1 - l2 * l2 + d2) / (2.0 * d)
            h2 = l1 * l1 - a * a
            m.domain(name, h2, "A (crank and rod in line)")
            h = m.sqrt(h2)
            ux, uy = bx / d, by / d
            return a * ux - kappa * h * uy, a * uy + kappa * h * ux, bx, by

        def positions(q):
            ax, ay, bx, by = core(_ARRAYS, *q)
            return {"O": (0.0, 0.0), "A": (ax, ay), "B": (bx, by), "C": (q[1], 0.0)}

        def flat(psi, xc, cos=math.cos, sin=math.sin, sqrt=math.sqrt):
            # core's formulas written out on floats (a test holds them equal)
            bx, by = xc + l3 * cos(psi), l3 * sin(psi)
            d2 = bx * bx + by * by
            if not d2 > 0.0:
                _positive(name, d2, "the distance OB")
            d = sqrt(d2)
            a = (l1 * l1 - l2 * l2 + d2) / (2.0 * d)
            h2 = l1 * l1 - a * a
            if not h2 > 0.0:
                _positive(name, h2, "A (crank and rod in line)")
            h = kappa * sqrt(h2)
            ux, uy = bx / d, by / d
            return (0.0, 0.0, a * ux - h * uy, a * uy + h * ux, bx, by, xc, 0.0)

        def regularity(pose):
            (ax, ay), (bx, by) = pose["A"], pose["B"]
            return abs(_cross(ax, ay, bx - ax, by - ay)) / (l1 * l2)

        def owns(pose):
            (ax, ay), (bx, by) = pose["A"], pose["B"]
            return kappa * _cross(bx, by, ax, ay) > 0.0

        return Chart(name, (PSI, X_C), positions, regularity, owns, (1.0, l1), flat=flat)

    def chart(self, name: str) -> Chart:
        for c in self.charts:
            if c.name == name:
                return c
        raise KeyError(name)

    # -- initial states -------------------------------------------------------------------
    def initial_state(
        self,
        structure: str,
        phi: float,
        phi_dot: float,
        psi: float | None = None,
        psi_dot: float = 0.0,
        sigma: int = 1,
    ):
        """(view, q, q̇) for an initial state given by φ, φ̇ (and ψ, ψ̇ in ``free``) on the
        assembly σ of the seed's chart."""
        chart = self.chart("phi-psi" + ("+" if sigma > 0 else "-"))
        if structure == "free":
            if psi is None:
                raise SceneError("initial.psi_deg", None, "an initial rocker angle (free structure)")
            view = self._view_of(structure, chart)
            q, qd = np.array([phi, psi], float), np.array([phi_dot, psi_dot], float)
        elif structure == "locked":
            if psi is not None and abs(psi - self.psi_lock) > 1e-12:
                raise SceneError(
                    "initial.psi_deg",
                    math.degrees(psi),
                    f"ψ = ψ_lock = {math.degrees(self.psi_lock):g}° in the locked structure",
                )
            view = self._view_of(structure, chart)
            q, qd = np.array([phi], float), np.array([phi_dot], float)
        elif structure == "held":
            if self.x_top is None:
                raise SceneError("structure.initial", structure, "a top stop (x_top) for 'held'")
            return self._held_initial(phi, phi_dot, psi, self.x_top)
        else:
            raise SceneError("structure.initial", structure, "'free', 'locked' or 'held'")
        try:
            view.positions(list(q))
        except ChartDomainError:
            raise SceneError(
                "initial",
                {"phi_deg": math.degrees(phi), "psi_deg": None if psi is None else math.degrees(psi)},
                "a configuration where the links assemble (|l3·sin ψ − l1·sin φ| < l2)",
            ) from None
        return view, q, qd

    def _view_of(self, structure: str, chart: Chart) -> ChartView:
        """The structure's view of ``chart``: the one object :meth:`views` gives for it (its
        kernels and plans are the ones a run finds when it comes back to that chart)."""
        for view in self.views(structure):
            if view.chart is chart:
                return view
        raise KeyError(f"no view of chart {chart.name} in structure {structure!r}")

    def _held_initial(self, phi: float, phi_dot: float, psi_hint: float | None, x_top: float):
        """Slider at ``x_top``; ψ from the four-bar closure on the assembly nearest ``psi_hint``."""
        best = None
        for view in self.views("held"):
            if view.coordinates[0].name != "phi":
                continue
            try:
                pose = view.positions([phi])
            except ChartDomainError:
                continue
            (bx, by), (cx, cy) = pose["B"], pose["C"]
            psi = float(np.arctan2(by - cy, bx - cx))
            if psi_hint is not None:
                from .mechanism import unwrap_to

                psi = unwrap_to(psi, psi_hint)
            dist = 0.0 if psi_hint is None else abs(psi - psi_hint)
            score = (
                round(dist, 9),
                -view.regularity({k: (float(x), float(y)) for k, (x, y) in pose.items()}),
            )
            if best is None or score < best[0]:
                best = (score, view)
        if best is None:
            raise SceneError(
                "initial.phi_deg",
                math.degrees(phi),
                f"a crank angle where the four-bar assembles with the slider at x_top = {x_top * 1000:g} mm",
            )
        return best[1], np.array([phi], float), np.array([phi_dot], float)
