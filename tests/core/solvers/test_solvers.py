"""Integrators on problems with exact solutions; the step contract."""

import math

import numpy as np
import pytest
from scipy.integrate import DOP853 as ScipyDOP853

from mps_core.errors import ChartDomainError
from mps_core.solvers import DOP853, RK4, RK6, RK8, AdaptiveSolver, LinearAcceleration, make_solver


class E:
    def __init__(self, qdd):
        self.qdd = np.asarray(qdd, float)


def oscillator(omega):
    return lambda t, q, qd: E(-(omega**2) * q)


def run(solver_cls, fun, q0, qd0, t_end, n, **kw):
    s = solver_cls(fun, 0.0, q0, qd0, **kw)
    for k in range(1, n + 1):
        s.step_to(t_end * k / n)
    return s


def test_linear_acceleration_is_exact_for_acceleration_linear_in_time():
    fun = lambda t, q, qd: E([2.0 + 3.0 * t])  # noqa: E731
    s = run(LinearAcceleration, fun, [1.0], [-0.5], 2.0, 7)
    t = 2.0
    assert s.q[0] == pytest.approx(1.0 - 0.5 * t + t**2 + 0.5 * t**3, rel=1e-14)
    assert s.qd[0] == pytest.approx(-0.5 + 2 * t + 1.5 * t**2, rel=1e-14)
    # the dense output is the step's cubic: exact inside the step too
    q, qd = s.dense_output()(t - 0.1)
    tt = t - 0.1
    assert q[0] == pytest.approx(1.0 - 0.5 * tt + tt**2 + 0.5 * tt**3, rel=1e-13)


@pytest.mark.parametrize(
    "cls,order,ns",
    [
        (LinearAcceleration, 2, (20, 40, 80, 160)),
        (RK4, 4, (20, 40, 80, 160)),
        (RK6, 6, (6, 8, 12, 16)),
        (RK8, 8, (4, 6, 8, 10)),
    ],
)
def test_order_on_the_harmonic_oscillator(cls, order, ns):
    w = 2 * math.pi
    errs = []
    for n in ns:
        s = run(cls, oscillator(w), [1.0], [0.0], 0.8, n)
        errs.append(math.hypot(s.q[0] - math.cos(0.8 * w), (s.qd[0] + w * math.sin(0.8 * w)) / w))
    p = np.polyfit(np.log(1.0 / np.array(ns)), np.log(errs), 1)[0]
    assert abs(p - order) < 0.15, (errs, p)


@pytest.mark.parametrize("cls,per_step", [(LinearAcceleration, 2), (RK4, 4), (RK6, 7), (RK8, 12)])
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
    a0 = -(w**2)
    a1 = -(w**2) * (1.0 + 2 * a0 * dt**2 / 6) / (1 + w**2 * dt**2 / 6)
    assert s.q[0] == pytest.approx(1.0 + (2 * a0 + a1) * dt**2 / 6, rel=1e-13)
    assert s.nfev == 1 + 1 + 30


@pytest.mark.parametrize("cls", [LinearAcceleration, RK4, RK6, RK8, DOP853])
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
    assert s.nfev > 0 and s.current.qdd[0] == pytest.approx(-(w**2) * s.q[0])


def test_adaptive_interrupt_stops_at_an_internal_step():
    s = AdaptiveSolver(oscillator(1.0), 0.0, [1.0], [0.0], rtol=1e-6)
    s.step_to(10.0, interrupt=lambda t, q, qd: q[0] < 0.0)
    assert s.t < 10.0 and s.q[0] < 0.0


def test_unknown_solver_name():
    with pytest.raises(ValueError, match="solver 'euler'"):
        make_solver("euler", oscillator(1.0), 0.0, [1.0], [0.0])


# -- DOP853 on floats against scipy's ----------------------------------------------------------
def coupled_pendulums(t, q, qd):
    """Two pendulums coupled by a spring, with damping and a forcing: no symmetry to hide an
    indexing slip."""
    a, b = q
    va, vb = qd
    return E(
        [
            -9.81 * math.sin(a) - 2.0 * (a - b) - 0.1 * va + 0.5 * math.cos(3.0 * t),
            -4.0 * math.sin(b) + 2.0 * (a - b) - 0.3 * vb,
        ]
    )


def _scipy_dop853(rtol, q0, v0):
    def f(t, y):
        return np.concatenate((y[2:], coupled_pendulums(t, y[:2], y[2:]).qdd))

    return ScipyDOP853(f, 0.0, np.array(q0 + v0), np.inf, rtol=rtol, atol=rtol * 1e-3)


