"""Whole runs of the press against exact references built independently (tests/reference)."""

import math
from dataclasses import replace

import numpy as np
import pytest
from reference import press_exact as pe

from mps_core import ChartBreakdown, SingularConfiguration, build, load_scene, scene_from_text, simulate

PAPER = load_scene("paper")


def max_err(traj, ref, name, t_from=-1.0):
    """Max |traj − ref| over the trajectory's times (ref on a finer grid containing them)."""
    idx = np.searchsorted(ref.t, traj.t - 1e-12)
    assert np.allclose(ref.t[idx], traj.t, atol=1e-12)
    sel = traj.t >= t_from
    return float(np.abs(traj[name][sel] - getattr(ref, name)[idx][sel]).max())


def slope(dts, errs):
    return float(np.polyfit(np.log(dts), np.log(errs), 1)[0])


# -- the seed's test ---------------------------------------------------------------------------
def test_paper_at_the_seeds_settings(paper_reference_005):
    """40 steps of 1.25 ms, central differences with 0.1°: the error is the linear acceleration
    method's O(Δt²) truncation (Δ contributes about 1 %, see the next assertion)."""
    traj = simulate(PAPER)
    r = paper_reference_005
    assert len(traj) == 41 and traj.t[-1] == pytest.approx(0.05)
    e_phi, e_phid, e_phidd = (max_err(traj, r, n) for n in ("phi", "phi_dot", "phi_ddot"))
    assert e_phi < 1e-3  # seen: 5.1e-4 rad at t = 0.05 s
    assert e_phid < 0.1  # seen: 0.03 rad/s of ~20–45 rad/s
    assert e_phidd < 60.0  # seen: ~1–2 % of |phi_ddot| ~ 1800 rad/s²
    # the derivative scheme is not what limits the seed's accuracy: exact derivatives change
    # phi by far less than the step's error
    exact = simulate(PAPER, scheme="autodiff")
    assert np.abs(exact.phi - traj.phi).max() < 0.1 * e_phi
    # and halving the step divides the error by about four
    half = simulate(PAPER, steps=80)
    ratio = e_phi / max_err(half, r, "phi")
    assert 3.0 < ratio < 5.5, ratio


@pytest.mark.parametrize(
    "solver,steps,order",
    [
        ("linear-acceleration", (50, 100, 200, 400), 2.0),
        ("rk4", (25, 50, 100, 200), 4.0),
        ("rk6", (40, 50, 80, 100), 6.0),
        ("rk8", (5, 8, 10, 16), 8.0),
    ],
)
def test_convergence_order_on_paper(paper_reference_005, solver, steps, order):
    r = paper_reference_005
    dts, errs = [], []
    for n in steps:
        traj = simulate(PAPER, solver=solver, steps=n, scheme="autodiff")
        dts.append(0.05 / n)
        errs.append(max_err(traj, r, "phi"))
    p = slope(dts, errs)
    assert abs(p - order) < 0.3, (errs, p)


def test_central_differences_converge_with_delta_squared():
    """Same step, shrinking Δ: the difference to exact derivatives falls as Δ²."""
    exact = simulate(PAPER, solver="rk4", steps=200, scheme="autodiff")
    deltas = [0.4, 0.2, 0.1]
    errs = [
        np.abs(
            simulate(PAPER, solver="rk4", steps=200, delta=math.radians(d)).phi_ddot - exact.phi_ddot
        ).max()
        for d in deltas
    ]
    assert abs(slope(deltas, errs) - 2.0) < 0.2, errs


def test_adaptive_reference_solvers(paper_reference):
    r = paper_reference
    tight = simulate(PAPER, solver="dop853", t_end=0.1, dt=1e-3, rtol=1e-11, atol=1e-12, scheme="autodiff")
    assert max_err(tight, r, "phi") < 1e-8
    assert max_err(tight, r, "phi_dot") < 1e-6
    radau = simulate(PAPER, solver="radau", t_end=0.1, dt=1e-3, rtol=1e-8, scheme="autodiff")
    assert max_err(radau, r, "phi") < 1e-5


