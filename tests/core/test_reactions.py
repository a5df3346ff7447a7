"""Joint reactions and the foundation load (contract §7): against a classical closed-form
crank-slider force analysis, the balance of the whole machine, the least-squares residual as a
check of the dynamics, impulses at a latch impact, and the CLI columns."""

import csv
import math

import numpy as np
import pytest
from reference import press_exact as pe

from mps_core import build, load_scene
from mps_core.cli import main
from mps_core.dynamics.engine import PartialSystems
from mps_core.dynamics.reaction_observer import ReactionObserver
from mps_core.dynamics.reactions import REACTION_COLUMNS, compute_reactions, impulses, plastic_impact
from mps_core.model.effects import MOTOR_PRESETS, Gravity, Motor
from mps_core.model.mechanism import ChartView
from mps_core.model.press import PressMechanism
from mps_core.names import COLUMNS

G = (-9.81, 0.0)
L1, L2, L3 = 0.015, 0.040, 0.030
M1, J1, M2, J2, M3, M4 = 4.6, 0.034, 20.0, 0.036, 18.0, 100.0


def classical_crank_slider(phi, phid, phidd, torque, g=G):
    """Textbook force analysis of the locked press (rocker locked to the slider at psi = 0, so B
    runs on the guide's axis at x_C + l3): crank l1 with its centre of mass at A, rod l2 with its
    centre of mass at B, rocker + slider translating with C. Sequential elimination from the
    slider group to the crank; returns the reactions (contract §7 signs) and the crank's moment
    equation about O left over (zero when phidd is the true acceleration)."""
    gx, gy = g
    s, c = math.sin(phi), math.cos(phi)
    st = -L1 * s / L2  # sin(theta2), rod angle A->B
    ct = math.sqrt(1.0 - st * st)
    thd = -L1 * c * phid / (L2 * ct)
    thdd = (L1 * s * phid**2 - L1 * c * phidd + L2 * st * thd**2) / (L2 * ct)
    xB = L1 * c + L2 * ct
    xBdd = -L1 * (c * phid**2 + s * phidd) - L2 * (ct * thd**2 + st * thdd)
    A = np.array([L1 * c, L1 * s])
    B = np.array([xB, 0.0])
    aA = L1 * np.array([-s * phidd - c * phid**2, c * phidd - s * phid**2])
    m34 = M3 + M4
    FBx = m34 * (gx - xBdd)  # rocker + slider along x
    FAx = FBx + M2 * gx - M2 * xBdd  # rod along x
    AB = A - B  # rod: moment about B (its centre)
    FAy = (-J2 * thdd + AB[1] * FAx) / AB[0]
    FBy = FAy - M2 * gy
    FCx = -FBx + M3 * gx - M3 * xBdd  # rocker along x
    FCy = -FBy + M3 * gy
    N = FCy + M4 * gy  # slider along y
    M_latch = -(L3 * FBy)  # rocker: moment about C, no rotation
    M_guide = M_latch  # slider: moment about C
    FO = np.array([FAx, FAy]) + M1 * np.array(g) - M1 * aA
    eom = (A[0] * FAy - A[1] * FAx) + M1 * (A[0] * gy - A[1] * gx) + torque - (J1 + M1 * L1**2) * phidd
    xC = xB - L3
    return {
        "F_O_x": FO[0],
        "F_O_y": FO[1],
        "F_A_x": FAx,
        "F_A_y": FAy,
        "F_B_x": FBx,
        "F_B_y": FBy,
        "F_C_x": FCx,
        "F_C_y": FCy,
        "N_guide": N,
        "M_guide": M_guide,
        "M_latch": M_latch,
        "M_motor": torque,
        "F_found_x": FO[0],
        "F_found_y": FO[1] + N,
        "M_found_O": xC * N + M_guide - torque,
    }, eom


def classical_phidd(phi, phid, torque):
    """The acceleration that closes the crank's moment equation (everything is affine in it)."""
    e0 = classical_crank_slider(phi, phid, 0.0, torque)[1]
    e1 = classical_crank_slider(phi, phid, 1.0, torque)[1]
    return -e0 / (e1 - e0)


def _locked():
    mech = PressMechanism()
    motor = Motor.for_crank_speed(MOTOR_PRESETS["4A80B4U3"], 43.5)
    effects = [Gravity(G), motor]
    for e in effects:
        e.bind(mech)
    return mech, effects, ChartView(mech.chart("phi-psi+"), {"psi": 0.0})


