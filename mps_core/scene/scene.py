"""Scene files: TOML in, a validated scene in SI units out.

A scene names the mechanism and its bodies, the structure and the initial state, the effects it
wants (only those are built and evaluated), the solver and the charts' policy. Files for people
use units in the key names (``l1_mm``, ``phi_deg``, ``t_end_s``); inside, everything is SI.
Everything is validated before anything runs: an unknown key, a wrong type, a missing unit or a
non-physical value raises :class:`~mps_core.errors.SceneError` naming the field, the value and
what was expected.

Presets ship in ``mps_core/scene/presets/*.toml``; ``load_scene("paper")`` loads one, any other string
is read as a path.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path

from ..caches import Memo
from ..derivatives import SCHEMES
from ..errors import SceneError
from ..model.effects import (
    MOTOR_PRESETS,
    Blanking,
    DisengageCylinder,
    EngageCylinder,
    Gravity,
    GuideFriction,
    JointFriction,
    Latch,
    Motor,
    MotorData,
    RetentionSprings,
    SliderDamper,
    TopStop,
)
from ..model.effects.top_stop import HOLDING_MODELS
from ..model.effects.top_stop import MODELS as TOP_STOP_MODELS
from ..model.press import BODY_NAMES, SEED_BODIES, BodyData, PressGeometry, PressMechanism
from ..solvers import ADAPTIVE_SOLVERS, SOLVERS
from .settings import CHANGE_POINTS, COMMANDS, SWITCH_POINTS, ChartPolicy, SolverSettings

#: the top-level tables of a scene file, in the order they are checked
SECTIONS = (
    "scene",
    "mechanism",
    "bodies",
    "structure",
    "initial",
    "commands",
    "effects",
    "solver",
    "outputs",
    "charts",
)
STRUCTURES = ("free", "locked", "held")


@dataclass(frozen=True)
class EffectSpec:
    kind: str
    params: dict


@dataclass(frozen=True)
class Scene:
    """A validated scene, SI units."""

    name: str
    description: str
    geometry: PressGeometry
    assembly: int
    bodies: dict
    x_top: float | None
    structure: str
    psi_lock: float
    initial: dict
    effects: tuple
    solver: SolverSettings
    t_end: float
    dt: float
    charts: ChartPolicy
    commands: tuple = ()
    #: outputs the scene asks for (only those are computed): reactions and foundation load
    reactions: bool = False
    #: at the held four-bar's change point: "continue" (smooth) or "keep-side" (plastic impact)
    change_point: str = "continue"
    text: str = ""
    origin: str = ""

    @property
    def steps(self) -> int:
        return max(1, int(round(self.t_end / self.dt)))

    def with_overrides(
        self,
        *,
        t_end=None,
        steps=None,
        dt=None,
        solver=None,
        delta=None,
        scheme=None,
        iterations=None,
        rtol=None,
        atol=None,
        chart_switching=None,
        switch_points=None,
        step=None,
    ) -> Scene:
        """The same scene with run settings changed (the CLI's options), validated again."""
        s = self
        if steps is not None and dt is not None:
            raise SceneError("steps/dt", (steps, dt), "either a number of steps or a step, not both")
        t_end = s.t_end if t_end is None else _positive("t_end_s", t_end, upper=1e5)
        if steps is not None:
            if not isinstance(steps, int) or steps < 1:
                raise SceneError("solver.steps", steps, "a positive integer")
            dt = t_end / steps
        elif dt is None:
            dt = s.dt  # a new end time keeps the step
            if dt > t_end:
                dt = t_end
        _check_dt("solver.dt_s", dt, t_end)
        st = s.solver
        if solver is not None:
            _choice("solver.method", solver, SOLVERS)
            st = replace(st, name=solver)
        if delta is not None:
            st = replace(st, delta=_delta("solver.delta_deg", math.degrees(delta)))
        if scheme is not None:
            _choice("solver.derivatives", scheme, SCHEMES)
            st = replace(st, scheme=scheme)
        if iterations is not None:
            if isinstance(iterations, bool) or not isinstance(iterations, int) or not 1 <= iterations <= 50:
                raise SceneError("solver.corrector_iterations", iterations, "an integer from 1 to 50")
            st = replace(st, iterations=iterations)
        if rtol is not None:
            st = replace(st, rtol=_tol("solver.rtol", rtol))
        if atol is not None:
            st = replace(st, atol=_tol("solver.atol", atol))
        if switch_points is not None:
            _choice("solver.switch_points", switch_points, SWITCH_POINTS)
            st = replace(st, switch_points=switch_points)
        if step is not None:
            st = replace(st, step=_step("solver.step_s", step, t_end))
        if st.step is not None:
            _check_step_solver(st)
        ch = s.charts if chart_switching is None else replace(s.charts, switching=chart_switching)
        return replace(s, t_end=t_end, dt=dt, solver=st, charts=ch)

    # -- building -------------------------------------------------------------------------
    def mechanism(self) -> PressMechanism:
        """The scene's mechanism: one object for every scene of equal geometry, bodies, lock
        angle and top stop (a mechanism holds nothing a run changes), so that what is made
        per chart view (views, kernels' keys) is made once in a process."""
        key = (self.geometry, tuple(sorted(self.bodies.items())), self.psi_lock, self.x_top)
        try:
            mech = _MECHANISMS.get(key)
        except TypeError:  # a body given by hand with a list for its com
            return PressMechanism(self.geometry, self.bodies, psi_lock=self.psi_lock, x_top=self.x_top)
        if mech is None:
            mech = _MECHANISMS.keep(
                key, PressMechanism(self.geometry, self.bodies, psi_lock=self.psi_lock, x_top=self.x_top)
            )
        return mech

    def linkage(self) -> PressMechanism:
        """The mechanism of the scene's geometry, lock angle and top stop with the seed's
        bodies: for what depends on the geometry alone (the charts and their views, an
        initial state assembled), one object for every scene that shares it, whatever its
        bodies (a sweep over masses builds it once)."""
        key = (self.geometry, self.psi_lock, self.x_top)
        mech = _LINKAGES.get(key)
        if mech is None:
            mech = _LINKAGES.keep(
                key, PressMechanism(self.geometry, psi_lock=self.psi_lock, x_top=self.x_top)
            )
        return mech

    def build_effects(self, mechanism) -> list:
        """The effects the scene lists, and only those (a spring's damping is its own unit)."""
        out = []
        for e in self.effects:
            built = _EFFECT_BUILDERS[e.kind](e.params, self)
            out.extend(built if isinstance(built, list) else [built])
        return out

    def initial_state(self, mechanism):
        i = self.initial
        return mechanism.initial_state(
            self.structure, i["phi"], i["phi_dot"], i.get("psi"), i.get("psi_dot", 0.0), sigma=self.assembly
        )


#: mechanisms by what makes them (:meth:`Scene.mechanism`)
_MECHANISMS = Memo("scene.mechanisms", 64)
#: mechanisms with the seed's bodies by their geometry (:meth:`Scene.linkage`)
_LINKAGES = Memo("scene.linkages", 64)


# -- field checks -------------------------------------------------------------------------
def _num(fieldname, v, expected="a number") -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise SceneError(fieldname, v, expected)
    return float(v)


def _positive(fieldname, v, upper=None, unit="") -> float:
    x = _num(fieldname, v, f"a positive number{unit}")
    if x <= 0 or (upper is not None and x > upper):
        rng = f" up to {upper:g}" if upper is not None else ""
        raise SceneError(fieldname, v, f"a positive number{unit}{rng}")
    return x


def _choice(fieldname, v, options):
    if v not in options:
        raise SceneError(fieldname, v, "one of " + ", ".join(repr(o) for o in options))
    return v


def _delta(fieldname, deg) -> float:
    x = _num(fieldname, deg, "a virtual displacement in degrees")
    if not (1e-7 <= x <= 5.0):
        raise SceneError(fieldname, deg, "a virtual displacement between 1e-7° and 5°")
    return math.radians(x)


def _tol(fieldname, v) -> float:
    x = _num(fieldname, v, "a tolerance")
    if not (1e-15 <= x <= 1e-2):
        raise SceneError(fieldname, v, "a tolerance between 1e-15 and 1e-2")
    return x


def _step(fieldname, step, t_end) -> float:
    """A fixed-step solver's own step (seconds): as a step of the output grid."""
    _check_dt(fieldname, step, t_end)
    return float(step)


def _check_step_solver(st) -> None:
    if st.name in ADAPTIVE_SOLVERS:
        raise SceneError(
            "solver.step_s",
            st.step,
            "no step for the adaptive solver " + st.name + " (it chooses its own): "
            "a fixed-step solver (linear-acceleration, rk4, rk6, rk8)",
        )


def _check_dt(fieldname, dt, t_end):
    x = _num(fieldname, dt, "a step in seconds")
    if not (1e-8 <= x <= 0.1):
        raise SceneError(fieldname, dt, "a step between 1e-8 s and 0.1 s")
    if x > t_end:
        raise SceneError(fieldname, dt, f"a step no longer than t_end_s = {t_end:g}")
    if t_end / x > 5e7:
        raise SceneError(fieldname, dt, f"at most 5e7 steps over t_end_s = {t_end:g}")


class _Table:
    """Reads one TOML table, remembering which keys were used so leftovers are refused."""

    def __init__(self, data, path: str, units_hint: dict | None = None):
        if not isinstance(data, dict):
            raise SceneError(path, data, "a table")
        self.data = data
        self.path = path
        self.used: set[str] = set()
        self.units_hint = units_hint or {}

    def get(self, key, default=None, required=False):
        self.used.add(key)
        if key not in self.data:
            if required:
                near = [k for k, v in self.units_hint.items() if v == key and k in self.data]
                if near:
                    raise SceneError(
                        f"{self.path}.{near[0]}",
                        self.data[near[0]],
                        f"no such key (did you mean {key!r}? units go in the key's name)",
                    )
                raise SceneError(f"{self.path}.{key}", None, "a value (this field is required)")
            return default
        return self.data[key]

    def field(self, key):
        return f"{self.path}.{key}"

    def done(self):
        for k in self.data:
            if k not in self.used:
                hint = self.units_hint.get(k)
                exp = (
                    f"no such key (did you mean {hint!r}? units go in the key's name)"
                    if hint
                    else "no such key; known keys: " + ", ".join(sorted(self.used))
                )
                raise SceneError(f"{self.path}.{k}", self.data[k], exp)


_UNIT_HINTS = {
    "mechanism": {"l1": "l1_mm", "l2": "l2_mm", "l3": "l3_mm"},
    "initial": {"phi": "phi_deg", "psi": "psi_deg", "phi_dot": "phi_dot_rad_s", "psi_dot": "psi_dot_rad_s"},
    "solver": {"t_end": "t_end_s", "dt": "dt_s", "delta": "delta_deg"},
    "body": {
        "mass": "mass_kg",
        "inertia": "inertia_kg_m2",
        "com": "com_mm",
        "J": "inertia_kg_m2",
        "m": "mass_kg",
    },
    "structure": {"psi_lock": "psi_lock_deg"},
}


def _build_gravity(p, scene):
    return Gravity(p["g"])


def _build_motor(p, scene):
    data: MotorData = p["data"]
    if p.get("ratio") is not None:
        return Motor(data, p["ratio"], p["efficiency"])
    return Motor.for_crank_speed(data, p["crank_speed"], efficiency=p["efficiency"])


def _build_springs(p, scene):
    out = [RetentionSprings(p["stiffness"], p["preload"], scene.x_top)]
    if p["damping"] > 0.0:
        out.append(SliderDamper(p["damping"], name="springs-damping"))
    return out


_EFFECT_BUILDERS = {
    "gravity": _build_gravity,
    "motor": _build_motor,
    "springs": _build_springs,
    "top_stop": lambda p, sc: TopStop(sc.x_top, p["model"], p["stiffness"], p["damping"]),
    "engage_cylinder": lambda p, sc: EngageCylinder(p["force"], p["stroke"], sc.x_top),
    "latch": lambda p, sc: Latch(sc.psi_lock),
    "disengage_cylinder": lambda p, sc: DisengageCylinder(p["torque"], p["duration"]),
    "blanking": lambda p, sc: Blanking(p["peak_force"], p["x_contact"], p["thickness"], p["breakthrough"]),
    "joint_friction": lambda p, sc: JointFriction(p["coulomb"], p["viscous"], p["rate_smooth"], p["joints"]),
    "guide_friction": lambda p, sc: GuideFriction(p["coulomb"], p["viscous"], p["speed_smooth"]),
}

#: effects that need the top stop's position (mechanism.x_top_mm)
_NEEDS_X_TOP = ("springs", "top_stop", "engage_cylinder")


def _nonneg(fieldname, v, unit) -> float:
    x = _num(fieldname, v, f"a number >= 0{unit}")
    if x < 0:
        raise SceneError(fieldname, v, f"a number >= 0{unit}")
    return x


def _effect(i, raw) -> EffectSpec:
    path = f"effects[{i}]"
    t = _Table(raw, path)
    kind = t.get("type", required=True)
    _choice(f"{path}.type", kind, tuple(_EFFECT_BUILDERS))
    simple = _SIMPLE_EFFECTS.get(kind)
    if simple is not None:
        params = simple(t, path)
        t.done()
        return EffectSpec(kind, params)
    if kind == "gravity":
        g = t.get("g_m_s2", [-9.81, 0.0])
        if (
            not isinstance(g, list)
            or len(g) != 2
            or not all(
                isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in g
            )
        ):
            raise SceneError(f"{path}.g_m_s2", g, "two numbers [g_x, g_y] in m/s²")
        t.done()
        return EffectSpec("gravity", {"g": (float(g[0]), float(g[1]))})
    # motor
    model = t.get("model", "4A80B4U3")
    base = MOTOR_PRESETS.get(model)
    if base is None and model != "custom":
        raise SceneError(
            f"{path}.model", model, "a motor preset (" + ", ".join(MOTOR_PRESETS) + ") or 'custom'"
        )
    vals = {}
    for key, attr in (
        ("power_w", "power_w"),
        ("sync_rpm", "sync_rpm"),
        ("rated_slip", "rated_slip"),
        ("breakdown_ratio", "breakdown_ratio"),
    ):
        v = t.get(key)
        if v is None:
            if base is None:
                raise SceneError(f"{path}.{key}", None, "a value (custom motor)")
            vals[attr] = getattr(base, attr)
        else:
            vals[attr] = _positive(f"{path}.{key}", v)
    if not (0 < vals["rated_slip"] < 1):
        raise SceneError(f"{path}.rated_slip", vals["rated_slip"], "a slip between 0 and 1")
    if vals["breakdown_ratio"] <= 1:
        raise SceneError(f"{path}.breakdown_ratio", vals["breakdown_ratio"], "M_k/M_n greater than 1")
    data = MotorData(
        **vals, source=base.source if base and vals == {k: getattr(base, k) for k in vals} else "scene"
    )
    ratio = t.get("ratio")
    speed = t.get("crank_speed_rad_s")
    if ratio is not None and speed is not None:
        raise SceneError(f"{path}.ratio", ratio, "either ratio or crank_speed_rad_s, not both")
    if ratio is not None:
        ratio = _positive(f"{path}.ratio", ratio)
    else:
        speed = _positive(f"{path}.crank_speed_rad_s", 43.5 if speed is None else speed)
    eff = t.get("efficiency", 1.0)
    eff = _num(f"{path}.efficiency", eff, "an efficiency in (0, 1]")
    if not (0 < eff <= 1):
        raise SceneError(f"{path}.efficiency", eff, "an efficiency in (0, 1]")
    t.done()
    return EffectSpec("motor", {"data": data, "ratio": ratio, "crank_speed": speed, "efficiency": eff})


def _springs(t, path):
    k = _positive(f"{path}.stiffness_n_m", t.get("stiffness_n_m", required=True), unit=" (N/m)")
    f0 = _nonneg(f"{path}.preload_n", t.get("preload_n", required=True), " (N)")
    c = _nonneg(f"{path}.damping_n_s_m", t.get("damping_n_s_m", 0.0), " (N·s/m)")
    return {"stiffness": k, "preload": f0, "damping": c}


def _top_stop(t, path):
    model = t.get("model", "rigid")
    _choice(f"{path}.model", model, TOP_STOP_MODELS)
    k = t.get("stiffness_n_m", None if model == "elastic" else 0.0)
    if model == "elastic":
        if k is None:
            raise SceneError(f"{path}.stiffness_n_m", None, "a contact stiffness (elastic stop)")
        k = _positive(f"{path}.stiffness_n_m", k, unit=" (N/m)")
    c = _nonneg(f"{path}.damping_n_s_m", t.get("damping_n_s_m", 0.0), " (N·s/m)")
    return {"model": model, "stiffness": float(k), "damping": c}


def _engage(t, path):
    f = _positive(f"{path}.force_n", t.get("force_n", required=True), unit=" (N)")
    stroke = (
        _positive(f"{path}.stroke_mm", t.get("stroke_mm", required=True), upper=10.0, unit=" (mm)") / 1000.0
    )
    return {"force": f, "stroke": stroke}


def _latch(t, path):
    return {}


def _disengage(t, path):
    m = _positive(f"{path}.torque_nm", t.get("torque_nm", required=True), unit=" (N·m)")
    d = _positive(f"{path}.duration_s", t.get("duration_s", required=True), upper=10.0, unit=" (s)")
    return {"torque": m, "duration": d}


def _blanking(t, path):
    per = _positive(f"{path}.perimeter_mm", t.get("perimeter_mm", required=True), unit=" (mm)")
    th = _positive(f"{path}.thickness_mm", t.get("thickness_mm", required=True), upper=20.0, unit=" (mm)")
    tau = _positive(
        f"{path}.shear_strength_mpa", t.get("shear_strength_mpa", required=True), upper=3000.0, unit=" (MPa)"
    )
    xc = _num(f"{path}.contact_mm", t.get("contact_mm", required=True), "a slider position (mm)")
    bt = _num(f"{path}.breakthrough", t.get("breakthrough", 0.5), "a fraction of the thickness")
    if not (0 < bt <= 1):
        raise SceneError(f"{path}.breakthrough", bt, "a fraction of the thickness in (0, 1]")
    # peak blanking force L·t·τ (mm · mm · N/mm²)
    return {
        "peak_force": per * th * tau,
        "x_contact": xc / 1000.0,
        "thickness": th / 1000.0,
        "breakthrough": bt,
    }


def _joint_friction(t, path):
    joints = t.get("joints", ["O", "A", "B", "C"])
    if not isinstance(joints, list) or not joints or any(j not in ("O", "A", "B", "C") for j in joints):
        raise SceneError(f"{path}.joints", joints, "a list of joints among 'O', 'A', 'B', 'C'")
    return {
        "coulomb": _nonneg(f"{path}.coulomb_nm", t.get("coulomb_nm", 0.0), " (N·m)"),
        "viscous": _nonneg(f"{path}.viscous_nm_s", t.get("viscous_nm_s", 0.0), " (N·m·s)"),
        "rate_smooth": _positive(
            f"{path}.rate_smooth_rad_s", t.get("rate_smooth_rad_s", 0.05), unit=" (rad/s)"
        ),
        "joints": tuple(joints),
    }


def _guide_friction(t, path):
    return {
        "coulomb": _nonneg(f"{path}.coulomb_n", t.get("coulomb_n", 0.0), " (N)"),
        "viscous": _nonneg(f"{path}.viscous_n_s_m", t.get("viscous_n_s_m", 0.0), " (N·s/m)"),
        "speed_smooth": _positive(f"{path}.speed_smooth_m_s", t.get("speed_smooth_m_s", 1e-3), unit=" (m/s)"),
    }


_SIMPLE_EFFECTS = {
    "springs": _springs,
    "top_stop": _top_stop,
    "engage_cylinder": _engage,
    "latch": _latch,
    "disengage_cylinder": _disengage,
    "blanking": _blanking,
    "joint_friction": _joint_friction,
    "guide_friction": _guide_friction,
}


def _commands(raw) -> tuple:
    if not isinstance(raw, list):
        raise SceneError("commands", raw, "an array of tables [[commands]] with t_s and command")
    out = []
    for i, c in enumerate(raw):
        t = _Table(c, f"commands[{i}]", {"t": "t_s"})
        ts = _num(f"commands[{i}].t_s", t.get("t_s", required=True), "a time in seconds >= 0")
        if ts < 0:
            raise SceneError(f"commands[{i}].t_s", ts, "a time in seconds >= 0")
        name = t.get("command", required=True)
        _choice(f"commands[{i}].command", name, COMMANDS)
        t.done()
        out.append((ts, name))
    return tuple(sorted(out))


def _meta(data, name: str) -> tuple[str, str]:
    meta = _Table(data, "scene")
    sname = meta.get("name", name)
    if not isinstance(sname, str) or not sname:
        raise SceneError("scene.name", sname, "a non-empty string")
    desc = meta.get("description", "")
    if not isinstance(desc, str):
        raise SceneError("scene.description", desc, "a string")
    meta.get("source")
    meta.done()
    return sname, desc


def _mechanism(data) -> tuple[PressGeometry, int, float | None]:
    """[mechanism]: the geometry, the assembly, the top stop's position (m, or None)."""
    mt = _Table(data, "mechanism", _UNIT_HINTS["mechanism"])
    mtype = mt.get("type", "press")
    _choice("mechanism.type", mtype, ("press",))
    l1 = _positive("mechanism.l1_mm", mt.get("l1_mm", 15.0), unit=" (mm)") / 1000.0
    l2 = _positive("mechanism.l2_mm", mt.get("l2_mm", 40.0), unit=" (mm)") / 1000.0
    l3 = _positive("mechanism.l3_mm", mt.get("l3_mm", 30.0), unit=" (mm)") / 1000.0
    if l2 <= l1:
        raise SceneError(
            "mechanism.l2_mm",
            l2 * 1000,
            f"a rod longer than the crank (l1_mm = {l1 * 1000:g}) so the crank can turn",
        )
    assembly = mt.get("assembly", 1)
    _choice("mechanism.assembly", assembly, (1, -1))
    x_top = mt.get("x_top_mm")
    if x_top is not None:
        x_top = _num("mechanism.x_top_mm", x_top, "the top stop's position (mm)") / 1000.0
        lo, hi = l2 - l1 - l3, l1 + l2 + l3
        if not (lo < x_top < hi):
            raise SceneError(
                "mechanism.x_top_mm",
                x_top * 1000,
                f"a slider position the links can reach ({lo * 1000:g} to {hi * 1000:g} mm)",
            )
    mt.done()
    return PressGeometry(l1, l2, l3), assembly, x_top


def _bodies(data) -> dict:
    """[bodies.NAME]: each body's mass, inertia and centre of mass (the seed's by default)."""
    bt = _Table(data, "bodies")
    bodies = {}
    for bname in BODY_NAMES:
        raw_b = bt.get(bname)
        bodies[bname] = SEED_BODIES[bname] if raw_b is None else _parsed(_body, raw_b, bname)
    bt.done()
    return bodies


def _body(data, bname: str) -> BodyData:
    """[bodies.NAME]: one body's (its fields the seed's where not given)."""
    d = SEED_BODIES[bname]
    b = _Table(data, f"bodies.{bname}", _UNIT_HINTS["body"])
    mass = _positive(f"bodies.{bname}.mass_kg", b.get("mass_kg", d.mass), unit=" (kg)")
    inertia = _num(
        f"bodies.{bname}.inertia_kg_m2",
        b.get("inertia_kg_m2", d.inertia),
        "a moment of inertia >= 0 (kg·m²)",
    )
    if inertia < 0:
        raise SceneError(f"bodies.{bname}.inertia_kg_m2", inertia, "a moment of inertia >= 0 (kg·m²)")
    com = b.get("com_mm")
    if com is not None:
        if (
            not isinstance(com, list)
            or len(com) != 2
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in com)
        ):
            raise SceneError(
                f"bodies.{bname}.com_mm", com, "two numbers [along, across] in mm in the body frame"
            )
        com = (com[0] / 1000.0, com[1] / 1000.0)
    b.done()
    return BodyData(mass, inertia, com)