def test_adaptive_solvers_carry_on_through_changes_of_chart(paper_reference):
    """With central differences a stage of a new chart's first step can leave its domain: the
    solver shrinks that step (as for a rejected error) instead of giving up."""
    traj = simulate(PAPER, solver="dop853", t_end=0.1, dt=1e-3, rtol=1e-6)
    assert len([e for e in traj.events if e["kind"] == "chart"]) >= 3
    assert max_err(traj, paper_reference, "phi") < 1e-4


# -- the chart's branch point ------------------------------------------------------------------
def test_passes_the_branch_point_of_the_seeds_chart(paper_reference):
    """`mps run paper --t-end 0.1 --dt 1e-4`: the (phi, psi) chart breaks down at t ≈ 0.0568 s;
    the run changes chart before it and agrees with the exact motion after it."""
    r = paper_reference
    crossings = pe.chart_breakdown_times(r)
    assert len(crossings) == 1 and 0.0565 < crossings[0] < 0.0571
    traj = simulate(PAPER, t_end=0.1, dt=1e-4)
    first = traj.events[0]
    assert first["kind"] == "chart" and first["from"] == "phi-psi+" and first["t"] < crossings[0]
    assert set(traj.chart[traj.t > crossings[0]]).isdisjoint({"phi-psi+"})
    assert max_err(traj, r, "phi", t_from=crossings[0]) < 1e-4  # seen: 3.7e-5 rad
    assert max_err(traj, r, "phi_dot", t_from=crossings[0]) < 5e-3
    assert max_err(traj, r, "psi", t_from=crossings[0]) < 5e-4
    assert max_err(traj, r, "x_C", t_from=crossings[0]) < 5e-6  # metres
    assert np.all(np.isfinite(traj.phi_ddot)) and np.all(np.isfinite(traj.psi_ddot))


def test_without_chart_switching_the_run_stops_with_a_typed_error():
    with pytest.raises(ChartBreakdown) as info:
        simulate(PAPER, t_end=0.1, dt=1e-4, chart_switching=False)
    err = info.value
    assert 0.05 < err.t < 0.0569
    assert "phi-psi+" in str(err) and "phi_deg=" in str(err) and "psi_deg=" in str(err)


def test_a_singular_position_of_the_machine_raises_a_typed_error():
    """l3 = l2 − l1: at phi = 90°, psi = −90° crank, rod and rocker lie on one line across the
    guide, where every chart degenerates."""
    text = (
        PAPER.text.replace("l1_mm = 15.0", "l1_mm = 10.0")
        .replace("com_mm = [15.0, 0.0]", "com_mm = [10.0, 0.0]")
        .replace("phi_deg = -64.1", "phi_deg = 90.0")
        .replace("psi_deg = -46.34", "psi_deg = -89.9999")
    )
    scene = scene_from_text(text)
    with pytest.raises(SingularConfiguration) as info:
        build(scene).run(scene.t_end, scene.dt)
    assert info.value.t == 0.0 and "phi_deg=90" in str(info.value)


# -- energy ------------------------------------------------------------------------------------
def gravity_only(scene):
    return replace(scene, effects=tuple(e for e in scene.effects if e.kind == "gravity"))


def test_energy_is_conserved_with_gravity_alone_and_the_bound_shrinks_with_the_step():
    """Free fall of the free mechanism through the branch point (t ≈ 0.063 s)."""
    scene = gravity_only(PAPER)
    drifts = []
    for dt in (2e-4, 1e-4, 5e-5):
        traj = simulate(scene, t_end=0.2, dt=dt, scheme="autodiff")
        assert traj.events, "the run should change chart"
        drifts.append(np.abs(traj.energy - traj.energy[0]).max())
    assert drifts[0] > drifts[1] > drifts[2]
    assert slope([2e-4, 1e-4, 5e-5], drifts) > 1.8, drifts
    assert drifts[-1] < 1e-3 * abs(traj.energy[0])


# -- the locked structure ----------------------------------------------------------------------
LOCKED = (
    PAPER.text.replace('initial = "free"', 'initial = "locked"')
    .replace("phi_deg = -64.1", "phi_deg = 0.0")
    .replace("psi_deg = -46.34", "psi_deg = 0.0")
)