@pytest.mark.parametrize(
    "phi_deg,phid", [(0.0, 43.5), (37.0, 40.0), (100.0, 46.0), (181.0, 44.0), (250.0, 30.0), (330.0, 45.0)]
)
def test_locked_reactions_match_the_classical_crank_slider(phi_deg, phid):
    mech, effects, view = _locked()
    phi = math.radians(phi_deg)
    torque = pe.motor_torque(phid)
    phidd = classical_phidd(phi, phid, torque)
    # the engine's exact dynamics agree with the classical one
    ev = PartialSystems(mech, effects, "autodiff").evaluate(view, 0.0, [phi], [phid])
    assert ev.qdd[0] == pytest.approx(phidd, rel=1e-10, abs=1e-8)
    rx = compute_reactions(mech, effects, view, 0.0, [phi], [phid], [phidd])
    ref, eom = classical_crank_slider(phi, phid, phidd, torque)
    assert abs(eom) < 1e-9
    scale = max(abs(v) for v in ref.values())
    for k, v in ref.items():
        assert rx[k] == pytest.approx(v, abs=1e-9 * scale), k
    assert rx["F_stop"] == 0.0
    assert set(rx.unknowns) == {
        "F_O_x",
        "F_O_y",
        "F_A_x",
        "F_A_y",
        "F_B_x",
        "F_B_y",
        "F_C_x",
        "F_C_y",
        "N_guide",
        "M_guide",
        "M_latch",
    }
    assert rx["residual_force_N"] < 1e-9 * scale and rx["balance_residual_N"] < 1e-9 * scale


def test_locked_run_frame_forces_match_the_classical_analysis():
    """The working scene, exact derivatives, 300 steps: at every recorded step the frame forces
    equal the closed form at the step's (phi, phi_dot, phi_ddot)."""
    scene = load_scene("working").with_overrides(t_end=0.03, dt=1e-4, scheme="autodiff")
    sim = build(scene)
    sim.observers.append(ReactionObserver())
    tr = sim.run(scene.t_end, scene.dt)
    for i in range(0, len(tr), 15):
        ref, _ = classical_crank_slider(
            tr.phi[i], tr.phi_dot[i], tr.phi_ddot[i], pe.motor_torque(tr.phi_dot[i])
        )
        for k in (
            "F_O_x",
            "F_O_y",
            "N_guide",
            "M_guide",
            "M_latch",
            "M_motor",
            "F_found_x",
            "F_found_y",
            "M_found_O",
        ):
            assert tr[k][i] == pytest.approx(ref[k], abs=1e-8 * 6e3), (k, tr.t[i])
    assert tr["residual_force_N"].max() < 1e-8
    assert tr["balance_residual_N"].max() < 1e-9


def test_free_paper_balance_is_round_off_and_the_residual_is_the_derivatives_error():
    """Balance at round-off with the seed's settings; the least-squares leftover is what the
    step's accelerations miss of the exact equations of motion: O(delta^2) with central
    differences, round-off with exact derivatives."""
    res = {}
    for label, ov in (
        ("0.1", {}),
        ("0.01", {"delta": math.radians(0.01)}),
        ("exact", {"scheme": "autodiff"}),
    ):
        scene = load_scene("paper").with_overrides(**ov)
        sim = build(scene)
        sim.observers.append(ReactionObserver())
        tr = sim.run(scene.t_end, scene.dt)
        F = np.hypot(tr["F_found_x"], tr["F_found_y"])
        assert F.max() > 1e3
        assert tr["balance_residual_N"].max() < 1e-12 * F.max() * 1e3
        assert tr["balance_residual_Nm"].max() < 1e-9
        assert np.all(tr["M_latch"] == 0.0) and np.all(tr["F_stop"] == 0.0)
        # slider's centre of mass at C, nothing turns it: the guide carries no moment, but for
        # the share of the leftover that the exact balance about O puts there
        assert np.abs(tr["M_guide"]).max() < (1e-10 if label == "exact" else 1e-3)
        res[label] = (tr["residual_force_N"].max(), tr["residual_moment_Nm"].max())
    assert 1e-3 < res["0.1"][0] < 0.1
    ratio = res["0.1"][0] / res["0.01"][0]
    assert 80 < ratio < 120  # O(delta^2)
    assert res["exact"][0] < 1e-8 and res["exact"][1] < 1e-10