def _structure(data) -> tuple[str, float, str]:
    """[structure]: the initial structure, the lock angle, the change point's rule."""
    stt = _Table(data, "structure", _UNIT_HINTS["structure"])
    structure = stt.get("initial", "free")
    _choice("structure.initial", structure, STRUCTURES)
    psi_lock = math.radians(_num("structure.psi_lock_deg", stt.get("psi_lock_deg", 0.0)))
    change_point = stt.get("change_point", "continue")
    _choice("structure.change_point", change_point, CHANGE_POINTS)
    stt.done()
    return structure, psi_lock, change_point


def _initial(data, structure: str) -> dict:
    """[initial]: the initial state, SI."""
    it = _Table(data, "initial", _UNIT_HINTS["initial"])
    phi = math.radians(_num("initial.phi_deg", it.get("phi_deg", required=True)))
    phi_dot = _num("initial.phi_dot_rad_s", it.get("phi_dot_rad_s", 0.0))
    psi_deg = it.get("psi_deg")
    psi = None if psi_deg is None else math.radians(_num("initial.psi_deg", psi_deg))
    psi_dot = _num("initial.psi_dot_rad_s", it.get("psi_dot_rad_s", 0.0))
    it.done()
    if structure == "locked" and psi_dot != 0.0:
        raise SceneError("initial.psi_dot_rad_s", psi_dot, "0 in the locked structure")
    return {"phi": phi, "phi_dot": phi_dot, "psi": psi, "psi_dot": psi_dot}


