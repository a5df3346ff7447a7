"""The variable structure: switches as events inside the step, impacts, commands, hard cases."""

import math

import numpy as np
import pytest
from reference import press_exact as pe
from scipy.optimize import brentq

from mps_core import SceneError, build, load_scene, scene_from_text, simulate
from mps_core.model import PressMechanism
from mps_core.model.effects import Controls, Gravity, Latch
from mps_core.run.simulation import CommandRefused, Simulation
from mps_core.run.stability import StabilityError
from mps_core.scene.settings import SolverSettings

SWITCHES = ("latch-closes", "stop-contact", "stop-release", "latch-opens")


def structure_sequence(traj):
    return [str(traj.structure[0])] + [e["to"] for e in traj.events if e["kind"] in SWITCHES]


def energy_residual(traj):
    return traj.T + traj.V - (traj.T[0] + traj.V[0]) - traj.W + traj.E_impact


# -- the press cycle -------------------------------------------------------------------------
@pytest.fixture(scope="module")
def press_cycle():
    return simulate("press-cycle")


def test_press_cycle_runs_through_its_structures(press_cycle):
    traj = press_cycle
    assert structure_sequence(traj)[:5] == ["held", "free", "locked", "free", "held"]
    kinds = [e["kind"] for e in traj.events]
    assert kinds.count("command") == 2
    assert np.all(np.isfinite(traj.phi_ddot)) and np.all(np.isfinite(traj.x_C))
    # three working strokes: the slider reaches the bottom (x_C = -5 mm) three times when locked
    locked = traj.structure == "locked"
    x = traj.x_C[locked]
    bottoms = np.sum((x[1:-1] < x[:-2]) & (x[1:-1] <= x[2:]) & (x[1:-1] < 0))
    assert bottoms == 3
    assert x.min() == pytest.approx(-0.005, abs=1e-6) and x.max() <= 0.025 + 1e-9


def test_events_sit_on_the_roots_of_the_interpolant(press_cycle):
    for e in press_cycle.events:
        if e["kind"] == "latch-closes":
            rate = abs(e["velocities_before"]["psi_dot"])
            assert abs(e["state"]["psi"] - 0.0) / rate < 1e-9
        elif e["kind"] == "stop-contact":
            rate = abs(e["velocities_before"]["x_C_dot"])
            assert abs(e["state"]["x_C"] - 0.0255) / rate < 1e-9
            assert e["velocities_after"]["x_C_dot"] == pytest.approx(0.0, abs=1e-12)
        elif e["kind"] == "command":
            assert e["t"] in (0.008, 0.4351)


def test_press_cycle_energy_balance_closes_to_the_step_order():
    """T + V − (T0 + V0) = W − E_impact: what is left is the O(Δt²) integration error."""
    res = []
    for dt in (2e-4, 1e-4):
        traj = simulate("press-cycle", dt=dt, t_end=0.6)
        res.append(np.abs(energy_residual(traj)).max())
        assert traj.E_impact[-1] > 50.0 and traj.W[-1] > 100.0
    assert res[1] < 0.05  # J, of ~100 J exchanged; seen 1.7e-2
    assert 3.0 < res[0] / res[1] < 5.5, res


def test_only_the_effects_a_scene_lists_are_built():
    scene = load_scene("press-cycle")
    kinds = {e.kind for e in scene.build_effects(scene.mechanism())}
    assert kinds == {
        "gravity",
        "motor",
        "springs",
        "top_stop",
        "engage_cylinder",
        "latch",
        "disengage_cylinder",
        "blanking",
    }
    paper = load_scene("paper")
    assert {e.kind for e in paper.build_effects(paper.mechanism())} == {"gravity", "motor"}


# -- impacts -----------------------------------------------------------------------------------
def armed_latch_run(psi_lock=0.0, solver="linear-acceleration", scheme="central", dt=1e-4, t_end=0.1):
    m = PressMechanism(psi_lock=psi_lock)
    controls = Controls(structure="free", latch_armed=True)
    effects = [Gravity((-9.81, 0.0)), pe_motor(), Latch(psi_lock)]
    init = m.initial_state("free", math.radians(-64.1), 43.5, math.radians(-46.34), 0.0)
    sim = Simulation(m, "free", effects, init, controls=controls, solver=SolverSettings(solver, scheme))
    return m, sim, sim.run(t_end, dt)