def test_balanced_crank_slider_shaking_force_harmonics():
    """Crank's centre of mass at O, constant speed prescribed (q_dot = w, q_ddot = 0; the drive
    torque is then an unknown): the shaking force is that of the reciprocating mass
    m = m2 + m3 + m4 moving with B, x_B = r cos(phi) + l sqrt(1 - (r/l)^2 sin^2(phi)). Its first
    harmonic is exactly m r w^2; the second is (r/l) m r w^2 (1 + l^2/4 + 15 l^4/128 + ...),
    l = r/l = 0.375: the classical (r/l) m r w^2 is 3.7 % low, the three-term series 0.03 %."""
    from mps_core.analysis.loads import harmonics
    from mps_core.model.press import BodyData

    mech = PressMechanism(bodies={"crank": BodyData(M1, J1, (0.0, 0.0))})
    grav = Gravity(G)
    grav.bind(mech)
    view = ChartView(mech.chart("phi-psi+"), {"psi": 0.0})
    w, N = 43.5, 128
    fx, fy = np.empty(N), np.empty(N)
    for j in range(N):
        rx = compute_reactions(mech, [grav], view, 0.0, [2 * math.pi * j / N], [w], [0.0], drive="crank")
        fx[j], fy[j] = rx["F_found_x"], rx["F_found_y"]
        assert rx["residual_force_N"] < 1e-9 and rx["balance_residual_N"] < 1e-9
    m = M2 + M3 + M4
    lam = L1 / L2
    mean, amp, _ = harmonics(fx)
    assert mean == pytest.approx((M1 + m) * G[0], rel=1e-12)
    assert amp[0] == pytest.approx(m * L1 * w**2, rel=1e-10)
    classical = lam * m * L1 * w**2
    assert amp[1] == pytest.approx(classical, rel=0.04)
    assert amp[1] == pytest.approx(classical * (1 + lam**2 / 4 + 15 * lam**4 / 128), rel=5e-4)
    assert np.abs(fy).max() < 1e-9 and amp[2] < 1e-9 * amp[0]  # odd harmonics above the 1st: 0


def test_latch_impact_impulses_are_the_momentum_jumps():
    """A synthetic latch closing in the free structure: q_dot jumps by the plastic-impact
    formula; the impulses each body receives add up to its momentum jump."""
    mech = PressMechanism()
    view = ChartView(mech.chart("phi-psi+"))
    q = np.array([math.radians(-20.0), math.radians(-8.0)])
    qd_minus = np.array([43.0, -25.0])
    A = PartialSystems(mech, [], "autodiff").evaluate(view, 0.0, q, qd_minus).A
    qd_plus, lam = plastic_impact(A, qd_minus, [0.0, 1.0])
    assert qd_plus[1] == pytest.approx(0.0, abs=1e-12)
    assert qd_plus[0] == pytest.approx(qd_minus[0] + A[0, 1] / A[0, 0] * qd_minus[1], rel=1e-12)
    imp = impulses(mech, view, q, qd_minus, qd_plus, closing=("psi",), t=0.1)
    v = imp.values
    # momentum jumps, computed here from the engine's exact analogs
    kin = PartialSystems(mech, [], "autodiff").kinematics(view, 0.0, q, qd_minus)
    dq = qd_plus - qd_minus
    P = {p: kin.position(p) for p in ("O", "A", "B", "C")}
    cross = lambda r, f: r[0] * f[1] - r[1] * f[0]  # noqa: E731
    FO, FA = np.array([v["F_O_x"], v["F_O_y"]]), np.array([v["F_A_x"], v["F_A_y"]])
    FB, FC = np.array([v["F_B_x"], v["F_B_y"]]), np.array([v["F_C_x"], v["F_C_y"]])
    Nv = np.array([0.0, v["N_guide"]])
    received = {  # (impulse, angular impulse about the centre of mass), contract §7 signs
        "crank": (-FO + FA, cross(P["O"] - P["A"], -FO)),
        "rod": (FB - FA, cross(P["A"] - P["B"], -FA)),
        "rocker": (-FB - FC, cross(P["B"] - P["C"], -FB) - v["M_latch"]),
        "slider": (FC - Nv, -v["M_guide"] + v["M_latch"]),
    }
    scale = np.abs(list(v.values())).max()
    for b in mech.bodies:
        dp = b.mass * (kin.analog(f"G_{b.name}") @ dq)
        dL = b.inertia * (kin.angular_analog(b.name) @ dq)
        assert np.allclose(received[b.name][0], dp, atol=1e-10 * scale), b.name
        assert received[b.name][1] == pytest.approx(dL, abs=1e-10 * scale), b.name
        assert np.allclose(imp.momentum_jump[b.name], (*dp, dL), atol=1e-10 * scale)
    # the latch's angular impulse is the constraint's multiplier; energy lost as contract §5
    assert v["M_latch"] == pytest.approx(lam, rel=1e-9)
    assert imp.energy_loss == pytest.approx(
        0.5 * (A[1, 1] - A[0, 1] ** 2 / A[0, 0]) * qd_minus[1] ** 2, rel=1e-9
    )
    total = sum(b.mass * (kin.analog(f"G_{b.name}") @ dq) for b in mech.bodies)
    assert np.allclose([v["F_found_x"], v["F_found_y"]], -total, atol=1e-10 * scale)
    assert np.abs(imp.residual).max() < 1e-10 * scale
    ev = imp.as_event()
    assert ev["kind"] == "impulse" and ev["duration_s"] == 0.0 and "M_latch" in ev["impulses_Ns"]


