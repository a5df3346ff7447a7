"""A scene file's tables, one parser each (``[scene]``, ``[mechanism]``, ``[bodies.NAME]``,
``[structure]``, ``[initial]``, ``[[commands]]``, ``[solver]``, ``[outputs]``, ``[charts]``; the
effects' in :mod:`.effect_specs`), the top-level sections checked first, and each table's parse
remembered by its content (:func:`parsed`)."""

from __future__ import annotations

import difflib
import math

from ..caches import Memo
from ..derivatives import SCHEMES
from ..errors import SceneError
from ..model.press import BODY_NAMES, SEED_BODIES, BodyData, PressGeometry
from ..solvers import SOLVERS
from ._fields import UNIT_HINTS, Table, check_dt, choice, displacement, fixed_step, num, positive, tolerance
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


#: each table's parse by its content: the sweeps build thousands of scenes that differ in a
#: field or two (:mod:`mps_core.analysis.sweep`), and a table seen before gives what its
#: parser gave then (a parser is a function of its table and the arguments it is given)
_TABLES = Memo("scene.tables", 1024)


def parsed(parse, data, *args):
    """``parse(data, *args)``, remembered by the table's text (``repr``: TOML's values, and
    1, 1.0 and true apart); a dict it gives is copied (a scene's own); an error is not kept
    (the same table raises it again)."""
    key = (parse, repr(data), args)
    out = _TABLES.get(key)
    if out is None:
        out = _TABLES.keep(key, parse(data, *args))
    return dict(out) if isinstance(out, dict) else out


def check_sections(raw: dict) -> None:
    """Refuse a top-level table the scene file does not know, before any table is read.

    A misspelt ``[inital]`` would otherwise leave ``[initial]`` empty and be reported as its
    first missing value."""
    for key in raw:
        if key not in SECTIONS:
            near = difflib.get_close_matches(key, SECTIONS, n=1)
            hint = f" (did you mean [{near[0]}]?)" if near else ""
            raise SceneError("section", key, "one of the sections " + ", ".join(SECTIONS) + hint)


def parse_meta(data, name: str) -> tuple[str, str]:
    meta = Table(data, "scene")
    sname = meta.get("name", name)
    if not isinstance(sname, str) or not sname:
        raise SceneError("scene.name", sname, "a non-empty string")
    desc = meta.get("description", "")
    if not isinstance(desc, str):
        raise SceneError("scene.description", desc, "a string")
    meta.get("source")
    meta.done()
    return sname, desc


def parse_mechanism(data) -> tuple[PressGeometry, int, float | None]:
    """[mechanism]: the geometry, the assembly, the top stop's position (m, or None)."""
    mt = Table(data, "mechanism", UNIT_HINTS["mechanism"])
    mtype = mt.get("type", "press")
    choice("mechanism.type", mtype, ("press",))
    l1 = positive("mechanism.l1_mm", mt.get("l1_mm", 15.0), unit=" (mm)") / 1000.0
    l2 = positive("mechanism.l2_mm", mt.get("l2_mm", 40.0), unit=" (mm)") / 1000.0
    l3 = positive("mechanism.l3_mm", mt.get("l3_mm", 30.0), unit=" (mm)") / 1000.0
    if l2 <= l1:
        raise SceneError(
            "mechanism.l2_mm",
            l2 * 1000,
            f"a rod longer than the crank (l1_mm = {l1 * 1000:g}) so the crank can turn",
        )
    assembly = mt.get("assembly", 1)
    choice("mechanism.assembly", assembly, (1, -1))
    x_top = mt.get("x_top_mm")
    if x_top is not None:
        x_top = num("mechanism.x_top_mm", x_top, "the top stop's position (mm)") / 1000.0
        lo, hi = l2 - l1 - l3, l1 + l2 + l3
        if not (lo < x_top < hi):
            raise SceneError(
                "mechanism.x_top_mm",
                x_top * 1000,
                f"a slider position the links can reach ({lo * 1000:g} to {hi * 1000:g} mm)",
            )
    mt.done()
    return PressGeometry(l1, l2, l3), assembly, x_top


def parse_bodies(data) -> dict:
    """[bodies.NAME]: each body's mass, inertia and centre of mass (the seed's by default)."""
    bt = Table(data, "bodies")
    bodies = {}
    for bname in BODY_NAMES:
        raw_b = bt.get(bname)
        bodies[bname] = SEED_BODIES[bname] if raw_b is None else parsed(_body, raw_b, bname)
    bt.done()
    return bodies