def exact_mass_matrix(state):
    """The exact (φ, ψ) mass matrix on the assembly the configuration lies on."""
    phi, psi, xc = state["phi"], state["psi"], state["x_C"]
    xb = xc + 0.030 * math.cos(psi)
    sigma = 1 if xb - 0.015 * math.cos(phi) > 0 else -1
    return np.asarray(pe.lagrange_phi_psi(sigma=sigma).mass_matrix(phi, psi), float)


def pe_motor():
    from mps_core.model.effects import MOTOR_PRESETS, Motor

    return Motor.for_crank_speed(MOTOR_PRESETS["4A80B4U3"], 43.5)


def test_plastic_latch_impact_keeps_the_cranks_momentum_and_loses_the_predicted_energy():
    m, sim, traj = armed_latch_run()
    ev = next(e for e in traj.events if e["kind"] == "latch-closes")
    before, after = ev["velocities_before"], ev["velocities_after"]
    assert after["psi_dot"] == pytest.approx(0.0, abs=1e-9)
    # exact mass matrix of the seed's chart at the impact configuration
    A = exact_mass_matrix(ev["state"])
    p_before = A[0, 0] * before["phi_dot"] + A[0, 1] * before["psi_dot"]
    p_after = A[0, 0] * after["phi_dot"]
    # the engine's A (central differences, Δ = 0.1°) differs from the exact one by O(Δ²)
    assert p_after == pytest.approx(p_before, rel=1e-5)
    lost = 0.5 * (A[1, 1] - A[0, 1] ** 2 / A[0, 0]) * before["psi_dot"] ** 2
    assert ev["energy_lost"] == pytest.approx(lost, rel=1e-5)
    assert traj.structure[-1] == "locked"
    # with exact derivatives the momentum is kept to round-off
    m, sim, traj = armed_latch_run(scheme="autodiff")
    ev = next(e for e in traj.events if e["kind"] == "latch-closes")
    b, a = ev["velocities_before"], ev["velocities_after"]
    A = exact_mass_matrix(ev["state"])
    assert A[0, 0] * a["phi_dot"] == pytest.approx(A[0, 0] * b["phi_dot"] + A[0, 1] * b["psi_dot"], rel=1e-12)


@pytest.mark.parametrize("offset", [-3e-5, 3e-5])
def test_event_next_to_a_chart_change_is_located_and_mapped_exactly(paper_reference, offset):
    """The latch set at the rocker angle of 30 µs before / after a change of chart."""
    r = paper_reference
    psi_of = lambda t: r.dense(t)[2]  # noqa: E731  (redundant state: phi, theta2, psi, x_C, …)
    free = simulate(load_scene("paper"), t_end=0.1, dt=1e-4, solver="rk4", scheme="autodiff")
    # the last change of chart before 0.1 s (ψ rises through values it has not had before)
    t_switch = [e["t"] for e in free.events if e["kind"] == "chart" and e["t"] > 0.09][0]
    psi_lock = float(psi_of(t_switch + offset))
    m, sim, traj = armed_latch_run(psi_lock, solver="rk4", scheme="autodiff", dt=1e-4)
    ev = next(e for e in traj.events if e["kind"] == "latch-closes")
    # the first time the exact motion reaches psi_lock
    grid = np.linspace(0.0, 0.1, 20001)
    g = np.array([psi_of(t) for t in grid]) - psi_lock
    k = int(np.argmax(np.sign(g[1:]) != np.sign(g[:-1])))
    t_ref = brentq(lambda t: psi_of(t) - psi_lock, grid[k], grid[k + 1], xtol=1e-15)
    assert abs(ev["t"] - t_ref) < 1e-8
    assert ev["state"]["phi"] == pytest.approx(float(r.dense(t_ref)[0]), abs=1e-8)
    assert traj.structure[-1] == "locked"
    charts_before = [e for e in traj.events if e["kind"] == "chart" and e["t"] <= ev["t"]]
    assert len(charts_before) == len([e for e in free.events if e["kind"] == "chart" and e["t"] <= ev["t"]])
    assert abs(ev["t"] - t_switch) < 1e-4


