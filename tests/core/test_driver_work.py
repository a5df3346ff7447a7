"""The run driver's per-step work: its shortcuts give the numbers of the long way, exactly."""

import numpy as np
import pytest

from mps_core import build, load_scene, scene_from_text
from mps_core.model import PressMechanism
from mps_core.model.effects import RetentionSprings, TopStop
from mps_core.model.effects.base import stiffness_x_bound
from mps_core.solvers import LinearAcceleration


def columns_equal(a, b):
    assert set(a.columns) == set(b.columns)
    for k, x in a.columns.items():
        y = b.columns[k]
        assert x.dtype == y.dtype and x.shape == y.shape, k
        if x.dtype.kind == "f":
            assert np.array_equal(x, y, equal_nan=True), k
        else:
            assert np.array_equal(x, y), k


class Every:
    """An observer that calls ``check(simulation, evaluation)`` at every recorded step."""

    def __init__(self, check):
        self.check = check
        self.n = 0

    def observe(self, sim, e):
        self.check(sim, e)
        self.n += 1

    def columns(self):
        return {}


# -- recording --------------------------------------------------------------------------------
def test_a_record_reads_what_a_fresh_observation_reads():
    """Right after a step the record reuses the angles read for unwrapping: the same numbers as
    reading them again, in every structure and chart of the press cycle."""
    views = set()

    def check(sim, e):
        kept = sim.observables.observations(e)
        sim._phys_of = None
        fresh = sim.observables.observations(e)
        sim._phys_of = e
        assert kept == fresh or np.array_equal(kept, fresh, equal_nan=True)
        views.add(e.view.name)

    sim = build("press-cycle")
    sim.observers.append(Every(check))
    traj = sim.run(1.0, 1e-3)
    assert set(traj.structure) == {"held", "free", "locked"} and len(views) >= 4


def test_the_recorded_potential_energy_is_the_engines():
    def check(sim, e):
        assert sim.energy.potential(e.kin) == sim.engine.potential_energy(e.kin)

    for scene in ("press-cycle", "paper"):
        sim = build(scene)
        sim.observers.append(Every(check))
        sim.run(0.3, 1e-3)


def test_the_trajectory_has_every_column_once_a_step():
    traj = build("paper").run(0.01, 1e-3)
    from mps_core.names import COLUMNS

    assert list(traj.columns) == list(COLUMNS)
    assert all(len(v) == 11 for v in traj.columns.values())
    assert traj.structure.dtype.kind == "U" and traj.T.dtype == float


# -- the stop's reaction -------------------------------------------------------------------------
@pytest.mark.parametrize("scheme", ["central", "autodiff"])
@pytest.mark.parametrize("kernels", [True, False])
def test_the_equations_on_floats_are_those_of_the_evaluation(kernels, scheme):
    """``equations`` (A, h, Q as floats) and ``accelerations`` (q̈ as floats) give the numbers
    of ``evaluate``, bit for bit, with and without kernels, and count one evaluation each."""
    scene = load_scene("paper").with_overrides(scheme=scheme)
    sim = build(scene)
    eng = sim.engine
    eng.kernels = kernels
    q, qd = sim.solver.q + 0.01, sim.solver.qd + 0.5
    e = eng.evaluate(sim.view, 0.0, q, qd)
    before = eng.counts["evaluations"]
    A, h, Q = eng.equations(sim.view, 0.0, q.tolist(), qd.tolist())
    assert A == e.A.tolist() and h == e.h.tolist() and Q == e.Q.tolist()
    assert eng.accelerations(sim.view, 0.0, q.tolist(), qd.tolist()) == e.qdd.tolist()
    assert eng.counts["evaluations"] == before + 2


def test_the_stop_force_is_evaluated_once_a_held_step():
    """The work counts of the press cycle at 1 ms: the solver's two evaluations a step, and one
    of the unfrozen chart for the stop's reaction at the end of a held step."""
    traj = build("press-cycle").run(1.0, 1e-3)
    c = traj.counts
    held_steps = int(np.sum(traj.structure[1:] == "held"))
    releases = sum(e["kind"] == "stop-release" for e in traj.events)
    contacts = sum(e["kind"] == "stop-contact" for e in traj.events)
    # beyond the held steps: the root searches of the releases and a check at each contact
    assert c["evaluations"] - c["solver_evaluations"] <= held_steps + 12 * releases + contacts
    assert c["solver_evaluations"] <= 2 * c["steps"] + 40
    # one step more than the grid's 1000 at each event, command and the disengage cylinder's end
    # (the root searches take a few evaluations more or less with the platform's round-off)
    assert c["evaluations"] <= 2230 and c["steps"] <= 1010