def _effects(raw_effects, x_top: float | None, structure: str, commands: tuple) -> tuple:
    """[[effects]]: each once, with what it needs from the mechanism, the structure and the
    commands that act through it."""
    if not isinstance(raw_effects, list):
        raise SceneError("effects", raw_effects, "an array of tables [[effects]]")
    effects = tuple(_effect(i, e) for i, e in enumerate(raw_effects))
    kinds = [e.kind for e in effects]
    for k in set(kinds):
        if kinds.count(k) > 1:
            raise SceneError("effects", kinds, f"each effect once ({k!r} is listed twice)")
    for i, e in enumerate(effects):
        if e.kind in _NEEDS_X_TOP and x_top is None:
            raise SceneError(
                "mechanism.x_top_mm", None, f"the top stop's position (effects[{i}] {e.kind!r} needs it)"
            )
    rigid_stop = any(e.kind == "top_stop" and e.params["model"] in HOLDING_MODELS for e in effects)
    if structure == "held" and not rigid_stop:
        raise SceneError(
            "structure.initial", structure, "a rigid (or clamp) top_stop effect for the held structure"
        )
    for i, (_ts, name) in enumerate(commands):
        need = {
            "engage": ("latch", "engage_cylinder"),
            "disengage": ("latch",),
            "stop": ("motor",),
            "start": ("motor",),
        }[name]
        missing = [k for k in need if k not in kinds]
        if missing:
            raise SceneError(
                f"commands[{i}].command",
                name,
                "a command whose effects the scene lists (missing: " + ", ".join(missing) + ")",
            )
    return effects