# -- commands ------------------------------------------------------------------------------------
def test_commands_take_effect_at_their_exact_time_and_bad_ones_are_refused():
    sim = build(load_scene("press-cycle").with_overrides(t_end=0.02))
    sim.advance_to(0.0031)
    with pytest.raises(CommandRefused, match="not engaged"):
        sim.command("disengage")
    for bad in ("", "ENGAGE", "lift", None):
        with pytest.raises(CommandRefused, match="expected one of"):
            sim.command(bad)
    sim.command("stop", t=0.00412345)
    sim.advance_to(0.005)
    ev = [e for e in sim.events if e["kind"] == "command" and e["command"] == "stop"]
    assert ev and ev[0]["t"] == 0.00412345 and sim.controls.motor_on is False
    with pytest.raises(CommandRefused, match="already off"):
        sim.command("stop")
    sim.command("start")
    sim.advance_to(0.0101)
    assert sim.structure != "held"  # the scene's engage at 8 ms took the slider off its stop
    with pytest.raises(CommandRefused, match="already engaging"):
        sim.command("engage")


# -- stiff effects -------------------------------------------------------------------------------
# a 1e10 N/m spring relaxed at the slider's initial position: T_min ≈ 0.74 ms
STIFF = (
    load_scene("free-fall")
    .text.replace("assembly = 1", "assembly = 1\nx_top_mm = 24.989060906713247")
    .replace("[solver]", '[[effects]]\ntype = "springs"\nstiffness_n_m = 1.0e10\npreload_n = 0.0\n\n[solver]')
)


def test_a_step_beyond_the_stability_limit_is_refused_with_the_reason():
    scene = scene_from_text(STIFF.replace("[solver]", '[solver]\nstiff = "error"'))
    with pytest.raises(StabilityError) as info:
        simulate(scene, t_end=0.01, dt=1e-3)
    msg = str(info.value)
    assert "stability limit" in msg and "T_min" in msg and "springs" in msg


def test_a_step_beyond_the_stability_limit_is_subdivided():
    scene = scene_from_text(STIFF)
    coarse = simulate(scene, t_end=0.02, dt=1e-3)
    fine = simulate(scene, t_end=0.02, dt=1e-5)
    assert coarse.counts["steps"] >= 20 * 4  # substeps of at most T_min/(2π) were taken
    assert np.all(np.isfinite(coarse.x_C)) and np.all(np.isfinite(coarse.phi_ddot))
    e, ef = coarse.T + coarse.V, fine.T + fine.V
    # no blow-up: the energy never grows. The predictor-corrector damps a mode resolved with
    # ω·Δt ≈ 1 (about 4 % of its amplitude a step), so the stiff mode's share is lost here,
    # where the fine step (ω·Δt ≈ 0.09) keeps the energy to 0.1 %.
    assert e.max() <= e[0] * (1 + 1e-9) and np.all(np.diff(e) <= 1e-6 * abs(e[0]))
    assert np.abs(ef - ef[0]).max() < 1e-3 * abs(ef[0])
    # without the subdivision the same step blows up
    with pytest.raises(StabilityError):
        simulate(scene_from_text(STIFF.replace("[solver]", '[solver]\nstiff = "error"')), t_end=0.02, dt=1e-3)


def test_the_predictor_corrector_stability_limit_is_omega_dt_2():
    """On q̈ = −q the seed's scheme (one correction) is bounded up to ω·Δt = 2, not beyond."""
    from mps_core.solvers import LinearAcceleration

    class E:
        def __init__(self, a):
            self.qdd = a

    def final_amplitude(h, n=400):
        s = LinearAcceleration(lambda t, q, qd: E(-q), 0.0, [1.0], [0.0])
        for k in range(1, n + 1):
            s.step_to(k * h)
        return math.hypot(s.q[0], s.qd[0])

    assert final_amplitude(1.95) <= 1.0
    assert final_amplitude(2.05) > 1e3


