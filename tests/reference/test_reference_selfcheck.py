"""Self-consistency checks of the exact reference models in press_exact."""

from __future__ import annotations

import math

import numpy as np
import pytest

from . import press_exact as pe

P = pe.DEFAULT_PARAMS
# Singular configuration of the (phi, psi) chart on the paper run (motor +
# gravity): the rod AB is perpendicular to the guide at about t = 0.0568 s.
T_BRANCH_PAPER = 0.0568


# ---------------------------------------------------------------------------
# Shared trajectories (computed once per test session)
# ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def paper_redundant():
    t = np.linspace(0.0, 0.1, 2001)
    return pe.integrate_redundant(0.1, t, motor=True)


@pytest.fixture(scope="module")
def paper_phi_psi():
    t = np.linspace(0.0, 0.05, 1001)
    return pe.integrate_phi_psi(0.05, t, motor=True)


@pytest.fixture(scope="module")
def gravity_redundant():
    t = np.linspace(0.0, 0.2, 2001)
    return pe.integrate_redundant(0.2, t, motor=False)


# ---------------------------------------------------------------------------
# Motor
# ---------------------------------------------------------------------------


def test_motor_rated_point_and_synchronous_speed():
    c = pe.motor_constants(P)
    # At the rated crank speed the slip is s_n and Kloss gives M_n.
    assert pe.motor_torque(P.crank_speed_rated) == pytest.approx(c["u"] * c["M_n"], rel=1e-13)
    # No torque at synchronous speed; breakdown torque at s = s_k.
    assert abs(pe.motor_torque(P.omega_sync / c["u"])) < 1e-12
    w_k = (1.0 - c["s_k"]) * P.omega_sync / c["u"]
    assert pe.motor_torque(w_k) == pytest.approx(c["u"] * c["M_k"], rel=1e-13)


# ---------------------------------------------------------------------------
# Kinematics of the (phi, psi) chart against finite differences
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("sigma", [1, -1])
def test_phi_psi_jacobians_match_finite_differences(sigma):
    m = pe.lagrange_phi_psi(P, sigma)
    rng = np.random.default_rng(1)
    h = 1e-6
    checked = 0
    for _ in range(40):
        phi, psi = rng.uniform(-math.pi, math.pi, size=2)
        if pe.closure_sqrt_arg(phi, psi) < 0.2 * P.l2**2:
            continue
        for k, (dphi, dpsi) in enumerate([(h, 0.0), (0.0, h)]):
            fp = m.positions(phi + dphi, psi + dpsi)
            fm = m.positions(phi - dphi, psi - dpsi)
            for name in "ABC":
                fd = (fp[name] - fm[name]) / (2 * h)
                np.testing.assert_allclose(m.jacobian(name, phi, psi)[:, k], fd, atol=1e-9)
            fd_th = (fp["theta2"] - fm["theta2"]) / (2 * h)
            assert m.theta2_grad(phi, psi)[k] == pytest.approx(fd_th, abs=1e-8)
        # theta2 really is the angle of A->B
        pos = m.positions(phi, psi)
        d = pos["B"] - pos["A"]
        assert np.hypot(*d) == pytest.approx(P.l2, rel=1e-13)
        assert math.atan2(d[1], d[0]) % (2 * math.pi) == pytest.approx(
            float(pos["theta2"]) % (2 * math.pi), abs=1e-12
        )
        checked += 1
    assert checked >= 10


def test_phi_psi_mass_matrix_matches_redundant_projection():
    """M_q = Z^T M_z Z with Z = dz/dq, z = (phi, theta2, psi, x_C)."""
    mq = pe.lagrange_phi_psi(P)
    mz = pe.redundant_model(P)
    rng = np.random.default_rng(2)
    for _ in range(20):
        phi, psi = rng.uniform(-math.pi, math.pi, size=2)
        if pe.closure_sqrt_arg(phi, psi) < 0.1 * P.l2**2:
            continue
        pos = mq.positions(phi, psi)
        z = np.array([phi, pos["theta2"], psi, pos["C"][0]], dtype=float)
        dth = mq.theta2_grad(phi, psi)
        JC = mq.jacobian_C(phi, psi)
        Z = np.array([[1.0, 0.0], dth, [0.0, 1.0], JC[0]])
        np.testing.assert_allclose(
            mq.mass_matrix(phi, psi), Z.T @ mz.mass_matrix(z) @ Z, rtol=1e-12, atol=1e-14
        )
        assert np.linalg.norm(mz.constraint(z)) < 1e-15


# ---------------------------------------------------------------------------
# (a) (phi, psi) Lagrange vs redundant coordinates before the branch point
# ---------------------------------------------------------------------------


