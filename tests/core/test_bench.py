"""The benchmarks (`mps bench`): the peer's exact model, the work-precision study's orders and
work budgets, the round-off floor of central differences; and that the fast paths of the engine
and the jets give the numbers of the general ones. No wall-clock assertions."""

import math

import numpy as np
import pytest

from mps_core import build, load_scene, simulate
from mps_core.bench import accuracy
from mps_core.bench.common import Case, Setting, resolve_case
from mps_core.bench.peers import exact_model, run_peer, supports
from mps_core.derivatives.jet import Jet, ScalarJet, seed
from mps_core.dynamics.engine import PartialSystems
from mps_core.model.effects import Gravity, Motor

PAPER = load_scene("paper")


def slope(x, y):
    return float(np.polyfit(np.log(x), np.log(y), 1)[0])


# -- the peer ------------------------------------------------------------------------------
def test_exact_model_agrees_with_the_independent_reference(paper_reference):
    """Two formulations derived separately (three coordinates and one closure here, four and
    two in tests/reference) give the same motion through the branch point."""
    r = paper_reference
    run = run_peer(PAPER, 0.1, r.t, rtol=1e-12, atol=1e-12)
    assert np.abs(run.phi - r.phi).max() < 1e-9
    assert np.abs(run.phi_dot - r.phi_dot).max() < 1e-7
    assert np.abs(run.phi_ddot - r.phi_ddot).max() < 1e-4 * np.abs(r.phi_ddot).max()
    assert run.closure < 1e-10 and run.nfev > 0


def test_exact_model_covers_only_what_it_knows():
    assert supports(PAPER) == (True, "")
    locked = PAPER.with_overrides()
    from dataclasses import replace

    ok, why = supports(replace(locked, structure="locked"))
    assert not ok and "structure" in why
    with pytest.raises(ValueError, match="does not cover"):
        exact_model(replace(locked, structure="locked"))


# -- the work-precision study ----------------------------------------------------------------
@pytest.fixture(scope="module")
def quick_study():
    return accuracy.study(
        ["paper"],
        ("linear-acceleration", "rk4", "peer", "mujoco"),
        quick=True,
        repeats=1,
        log=lambda *a: None,
    )["paper"]


def _series(rows, solver, scheme):
    rs = sorted((r for r in rows if r["solver"] == solver and r["scheme"] == scheme), key=lambda r: -r["dt"])
    return [r["dt"] for r in rs], [r["max_err_phi"] for r in rs], rs


@pytest.mark.parametrize("solver,order", [("linear-acceleration", 2.0), ("rk4", 4.0)])
def test_measured_orders_on_paper_through_the_branch_point(quick_study, solver, order):
    dts, errs, _ = _series(quick_study["rows"], solver, "autodiff")
    assert len(dts) == 3
    assert abs(slope(dts, errs) - order) < 0.25, errs


def test_rk4_with_central_differences_levels_off_at_the_delta_error(quick_study):
    """At Δ = 0.1° the derivative error (O(Δ²), not the step) bounds RK4's accuracy."""
    _, central, _ = _series(quick_study["rows"], "rk4", "central 0.1°")
    _, exact, _ = _series(quick_study["rows"], "rk4", "autodiff")
    assert max(central) / min(central) < 1.5
    assert exact[-1] < 1e-3 * central[-1]


@pytest.mark.parametrize("solver,per_step", [("linear-acceleration", 2), ("rk4", 4)])
def test_work_budgets_of_the_study_rows(quick_study, solver, per_step):
    """Position points per evaluation: 13 (central, n = 2), 1 (jets); evaluations per step as
    the design says, plus one at each change of chart (the solver restarts there)."""
    for scheme, points in (("central 0.1°", 13), ("autodiff", 1)):
        for r in _series(quick_study["rows"], solver, scheme)[2]:
            assert r["position_points"] == points * r["evaluations"]
            extra = r["evaluations"] - 1 - per_step * r["steps"]
            assert 1 <= extra <= 4, r  # paper's 0.1 s: 2–3 changes of chart