# -- idle and the change point -------------------------------------------------------------------
def held_idle(text, turns, dt=2e-4):
    scene = scene_from_text(text)
    t_end = turns * 2 * math.pi / 43.5
    return simulate(scene, t_end=t_end, dt=dt)


HOLD = load_scene("idle").text.replace("preload_n = 2500.0", "preload_n = 1.0e6")


@pytest.mark.slow
def test_idle_held_for_100_turns_is_periodic_on_its_branch():
    """With a hold-down above the four-bar's pull (~0.68 MN at x_top = 25.5 mm) the slider stays
    on its stop: the crank-rocker turns 100 times, ψ within its Grashof range."""
    traj = held_idle(HOLD, 100, dt=5e-4)
    assert set(traj.structure) == {"held"}
    turns = (traj.phi[-1] - traj.phi[0]) / (2 * math.pi)
    assert turns > 90
    psi = np.degrees(traj.psi)
    assert psi.min() > -127.3 and psi.max() < -15.3
    assert np.all(np.isfinite(traj.phi_ddot))
    # periodic: each turn's ψ range the same
    k = np.floor((traj.phi - traj.phi[0]) / (2 * math.pi)).astype(int)
    mins = [psi[k == i].min() for i in range(5, 85)]
    assert np.ptp(mins) < 0.05


def test_idle_at_the_contract_preload_lifts_off_near_the_toggle_and_stays_finite():
    """With springs the drive can work against (2.5 kN), the idle slider lifts off its stop:
    the events record it and the energy balance still closes."""
    traj = simulate("idle", t_end=0.3)
    kinds = [e["kind"] for e in traj.events]
    assert "stop-release" in kinds and "stop-contact" in kinds
    assert np.all(np.isfinite(traj.phi_ddot))
    assert np.abs(energy_residual(traj)).max() < 0.1


# at the change point no one-sided stop holds (the reaction grows without bound as the
# transmission angle goes to zero at phi = 0): the slider is clamped for this study
CHANGE = (
    load_scene("idle")
    .text.replace("x_top_mm = 25.5", "x_top_mm = 25.0")
    .replace('model = "rigid"', 'model = "clamp"')
)


def test_change_point_is_passed_on_the_smooth_continuation():
    traj = held_idle(CHANGE, 6, dt=2e-4)
    cps = [e for e in traj.events if e["kind"] == "change-point"]
    assert len(cps) >= 5
    assert all(e["choice"] == "smooth continuation" for e in cps)
    assert set(traj.structure) == {"held"}
    assert np.all(np.isfinite(traj.psi)) and np.all(np.isfinite(traj.phi_ddot))
    psi = np.degrees(traj.psi)
    # on the smooth continuation the rocker swings to ψ > 0 on alternate turns
    k = np.floor((traj.phi - traj.phi[0]) / (2 * math.pi)).astype(int)
    signs = [np.sign(psi[k == i].mean()) for i in range(1, 5)]
    assert signs[0] != signs[1] and signs[1] != signs[2]
    # positions at the change point: O, A, C, B on the x axis
    for e in cps[:3]:
        assert abs(math.sin(e["phi"])) < 1e-6 and abs(math.sin(e["psi"])) < 1e-3


# -- long conservative run -----------------------------------------------------------------------
@pytest.mark.slow
def test_long_conservative_run_keeps_energy_and_the_closure():
    """10⁵ steps of free fall (gravity alone): energy bounded, |AB| = l2 to round-off."""
    scene = load_scene("free-fall")
    sim = build(scene.with_overrides(t_end=2.0, dt=2e-5, scheme="autodiff"))
    l2 = scene.geometry.l2
    worst = [0.0]

    class Closure:
        def observe(self, s, e):
            a, b = e.kin.position("A"), e.kin.position("B")
            worst[0] = max(worst[0], abs(math.hypot(*(b - a)) - l2))

        def columns(self):
            return {}

    sim.observers.append(Closure())
    traj = sim.run(2.0, 2e-5)
    assert len(traj) == 100_001
    assert worst[0] < 1e-16 * 50
    e = traj.energy
    assert np.abs(e - e[0]).max() < 1e-3 * abs(e[0])


