"""The fused kernels: q̈ from (t, q, q̇) in one generated function, the effects traced in."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mps_core import build, load_scene, preset_names
from mps_core.model.effects import Effect, JointFriction


def _spy(eng, sim=None):
    """Wrap ``accelerations`` and the per-view accelerators the solvers call: every call's q̈
    beside the general path's at the same state, and how many calls the fused functions
    answered. ``sim``: its solver is made again with the wrapped accelerator."""
    seen = []
    fused_calls = [0]

    def check(view, t, ql, vl, call):
        before = eng.counts["evaluations"]
        plan = eng._plans.get(view)
        fused_before = plan.fused if plan is not None else None
        out = call(t, ql, vl)
        assert eng.counts["evaluations"] == before + 1
        if plan is not None and plan.fused is not None and fused_before is not None:
            fused_calls[0] += 1
        general = eng._solve_on_floats(view, t, ql, vl)
        ref = general[3] if general is not None else eng.evaluate(view, t, ql, vl).qdd.tolist()
        seen.append((view.name, t, out, ref))
        if plan is not None and plan.fused is not None:
            _check_whole_evaluation(eng, view, plan, t, ql, vl)
        return out

    accelerations, accelerator = eng.accelerations, eng.accelerator
    eng.accelerations = lambda view, t, ql, vl: check(view, t, ql, vl, lambda *a: accelerations(view, *a))

    def spied(view):
        accel = accelerator(view)
        return lambda t, ql, vl: check(view, t, ql, vl, accel)

    eng.accelerator = spied
    if sim is not None:
        s = sim.solver
        sim._restart(sim.view, s.t, s.q, s.qd)
    return seen, fused_calls


def _check_whole_evaluation(eng, view, plan, t, ql, vl):
    """The fused evaluation (kinematics, A, h, θ̈, Q, Q_nc, q̈ in one call) against the exact
    kernel, the effects one by one and the solve: the same numbers."""
    from mps_core.codegen.fused_kernels import ForceLawBranch
    from mps_core.codegen.kernels import solve_given_h
    from mps_core.dynamics.engine import Kinematics

    try:
        got = plan.fused.full(t, *ql, *vl)
    except ForceLawBranch:
        return
    xl, jl, wl, A, h, conv = plan.exact(*ql, *vl)
    kin = Kinematics(
        t, None, None, eng.maps.names, bodies=eng.maps.body_index, lists=(xl, jl, wl), conv=conv, v=vl
    )
    Q, Qnc = eng.forces.generalized(t, kin)
    assert list(got) == [xl, jl, wl, A, h, conv, Q, Qnc, solve_given_h(A, h, Q)]


@pytest.mark.parametrize("name", preset_names())
def test_every_preset_chart_and_structure_gives_the_general_paths_accelerations(name):
    """Along a run of each preset with exact derivatives (through its structures, charts,
    impacts and commands), the fused function's q̈ is the general path's, bit for bit, and
    the fused functions answer most of the solver's stages."""
    scene = load_scene(name).with_overrides(scheme="autodiff", solver="rk4")
    sim = build(scene)
    seen, fused_calls = _spy(sim.engine, sim)
    traj = sim.run(min(scene.t_end, 0.6), 1e-3)
    assert len(seen) > 100
    bad = [(v, t, a, b) for v, t, a, b in seen if a != b]
    assert not bad, bad[:3]
    assert fused_calls[0] > 0.8 * len(seen)
    asked = {v for v, _t, _a, _b in seen}  # the views the solver's stages ran in
    fused = {v.name for v, p in sim.engine._plans.items() if p.fused is not None}
    assert asked <= fused
    if name == "press-cycle":
        assert {"free", "locked", "held"} <= set(traj.structure.tolist())


def _paper(**kw):
    return build(load_scene("paper").with_overrides(scheme="autodiff", solver="rk4", **kw))