def test_locked_structure_is_the_classical_crank_slider():
    scene = scene_from_text(LOCKED)
    assert scene.structure == "locked"
    traj = simulate(scene, solver="rk4", t_end=0.2, dt=1e-4, scheme="autodiff")
    t = traj.t
    ref = pe.integrate_locked(0.2, t, 0.0, 43.5, motor=True)
    assert np.abs(traj.phi - ref.phi).max() < 1e-9
    assert np.abs(traj.phi_dot - ref.phi_dot).max() < 1e-7
    assert np.abs(traj.x_C - ref.x_C).max() < 1e-12
    assert np.all(traj.psi == 0.0) and np.all(traj.psi_dot == 0.0)
    # the seed's scheme on the same structure: second order in the step
    la = simulate(scene, t_end=0.2, dt=1e-4)
    assert np.abs(la.phi - ref.phi).max() < 1e-5
    assert la.counts["position_points"] == 5 * la.counts["evaluations"]


# -- the mass matrix along a run, and work budgets ---------------------------------------------
def test_mass_matrix_stays_symmetric_positive_definite_across_charts():
    sim = build(PAPER.with_overrides(t_end=0.1, dt=1e-4))
    seen = []
    original = sim.engine.evaluate

    def checked(view, t, q, qd):
        e = original(view, t, q, qd)
        assert np.allclose(e.A, e.A.T, rtol=0, atol=1e-13 * np.abs(e.A).max())
        seen.append(np.linalg.eigvalsh(e.A).min())
        return e

    sim.engine.evaluate = checked
    traj = sim.run(0.1, 1e-4)
    assert len(set(traj.chart)) >= 3 and min(seen) > 0


@pytest.mark.parametrize("solver,per_step", [("linear-acceleration", 2), ("rk4", 4), ("rk6", 7), ("rk8", 12)])
@pytest.mark.parametrize("scheme,points", [("central", 13), ("autodiff", 1)])
def test_work_budget(solver, per_step, scheme, points):
    traj = simulate(PAPER, solver=solver, scheme=scheme, steps=20, t_end=0.02)
    c = traj.counts
    assert not traj.events
    assert c["steps"] == 20
    assert c["evaluations"] == 1 + per_step * 20
    assert c["position_points"] == points * c["evaluations"]
    assert c["solver_evaluations"] == c["evaluations"]


@pytest.mark.parametrize(
    "solver,per_step,dt,steps,max_phi_err",
    [
        ("rk6", 7, 1e-2, 10, None),
        ("rk8", 12, 1e-2, 10, 2e-4),
        ("rk8", 12, 1.25e-2, 8, 3e-4),
        ("rk8", 12, 6.25e-3, 16, 2e-5),
    ],
)
def test_a_short_coarse_runs_work_is_its_steps_and_two_changes_of_chart(
    paper_reference, solver, per_step, dt, steps, max_phi_err
):
    """The work of a coarse run over ``paper``'s 0.1 s (the bench's cheapest settings): the
    first state's evaluation, the method's evaluations a step, and one evaluation at each change
    of chart (the new chart's start); two changes, (φ, ψ) → (ψ, x_C) → (φ, x_C), around the
    (φ, ψ) chart's branch point at t ≈ 0.057 s, and none more."""
    traj = simulate(PAPER, solver=solver, scheme="autodiff", t_end=0.1, dt=dt)
    c = traj.counts
    changes = [e for e in traj.events if e["kind"] == "chart"]
    assert len(traj.events) == len(changes) == 2
    assert [(e["from"], e["to"]) for e in changes] == [("phi-psi+", "psi-xc+"), ("psi-xc+", "phi-xc+")]
    assert all(0.035 < e["t"] < 0.07 and not e["forced"] for e in changes)
    assert c["steps"] == steps and len(traj) == steps + 1
    assert c["evaluations"] == 1 + per_step * steps + len(changes)
    assert c["solver_evaluations"] == c["evaluations"] == c["position_points"]
    if max_phi_err is not None:  # seen: 1.5e-4, 2.0e-4, 1.3e-5 rad at the outputs
        assert max_err(traj, paper_reference, "phi") < max_phi_err


