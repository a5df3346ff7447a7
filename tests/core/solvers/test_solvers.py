"""Integrators on problems with exact solutions; the step contract."""

import math

import numpy as np
import pytest

from mps_core.solvers import RK4, AdaptiveSolver, LinearAcceleration, make_solver


class E:
    def __init__(self, qdd):
        self.qdd = np.asarray(qdd, float)


def oscillator(omega):
    return lambda t, q, qd: E(-omega ** 2 * q)


def run(solver_cls, fun, q0, qd0, t_end, n, **kw):
    s = solver_cls(fun, 0.0, q0, qd0, **kw)
    for k in range(1, n + 1):
        s.step_to(t_end * k / n)
    return s


def test_linear_acceleration_is_exact_for_acceleration_linear_in_time():
    fun = lambda t, q, qd: E([2.0 + 3.0 * t])  # noqa: E731
    s = run(LinearAcceleration, fun, [1.0], [-0.5], 2.0, 7)
    t = 2.0
    assert s.q[0] == pytest.approx(1.0 - 0.5 * t + t ** 2 + 0.5 * t ** 3, rel=1e-14)
    assert s.qd[0] == pytest.approx(-0.5 + 2 * t + 1.5 * t ** 2, rel=1e-14)
    # the dense output is the step's cubic: exact inside the step too
    q, qd = s.dense_output()(t - 0.1)
    tt = t - 0.1
    assert q[0] == pytest.approx(1.0 - 0.5 * tt + tt ** 2 + 0.5 * tt ** 3, rel=1e-13)


@pytest.mark.parametrize("cls,order", [(LinearAcceleration, 2), (RK4, 4)])
def test_order_on_the_harmonic_oscillator(cls, order):
    w = 2 * math.pi
    errs, ns = [], (20, 40, 80, 160)
    for n in ns:
        s = run(cls, oscillator(w), [1.0], [0.0], 0.8, n)
        errs.append(math.hypot(s.q[0] - math.cos(0.8 * w), (s.qd[0] + w * math.sin(0.8 * w)) / w))
    p = np.polyfit(np.log(1.0 / np.array(ns)), np.log(errs), 1)[0]
    assert abs(p - order) < 0.15, (errs, p)


@pytest.mark.parametrize("cls,per_step", [(LinearAcceleration, 2), (RK4, 4)])
def test_evaluations_per_step(cls, per_step):
    s = run(cls, oscillator(1.0), [1.0], [0.0], 1.0, 10)
    assert s.nfev == 1 + per_step * 10 and s.nsteps == 10
    assert s.evaluations_per_step == per_step


def test_iterated_corrector_converges_to_the_implicit_method():
    """Iterating the corrector to convergence solves the implicit (Newmark β = 1/6) step."""
    w, dt = 3.0, 0.05
    s = LinearAcceleration(oscillator(w), 0.0, [1.0], [0.0], iterations=30)
    s.step_to(dt)
    # implicit linear acceleration on q'' = -w² q: solve for a1 exactly
    # a1 = -w² (q0 + v0 dt + (2 a0 + a1) dt²/6), a0 = -w²
    a0 = -w ** 2
    a1 = -w ** 2 * (1.0 + 2 * a0 * dt ** 2 / 6) / (1 + w ** 2 * dt ** 2 / 6)
    assert s.q[0] == pytest.approx(1.0 + (2 * a0 + a1) * dt ** 2 / 6, rel=1e-13)
    assert s.nfev == 1 + 1 + 30


@pytest.mark.parametrize("cls", [LinearAcceleration, RK4])
def test_a_step_is_all_or_nothing(cls):
    calls = {"n": 0}

    def fun(t, q, qd):
        calls["n"] += 1
        if t > 0.15:
            raise RuntimeError("outside")
        return E(-q)

    s = cls(fun, 0.0, [1.0], [0.0])
    s.step_to(0.1)
    state = (s.t, s.q.copy(), s.qd.copy(), s.current)
    with pytest.raises(RuntimeError):
        s.step_to(0.2)
    assert (s.t, s.current) == (state[0], state[3])
    assert np.array_equal(s.q, state[1]) and np.array_equal(s.qd, state[2])


@pytest.mark.parametrize("method", ["dop853", "radau"])
def test_adaptive_reference_on_the_oscillator(method):
    w = 2 * math.pi
    s = AdaptiveSolver(oscillator(w), 0.0, [1.0], [0.0], method=method, rtol=1e-10, atol=1e-12)
    for k in range(1, 11):
        s.step_to(0.1 * k)
        assert s.q[0] == pytest.approx(math.cos(w * 0.1 * k), abs=1e-7)
    assert s.nfev > 0 and s.current.qdd[0] == pytest.approx(-w ** 2 * s.q[0])


def test_adaptive_interrupt_stops_at_an_internal_step():
    s = AdaptiveSolver(oscillator(1.0), 0.0, [1.0], [0.0], rtol=1e-6)
    s.step_to(10.0, interrupt=lambda t, q, qd: q[0] < 0.0)
    assert s.t < 10.0 and s.q[0] < 0.0


def test_unknown_solver_name():
    with pytest.raises(ValueError, match="solver 'euler'"):
        make_solver("euler", oscillator(1.0), 0.0, [1.0], [0.0])