def _solver(data) -> tuple[SolverSettings, float, float]:
    """[solver]: the settings, the end time and the output step (s)."""
    sv = _Table(data, "solver", _UNIT_HINTS["solver"])
    method = sv.get("method", "linear-acceleration")
    _choice("solver.method", method, SOLVERS)
    scheme = sv.get("derivatives", "central")
    _choice("solver.derivatives", scheme, SCHEMES)
    delta = _delta("solver.delta_deg", sv.get("delta_deg", 0.1))
    iters = sv.get("corrector_iterations", 1)
    if isinstance(iters, bool) or not isinstance(iters, int) or iters < 1 or iters > 50:
        raise SceneError("solver.corrector_iterations", iters, "an integer from 1 to 50")
    rtol = _tol("solver.rtol", sv.get("rtol", 1e-9))
    atol = _tol("solver.atol", sv.get("atol", 1e-12))
    stiff = sv.get("stiff", "subdivide")
    _choice("solver.stiff", stiff, ("subdivide", "error"))
    switch_points = sv.get("switch_points", "auto")
    _choice("solver.switch_points", switch_points, SWITCH_POINTS)
    t_end = _positive("solver.t_end_s", sv.get("t_end_s", required=True), upper=1e5, unit=" (s)")
    steps = sv.get("steps")
    dt = sv.get("dt_s")
    if steps is not None and dt is not None:
        raise SceneError("solver.steps", steps, "either steps or dt_s, not both")
    if steps is not None:
        if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
            raise SceneError("solver.steps", steps, "a positive integer")
        dt = t_end / steps
    elif dt is None:
        dt = 1e-3
    _check_dt("solver.dt_s", dt, t_end)
    step = sv.get("step_s")
    if step is not None:
        step = _step("solver.step_s", step, t_end)
    sv.done()
    settings = SolverSettings(
        method, scheme, delta, iters, rtol, atol, stiff, switch_points=switch_points, step=step
    )
    return settings, t_end, float(dt)


