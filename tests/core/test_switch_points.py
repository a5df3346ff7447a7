"""Points where a force law is not smooth: the disengage cylinder's end (a time), the effects'
switching functions (a state: the punch touches the part, breaks through, the engage cylinder's
ramp). Steps end there; no step straddles them where the settings say so."""

import dataclasses

import numpy as np
import pytest

from mps_core import SceneError, build, load_scene, scene_from_text
from mps_core.model.effects import Blanking, Controls
from mps_core.scene.settings import SolverSettings


def press_cycle(method="linear-acceleration", t_end=None, **solver):
    scene = load_scene("press-cycle")
    scene = scene.with_overrides(
        solver=method, t_end=t_end, scheme="autodiff" if method == "dop853" else None
    )
    if solver:
        scene = dataclasses.replace(scene, solver=dataclasses.replace(scene.solver, **solver))
    return scene


def advance_on_grid(sim, t_end, dt=1e-3):
    """Advance on the dt grid, then to t_end (advance_to itself takes one fixed step)."""
    while sim.t < t_end - 1e-12:
        sim.advance_to(min(t_end, (round(sim.t / dt) + 1) * dt))


# -- the disengage cylinder acts for its duration, ending at a step boundary --------------------
def test_the_disengage_cylinder_stops_acting_at_a_step_boundary():
    scene = press_cycle(t_end=0.5)
    sim = build(scene)
    cyl = sim.structures.parts.disengage

    def go(t_end):
        advance_on_grid(sim, t_end)

    go(0.4351)
    assert not sim.controls.disengage_on
    go(0.436)  # the disengage command at 0.4351 has been taken
    assert sim.controls.disengage_on and cyl.active(sim.t)
    go(0.4551 - 1e-4)
    assert sim.controls.disengage_on
    go(0.4551)
    # a step ends at the cylinder's end; like a command, it takes effect as the next step begins
    assert sim.t == pytest.approx(0.4351 + cyl.duration, abs=1e-15)
    t_end = sim.t
    restarts = []
    sim._restart = lambda *a, _r=sim._restart: (restarts.append(sim.solver.t), _r(*a))[1]
    go(0.4552)
    ends = [e for e in sim.events if e["kind"] == "cylinder-off"]
    assert len(ends) == 1 and ends[0]["t"] == t_end and ends[0]["effect"] == "disengage_cylinder"
    assert restarts == [t_end] and not sim.controls.disengage_on
    e = sim.solver.current
    assert cyl.generalized_force(e.t, e.kin) is None


def test_a_second_disengage_moves_the_cylinder_end():
    sim = build(press_cycle(t_end=0.5))

    def go(t_end):
        advance_on_grid(sim, t_end)

    go(0.1)  # engaged and locked by now
    assert sim.structure == "locked"
    sim.command("disengage")
    go(sim.t + 0.005)
    sim.controls.engage_on = True  # as if engaged again: a disengage is accepted
    sim.command("disengage")
    t2 = sim.t
    go(t2 + 0.03)
    ends = [e["t"] for e in sim.events if e["kind"] == "cylinder-off"]
    assert ends == [pytest.approx(t2 + sim.structures.parts.disengage.duration, abs=1e-15)]


# -- switching functions ---------------------------------------------------------------------------
def test_blanking_switching_functions_bracket_its_force():
    b = Blanking(peak_force=1e4, x_contact=0.0, thickness=0.004)
    b.use(Controls(structure="locked"))

    class Kin:
        def __init__(self, x, v):
            self.x, self.v = x, v

        def xy(self, p):
            return self.x, 0.0

        def vxy(self, p):
            return self.v, 0.0

    assert b.switches == ("contact", "breakthrough", "turn")
    for x, v in [(0.001, -0.1), (-0.001, -0.1), (-0.003, -0.1), (-0.001, 0.1)]:
        contact, through, turn = b.switch_values(0.0, Kin(x, v))
        inside = contact > 0.0 and through < 0.0 and turn < 0.0
        assert (b.force(x, v) != 0.0) == inside
    b.use(Controls(structure="free"))
    assert b.switch_values(0.0, Kin(-0.001, -0.1)) == [1.0, 1.0, 1.0]