@pytest.mark.parametrize("rtol", [1e-4, 1e-6])
def test_float_dop853_takes_scipys_steps(rtol):
    """Step by internal step (an interrupt that always stops), the same steps as scipy's DOP853
    on y = (q, q̇), the same states and the same dense output. (The step sizes agree to
    round-off in the error estimate, a difference of nearly equal sums: at loose tolerances to
    about 1e-9, at tight ones less; see the next test.)"""
    q0, v0 = [1.2, -0.4], [0.0, 0.7]
    mine = DOP853(coupled_pendulums, 0.0, q0, v0, rtol=rtol, atol=rtol * 1e-3)
    ref = _scipy_dop853(rtol, q0, v0)
    t_prev = 0.0
    for _ in range(40):
        ref.step()
        mine.step_to(1e9, interrupt=lambda t, q, qd: True)
        assert mine.t == pytest.approx(ref.t, rel=1e-8)
        assert np.allclose(np.concatenate((mine.q, mine.qd)), ref.y, rtol=1e-7, atol=1e-8)
        t_mid = 0.5 * (t_prev + mine.t)
        q, qd = mine.dense_output()(t_mid)
        assert np.allclose(np.concatenate((q, qd)), ref.dense_output()(t_mid), rtol=1e-7, atol=1e-8)
        t_prev = mine.t
    assert mine.nsteps == 40
    # 12 stages an attempt (11 for a rejected one), 3 for each dense output, 1 each report
    assert mine.nfev <= ref.nfev + 40 * 3 + 40 + 1


@pytest.mark.parametrize("rtol", [1e-8, 1e-11])
def test_float_dop853_matches_scipy_at_tight_tolerances(rtol):
    """Over 5 s: as many steps as scipy's (±2 %) and the same end state to the tolerance."""
    q0, v0 = [1.2, -0.4], [0.0, 0.7]
    mine = DOP853(coupled_pendulums, 0.0, q0, v0, rtol=rtol, atol=rtol * 1e-3)
    mine.step_to(5.0)
    ref = _scipy_dop853(rtol, q0, v0)
    steps = 0
    while ref.t < 5.0:
        ref.step()
        steps += 1
    y_ref = ref.dense_output()(5.0)
    assert abs(mine.nsteps - steps) <= max(1, 0.02 * steps)
    assert np.allclose(np.concatenate((mine.q, mine.qd)), y_ref, rtol=100 * rtol, atol=0.0)


def test_float_dop853_converges_on_the_oscillator():
    w = 2 * math.pi
    s = DOP853(oscillator(w), 0.0, [1.0], [0.0], rtol=1e-10, atol=1e-12)
    for k in range(1, 11):
        s.step_to(0.1 * k)
        assert s.q[0] == pytest.approx(math.cos(w * 0.1 * k), abs=1e-8)
        assert s.current.qdd[0] == pytest.approx(-(w**2) * s.q[0])


def test_float_dop853_accel_gives_the_stages():
    """Given ``accel``, the stages use it and the reported states ``fun``: the same numbers."""
    w = 3.0
    calls = {"fun": 0, "accel": 0}

    def fun(t, q, qd):
        calls["fun"] += 1
        return E(-(w**2) * np.asarray(q))

    def accel(t, ql, vl):
        calls["accel"] += 1
        return [-(w**2) * ql[0]]

    a = DOP853(fun, 0.0, [1.0], [0.5], rtol=1e-9, atol=1e-12, accel=accel)
    b = DOP853(oscillator(w), 0.0, [1.0], [0.5], rtol=1e-9, atol=1e-12)
    for k in range(1, 6):
        a.step_to(0.2 * k)
        b.step_to(0.2 * k)
        assert a.q[0] == b.q[0] and a.qd[0] == b.qd[0]
    assert calls["fun"] == 1 + 5 and calls["accel"] == a.nfev - calls["fun"]


def test_float_dop853_shrinks_a_step_that_leaves_the_domain():
    """A stage outside the chart's domain shrinks the step, as a rejection does."""

    def fun(t, q, qd):
        if q[0] > 1.5:
            raise ChartDomainError("test", "outside")
        return E([1.0])

    s = DOP853(fun, 0.0, [0.0], [0.0], rtol=1e-6, atol=1e-9)
    s.step_to(1.6)  # q = t²/2 reaches 1.28 at t = 1.6
    assert s.q[0] == pytest.approx(0.5 * 1.6**2, rel=1e-9)
    with pytest.raises(ChartDomainError):
        s.step_to(2.0)  # q = 2 lies outside: the error reaches the caller


def test_rk8_stability_limit_from_its_tableau():
    """The scan of the stability function gives RK4's known 2√2 from RK4's tableau, and the
    eighth-order method holds an undamped oscillation just inside its own limit, not beyond."""
    from mps_core.solvers import rk6, rk8
    from mps_core.solvers.rk8 import IMAGINARY_LIMIT, imaginary_limit

    # the limits the modules write out are their tableaus' scans
    assert imaginary_limit(rk8._A, rk8._B) == pytest.approx(rk8.IMAGINARY_LIMIT, abs=1e-12)
    assert imaginary_limit(rk6._A, rk6._B) == pytest.approx(rk6.IMAGINARY_LIMIT, abs=1e-12)
    A4 = [[0, 0, 0, 0], [0.5, 0, 0, 0], [0, 0.5, 0, 0], [0, 0, 1, 0]]
    assert imaginary_limit(A4, [1 / 6, 1 / 3, 1 / 3, 1 / 6]) == pytest.approx(2 * 2**0.5, abs=2e-4)
    assert 5.5 < IMAGINARY_LIMIT < 6.5
    for factor, bounded in ((0.98, True), (1.05, False)):
        w, dt = 1.0, factor * IMAGINARY_LIMIT
        s = RK8(oscillator(w), 0.0, [1.0], [0.0])
        for k in range(1, 2001):
            s.step_to(k * dt)
        energy = s.q[0] ** 2 + s.qd[0] ** 2
        assert (energy < 1.01) == bounded, energy