def test_a_phi_psi_and_redundant_agree_before_branch_point(paper_phi_psi, paper_redundant):
    a = paper_phi_psi
    r = paper_redundant
    n = a.t.size
    np.testing.assert_array_equal(a.t, r.t[:n])
    assert np.max(np.abs(a.phi - r.phi[:n])) < 1e-9
    assert np.max(np.abs(a.psi - r.psi[:n])) < 1e-9
    assert np.max(np.abs(a.phi_dot - r.phi_dot[:n])) < 1e-7
    assert np.max(np.abs(a.psi_dot - r.psi_dot[:n])) < 1e-7
    assert np.max(np.abs(a.phi_ddot - r.phi_ddot[:n])) < 1e-5
    assert np.max(np.abs(a.psi_ddot - r.psi_ddot[:n])) < 1e-5
    assert np.max(np.abs(a.x_C - r.x_C[:n])) < 1e-11


def test_phi_psi_chart_refuses_to_pass_branch_point():
    with pytest.raises(ValueError, match="singular configuration"):
        pe.integrate_phi_psi(0.1, np.linspace(0.0, 0.1, 11))


def test_redundant_after_branch_point_matches_other_branch_chart(paper_redundant):
    """After the crossing, the sigma = -1 (phi, psi) chart restarted from the
    redundant state reproduces the redundant solution."""
    r = paper_redundant
    t_start = 0.065
    y = r.dense(t_start)
    assert math.cos(y[1]) < -0.05  # clearly on the sigma = -1 branch
    t = np.linspace(t_start, 0.1, 351)
    b = pe.integrate_phi_psi(0.1, t, motor=True, sigma=-1, t0=t_start, state0=(y[0], y[2], y[4], y[6]))
    Y = r.dense(t)
    assert np.max(np.abs(b.phi - Y[0])) < 1e-9
    assert np.max(np.abs(b.psi - Y[2])) < 1e-9
    assert np.max(np.abs(b.x_C - Y[3])) < 1e-11


# ---------------------------------------------------------------------------
# (b) energy conservation, gravity only, through the branch point
# ---------------------------------------------------------------------------


def test_b_energy_conserved_gravity_only(gravity_redundant):
    g = gravity_redundant
    E = g.E
    rel = np.max(np.abs(E - E[0])) / abs(E[0])
    print(
        f"\ngravity-only redundant run: max |E - E0|/|E0| = {rel:.3e}, "
        f"max |g(z)| = {g.constraint_pos.max():.3e} m, nfev = {g.nfev}"
    )
    assert rel < 1e-9
    assert g.constraint_pos.max() < 1e-9
    # the gravity-only run also passes the chart's singular configuration
    assert pe.chart_breakdown_times(g).size >= 1


def test_work_energy_with_motor(paper_redundant):
    """E(t) - E(0) equals the motor work integral of tau(phi') phi'."""
    r = paper_redundant
    tt = np.linspace(0.0, 0.1, 40001)
    Y = r.dense(tt)
    power = pe.motor_torque(Y[4]) * Y[4]
    from scipy.integrate import simpson

    W = simpson(power, x=tt)
    dE = r.E[-1] - r.E[0]
    assert dE == pytest.approx(W, rel=1e-9, abs=1e-9)


# ---------------------------------------------------------------------------
# (c) the redundant run passes the branch point with tiny drift
# ---------------------------------------------------------------------------


def test_c_redundant_passes_branch_point(paper_redundant):
    r = paper_redundant
    assert r.t[-1] == pytest.approx(0.1)
    roots = pe.chart_breakdown_times(r)
    sq = pe.closure_sqrt_arg(r.phi, r.psi)
    signed = P.l2 * np.cos(r.theta2)  # x_B - x_A; its square is the radicand
    np.testing.assert_allclose(signed**2, sq, atol=1e-15)
    t_root = roots[0]
    y = r.dense(t_root)
    sq_root = pe.closure_sqrt_arg(y[0], y[2])
    print(
        f"\npaper run: radicand l2^2-(l3 sin psi - l1 sin phi)^2 vanishes at t = "
        f"{', '.join(f'{v:.12f}' for v in roots)} s; min on grid {sq.min():.3e} m^2 at "
        f"t = {r.t[np.argmin(sq)]:.5f} s; value at root {sq_root:.3e} m^2; "
        f"max |g(z)| = {r.constraint_pos.max():.3e} m, max |G z'| = "
        f"{r.constraint_vel.max():.3e} m/s, nfev = {r.nfev}"
    )
    assert roots.size == 1
    assert abs(t_root - T_BRANCH_PAPER) < 5e-4
    # the radicand touches zero: x_B - x_A changes sign (sigma +1 -> -1)
    # radicand at the root: zero up to rounding/constraint drift (l2^2 = 1.6e-3 m^2)
    assert abs(sq_root) < 1e-14
    assert signed[r.t < t_root].min() > 0.0
    assert signed[r.t > t_root].max() < 0.0
    assert sq.min() < 1e-5 * P.l2**2  # grid minimum is next to the crossing
    assert abs(r.t[np.argmin(sq)] - t_root) <= 0.1 / 2000
    # constraint drift of the unstabilised index-1 integration
    assert r.constraint_pos.max() < 1e-9
    assert r.constraint_vel.max() < 1e-8
    # smooth through the crossing: accelerations stay bounded
    assert np.all(np.isfinite(r.phi_ddot)) and np.max(np.abs(r.phi_ddot)) < 1e5


