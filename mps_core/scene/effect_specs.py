"""A scene's effects: each ``[[effects]]`` table read into an :class:`EffectSpec` (the kind and
its parameters, SI), checked against the mechanism, the structure and the commands, and built
into the model's effects (:data:`EFFECT_BUILDERS`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

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
from ._fields import Table, choice, nonneg, num, positive


@dataclass(frozen=True)
class EffectSpec:
    """One effect a scene lists: its kind (the table's ``type``) and its parameters, SI."""

    kind: str
    params: dict


def parse_effects(raw_effects, x_top: float | None, structure: str, commands: tuple) -> tuple:
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


def _effect(i, raw) -> EffectSpec:
    path = f"effects[{i}]"
    t = Table(raw, path)
    kind = t.get("type", required=True)
    choice(f"{path}.type", kind, tuple(EFFECT_BUILDERS))
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
            vals[attr] = positive(f"{path}.{key}", v)
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
        ratio = positive(f"{path}.ratio", ratio)
    else:
        speed = positive(f"{path}.crank_speed_rad_s", 43.5 if speed is None else speed)
    eff = t.get("efficiency", 1.0)
    eff = num(f"{path}.efficiency", eff, "an efficiency in (0, 1]")
    if not (0 < eff <= 1):
        raise SceneError(f"{path}.efficiency", eff, "an efficiency in (0, 1]")
    t.done()
    return EffectSpec("motor", {"data": data, "ratio": ratio, "crank_speed": speed, "efficiency": eff})


def _springs(t, path):
    k = positive(f"{path}.stiffness_n_m", t.get("stiffness_n_m", required=True), unit=" (N/m)")
    f0 = nonneg(f"{path}.preload_n", t.get("preload_n", required=True), " (N)")
    c = nonneg(f"{path}.damping_n_s_m", t.get("damping_n_s_m", 0.0), " (N·s/m)")
    return {"stiffness": k, "preload": f0, "damping": c}


def _top_stop(t, path):
    model = t.get("model", "rigid")
    choice(f"{path}.model", model, TOP_STOP_MODELS)
    k = t.get("stiffness_n_m", None if model == "elastic" else 0.0)
    if model == "elastic":
        if k is None:
            raise SceneError(f"{path}.stiffness_n_m", None, "a contact stiffness (elastic stop)")
        k = positive(f"{path}.stiffness_n_m", k, unit=" (N/m)")
    c = nonneg(f"{path}.damping_n_s_m", t.get("damping_n_s_m", 0.0), " (N·s/m)")
    return {"model": model, "stiffness": float(k), "damping": c}


def _engage(t, path):
    f = positive(f"{path}.force_n", t.get("force_n", required=True), unit=" (N)")
    stroke = (
        positive(f"{path}.stroke_mm", t.get("stroke_mm", required=True), upper=10.0, unit=" (mm)") / 1000.0
    )
    return {"force": f, "stroke": stroke}


def _latch(t, path):
    return {}


def _disengage(t, path):
    m = positive(f"{path}.torque_nm", t.get("torque_nm", required=True), unit=" (N·m)")
    d = positive(f"{path}.duration_s", t.get("duration_s", required=True), upper=10.0, unit=" (s)")
    return {"torque": m, "duration": d}


def _blanking(t, path):
    per = positive(f"{path}.perimeter_mm", t.get("perimeter_mm", required=True), unit=" (mm)")
    th = positive(f"{path}.thickness_mm", t.get("thickness_mm", required=True), upper=20.0, unit=" (mm)")
    tau = positive(
        f"{path}.shear_strength_mpa", t.get("shear_strength_mpa", required=True), upper=3000.0, unit=" (MPa)"
    )
    xc = num(f"{path}.contact_mm", t.get("contact_mm", required=True), "a slider position (mm)")
    bt = num(f"{path}.breakthrough", t.get("breakthrough", 0.5), "a fraction of the thickness")
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
        "coulomb": nonneg(f"{path}.coulomb_nm", t.get("coulomb_nm", 0.0), " (N·m)"),
        "viscous": nonneg(f"{path}.viscous_nm_s", t.get("viscous_nm_s", 0.0), " (N·m·s)"),
        "rate_smooth": positive(
            f"{path}.rate_smooth_rad_s", t.get("rate_smooth_rad_s", 0.05), unit=" (rad/s)"
        ),
        "joints": tuple(joints),
    }


def _guide_friction(t, path):
    return {
        "coulomb": nonneg(f"{path}.coulomb_n", t.get("coulomb_n", 0.0), " (N)"),
        "viscous": nonneg(f"{path}.viscous_n_s_m", t.get("viscous_n_s_m", 0.0), " (N·s/m)"),
        "speed_smooth": positive(f"{path}.speed_smooth_m_s", t.get("speed_smooth_m_s", 1e-3), unit=" (m/s)"),
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


#: effects that need the top stop's position (mechanism.x_top_mm)
_NEEDS_X_TOP = ("springs", "top_stop", "engage_cylinder")


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


#: each kind's effects from its parameters and the scene (a list where it makes two)
EFFECT_BUILDERS = {
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