def test_rk6_tableau_has_order_six_and_its_stability_polynomial():
    """Butcher's seven stages: the order conditions of the bushy and tall trees up to order six
    hold exactly (fractions); the stability function is the degree-6 Taylor polynomial of
    exp(z) plus z⁷/−2160, whose modulus exceeds 1 on the imaginary axis near 0 (growth
    ≈ 3.5e-4·(ωΔt)⁸ a step): the limit the driver uses is where it passes 1e-12."""
    from fractions import Fraction as F

    from mps_core.solvers.rk6 import A_EXACT, B_EXACT, C_EXACT, IMAGINARY_LIMIT

    A, b, c = A_EXACT, B_EXACT, C_EXACT
    s = len(b)
    for k in range(1, 7):  # Σ b c^(k−1) = 1/k
        assert sum(b[i] * c[i] ** (k - 1) for i in range(s)) == F(1, k)
    # tall trees: b A^(k−1) 1 = 1/k!, up to k = 6; then the z⁷ coefficient
    v = [F(1)] * s
    fact = 1
    for k in range(1, 8):
        fact *= k
        got = sum(b[i] * v[i] for i in range(s))
        if k <= 6:
            assert got == F(1, fact)
        else:
            assert got == F(-1, 2160)
        v = [sum(A[i][j] * v[j] for j in range(s)) for i in range(s)]
    # Σ b c A c (an order-4 tree) and Σ b c³ A c (order 6)
    Ac = [sum(A[i][j] * c[j] for j in range(s)) for i in range(s)]
    assert sum(b[i] * c[i] * Ac[i] for i in range(s)) == F(1, 8)
    assert sum(b[i] * c[i] ** 3 * Ac[i] for i in range(s)) == F(1, 12)
    assert 0.05 < IMAGINARY_LIMIT < 0.1
    # an undamped oscillation at ωΔt = 1 gains about 5.4e-4 a step
    s6 = RK6(oscillator(1.0), 0.0, [1.0], [0.0])
    for k in range(1, 1001):
        s6.step_to(float(k))
    energy = s6.q[0] ** 2 + s6.qd[0] ** 2
    assert 1.5 < energy < 4.0, energy


def test_rk6_dense_output_is_its_quintic_hermite():
    """Inside a step q follows the quintic Hermite polynomial of the ends' (q, q̇, q̈): a
    quintic motion comes out exact, q̇ as its derivative."""

    def fun(t, q, qd):
        return E([20.0 * t**3 - 6.0 * t])  # q = t⁵ − t³ + 2t

    s = RK6(fun, 0.0, [0.0], [2.0])
    s.step_to(0.4)
    for t in (0.05, 0.2, 0.33):
        q, qd = s.dense_output()(t)
        # the step is exact for this q̈ (a polynomial of degree 3 in t alone)
        assert q[0] == pytest.approx(t**5 - t**3 + 2 * t, rel=1e-13, abs=1e-15)
        assert qd[0] == pytest.approx(5 * t**4 - 3 * t**2 + 2, rel=1e-12)


class _Refuses(Exception):
    pass


@pytest.mark.parametrize(
    "make",
    [
        lambda f: LinearAcceleration(f, 0.0, [1.0], [0.0]),
        lambda f: RK4(f, 0.0, [1.0], [0.0]),
        lambda f: RK6(f, 0.0, [1.0], [0.0]),
        lambda f: RK8(f, 0.0, [1.0], [0.0]),
        lambda f: DOP853(f, 0.0, [1.0], [0.0], rtol=1e-8, atol=1e-10),
        lambda f: AdaptiveSolver(f, 0.0, [1.0], [0.0], rtol=1e-8, atol=1e-10),
    ],
    ids=["linear-acceleration", "rk4", "rk6", "rk8", "dop853", "scipy-dop853"],
)
def test_a_step_whose_evaluation_raises_changes_nothing(make):
    """The base's step_to (the template around each method's own step): where the evaluation
    at the new state raises, the solver is as it was before the step."""
    refuse = []
    base = oscillator(2.0)

    def fun(t, q, qd):
        if refuse and t >= refuse[0]:
            raise _Refuses
        return base(t, q, qd)

    s = make(fun)
    s.step_to(0.1)
    before = (s.t, s.q.copy(), s.qd.copy(), s.current, s.nsteps, s.dense_output()(0.05))
    refuse.append(0.15)
    with pytest.raises(_Refuses):
        s.step_to(0.2)
    after = (s.t, s.q, s.qd, s.current, s.nsteps, s.dense_output()(0.05))
    assert after[0] == before[0] and after[3] is before[3] and after[4] == before[4]
    for a, b in ((after[1], before[1]), (after[2], before[2]), (after[5][0], before[5][0])):
        assert np.array_equal(a, b)