def test_a_parameter_or_control_set_makes_the_function_again():
    sim = _paper()
    eng, view = sim.engine, sim.view
    q, v = sim.solver.q.tolist(), (sim.solver.qd + 0.3).tolist()
    first = eng.accelerations(view, 0.0, q, v)
    assert eng._plans[view].fused is not None
    motor = next(e for e in eng.effects if e.kind == "motor")
    other = _paper()  # another run in the same process: its counter never moves for this one
    version, others = eng.version[0], other.engine.version[0]
    motor.ratio = 2.0 * motor.ratio
    assert eng.version[0] > version and other.engine.version[0] == others
    # the controls move the counter of an engine whose effects read them (press-cycle's
    # cylinders), and no other's
    cycle = build(load_scene("press-cycle").with_overrides(scheme="autodiff"))
    before, mine = cycle.engine.version[0], eng.version[0]
    cycle.controls.engage_on = not cycle.controls.engage_on
    assert cycle.engine.version[0] > before and eng.version[0] == mine
    second = eng.accelerations(view, 0.0, q, v)
    assert second != first
    assert second == eng._solve_on_floats(view, 0.0, q, v)[3]
    motor.enabled = False
    third = eng.accelerations(view, 0.0, q, v)
    assert third == eng._solve_on_floats(view, 0.0, q, v)[3]
    assert third not in (first, second)
    assert "/ 157.0" not in eng._plans[view].fused.source  # the motor's law left out


class _Exponential(Effect):
    """A torque law that calls math on the state: it cannot be traced."""

    kind = "exponential"

    def generalized_force(self, t, kin):
        m = -math.exp(-abs(kin.rate("crank")))
        return [m * w for w in kin.omega("crank")]

    def loads(self, t, kin):
        raise NotImplementedError


def test_an_effect_that_cannot_be_traced_keeps_the_general_path():
    sim = _paper()
    eng, view = sim.engine, sim.view
    eng.effects.append(_Exponential())
    q, v = sim.solver.q.tolist(), sim.solver.qd.tolist()
    out = eng.accelerations(view, 0.0, q, v)
    assert eng._plans[view].fused is None
    assert out == eng._solve_on_floats(view, 0.0, q, v)[3]


def test_only_the_effects_the_scene_names_are_in_the_code():
    sim = _paper()
    eng, view = sim.engine, sim.view
    q, v = sim.solver.q.tolist(), sim.solver.qd.tolist()
    eng.accelerations(view, 0.0, q, v)
    plain = eng._plans[view].fused.source
    assert "tanh(" not in plain
    sim = _paper()
    eng, view = sim.engine, sim.view
    friction = JointFriction(coulomb=0.5, viscous=0.01)
    friction.bind(sim.mechanism)
    eng.effects.append(friction)
    out = eng.accelerations(view, 0.0, q, v)
    source = eng._plans[view].fused.source
    assert source.count("tanh(") == 4  # one joint each: O, A, B, C
    assert out == eng._solve_on_floats(view, 0.0, q, v)[3]


def test_a_state_outside_the_trace_falls_back_and_gets_its_own_function():
    """The engage cylinder's ramp: traced inside it, asked beyond its end (another branch of
    the law) the engine makes a second function and keeps both."""
    sim = build(load_scene("press-cycle").with_overrides(scheme="autodiff", solver="rk4"))
    eng = sim.engine
    seen, _ = _spy(eng, sim)
    sim.run(0.4, 1e-3)
    assert all(a == b for _v, _t, a, b in seen)
    assert any(p.fused_others for p in eng._plans.values())


def test_a_generated_step_calling_the_fused_function_gives_the_same_run():
    """rk8's stages call the fused function directly (the accelerator where it misses): the
    press cycle through its structures, impacts and the force laws' branches comes out bit for
    bit as with every stage through the accelerator, with the same work counted."""
    scene = load_scene("press-cycle").with_overrides(scheme="autodiff", solver="rk8")
    direct = build(scene)
    s = direct.solver
    direct._restart(direct.view, s.t, s.q, s.qd)  # as the other one below
    a = direct.run(0.5, 2e-3)
    plain = build(scene)
    accelerator = plain.engine.accelerator

    def no_direct(view):
        accel = accelerator(view)
        accel.direct = lambda: None
        return accel

    plain.engine.accelerator = no_direct
    s = plain.solver
    plain._restart(plain.view, s.t, s.q, s.qd)
    b = plain.run(0.5, 2e-3)
    assert {"free", "locked", "held"} <= set(a.structure.tolist())
    # some stages missed (a force law's other branch) and went through the accelerator
    assert any(p.fused_tries for p in direct.engine._plans.values())
    assert np.array_equal(a.phi, b.phi) and np.array_equal(a.psi_dot, b.psi_dot)
    assert a.counts["evaluations"] == b.counts["evaluations"]
    assert a.counts["solver_evaluations"] == b.counts["solver_evaluations"]