def test_peer_rows_and_recommendations(quick_study):
    peer = [r for r in quick_study["rows"] if r["solver"] == "peer"]
    assert [r["rtol"] for r in peer] == [1e-3, 1e-6, 1e-9]
    errs = [r["max_err_phi"] for r in peer]
    assert errs[0] > errs[1] > errs[2] and errs[2] < 1e-8
    rec = accuracy.recommendations(quick_study["rows"], targets=(1e-2, 1e-6))
    assert rec[0][1] is not None and rec[0][1]["max_err_phi"] <= 1e-2
    table = accuracy.format_table(quick_study["rows"])
    assert "rk4" in table and "peer" in table and "max|Δφ|" in table


def test_mujoco_rows_converge_as_its_soft_constraint_says_and_are_compared(quick_study):
    """MuJoCo's RK4 on the press closed by a soft connect (solref two steps): its φ error
    falls as dt² (the constraint's, not RK4's dt⁴), its closure opens by microns at most; each
    of its points gets the cheapest engine setting at least as accurate and the CPU ratio."""
    pytest.importorskip("mujoco")
    dts, errs, rows = _series(quick_study["rows"], "mujoco", "RK4, soft connect")
    assert len(dts) == 3
    assert abs(slope(dts, errs) - 2.0) < 0.3, errs
    assert all(r["closure_m"] < 1e-5 for r in rows)
    vs = accuracy.versus(quick_study["rows"])
    assert [p["dt"] for p, _, _ in vs] == sorted(dts, reverse=True)
    for p, best, ratio in vs:
        assert best["solver"] not in accuracy.PEERS
        assert best["max_err_phi"] <= p["max_err_phi"]
        assert ratio == pytest.approx(best["cpu_s"] / p["cpu_s"])
    # each pair timed again, the two engines' runs in turns: at least three rounds each
    assert [v for v, _side in quick_study["versus"]] == vs
    for (p, _best, _ratio), (best, mj, mine, ratio, spread, rounds) in quick_study["versus"]:
        assert best["max_err_phi"] <= p["max_err_phi"] and best["solver"] not in accuracy.PEERS
        assert rounds >= 3 and mj > 0 and mine > 0 and ratio > 0 and spread >= 0
    # the twin's operating point: an output every 1 ms, the setting at least as accurate there
    op = quick_study["operating_point"]
    assert op["every_s"] == 1e-3 and op["err"] <= op["mujoco_err"] and op["rounds"] >= 3
    assert op["cpu_s"] > 0 and op["mujoco_cpu_s"] > 0 and op["ratio"] > 0
    said = []
    accuracy.report({"paper": quick_study}, None, plot=False, log=said.append)
    table = "\n".join(said)
    assert "each pair timed in turns" in table and "spread" in table
    assert "the twin's operating point, an output every 1 ms" in table and op["setting"] in table


def test_mujoco_model_matches_the_scene():
    """The MJCF holds the scene's masses and inertias about z, gravity, RK4, and a connect
    that holds at the initial configuration (the model is written there)."""
    mujoco = pytest.importorskip("mujoco")
    from mps_core.bench.mujoco_peer import press_xml

    m = mujoco.MjModel.from_xml_string(press_xml(PAPER, 1e-4))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    assert m.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4
    assert list(m.opt.gravity[:2]) == [-9.81, 0.0]
    mech = PAPER.mechanism()
    for b in mech.bodies:
        assert m.body(b.name).mass[0] == pytest.approx(b.mass)
        if b.inertia:
            assert m.body(b.name).inertia[2] == pytest.approx(b.inertia)
    assert d.nefc == 3 and np.abs(d.efc_pos[:3]).max() < 1e-12


