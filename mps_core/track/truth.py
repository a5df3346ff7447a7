"""A press to follow: a *truth* scene that is not the twin's, run, and read by its sensors.

The truth differs from the nominal scene as a real press differs from its model
(:class:`TruthChanges`): the slider's and the rod's masses off by ±10 %, friction twice the
nominal (where the nominal has none, the truth gets the friction a real press has), another
blanking force curve and sheet thickness, the motor's torque 3 % off its catalogue. It runs on a
fine step and is sampled by its sensors (:class:`Sensors`): a 17-bit absolute encoder at 1 kHz
with quantisation and electrical noise, sampled at instants that jitter by up to ±0.2 ms around
the nominal grid and stamped with those instants; optionally a linear scale on the slider and the
motor's torque (from its current). The scene's commands are the mode signals.

Faults (:class:`Fault`) are injected at given times: ``double-blank`` (two parts in the die: the
blanking force doubled), ``broken-spring`` (the retention springs gone), ``clutch-slip`` (the
drive's torque halved for ``duration`` seconds: a slipping coupling or belt between motor and
crank; the press has no clutch of its own), ``missed-part`` (no part in the die from ``t`` until
the punch has gone through where the part would be: the next cut blanks nothing).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from ..dynamics.reactions import compute_reactions
from ..run.simulation import Simulation
from ..scene.scene import EffectSpec
from .measurements import Encoder, Measurement, MeasurementError, ModeSignal, TorqueSensor

if TYPE_CHECKING:
    from ..scene import Scene

__all__ = [
    "FAULTS",
    "PRESET_PART",
    "Fault",
    "Sensors",
    "TruthChanges",
    "TruthRun",
    "nominal_scene",
    "run_truth",
    "truth_scene",
    "with_blanking",
]

#: the faults that can be injected
FAULTS = ("double-blank", "broken-spring", "clutch-slip", "missed-part")


def timed_kinds(specs: list[str], option: str, kinds: tuple[str, ...]) -> list[tuple[float, str]]:
    """Return the (T, KIND) of command-line values ``T:KIND``, each checked.

    ``option`` names the option in the error (:class:`MeasurementError`); ``kinds`` are the
    KINDs it takes; T is in seconds, >= 0.
    """
    out = []
    for s in specs:
        when, _, kind = s.partition(":")
        try:
            t = float(when)
        except ValueError:
            t = math.nan
        if not (t >= 0.0 and kind in kinds):
            raise MeasurementError(option, s, f"T:KIND, T in seconds >= 0, KIND one of {', '.join(kinds)}")
        out.append((t, kind))
    return out


@dataclass(frozen=True)
class TruthChanges:
    """How the truth differs from the nominal scene (factors on the nominal's values)."""

    slider_mass: float = 1.10
    rod_mass: float = 0.90
    friction: float = 2.0
    motor_torque: float = 0.97
    #: the truth's blanking, replacing the nominal's (mm, MPa as in a scene file)
    blanking: dict = field(
        default_factory=lambda: {
            "perimeter_mm": 62.83,
            "thickness_mm": 1.5,
            "shear_strength_mpa": 300.0,
            "contact_mm": -2.0,
            "breakthrough": 0.6,
        }
    )
    #: the friction a real press has where the nominal scene lists none (before the factor)
    joint_friction_nm: float = 0.5
    guide_friction_n: float = 50.0


@dataclass(frozen=True)
class Fault:
    """A fault injected at time ``t`` (s): one of :data:`FAULTS`; ``duration`` for a slip."""

    t: float
    kind: str
    duration: float = 0.05

    def __post_init__(self) -> None:
        if self.kind not in FAULTS:
            raise MeasurementError("fault.kind", self.kind, "one of " + ", ".join(FAULTS))
        if not (math.isfinite(self.t) and self.t >= 0.0):
            raise MeasurementError("fault.t", self.t, "a time >= 0 (s)")


@dataclass(frozen=True)
class Sensors:
    """The press's sensors: the crank encoder at ``rate`` Hz with sampling jitter of up to
    ``jitter`` s either side; optional slider scale (resolution and noise, m) and motor torque
    (:class:`~mps_core.track.measurements.TorqueSensor`)."""

    encoder: Encoder = field(default_factory=Encoder)
    rate: float = 1000.0
    jitter: float = 2e-4
    slider: bool = False
    slider_resolution: float = 1e-6
    slider_noise: float = 1e-6
    motor_torque: bool = False
    torque_sensor: TorqueSensor = field(default_factory=TorqueSensor)

    def __post_init__(self) -> None:
        if not (self.rate > 0.0 and math.isfinite(self.rate)):
            raise MeasurementError("sensors.rate", self.rate, "a positive rate (Hz)")
        if not (0.0 <= self.jitter < 0.5 / self.rate):
            raise MeasurementError("sensors.jitter", self.jitter, f"a time in [0, {0.5 / self.rate:g}) s")


def truth_scene(nominal: Scene, changes: TruthChanges | None = None) -> Scene:
    """Return the truth scene: the nominal one changed as ``changes`` says."""
    c = changes or TruthChanges()
    bodies = dict(nominal.bodies)
    for name, factor in (("slider", c.slider_mass), ("rod", c.rod_mass)):
        bodies[name] = replace(bodies[name], mass=bodies[name].mass * factor)
    effects = []
    kinds = {e.kind for e in nominal.effects}
    blanking = _blanking_params(c.blanking)
    for e in nominal.effects:
        p = dict(e.params)
        if e.kind in ("joint_friction", "guide_friction"):
            p["coulomb"] *= c.friction
            p["viscous"] *= c.friction
        elif e.kind == "motor":
            p["efficiency"] = p["efficiency"] * c.motor_torque
        elif e.kind == "blanking":
            p = blanking
        effects.append(replace(e, params=p))
    if "blanking" not in kinds:
        effects.append(EffectSpec("blanking", blanking))
    if "joint_friction" not in kinds:
        effects.append(
            EffectSpec(
                "joint_friction",
                {
                    "coulomb": c.joint_friction_nm * c.friction,
                    "viscous": 0.0,
                    "rate_smooth": 0.05,
                    "joints": ("O", "A", "B", "C"),
                },
            )
        )
    if "guide_friction" not in kinds:
        effects.append(
            EffectSpec(
                "guide_friction",
                {"coulomb": c.guide_friction_n * c.friction, "viscous": 0.0, "speed_smooth": 1e-3},
            )
        )
    return replace(nominal, name=nominal.name + "-truth", bodies=bodies, effects=tuple(effects))


#: the part the presets blank (press-cycle's washer of 1 mm steel), as a scene file's table
PRESET_PART = {
    "perimeter_mm": 62.83,
    "thickness_mm": 1.0,
    "shear_strength_mpa": 320.0,
    "contact_mm": -3.0,
    "breakthrough": 0.5,
}


def with_blanking(scene: Scene, table: dict | None = None) -> Scene:
    """Return ``scene`` blanking the part ``table`` describes (a scene file's blanking table;
    default :data:`PRESET_PART`), in place of any it blanks."""
    params = _blanking_params(PRESET_PART if table is None else table)
    kept = tuple(e for e in scene.effects if e.kind != "blanking")
    spec = EffectSpec("blanking", params)
    return replace(scene, effects=kept + (spec,))


def nominal_scene(scene: Scene) -> Scene:
    """Return the nominal press a tracker follows: ``scene``, blanking the presets' part where
    it blanks none (where the punch works: the tracker's work window)."""
    if any(e.kind == "blanking" for e in scene.effects):
        return scene
    return with_blanking(scene)


def _blanking_params(raw: dict) -> dict:
    """Return the blanking effect's SI parameters from a scene file's table (checked as a scene's)."""
    from ..scene import scene_from_dict

    scene = scene_from_dict(
        {
            "scene": {"name": "blanking"},
            "mechanism": {"type": "press", "l1_mm": 15.0, "l2_mm": 40.0, "l3_mm": 30.0, "assembly": 1},
            "structure": {"initial": "locked"},
            "initial": {"phi_deg": 0.0, "phi_dot_rad_s": 43.5},
            "effects": [{"type": "blanking", **raw}],
            "solver": {"t_end_s": 0.01, "dt_s": 0.001},
        },
        name="blanking",
    )
    return dict(scene.effects[0].params)


@dataclass
class TruthRun:
    """The truth's record on its fine grid, the measurements and the mode signals."""

    t: np.ndarray
    phi: np.ndarray
    phi_dot: np.ndarray
    x_C: np.ndarray
    force: np.ndarray
    foundation_x: np.ndarray
    foundation_y: np.ndarray
    locked: np.ndarray
    measurements: list[Measurement]
    modes: list[ModeSignal]
    faults: tuple[Fault, ...] = ()
    scene: Any = None

    def at(self, t: float) -> dict[str, float]:
        """Return the truth at time t (linear interpolation on the fine grid)."""
        return {
            name: float(np.interp(t, self.t, getattr(self, name)))
            for name in ("phi", "phi_dot", "x_C", "force", "foundation_x", "foundation_y")
        }


def run_truth(
    truth: Scene,
    t_end: float,
    *,
    sensors: Sensors | None = None,
    faults: tuple[Fault, ...] = (),
    fine_dt: float = 5e-5,
    seed: int = 0,
    progress: Callable[[float], None] | None = None,
    stop: Callable[[], bool] | None = None,
) -> TruthRun:
    """Run the truth scene to ``t_end`` on a fine grid and sample its sensors.

    ``progress(t)`` is called as it goes; where ``stop()`` turns true it ends there (the truth,
    the measurements and the mode signals up to the time reached)."""
    sensors = sensors or Sensors()
    rng = np.random.default_rng(seed)
    mech = truth.mechanism()
    effects = truth.build_effects(mech)
    solver = replace(truth.solver, step=fine_dt)
    sim = Simulation(
        mech,
        truth.structure,
        effects,
        truth.initial_state(mech),
        solver=solver,
        charts=truth.charts,
        commands=truth.commands,
        change_point=truth.change_point,
    )
    blanking = [e for e in effects if e.kind == "blanking"]
    period = 1.0 / sensors.rate
    k = np.arange(1, int(math.floor(t_end / period)))
    samples = k * period + rng.uniform(-sensors.jitter, sensors.jitter, len(k))
    fine = np.arange(1, int(math.floor(t_end / fine_dt)) + 1) * fine_dt
    times = np.union1d(fine, samples)
    is_sample = np.isin(times, samples)
    pending = sorted(_fault_actions(effects, faults), key=lambda a: a[0])
    # a missed part: the part back once the punch has come down through where it would be
    # ([put it back, the slider position past the part, whether the slider was above it since])
    through: list[list] = []
    rows: list[tuple] = [_truth_row(sim, blanking)]
    out: list[Measurement] = []
    enc = sensors.encoder
    stopped = False
    for t, sampled in zip(times.tolist(), is_sample.tolist()):
        if stop is not None and stop():
            stopped = True
            break
        if progress is not None:
            progress(t)
        while pending and pending[0][0] <= t:
            t_fault, action = pending.pop(0)
            if t_fault > sim.t:
                sim.advance_to(t_fault)
            after = action()
            if after is not None:
                through.append([*after, False])
        sim.advance_to(t)
        if through:
            x_C, missing = sim.joint_state()[4], through[0]
            if x_C >= missing[1]:
                missing[2] = True
            elif missing[2]:
                through.pop(0)[0]()
        row = _truth_row(sim, blanking)
        rows.append(row)
        if sampled:
            out.extend(_read(sensors, enc, row, rng, sim))
    cols = np.array([r[:7] for r in rows], dtype=float)
    modes = [
        ModeSignal(float(c_t), c)
        for c_t, c in truth.commands
        if c in ("engage", "disengage") and not (stopped and c_t > rows[-1][0])
    ]
    return TruthRun(
        t=cols[:, 0],
        phi=cols[:, 1],
        phi_dot=cols[:, 2],
        x_C=cols[:, 3],
        force=cols[:, 4],
        foundation_x=cols[:, 5],
        foundation_y=cols[:, 6],
        locked=np.array([r[7] for r in rows], dtype=bool),
        measurements=out,
        modes=modes,
        faults=tuple(faults),
        scene=truth,
    )


def _truth_row(sim: Simulation, blanking: list) -> tuple:
    """Return (t, φ, φ̇, x_C, process force, foundation force x, y, locked) of the truth now."""
    e = sim.solver.current
    phi, phi_dot, _psi, _psi_dot, x_C, v_C = sim.joint_state()
    locked = sim.structure == "locked"
    force = sum(b.force(x_C, v_C) for b in blanking) if locked else 0.0
    rx = compute_reactions(sim.mechanism, sim.engine.effects, e.view, e.t, e.q, e.qd, e.qdd, kin=e.kin)
    return (e.t, phi, phi_dot, x_C, force, rx.values["F_found_x"], rx.values["F_found_y"], locked)


def _read(sensors: Sensors, enc: Encoder, row: tuple, rng: np.random.Generator, sim: Simulation) -> list:
    """Return the sensors' measurements at one sampling instant of the truth."""
    t, phi, phi_dot, x_C = row[:4]
    noise = float(rng.normal(0.0, enc.noise_counts)) * enc.lsb
    out = [enc.measurement(t, enc.count(phi, noise))]
    if sensors.slider:
        res = sensors.slider_resolution
        x = round((x_C + float(rng.normal(0.0, sensors.slider_noise))) / res) * res
        out.append(Measurement(t, "slider_position", x, sensors.slider_noise**2 + res**2 / 12.0))
    if sensors.motor_torque:
        motor = next((e for e in sim.effects if e.kind == "motor"), None)
        if motor is not None:
            m = motor.torque(phi_dot)
            sd = sensors.torque_sensor.sigma(m)
            out.append(Measurement(t, "motor_torque", m + float(rng.normal(0.0, sd)), sd**2))
    return out


def _fault_actions(effects: list, faults: tuple[Fault, ...]) -> list[tuple[float, Any]]:
    """Return the (time, action) pairs that change the truth's effects as the faults say."""
    out: list[tuple[float, Any]] = []
    for fault in faults:
        for e in effects:
            if fault.kind == "double-blank" and e.kind == "blanking":
                out.append((fault.t, _scaled(e, "f", 2.0)))
            elif fault.kind == "broken-spring" and e.kind == "springs":
                out.append((fault.t, _scaled(e, "k", 0.0)))
                out.append((fault.t, _scaled(e, "f0", 0.0)))
            elif fault.kind == "clutch-slip" and e.kind == "motor":
                out.append((fault.t, _scaled(e, "efficiency", 0.5)))
                out.append((fault.t + fault.duration, _scaled(e, "efficiency", 2.0)))
            elif fault.kind == "missed-part" and e.kind == "blanking":
                out.append((fault.t, _missing(e)))
    return out


def _missing(blanking: Any) -> Any:
    """Return an action that takes the part out of the die: its force zero (by assignment), and
    what puts it back, with the slider position below which the punch has gone through it."""

    def action() -> tuple[Any, float]:
        """Take the part out; return (put it back, the slider position past the part)."""
        force = blanking.f
        blanking.f = 0.0

        def back() -> None:
            blanking.f = force

        return back, blanking.x_contact - blanking.pb

    return action


def _scaled(effect: Any, name: str, factor: float) -> Any:
    """Return an action that multiplies an effect's parameter by ``factor`` (by assignment)."""

    def action() -> None:
        """Multiply the parameter."""
        setattr(effect, name, getattr(effect, name) * factor)

    return action