# -- the stability check --------------------------------------------------------------------------
def test_a_spring_at_a_centre_of_mass_bounds_its_omega():
    mech = PressMechanism(x_top=0.0255)
    m_at_c = sum(b.mass for b in mech.bodies if b.name in ("rocker", "slider"))
    assert stiffness_x_bound(2.0e4, mech, "C") == pytest.approx(2.0e4 / m_at_c, rel=1e-15)
    assert stiffness_x_bound(2.0e4, mech, "B") == pytest.approx(2.0e4 / mech.body("rod").mass)
    assert stiffness_x_bound(2.0e4, mech, "O") is None
    assert TopStop(0.0255).stiffness_bound(mech) == 0.0
    assert RetentionSprings(2.0e4, 10.0, 0.0255).stiffness_bound(mech) == stiffness_x_bound(2.0e4, mech, "C")


ELASTIC = (
    load_scene("free-fall")
    .text.replace("assembly = 1", "assembly = 1\nx_top_mm = 24.0")
    .replace(
        "[solver]",
        '[[effects]]\ntype = "springs"\nstiffness_n_m = 2.0e6\npreload_n = 0.0\n\n'
        '[[effects]]\ntype = "top_stop"\nmodel = "elastic"\nstiffness_n_m = 5.0e7\n\n[solver]',
    )
)


@pytest.mark.parametrize("scene,t_end,dt", [("press-cycle", 1.0, 1e-3), (ELASTIC, 0.2, 1e-4)])
def test_the_bounds_are_above_every_per_step_estimate(scene, t_end, dt):
    """ω² by trace(A⁻¹K) at every step, in every chart (one and two coordinates), never exceeds
    the sum of the effects' bounds: the shortcut keeps only steps the estimate keeps."""
    seen = []

    def check(sim, e):
        w2 = sim.stability.omega2(e)
        bound = sum(s.stiffness_bound(sim.mechanism) for s in sim.stability.stiff)
        if w2 is not None:
            assert w2 <= bound * (1.0 + 1e-12)
            seen.append((e.view.n, w2 / bound))

    sim = build(load_scene(scene) if "\n" not in scene else scene_from_text(scene))
    sim.observers.append(Every(check))
    sim.run(t_end, dt)
    assert {n for n, _ in seen} == {1, 2} or scene != "press-cycle"
    assert max(r for _, r in seen) > 0.05  # the bound is not vacuous


@pytest.mark.parametrize(
    "scene,t_end,dt", [("press-cycle", 0.5, 1e-3), (ELASTIC, 0.1, 1e-4), (ELASTIC, 0.05, 2e-3)]
)
def test_the_stability_shortcut_changes_nothing(scene, t_end, dt):
    def make():
        return build(load_scene(scene) if "\n" not in scene else scene_from_text(scene))

    fast = make()
    slow = make()
    slow.stability.always = 0.0  # the per-step estimate at every step
    a, b = fast.run(t_end, dt), slow.run(t_end, dt)
    columns_equal(a, b)
    assert a.events == b.events and a.counts == b.counts


def test_an_effect_without_a_bound_keeps_the_per_step_estimate():
    class Unbounded(RetentionSprings):
        stiffness_bound = None

    sim = build("idle")
    assert 0.0 < sim.stability.always < np.inf
    sim.stability.stiff.append(Unbounded(1.0, 0.0, 0.0255))
    assert sim.stability.always_stable() == 0.0


# -- the solver ---------------------------------------------------------------------------------
class E:
    def __init__(self, qdd):
        self.qdd = np.asarray(qdd, float)


@pytest.mark.parametrize("n", [1, 2, 3])
@pytest.mark.parametrize("iterations", [1, 2])
def test_linear_acceleration_on_floats_is_the_vector_formula(n, iterations):
    """The step written out on floats for n = 1, 2 gives the vector formulas' numbers exactly."""
    rng = np.random.default_rng(n)
    K = rng.normal(size=(n, n))

    def fun(t, q, qd):
        return E(-(K @ q) - 0.3 * qd + np.sin(t))

    s = LinearAcceleration(fun, 0.0, rng.normal(size=n), rng.normal(size=n), iterations=iterations)
    q, qd, a0 = s.q.copy(), s.qd.copy(), s.current.qdd.copy()
    for k in range(1, 6):
        t0, t1 = s.t, 0.01 * k
        dt = t1 - t0
        s.step_to(t1)
        a1 = fun(t1, q + qd * dt + a0 * (0.5 * dt * dt), qd + a0 * dt).qdd
        for _ in range(iterations):
            qd1 = qd + (a0 + a1) * (0.5 * dt)
            q1 = q + qd * dt + (2.0 * a0 + a1) * (dt * dt / 6.0)
            a1 = fun(t1, q1, qd1).qdd
        assert np.array_equal(s.q, q1) and np.array_equal(s.qd, qd1)
        assert np.array_equal(s.current.qdd, a1)
        q, qd, a0 = q1, qd1, a1
    assert s.nfev == 1 + 5 * (1 + iterations) and s.nsteps == 5