def test_the_mujoco_peer_steps_as_a_bare_mj_step_loop_does():
    """The peer's outputs, its accelerations included, cost no forward pass more than a bare
    mj_step loop of the same model: four torque callbacks a step (RK4's stages), and one for
    the first state; its φ is the bare loop's, step for step."""
    mujoco = pytest.importorskip("mujoco")
    from mps_core.bench.mujoco_peer import bare_loop, run_mujoco

    dt, t_end = 2.5e-3, 0.05
    steps = int(round(t_end / dt))
    t = np.arange(steps + 1) * dt
    run = run_mujoco(PAPER, t_end, t, dt)
    _cpu, calls = bare_loop(PAPER, t_end, dt)
    assert calls == 4 * steps and run.nfev == calls + 1
    # the same trajectory as mj_step's (the accelerations read where mj_step would compute
    # them at its next step's start)
    from mps_core.bench.mujoco_peer import _model

    m, d, qc, jc, phi0, control, _n = _model(PAPER, dt)
    mujoco.set_mjcb_control(control)
    try:
        phis = [phi0 + d.qpos[qc]]
        for _ in range(steps):
            mujoco.mj_step(m, d)
            phis.append(phi0 + d.qpos[qc])
        mujoco.mj_forward(m, d)
        qdd_end = d.qacc[jc]
    finally:
        mujoco.set_mjcb_control(None)
    assert np.allclose(run.phi, phis, rtol=0, atol=1e-12)
    assert run.phi_ddot[-1] == pytest.approx(qdd_end, rel=1e-9)


def test_central_differences_are_second_order_until_round_off():
    """Per evaluation, q̈ by central differences against exact derivatives: error ∝ Δ² from 1°
    to 0.01°, then round-off (∝ ε/Δ²) takes over: smaller Δ stops helping."""
    case = Case("paper", PAPER, 0.1)
    rows = accuracy.delta_study(case, None, deltas=(1.0, 0.1, 0.01, 1e-5), trajectory=False)
    e = {r["delta_deg"]: r["max_rel_err_qdd"] for r in rows}
    assert abs(slope([1.0, 0.1, 0.01], [e[1.0], e[0.1], e[0.01]]) - 2.0) < 0.2, e
    assert e[1e-5] > 10 * e[0.01], e


# -- work budgets ------------------------------------------------------------------------------
@pytest.mark.parametrize("iterations", [2, 3])
@pytest.mark.parametrize("scheme,points", [("central", 13), ("autodiff", 1)])
def test_iterated_corrector_budget(iterations, scheme, points):
    traj = simulate(PAPER, iterations=iterations, scheme=scheme, steps=20, t_end=0.02)
    c = traj.counts
    assert not traj.events
    assert c["evaluations"] == 1 + (1 + iterations) * 20
    assert c["position_points"] == points * c["evaluations"] == points * c["position_calls"]


def test_dop853_builds_its_dense_output_once_per_internal_step(monkeypatch):
    """Outputs at 1 kHz inside one internal step share its interpolant (DOP853's costs three
    evaluations), and a solver's start is evaluated once."""
    from scipy.integrate import DOP853

    calls = {"n": 0}
    original = DOP853.dense_output

    def counted(self):
        calls["n"] += 1
        return original(self)

    monkeypatch.setattr(DOP853, "dense_output", counted)
    scene = PAPER.with_overrides(
        solver="dop853", scheme="autodiff", rtol=1e-6, atol=1e-9, t_end=0.03, dt=1e-3
    )
    traj = build(scene).run(scene.t_end, scene.dt)
    c = traj.counts
    assert not traj.events
    assert len(traj.t) - 1 == 30 and c["steps"] < 15
    assert calls["n"] <= c["steps"]


# -- the fast paths give the general paths' numbers ------------------------------------------
def _press_positions(q):
    m = PAPER.mechanism()
    return {"psi-xc+": m.chart("psi-xc+").positions, "phi-psi+": m.chart("phi-psi+").positions}