def test_iterated_corrector_budget_and_accuracy(paper_reference_005):
    """Three corrections cost 4 evaluations a step; over the seed's 0.05 s they are the more
    accurate (over 0.1 s, through the branch point, they are not: README, bench)."""
    one = simulate(PAPER, scheme="autodiff")
    three = simulate(PAPER, scheme="autodiff", iterations=3)
    # a change of chart restarts the solver: one more evaluation at the new chart's start
    assert three.counts["evaluations"] == 1 + 4 * 40 + len(three.events)
    r = paper_reference_005
    assert max_err(three, r, "phi") < max_err(one, r, "phi")


# -- what runs share, and what a run's end leaves ---------------------------------------------
def test_scenes_of_equal_mechanism_share_it_and_its_views_and_runs_do_not_interfere():
    """Equal geometry and bodies: one mechanism object and one set of views (made once in a
    process); another geometry gets its own. Two runs of one mechanism stepped in turn give
    what each gives alone."""
    a, b = build(PAPER), build(PAPER)
    assert a.mechanism is b.mechanism
    assert [v for v in a.views("free")] == [v for v in b.views("free")]
    assert a.view in a.views("free")  # the start chart's view is the structure's own
    other = scene_from_text(
        PAPER.text.replace("l1_mm = 15.0", "l1_mm = 14.0").replace(
            "com_mm = [15.0, 0.0]", "com_mm = [14.0, 0.0]"
        )
    )
    assert build(other).mechanism is not a.mechanism
    alone = build(PAPER).run(0.1, 5e-3)
    for k in range(1, 21):  # a and b in turn, step by step, through three charts
        a.advance_to(k * 0.1 / 20)  # (the times run() steps to)
        b.advance_to(k * 0.1 / 20)
        assert a.solver.q.tolist() == b.solver.q.tolist()
    assert {e["to"] for e in a.events if e["kind"] == "chart"} >= {"psi-xc+", "phi-xc+"}
    assert a.joint_state()[::2] == (alone.phi[-1], alone.psi[-1], alone.x_C[-1])


def test_a_chart_change_due_at_a_runs_end_waits_for_the_next_step():
    """The chart's regularity falls below the switching threshold at the run's last step
    (paper, RK6 at 5 ms, t = 0.1 s): the run ends in that chart; the next step starts in the
    more regular one, as a run that goes on gives it."""
    scene = PAPER.with_overrides(solver="rk6", scheme="autodiff", dt=5e-3, t_end=0.1)
    sim = build(scene)
    traj = sim.run(0.1, 5e-3)
    assert traj.chart[-1] == "phi-xc+" and sim.view.name == "phi-xc+"
    assert sim.view.regularity(sim.solver.current.kin.pose) < sim.policy.switch_below
    sim.advance_to(0.105)
    assert sim.events[-1]["kind"] == "chart" and sim.events[-1]["t"] == 0.1
    assert sim.events[-1]["to"] == "psi-xc-"
    longer = build(scene.with_overrides(t_end=0.105)).run(0.105, 5e-3)
    assert longer.events[-1]["to"] == "psi-xc-" and longer.events[-1]["t"] == 0.1
    assert abs(longer.phi[-1] - sim.joint_state()[0]) < 1e-12


def test_a_long_step_whose_interpolant_leaves_the_chart_is_a_clear_error():
    """press-cycle at 50 ms steps: a step's interpolant crosses the (φ, ψ) chart's edge between
    its ends (the event watch reads it there). The step is undone and taken in the other
    charts; where every one fails, the run stops with an error that says when and where,
    never the engine's internal chart signal."""
    from mps_core import SimulationError, simulate
    from mps_core.errors import ChartDomainError

    with pytest.raises(SimulationError) as got:
        simulate("press-cycle", dt=0.05)
    assert not isinstance(got.value, ChartDomainError)
    assert str(got.value).startswith("t = ") and "phi_deg=" in str(got.value)
    assert got.value.partial is not None and len(got.value.partial) > 1