def _body(data, bname: str) -> BodyData:
    """[bodies.NAME]: one body's (its fields the seed's where not given)."""
    d = SEED_BODIES[bname]
    b = Table(data, f"bodies.{bname}", UNIT_HINTS["body"])
    mass = positive(f"bodies.{bname}.mass_kg", b.get("mass_kg", d.mass), unit=" (kg)")
    inertia = num(
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


def parse_structure(data) -> tuple[str, float, str]:
    """[structure]: the initial structure, the lock angle, the change point's rule."""
    stt = Table(data, "structure", UNIT_HINTS["structure"])
    structure = stt.get("initial", "free")
    choice("structure.initial", structure, STRUCTURES)
    psi_lock = math.radians(num("structure.psi_lock_deg", stt.get("psi_lock_deg", 0.0)))
    change_point = stt.get("change_point", "continue")
    choice("structure.change_point", change_point, CHANGE_POINTS)
    stt.done()
    return structure, psi_lock, change_point


def parse_initial(data, structure: str) -> dict:
    """[initial]: the initial state, SI."""
    it = Table(data, "initial", UNIT_HINTS["initial"])
    phi = math.radians(num("initial.phi_deg", it.get("phi_deg", required=True)))
    phi_dot = num("initial.phi_dot_rad_s", it.get("phi_dot_rad_s", 0.0))
    psi_deg = it.get("psi_deg")
    psi = None if psi_deg is None else math.radians(num("initial.psi_deg", psi_deg))
    psi_dot = num("initial.psi_dot_rad_s", it.get("psi_dot_rad_s", 0.0))
    it.done()
    if structure == "locked" and psi_dot != 0.0:
        raise SceneError("initial.psi_dot_rad_s", psi_dot, "0 in the locked structure")
    return {"phi": phi, "phi_dot": phi_dot, "psi": psi, "psi_dot": psi_dot}


def parse_commands(raw) -> tuple:
    if not isinstance(raw, list):
        raise SceneError("commands", raw, "an array of tables [[commands]] with t_s and command")
    out = []
    for i, c in enumerate(raw):
        t = Table(c, f"commands[{i}]", {"t": "t_s"})
        ts = num(f"commands[{i}].t_s", t.get("t_s", required=True), "a time in seconds >= 0")
        if ts < 0:
            raise SceneError(f"commands[{i}].t_s", ts, "a time in seconds >= 0")
        name = t.get("command", required=True)
        choice(f"commands[{i}].command", name, COMMANDS)
        t.done()
        out.append((ts, name))
    return tuple(sorted(out))


def parse_solver(data) -> tuple[SolverSettings, float, float]:
    """[solver]: the settings, the end time and the output step (s)."""
    sv = Table(data, "solver", UNIT_HINTS["solver"])
    method = sv.get("method", "linear-acceleration")
    choice("solver.method", method, SOLVERS)
    scheme = sv.get("derivatives", "central")
    choice("solver.derivatives", scheme, SCHEMES)
    delta = displacement("solver.delta_deg", sv.get("delta_deg", 0.1))
    iters = sv.get("corrector_iterations", 1)
    if isinstance(iters, bool) or not isinstance(iters, int) or iters < 1 or iters > 50:
        raise SceneError("solver.corrector_iterations", iters, "an integer from 1 to 50")
    rtol = tolerance("solver.rtol", sv.get("rtol", 1e-9))
    atol = tolerance("solver.atol", sv.get("atol", 1e-12))
    stiff = sv.get("stiff", "subdivide")
    choice("solver.stiff", stiff, ("subdivide", "error"))
    switch_points = sv.get("switch_points", "auto")
    choice("solver.switch_points", switch_points, SWITCH_POINTS)
    t_end = positive("solver.t_end_s", sv.get("t_end_s", required=True), upper=1e5, unit=" (s)")
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
    check_dt("solver.dt_s", dt, t_end)
    step = sv.get("step_s")
    if step is not None:
        step = fixed_step("solver.step_s", step, t_end)
    sv.done()
    settings = SolverSettings(
        method, scheme, delta, iters, rtol, atol, stiff, switch_points=switch_points, step=step
    )
    return settings, t_end, float(dt)


def parse_outputs(data) -> bool:
    """[outputs]: whether the reactions (and the foundation load) are computed."""
    ot = Table(data, "outputs")
    reactions = ot.get("reactions", False)
    if not isinstance(reactions, bool):
        raise SceneError("outputs.reactions", reactions, "true or false")
    ot.done()
    return reactions


def parse_charts(data) -> ChartPolicy:
    """[charts]: when to change chart, and when a configuration is singular."""
    ct = Table(data, "charts")
    switching = ct.get("switching", True)
    if not isinstance(switching, bool):
        raise SceneError("charts.switching", switching, "true or false")
    switch_below = num("charts.switch_below", ct.get("switch_below", 0.5))
    fail_below = num("charts.fail_below", ct.get("fail_below", 1e-3))
    if not (0 < fail_below < switch_below < 1):
        raise SceneError(
            "charts.switch_below",
            switch_below,
            f"a regularity between charts.fail_below = {fail_below:g} and 1",
        )
    ct.done()
    return ChartPolicy(switching, switch_below, fail_below)