def test_redundant_is_converged(paper_redundant):
    te = np.array([0.05, 0.1])
    fine = pe.integrate_redundant(0.1, te, rtol=1e-13, atol=1e-13)
    r = paper_redundant
    i = [np.searchsorted(r.t, v) for v in te]
    np.testing.assert_allclose(r.phi[i], fine.phi, rtol=0, atol=1e-11)
    np.testing.assert_allclose(r.phi_dot[i], fine.phi_dot, rtol=0, atol=1e-9)
    np.testing.assert_allclose(r.phi_ddot[i], fine.phi_ddot, rtol=0, atol=1e-7)


def test_redundant_state0_roundtrip():
    y = pe.redundant_state_from_minimal(*pe.PAPER_STATE0)
    m = pe.redundant_model(P)
    assert np.linalg.norm(m.constraint(y[:4])) < 1e-16
    assert np.linalg.norm(m.constraint_jacobian(y[:4]) @ y[4:]) < 1e-14
    assert y[0] == pe.PHI0 and y[2] == pe.PSI0 and y[4] == 43.5 and y[6] == 0.0
    assert math.cos(y[1]) > 0.0


# ---------------------------------------------------------------------------
# (d) locked crank-slider
# ---------------------------------------------------------------------------


def test_d_locked_energy_conserved_gravity_only():
    t = np.linspace(0.0, 0.3, 601)
    r = pe.integrate_locked(0.3, t, pe.PHI0, 43.5, motor=False)
    E = r.E
    rel = np.max(np.abs(E - E[0])) / abs(E[0])
    print(f"\nlocked crank-slider gravity-only: max |E - E0|/|E0| = {rel:.3e}")
    assert rel < 1e-9
    # and with an oblique gravity vector
    r2 = pe.integrate_locked(0.3, t, 0.3, -20.0, motor=False, gravity=(-6.0, 7.0))
    E2 = r2.E
    assert np.max(np.abs(E2 - E2[0])) / abs(E2[0]) < 1e-9


def test_locked_kinematics_and_inertia():
    lm = pe.crank_slider_locked(P)
    mz = pe.redundant_model(P)
    phi = np.linspace(-math.pi, math.pi, 37)
    h = 1e-5
    np.testing.assert_allclose(lm.x_C_d1(phi), (lm.x_C(phi + h) - lm.x_C(phi - h)) / (2 * h), atol=1e-10)
    np.testing.assert_allclose(lm.x_C_d2(phi), (lm.x_C_d1(phi + h) - lm.x_C_d1(phi - h)) / (2 * h), atol=1e-9)
    np.testing.assert_allclose(
        lm.theta2_d1(phi), (lm.theta2(phi + h) - lm.theta2(phi - h)) / (2 * h), atol=1e-9
    )
    np.testing.assert_allclose(lm.dJ(phi), (lm.J(phi + h) - lm.J(phi - h)) / (2 * h), atol=1e-9)
    for f in phi:
        # closed-form geometry
        xB = P.l1 * math.cos(f) + math.sqrt(P.l2**2 - (P.l1 * math.sin(f)) ** 2)
        assert float(lm.x_C(f)) == pytest.approx(xB - P.l3, abs=1e-15)
        z = np.array([f, float(lm.theta2(f)), 0.0, float(lm.x_C(f))])
        assert np.linalg.norm(mz.constraint(z)) < 1e-15
        # J(phi) = Z^T M_z Z with Z = dz/dphi (psi locked)
        Z = np.array([1.0, float(lm.theta2_d1(f)), 0.0, float(lm.x_C_d1(f))])
        assert float(lm.J(f)) == pytest.approx(Z @ mz.mass_matrix(z) @ Z, rel=1e-12)
        assert float(lm.gravity_torque(f)) == pytest.approx(
            -(float(lm.potential_energy(f + h)) - float(lm.potential_energy(f - h))) / (2 * h), abs=1e-6
        )


def test_locked_motor_run_is_consistent():
    """Work-energy balance of the locked model with the motor."""
    t = np.linspace(0.0, 0.2, 401)
    r = pe.integrate_locked(0.2, t, pe.PHI0, 43.5, motor=True)
    tt = np.linspace(0.0, 0.2, 40001)
    Y = r.dense(tt)
    from scipy.integrate import simpson

    W = simpson(pe.motor_torque(Y[1]) * Y[1], x=tt)
    assert r.E[-1] - r.E[0] == pytest.approx(W, rel=1e-9, abs=1e-9)