def test_friction_work_closes_the_energy_balance():
    """Joint and guide friction only where a scene lists them; their (negative) work is in W."""
    text = load_scene("working").text.replace(
        "[solver]",
        """[[effects]]
type = "joint_friction"
coulomb_nm = 0.5
viscous_nm_s = 0.002

[[effects]]
type = "guide_friction"
coulomb_n = 40.0
viscous_n_s_m = 50.0

[solver]""",
    )
    scene = scene_from_text(text)
    kinds = {e.kind for e in scene.build_effects(scene.mechanism())}
    assert {"joint_friction", "guide_friction"} <= kinds
    sim = build(scene.with_overrides(t_end=0.2))
    powers = []

    class FrictionPower:
        def observe(self, s, e):
            powers.append(sum(f.power(e.t, e.kin) for f in s.effects if "friction" in f.kind))

        def columns(self):
            return {}

    sim.observers.append(FrictionPower())
    with_friction = sim.run(0.2, scene.dt)
    without = simulate(load_scene("working"), t_end=0.2)
    assert np.abs(energy_residual(with_friction)).max() < 0.02
    # friction never does positive work, and it takes energy: the crank runs behind
    assert max(powers) <= 0.0 and min(powers) < -1.0
    assert with_friction.phi[-1] < without.phi[-1]


def test_change_point_with_the_rocker_kept_on_its_side():
    """The other documented choice: a plastic impact onto the branch that keeps the rocker at
    ψ ≤ 0. Here that branch turns back more than a right angle (in the mass metric), so the
    mechanism stops dead at each passage and the motor takes it on: logged, energy lost, the
    balance closed, nothing NaN."""
    text = CHANGE.replace('initial = "held"', 'initial = "held"\nchange_point = "keep-side"')
    traj = held_idle(text, 6, dt=2e-4)
    cps = [e for e in traj.events if e["kind"] == "change-point"]
    assert len(cps) >= 2 and all(e["choice"] == "keep side" for e in cps)
    assert np.degrees(traj.psi).max() < 1e-6
    for e in cps:
        assert e["energy_lost"] > 0.0 and e["phi_dot_after"] >= 0.0
    assert traj.E_impact[-1] == pytest.approx(sum(e["energy_lost"] for e in cps), rel=1e-12)
    assert np.abs(energy_residual(traj)).max() < 0.1
    assert np.all(np.isfinite(traj.phi_ddot))
    with pytest.raises(SceneError, match="central differences"):
        scene_from_text(text.replace('derivatives = "central"', 'derivatives = "autodiff"'))


def test_the_higher_order_methods_subdivide_at_their_own_limit():
    """RK4 and RK8 take the stiff spring's steps within their own limits on the imaginary
    axis (2√2 and, from RK8's tableau, about 5.96): bounded where the step given is far beyond
    them, RK8 in about 5.96/2√2 times fewer steps; with ``stiff = "error"`` both refuse."""
    from mps_core.solvers.rk8 import IMAGINARY_LIMIT

    steps = {}
    for solver in ("rk4", "rk8"):
        coarse = simulate(scene_from_text(STIFF), t_end=0.02, dt=1e-3, solver=solver, scheme="autodiff")
        assert np.all(np.isfinite(coarse.x_C)) and np.all(np.isfinite(coarse.phi_ddot))
        e = coarse.T + coarse.V
        # no blow-up: the energy never grows (both damp a mode resolved this coarsely: the
        # stiff mode's share is lost, as with the predictor-corrector above)
        assert e.max() <= e[0] * (1 + 1e-9) and np.all(np.diff(e) <= 1e-6 * abs(e[0]))
        steps[solver] = coarse.counts["steps"]
        with pytest.raises(StabilityError, match="stability limit"):
            simulate(
                scene_from_text(STIFF.replace("[solver]", '[solver]\nstiff = "error"')),
                t_end=0.02,
                dt=1e-3,
                solver=solver,
                scheme="autodiff",
            )
    assert steps["rk8"] > 20
    ratio = steps["rk4"] / steps["rk8"]
    assert 0.75 < ratio / (IMAGINARY_LIMIT / (2 * math.sqrt(2))) < 1.25, steps