@pytest.mark.parametrize("chart", ["phi-psi+", "psi-xc+"])
def test_scalar_jets_equal_array_jets(chart):
    f = _press_positions(None)[chart]
    q = np.array([-1.1, -0.8]) if chart == "phi-psi+" else np.array([-0.8, 0.024])
    v = np.array([43.5, -7.0])
    one = f(seed(q, v))
    arr = f(seed(q[None, :], v[None, :]))
    for p in "ABC":
        for a, b in zip(one[p], arr[p]):
            if not isinstance(a, Jet):
                continue
            assert isinstance(a, ScalarJet)
            assert np.allclose(a.val, b.val[0], rtol=1e-15, atol=1e-18)
            assert np.allclose(a.grad, b.grad[0], rtol=1e-14, atol=1e-17)
            assert np.allclose(a.d1, b.d1[0], rtol=1e-14, atol=1e-17)
            assert np.allclose(a.d2, b.d2[0], rtol=1e-13, atol=1e-15)


def test_scalar_jets_follow_numpy_at_the_edges():
    (x,) = seed(np.array([0.0]), np.array([1.0]))
    with np.errstate(all="ignore"):
        r = (x * 0.0).reciprocal()
        assert math.isinf(r.val) or math.isnan(r.val)
        s = (x - 1.0).sqrt()
        assert math.isnan(s.val)
    assert isinstance(Jet.constant(2.0, 2), ScalarJet) and Jet.constant(2.0, 2).grad.shape == (2,)
    # mixed with an array-valued jet, the array rules apply
    y = x + Jet(np.array([1.0, 2.0]), np.zeros((2, 1)), np.zeros(2), np.zeros(2))
    assert isinstance(y, Jet) and np.shape(y.val) == (2,)


class _GravityGeneral(Gravity):
    def loads(self, t, kin):
        return super().loads(t, kin)


class _MotorGeneral(Motor):
    def loads(self, t, kin):
        return super().loads(t, kin)


@pytest.mark.parametrize("scheme", ["central", "autodiff"])
def test_effects_fast_path_equals_virtual_work_of_their_loads(scheme):
    """Gravity's and the motor's generalized forces (one product each) are the virtual work of
    their loads; a subclass that overrides `loads` alone goes the general way."""
    sim = build(PAPER.with_overrides(scheme=scheme))
    g, m = sim.engine.effects
    slow = [_GravityGeneral(g.g), _MotorGeneral(m.data, m.ratio, m.efficiency)]
    e_fast = sim.engine.evaluate(sim.view, 0.0, sim.solver.q, sim.solver.qd)
    eng = PartialSystems(sim.mechanism, slow, scheme, sim.engine.delta)
    e_slow = eng.evaluate(sim.view, 0.0, sim.solver.q, sim.solver.qd)
    assert np.allclose(e_fast.Q, e_slow.Q, rtol=1e-13, atol=1e-12)
    assert np.allclose(e_fast.qdd, e_slow.qdd, rtol=1e-12)
    assert g.potential(e_fast.kin) == pytest.approx(
        -sum(b.mass * (g.g @ e_fast.kin.position(f"G_{b.name}")) for b in sim.mechanism.bodies), rel=1e-14
    )
    from mps_core.model.effects import Effect

    assert m.power(0.0, e_fast.kin) == pytest.approx(Effect.power(m, 0.0, e_fast.kin), rel=1e-14)


def test_kinematics_pose_is_built_once():
    sim = build(PAPER)
    kin = sim.solver.current.kin
    assert kin.pose is kin.pose
    assert kin.pose["A"] == pytest.approx(tuple(kin.position("A")), abs=0.0)


# -- the command line ------------------------------------------------------------------------
def test_bench_accuracy_command_writes_table_csv_and_plot(tmp_path, capsys):
    from mps_core.cli import main

    assert (
        main(["bench", "accuracy", "paper", "--quick", "--solvers", "rk4,peer", "--out", str(tmp_path)]) == 0
    )
    out = capsys.readouterr().out
    assert "work-precision" in out and "cheapest setting" in out
    rows = (tmp_path / "accuracy.csv").read_text().splitlines()
    assert rows[0].startswith("case,solver,scheme") and len(rows) == 1 + 6 + 3
    # matplotlib is a dependency of the package: the plot is always written
    assert (tmp_path / "accuracy-paper.png").stat().st_size > 10_000


