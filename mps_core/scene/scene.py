"""Scene files: TOML in, a validated scene in SI units out.

A scene names the mechanism and its bodies, the structure and the initial state, the effects it
wants (only those are built and evaluated), the solver and the charts' policy. Files for people
use units in the key names (``l1_mm``, ``phi_deg``, ``t_end_s``); inside, everything is SI.
Everything is validated before anything runs: an unknown key, a wrong type, a missing unit or a
non-physical value raises :class:`~mps_core.errors.SceneError` naming the field, the value and
what was expected.

Presets ship in ``mps_core/scene/presets/*.toml``; ``load_scene("paper")`` loads one, any other string
is read as a path.

The scene's tables are read by :mod:`.tables` (one parser a table) and :mod:`.effect_specs`
(the effects), field by field (:mod:`._fields`); here: the :class:`Scene` itself, the checks
across tables, and reading one from a dict, a text, a file or a preset.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path

from ..caches import Memo
from ..derivatives import SCHEMES
from ..errors import SceneError
from ..model.press import BODY_NAMES, PressGeometry, PressMechanism
from ..solvers import SOLVERS
from ._fields import Table, check_dt, check_step_solver, choice, displacement, fixed_step, positive, tolerance
from .effect_specs import EFFECT_BUILDERS, EffectSpec, parse_effects
from .settings import SWITCH_POINTS, ChartPolicy, SolverSettings
from .tables import (
    SECTIONS,
    STRUCTURES,
    check_sections,
    parse_bodies,
    parse_charts,
    parse_commands,
    parse_initial,
    parse_mechanism,
    parse_meta,
    parse_outputs,
    parse_solver,
    parse_structure,
    parsed,
)

__all__ = [
    "Scene",
    "EffectSpec",
    "load_scene",
    "preset_names",
    "scene_from_dict",
    "scene_from_text",
    "BODY_NAMES",
    "SECTIONS",
    "STRUCTURES",
]


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
        t_end = s.t_end if t_end is None else positive("t_end_s", t_end, upper=1e5)
        if steps is not None:
            if not isinstance(steps, int) or steps < 1:
                raise SceneError("solver.steps", steps, "a positive integer")
            dt = t_end / steps
        elif dt is None:
            dt = s.dt  # a new end time keeps the step
            if dt > t_end:
                dt = t_end
        check_dt("solver.dt_s", dt, t_end)
        st = s.solver
        if solver is not None:
            choice("solver.method", solver, SOLVERS)
            st = replace(st, name=solver)
        if delta is not None:
            st = replace(st, delta=displacement("solver.delta_deg", math.degrees(delta)))
        if scheme is not None:
            choice("solver.derivatives", scheme, SCHEMES)
            st = replace(st, scheme=scheme)
        if iterations is not None:
            if isinstance(iterations, bool) or not isinstance(iterations, int) or not 1 <= iterations <= 50:
                raise SceneError("solver.corrector_iterations", iterations, "an integer from 1 to 50")
            st = replace(st, iterations=iterations)
        if rtol is not None:
            st = replace(st, rtol=tolerance("solver.rtol", rtol))
        if atol is not None:
            st = replace(st, atol=tolerance("solver.atol", atol))
        if switch_points is not None:
            choice("solver.switch_points", switch_points, SWITCH_POINTS)
            st = replace(st, switch_points=switch_points)
        if step is not None:
            st = replace(st, step=fixed_step("solver.step_s", step, t_end))
        if st.step is not None:
            check_step_solver(st)
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
            built = EFFECT_BUILDERS[e.kind](e.params, self)
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


def scene_from_dict(raw: dict, *, name: str = "scene", text: str = "", origin: str = "") -> Scene:
    """A validated scene from a parsed TOML document: its sections known, one parser a table,
    in the order the tables are checked, then what crosses tables."""
    top = Table(raw, "scene file")
    check_sections(raw)
    sname, desc = parsed(parse_meta, top.get("scene", {}), name)
    geometry, assembly, x_top = parsed(parse_mechanism, top.get("mechanism", {}))
    bodies = parsed(parse_bodies, top.get("bodies", {}))
    structure, psi_lock, change_point = parsed(parse_structure, top.get("structure", {}))
    initial = parsed(parse_initial, top.get("initial", {}), structure)
    commands = parsed(parse_commands, top.get("commands", []))
    effects = parsed(parse_effects, top.get("effects", []), x_top, structure, commands)
    solver, t_end, dt = parsed(parse_solver, top.get("solver", {}))
    reactions = parsed(parse_outputs, top.get("outputs", {}))
    charts = parsed(parse_charts, top.get("charts", {}))
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


def _check_across_tables(scene: Scene) -> None:
    """What no one table decides: the step against the solver, the change point's rule
    against the derivatives, the commands' times, and the initial state assembling (on the
    closure, in held) before anything runs."""
    if scene.solver.step is not None:
        check_step_solver(scene.solver)
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