def test_auto_locates_switch_points_with_adaptive_solvers_only():
    assert SolverSettings("dop853").locates_switch_points()
    assert SolverSettings("radau").locates_switch_points()
    assert not SolverSettings("linear-acceleration").locates_switch_points()
    assert not SolverSettings("rk4").locates_switch_points()
    assert SolverSettings("rk4", switch_points="locate").locates_switch_points()
    assert not SolverSettings("dop853", switch_points="step-over").locates_switch_points()
    with pytest.raises(ValueError, match="switch_points = 'sometimes'"):
        SolverSettings("dop853", switch_points="sometimes").locates_switch_points()


def test_a_scene_names_its_switch_points_setting():
    text = load_scene("press-cycle").text
    assert scene_from_text(text).solver.switch_points == "auto"
    assert (
        scene_from_text(
            text.replace("[solver]\n", '[solver]\nswitch_points = "locate"\n')
        ).solver.switch_points
        == "locate"
    )
    with pytest.raises(SceneError, match="solver.switch_points"):
        scene_from_text(text.replace("[solver]\n", '[solver]\nswitch_points = "never"\n'))


@pytest.mark.parametrize("method", ["linear-acceleration", "rk4"])
def test_a_located_switch_point_ends_a_step_there(method):
    """Forced on a fixed-step solver: every crossing of the cycle's switching functions is a
    step's end, where the function is zero to round-off."""
    scene = press_cycle(method, t_end=0.12, switch_points="locate")
    sim = build(scene)
    seen = []
    events = sim.events_now
    count = events.count_switch

    def at_switch(t):
        seen.append((t, sim.solver.t, sim.solver.q.copy(), sim.solver.qd.copy(), sim.view))
        count(t)

    events.count_switch = at_switch
    events._by_state.clear()  # the event lists take the action when made
    traj = sim.run(scene.t_end, scene.dt)
    assert traj.counts["switch_points"] == len(seen) >= 4
    for t, t_solver, q, qd, view in seen:
        assert t == t_solver
        kin = sim.engine.state_kinematics(view, t, q.tolist(), qd.tolist())
        values = [v for e in events.switching for v in e.switch_values(t, kin)]
        assert min(abs(v) for v in values) < 1e-9


def test_step_over_is_the_fixed_step_default_and_costs_nothing():
    traj = build(press_cycle(t_end=0.12)).run(0.12, 1e-3)
    assert traj.counts["switch_points"] == 0


@pytest.mark.parametrize("grid", [1e-3, 2e-3])
def test_located_switch_points_keep_dop853_within_its_tolerance(grid):
    """At a kink an adaptive solver's error estimate is wrong (it assumes a smooth right-hand
    side). Located, the cycle's switching points leave φ at rtol 1e-10 within 1e-8 rad of the
    rtol 1e-12 run on every grid; stepped over, on the 1 ms grid it is 3e-7 rad off (on others
    it can be lucky)."""
    runs = {}
    for rtol, mode in [(1e-10, "locate"), (1e-10, "step-over"), (1e-12, "locate")]:
        scene = press_cycle("dop853", t_end=0.35, rtol=rtol, atol=rtol * 1e-3, switch_points=mode)
        runs[rtol, mode] = build(scene).run(scene.t_end, grid)
    ref = runs[1e-12, "locate"]
    located = np.abs(runs[1e-10, "locate"].phi - ref.phi).max()
    over = np.abs(runs[1e-10, "step-over"].phi - ref.phi).max()
    assert runs[1e-10, "locate"].counts["switch_points"] >= 6
    assert runs[1e-10, "step-over"].counts["switch_points"] == 0
    assert located < 1e-8
    if grid == 1e-3:
        assert over > 1e-7


@pytest.mark.parametrize("scheme", ["central", "autodiff"])
def test_state_kinematics_reads_what_an_evaluation_reads(scheme):
    scene = load_scene("press-cycle").with_overrides(scheme=scheme, t_end=0.05)
    sim = build(scene)
    sim.run(0.05, 1e-3)
    eng, view = sim.engine, sim.view
    q, qd = sim.solver.q + 1e-3, sim.solver.qd + 0.1
    before = eng.counts["evaluations"]
    kin = eng.state_kinematics(view, 0.05, q.tolist(), qd.tolist())
    assert eng.counts["evaluations"] == before
    e = eng.evaluate(view, 0.05, q, qd)
    assert kin.pose == e.kin.pose
    for p in ("C", "B"):
        assert kin.jac(p) == e.kin.jac(p) and kin.vxy(p) == e.kin.vxy(p)