def test_reactions_only_when_asked_and_the_cli_columns(tmp_path, capsys):
    scene = load_scene("paper")
    sim = build(scene)
    assert sim.observers == []
    assert "F_O_x" not in sim.run(scene.t_end, scene.dt).columns
    out = tmp_path / "r.csv"
    assert main(["run", "paper", "--reactions", "--csv", str(out)]) == 0
    assert "foundation force peak" in capsys.readouterr().out
    rows = list(csv.reader(out.open()))
    assert rows[0] == list(COLUMNS) + list(REACTION_COLUMNS)
    assert rows[0][len(COLUMNS) : len(COLUMNS) + 16] == (
        "F_O_x,F_O_y,F_A_x,F_A_y,F_B_x,F_B_y,F_C_x,F_C_y,N_guide,M_guide,M_latch,F_stop,M_motor,"
        "F_found_x,F_found_y,M_found_O"
    ).split(",")
    assert len(rows) == 42
    assert all(math.isfinite(float(x)) for x in rows[-1][len(COLUMNS) :])


def test_the_residual_is_the_equation_of_motion_left_over():
    """J_b^T r = A q_ddot + h - Q with the exact A, h, Q: at the end of the seed's run (central
    differences) the residual projected on the analogs is the exact mass matrix times the step's
    acceleration error."""
    from mps_core.dynamics.reactions import body_motion

    scene = load_scene("paper")
    sim = build(scene)
    sim.run(scene.t_end, scene.dt)
    e = sim.solver.current
    mech = sim.mechanism
    rx = compute_reactions(mech, sim.engine.effects, e.view, e.t, e.q, e.qd, e.qdd)
    m = body_motion(mech, e.view, e.q, e.qd)
    rows = m.com_rows(mech)
    Jb = np.zeros((3 * len(mech.bodies), e.view.n))
    Jb[0::3], Jb[1::3], Jb[2::3] = m.J[rows][:, 0], m.J[rows][:, 1], m.W
    exact = PartialSystems(mech, sim.engine.effects, "autodiff").evaluate(e.view, e.t, e.q, e.qd)
    lhs, rhs = Jb.T @ rx.residual, exact.A @ (e.qdd - exact.qdd)
    assert np.abs(rhs).max() > 1e-4  # central differences: O(delta^2), not zero
    assert np.allclose(lhs, rhs, rtol=1e-7, atol=1e-12)


def test_press_cycle_balance_at_round_off_in_every_structure():
    """held (F_stop), free, locked (M_latch): the moving system's balance holds to round-off,
    the stop pushes only while held, the latch carries moment only while locked."""
    from dataclasses import replace

    from mps_core import load_scene, simulate

    traj = simulate(replace(load_scene("press-cycle"), reactions=True), t_end=0.6)
    s = traj.structure
    assert {"held", "free", "locked"} <= set(s)
    assert traj.balance_residual_N.max() < 1e-9 and traj.balance_residual_Nm.max() < 1e-9
    held, locked = s == "held", s == "locked"
    assert np.all(traj.F_stop[held] >= -1e-9) and np.all(traj.F_stop[~held] == 0.0)
    assert np.any(traj.F_stop[held] > 100.0)
    assert np.all(traj.M_latch[~locked] == 0.0) and np.any(np.abs(traj.M_latch[locked]) > 1.0)


def test_stop_force_from_newton_euler_equals_the_constraint_force_of_the_lagrange_equations():
    """Two formulations of the held slider's top-stop force: Newton–Euler per body (least
    squares) and the multiplier of x_C = x_top from the unfrozen chart's Lagrange equations."""
    from mps_core import build, load_scene
    from mps_core.dynamics.reactions import compute_reactions

    sim = build(load_scene("idle").with_overrides(t_end=0.02, scheme="autodiff"))
    pairs = []

    class Both:
        def observe(self, s, e):
            if s.structure != "held":
                return
            lam = s.structures.stop_force(e.t, e.q, e.qd, e.view)
            r = compute_reactions(s.mechanism, s.effects, e.view, e.t, e.q, e.qd, e.qdd)
            pairs.append((r.values["F_stop"], -lam))

        def columns(self):
            return {}

    sim.observers.append(Both())
    sim.run(0.02, 1e-4)
    assert len(pairs) > 50
    a = np.array(pairs)
    assert np.allclose(a[:, 0], a[:, 1], rtol=1e-9, atol=1e-6 * np.abs(a).max())