def test_a_fused_evaluation_that_is_not_finite_leaves_the_answer_to_the_kernel():
    """Where the fused whole evaluation gives None (q̈ not finite) the evaluation is the exact
    kernel's and the effects', which raise the engine's own error where there is one."""
    sim = _paper()
    eng, view = sim.engine, sim.view
    q, v = sim.solver.q, sim.solver.qd + 0.2
    ref = eng.evaluate(view, 0.0, q, v).qdd.tolist()
    fused = eng._plans[view].fused
    calls = []

    def not_finite(*a):
        calls.append(a)
        return None

    full = fused.full
    fused.full = not_finite
    try:
        assert eng.evaluate(view, 0.0, q, v).qdd.tolist() == ref
    finally:
        fused.full = full
    assert calls


@pytest.mark.parametrize("name", preset_names())
def test_central_tails_give_the_effects_one_by_one_and_the_solve(name):
    """With the seed's central differences the effects and the solve after the central
    kernel are one traced call (fused_kernels.central_tail): along a run of each preset
    through its structures, charts, impacts and commands, Q, Q_nc and q̈ are those of the
    effects called one by one and the solve, bit for bit, and the tails answer most calls."""
    from mps_core.codegen.kernels import solve_given_h
    from mps_core.derivatives.tracing import BranchChanged
    from mps_core.dynamics.engine import Kinematics

    scene = load_scene(name).with_overrides(scheme="central", solver="linear-acceleration")
    sim = build(scene)
    eng = sim.engine
    solve = eng.central.kernel_solve
    calls, by_tail = [0], [0]

    def spied(view, t, q, qd, ql, vl, plan):
        tail_before = plan.tail
        kin, A, h, Q, Qnc, qdd = solve(view, t, q, qd, ql, vl, plan)
        try:
            xl, jl, wl, A2, h2, wb = (plan.inline or plan.kernel)(*ql, *vl)
        except BranchChanged:
            xl, jl, wl, A2, h2, wb = plan.kernel(*ql, *vl)
        one_by_one = Kinematics(
            t,
            None,
            None,
            eng.maps.names,
            bodies=eng.maps.body_index,
            lists=(xl, jl, wl),
            side=(wb, plan.inv2d),
            v=list(vl),
        )
        Q2, Qnc2 = eng.forces.generalized(t, one_by_one)
        assert (A, h, Q, Qnc, qdd) == (A2, h2, Q2, Qnc2, solve_given_h(A2, h2, Q2)), (view.name, t)
        calls[0] += 1
        by_tail[0] += plan.tail is not None and plan.tail is tail_before
        return kin, A, h, Q, Qnc, qdd

    eng.central.kernel_solve = spied
    sim.run(min(scene.t_end, 0.6), 1e-3)
    assert calls[0] > 100
    assert by_tail[0] > 0.8 * calls[0], (by_tail[0], calls[0])


def test_a_live_effects_values_are_read_at_each_call_and_never_shared():
    """An estimator's unknown inputs (``live``: changed in place at every measurement) are
    inputs of the fused function read at each call: the same function gives the general path's
    q̈ at every value, and two engines' values never mix."""
    from mps_core.track import Tracker
    from mps_core.track.truth import nominal_scene

    scene = nominal_scene(load_scene("working").with_overrides(scheme="autodiff"))
    a, b = Tracker(scene), Tracker(scene)
    eng, view = a.sim.engine, a.sim.view
    q, v = a.sim.solver.q.tolist(), a.sim.solver.qd.tolist()
    before = eng.accelerations(view, 0.0, q, v)
    plan = eng._plans[view]
    fused, version = plan.fused, eng.version[0]
    assert fused is not None and "_live0[0]" in fused.source and "_live0[1]" in fused.source
    a.inputs.set(2.0e4, -3.0)
    after = eng.accelerations(view, 0.0, q, v)
    assert plan.fused is fused and eng.version[0] == version  # no code made again
    assert after != before
    _check_whole_evaluation(eng, view, plan, 0.0, q, v)  # the general path's numbers
    b.inputs.set(-5.0e3, 7.0)
    other = b.sim.engine.accelerations(b.sim.view, 0.0, q, v)
    assert b.sim.engine._plans[b.sim.view].fused is not fused
    assert other not in (before, after)
    assert eng.accelerations(view, 0.0, q, v) == after  # b's values are b's alone
    # the reactions' known loads read them too: the general sums at each value, bit for bit
    from mps_core.dynamics.reactions import kernels_of

    sums = kernels_of(a.sim.mechanism).loads(eng.effects)
    fun = eng.evaluator(view)
    for force in (1.0e4, -2.0e4):
        a.inputs.set(force, 1.5)
        e = fun(0.0, np.array(q), np.array(v))
        assert sums(0.0, e.kin) == sums.sums(0.0, e.kin)
    assert any("_live0[0]" in fn.source for fns in sums._traced.values() for fn in fns)
