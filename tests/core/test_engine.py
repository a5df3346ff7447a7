"""The partial-system engine against the exact (symbolic) equations of the press."""

import math

import numpy as np
import pytest
from reference import press_exact as pe

from mps_core.dynamics.engine import PartialSystems, stencil
from mps_core.model import PressMechanism
from mps_core.model.effects import MOTOR_PRESETS, Gravity, Motor
from mps_core.model.mechanism import ChartView

STATES = [(-1.1187560505, -0.8087855754), (0.3, -1.0), (2.0, -0.4), (-2.5, -1.3)]


DELTA = math.radians(0.1)


def engine(scheme, delta=DELTA, effects=None):
    m = PressMechanism()
    eff = (
        effects
        if effects is not None
        else [Gravity((-9.81, 0.0)), Motor.for_crank_speed(MOTOR_PRESETS["4A80B4U3"], 43.5)]
    )
    return m, PartialSystems(m, eff, scheme, delta)


def test_stencil_sizes():
    assert len(stencil(1)[0]) == 5
    assert len(stencil(2)[0]) == 13
    assert len(stencil(3)[0]) == 1 + 12 + 12


@pytest.mark.parametrize("q", STATES)
def test_central_analogs_and_mass_matrix_are_second_order(q):
    exact = pe.lagrange_phi_psi()
    J_exact = {p: np.asarray(exact.jacobian(p, *q), float) for p in "ABC"}
    M_exact = np.asarray(exact.mass_matrix(*q), float)
    errs_J, errs_A = [], []
    for deg in (0.4, 0.2, 0.1):
        m, eng = engine("central", math.radians(deg))
        view = ChartView(m.chart("phi-psi+"))
        e = eng.evaluate(view, 0.0, q, [43.5, 0.0])
        errs_J.append(max(np.abs(e.kin.analog(p) - J_exact[p]).max() for p in "ABC"))
        errs_A.append(np.abs(e.A - M_exact).max())
    for errs in (errs_J, errs_A):
        ratios = [errs[i] / errs[i + 1] for i in range(len(errs) - 1)]
        assert all(3.5 < r < 4.5 for r in ratios), (errs, ratios)


@pytest.mark.parametrize("q", STATES)
def test_autodiff_matches_exact_equations(q):
    exact = pe.lagrange_phi_psi()
    m, eng = engine("autodiff")
    view = ChartView(m.chart("phi-psi+"))
    qd = np.array([43.5, -12.0])
    e = eng.evaluate(view, 0.0, q, qd)
    M_exact = np.asarray(exact.mass_matrix(*q), float)
    assert np.allclose(e.A, M_exact, rtol=1e-12, atol=1e-14)
    qdd_exact = exact.qdd(0.0, np.array(q), qd, motor=True)
    assert np.allclose(e.qdd, qdd_exact, rtol=1e-10, atol=1e-8)


@pytest.mark.parametrize("q", STATES)
def test_central_accelerations_converge_to_exact(q):
    exact = pe.lagrange_phi_psi()
    qd = np.array([43.5, -12.0])
    qdd_exact = exact.qdd(0.0, np.array(q), qd, motor=True)
    errs = []
    for deg in (0.4, 0.2, 0.1):
        m, eng = engine("central", math.radians(deg))
        errs.append(np.abs(eng.evaluate(ChartView(m.chart("phi-psi+")), 0.0, q, qd).qdd - qdd_exact).max())
    assert errs[0] / errs[1] > 3.5 and errs[1] / errs[2] > 3.5, errs


def test_any_chart_gives_the_same_physical_accelerations():
    """The same physical state evaluated in every regular chart: the same crank acceleration."""
    m, eng = engine("autodiff")
    home = ChartView(m.chart("phi-psi+"))
    q, qd = np.array([0.3, -1.0]), np.array([43.5, -12.0])
    e0 = eng.evaluate(home, 0.0, q, qd)
    jets = home.pose_jets(q, qd)
    for view in m.views("free"):
        if not view.owns(e0.kin.pose):
            continue
        q2, qd2 = view.state_from(jets, {"phi": q[0], "psi": q[1]})
        e = eng.evaluate(view, 0.0, q2, qd2)
        for p in "ABC":
            assert np.allclose(e.kin.position(p), e0.kin.position(p), atol=1e-15)
            assert np.allclose(e.kin.velocity(p), e0.kin.velocity(p), rtol=1e-12, atol=1e-12)
        # kinetic energy is a scalar: the same in every chart
        assert math.isclose(e.kinetic_energy, e0.kinetic_energy, rel_tol=1e-12)
        # crank angular acceleration, read through the new chart's exact mapping
        phi_jet = m.observables["phi"].jet(view.pose_jets(q2, qd2), 2)
        phi_ddot = float(phi_jet.grad @ e.qdd + phi_jet.d2)
        assert math.isclose(phi_ddot, e0.qdd[0], rel_tol=1e-9), view.name


def test_effects_only_those_listed_are_called():
    class Spy(Gravity):
        calls = 0

        def loads(self, t, kin):
            Spy.calls += 1
            return super().loads(t, kin)

    m, eng = engine("central", effects=[Spy((-9.81, 0.0))])
    eng.evaluate(ChartView(m.chart("phi-psi+")), 0.0, STATES[0], [1.0, 0.0])
    assert Spy.calls == 1
    m, eng = engine("central", effects=[])
    e = eng.evaluate(ChartView(m.chart("phi-psi+")), 0.0, STATES[0], [0.0, 0.0])
    assert np.all(e.Q == 0.0) and np.allclose(e.qdd, 0.0)


def test_a_fresh_engines_first_evaluation_in_a_view_takes_the_pair_used_before():
    """A second simulation of the same scene evaluates a chart it changes to with the exact
    kernel and fused function the first one used there: one call, the same numbers as the
    lookups give, the same functions in its plan; where that pair does not hold (a failed
    guard: another branch) the lookups answer, with the same numbers."""
    import mps_core.dynamics.exact as exact_module
    from mps_core import build, load_scene
    from mps_core.derivatives.tracing import BranchChanged

    scene = load_scene("paper").with_overrides(solver="rk6", scheme="autodiff", dt=5e-3, t_end=0.1)
    first = build(scene)
    states = {}
    evaluate = first.engine.evaluate

    def spy(view, t, q, qd):
        e = evaluate(view, t, q, qd)
        states.setdefault(view, e)
        return e

    first.engine.evaluate = spy
    first.run(0.1, 5e-3)
    assert len(states) >= 3  # the start chart and those it changed to
    for view, e0 in states.items():
        plan0 = first.engine._plans[view]
        for fails in (False, True):
            sim = build(scene)
            pair = exact_module._FIRST[view, sim.engine.tables.number, sim.engine.fingerprint()]
            assert pair == (plan0.exact, plan0.fused)
            calls = []
            full = pair[1].full

            def counted(*a, _full=full, _fails=fails, calls=calls, view=view):
                calls.append(a)
                if _fails:
                    raise BranchChanged(view.name)
                return _full(*a)

            pair[1].full = counted
            try:
                e1 = sim.engine.evaluate(view, e0.t, e0.q, e0.qd)
            finally:
                pair[1].full = full
            assert calls and (len(calls) == 1 or fails)
            if fails:  # (the fused function failing alone: the kernel and the
                # effects one by one, the same numbers to round-off)
                np.testing.assert_allclose(e1.qdd, e0.qdd, rtol=1e-12, atol=0)
            else:
                assert e1.qdd.tolist() == e0.qdd.tolist() and e1.kin._xl == e0.kin._xl
            assert sim.engine._plans[view].exact is plan0.exact