def test_cases_resolve():
    assert resolve_case("paper").t_end == 0.1
    assert resolve_case("paper-long").t_end == 1.0
    s = Setting("linear-acceleration", "central", 0.1, iterations=3)
    assert s.family == "la-iterated" and "×3" in s.label


def test_the_ladder_gives_the_high_order_methods_longer_steps_on_the_error_grid():
    """RK6 and RK8 also run at 12.5, 10 and 6.25 ms (RK4 and linear acceleration from 5 ms
    down, a quick study from 1.25 ms down); every fixed step divides each built-in case's end
    time and is a whole number of the 1.25 ms error grid's points or divides it, so that the
    errors are read at each output of the coarse runs."""
    for name in ("paper", "paper-long"):
        case = resolve_case(name)
        steps = {}
        for s, dt in accuracy.plan(case):
            if not s.adaptive and s.solver != "mujoco":
                steps.setdefault(s.family, set()).add(dt)
        assert max(steps["rk8"]) == max(steps["rk6"]) == 12.5e-3
        assert {12.5e-3, 10e-3, 6.25e-3} <= steps["rk8"] and max(steps["rk4"]) == 5e-3
        for dt in set().union(*steps.values()):
            n, per = case.t_end / dt, max(dt, accuracy.GRID) / min(dt, accuracy.GRID)
            assert abs(n - round(n)) < 1e-9 and abs(per - round(per)) < 1e-9, dt
    quick = {dt for s, dt in accuracy.plan(resolve_case("paper"), quick=True) if s.solver == "rk8"}
    assert max(quick) == accuracy.GRID


def test_a_coarse_runs_evaluations_alone_are_taken_at_the_states_it_kept(monkeypatch):
    """RK8 at 10 ms over ``paper``: the least its steps cost is its 123 evaluations (1 + 12 a
    step + 1 at each of its two changes of chart) times one q̈ by the fused function, timed at
    the 12 states the run kept (its 10 steps' ends, the two new charts' starts at two of those
    times; the first state's is the build's); each state's fused function is called, once to
    make it and then ``number`` times a batch, no other path."""
    case = resolve_case("paper")
    calls = []
    real = accuracy.evaluations_along

    def along(scene, t_end):
        sim, states = real(scene, t_end)
        for plan in sim.engine._plans.values():
            f = plan.fused

            def counted(t, *a, f=f):
                calls.append(t)
                return f(t, *a)

            plan.fused = counted
        return sim, states

    monkeypatch.setattr(accuracy, "evaluations_along", along)
    rk8 = Setting("rk8", "autodiff")
    per, states, count = accuracy.evaluations_alone(case, rk8, 10e-3, number=2, repeats=1)
    assert (states, count) == (12, 123) and per > 0.0
    assert len(calls) == (1 + 2) * 12 and len(set(calls)) == 10


@pytest.mark.parametrize("solver", ["rk6", "dop853"])
def test_a_run_past_its_evaluation_budget_stops(solver):
    """The study's budget: a fixed-step run is looked at every output step, an adaptive one at
    every evaluation; either stops with OverBudget, not after the run."""
    from mps_core.bench.common import OverBudget, Setting, resolve_case, run_setting

    case = resolve_case("paper")
    s = Setting(solver, "autodiff", 0.0, 1, 1e-8 if solver == "dop853" else None)
    with pytest.raises(OverBudget):
        run_setting(case, s, 1.25e-3, repeats=1, max_evaluations=100)
    _cpu, traj, _n = run_setting(case, s, 1.25e-3, repeats=1, max_evaluations=100_000)
    assert traj.counts["evaluations"] > 100