def _outputs(data) -> bool:
    """[outputs]: whether the reactions (and the foundation load) are computed."""
    ot = _Table(data, "outputs")
    reactions = ot.get("reactions", False)
    if not isinstance(reactions, bool):
        raise SceneError("outputs.reactions", reactions, "true or false")
    ot.done()
    return reactions


def _charts(data) -> ChartPolicy:
    """[charts]: when to change chart, and when a configuration is singular."""
    ct = _Table(data, "charts")
    switching = ct.get("switching", True)
    if not isinstance(switching, bool):
        raise SceneError("charts.switching", switching, "true or false")
    switch_below = _num("charts.switch_below", ct.get("switch_below", 0.5))
    fail_below = _num("charts.fail_below", ct.get("fail_below", 1e-3))
    if not (0 < fail_below < switch_below < 1):
        raise SceneError(
            "charts.switch_below",
            switch_below,
            f"a regularity between charts.fail_below = {fail_below:g} and 1",
        )
    ct.done()
    return ChartPolicy(switching, switch_below, fail_below)


def _check_across_tables(scene: Scene) -> None:
    """What no one table decides: the step against the solver, the change point's rule
    against the derivatives, the commands' times, and the initial state assembling (on the
    closure, in held) before anything runs."""
    if scene.solver.step is not None:
        _check_step_solver(scene.solver)
    if scene.change_point == "keep-side" and scene.solver.scheme != "central":
        raise SceneError(
            "structure.change_point",
            scene.change_point,
            "'continue' with solver.derivatives = 'autodiff' (keep-side restarts "
            "exactly at the change point: it needs central differences)",
        )
    for i, (ts, _name) in enumerate(scene.commands):
        if ts > scene.t_end:
            raise SceneError(f"commands[{i}].t_s", ts, f"a time within t_end_s = {scene.t_end:g}")
    view, q, _ = scene.initial_state(scene.linkage())  # the geometry's: the bodies play no part
    psi = scene.initial["psi"]
    if scene.structure == "held" and psi is not None:
        pose = view.positions(list(q))
        psi0 = math.atan2(pose["B"][1] - pose["C"][1], pose["B"][0] - pose["C"][0])
        d = (psi - psi0 + math.pi) % (2 * math.pi) - math.pi
        if abs(d) > math.radians(10.0):
            raise SceneError(
                "initial.psi_deg",
                math.degrees(psi),
                f"a rocker angle near the closure's {math.degrees(psi0):.2f}° (in "
                "held, ψ follows from the closure; psi_deg picks the assembly)",
            )


#: each table's parse by its content: the sweeps build thousands of scenes that differ in a
#: field or two (:mod:`mps_core.analysis.sweep`), and a table seen before gives what its
#: parser gave then (a parser is a function of its table and the arguments it is given)
_TABLES = Memo("scene.tables", 1024)


def _parsed(parse, data, *args):
    """``parse(data, *args)``, remembered by the table's text (``repr``: TOML's values, and
    1, 1.0 and true apart); a dict it gives is copied (a scene's own); an error is not kept
    (the same table raises it again)."""
    key = (parse, repr(data), args)
    out = _TABLES.get(key)
    if out is None:
        out = _TABLES.keep(key, parse(data, *args))
    return dict(out) if isinstance(out, dict) else out


def _check_sections(raw: dict) -> None:
    """Refuse a top-level table the scene file does not know, before any table is read.

    A misspelt ``[inital]`` would otherwise leave ``[initial]`` empty and be reported as its
    first missing value."""
    for key in raw:
        if key not in SECTIONS:
            near = difflib.get_close_matches(key, SECTIONS, n=1)
            hint = f" (did you mean [{near[0]}]?)" if near else ""
            raise SceneError("section", key, "one of the sections " + ", ".join(SECTIONS) + hint)


def scene_from_dict(raw: dict, *, name: str = "scene", text: str = "", origin: str = "") -> Scene:
    """A validated scene from a parsed TOML document: its sections known, one parser a table,
    in the order the tables are checked, then what crosses tables."""
    top = _Table(raw, "scene file")
    _check_sections(raw)
    sname, desc = _parsed(_meta, top.get("scene", {}), name)
    geometry, assembly, x_top = _parsed(_mechanism, top.get("mechanism", {}))
    bodies = _parsed(_bodies, top.get("bodies", {}))
    structure, psi_lock, change_point = _parsed(_structure, top.get("structure", {}))
    initial = _parsed(_initial, top.get("initial", {}), structure)
    commands = _parsed(_commands, top.get("commands", []))
    effects = _parsed(_effects, top.get("effects", []), x_top, structure, commands)
    solver, t_end, dt = _parsed(_solver, top.get("solver", {}))
    reactions = _parsed(_outputs, top.get("outputs", {}))
    charts = _parsed(_charts, top.get("charts", {}))
    top.done()
    scene = Scene(
        sname,
        desc,
        geometry,
        assembly,
        bodies,
        x_top,
        structure,
        psi_lock,
        initial,
        effects,
        solver,
        t_end,
        dt,
        charts,
        commands,
        reactions,
        change_point,
        text,
        origin,
    )
    _check_across_tables(scene)
    return scene


def preset_names() -> list[str]:
    return sorted(
        p.name[:-5] for p in resources.files("mps_core.scene.presets").iterdir() if p.name.endswith(".toml")
    )


def load_scene(spec: str | Path) -> Scene:
    """A preset by name, or a scene file by path."""
    spec = str(spec)
    if spec in preset_names():
        res = resources.files("mps_core.scene.presets").joinpath(spec + ".toml")
        text = res.read_text()
        origin = f"preset:{spec}"
    else:
        path = Path(spec)
        if not path.exists():
            raise SceneError(
                "scene", spec, "a preset name (" + ", ".join(preset_names()) + ") or the path of a scene file"
            )
        from ..files.inputs import read_text

        text = read_text(path, "scene file", "a TOML scene")
        origin = str(path)
    return scene_from_text(text, name=Path(spec).stem, origin=origin)


def scene_from_text(text: str, *, name: str = "scene", origin: str = "") -> Scene:
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError("scene file", origin or name, f"valid TOML ({exc})") from None
    return scene_from_dict(raw, name=name, text=text, origin=origin)
