"""Reaction kernels (mps_core.codegen.reaction_kernels) against the general Newton–Euler solution of
mps_core.dynamics.reactions: the same reactions, residuals and balance on every structure, at every
step of a press cycle (impacts and chart changes among them), with exact and with the seed's
central derivatives; the general path wherever the kernel does not hold."""

import math

import numpy as np
import pytest

from mps_core import build, load_scene
from mps_core.codegen.reaction_kernels import PIVOT_GUARD, Fallback
from mps_core.derivatives.tracing import BranchChanged
from mps_core.dynamics.reactions import REACTION_COLUMNS, compute_reactions, kernels_of, reaction_values

FORCES = [c for c in REACTION_COLUMNS if not c.startswith(("residual", "balance"))]
DT = 1e-3


def cycle(scheme: str, t_end: float = 1.0):
    """(simulation, states): press-cycle at 1 kHz in ``scheme``, the evaluation of every step
    (free, held and locked, with the engage, latch, disengage and stop impacts on the way)."""
    scene = load_scene("press-cycle").with_overrides(dt=DT, t_end=t_end, scheme=scheme)
    sim = build(scene)
    n = round(t_end / DT)
    states = [(sim.solver.current, sim.structure)]
    for k in range(1, n + 1):
        sim.advance_to(k * t_end / n)
        states.append((sim.solver.current, sim.structure))
    return sim, states


def from_kinematics(sim, e) -> bool:
    """Whether the evaluation's kinematics carry the bodies' motion (an exact kernel's): the
    reaction kernel then reads it instead of running the position function forward."""
    cv = e.kin._conv
    return cv is not None and len(cv) == 3 * len(sim.mechanism.bodies)


def call(kernel, sim, e, loads):
    """A reaction kernel (either kind) at an evaluation, on the given load sums."""
    ql, vl, al = e.q.tolist(), e.qd.tolist(), e.qdd.tolist()
    if from_kinematics(sim, e):
        return kernel(*ql, *vl, *al, e.kin._xl, e.kin._jl, e.kin._wl, e.kin._conv, loads)
    return kernel(*ql, *vl, *al, loads)


def both(sim, e):
    """(kernel's values, general path's Reactions) at an evaluation."""
    fast = reaction_values(
        sim.mechanism, sim.engine.effects, e.view, e.t, e.q.tolist(), e.qd.tolist(), e.qdd.tolist(), e.kin
    )
    ref = compute_reactions(
        sim.mechanism, sim.engine.effects, e.view, e.t, e.q, e.qd, e.qdd, kin=e.kin, kernel=False
    )
    return fast, ref


@pytest.fixture(scope="module")
def exact_cycle():
    return cycle("autodiff")


@pytest.fixture(scope="module")
def central_cycle():
    return cycle("central", t_end=0.6)


def test_exact_kernel_equals_newton_euler_on_every_structure(exact_cycle):
    sim, states = exact_cycle
    seen = {}
    times = {}
    for e, structure in states:
        fast, ref = both(sim, e)
        assert fast is not None, f"no kernel at t = {e.t} in {e.view.name}"
        values, residual, unknowns = fast
        got = dict(zip(REACTION_COLUMNS, values))
        big = max(abs(ref.values[c]) for c in FORCES)
        for c in FORCES:
            assert abs(got[c] - ref.values[c]) <= 1e-9 * big, (c, e.t, got[c], ref.values[c])
        assert unknowns == ref.unknowns and len(unknowns) == ref.rank
        # the same leftover, and the whole machine's balance at round-off
        np.testing.assert_allclose(residual, ref.residual, rtol=0, atol=1e-10 * big)
        for c in ("residual_force_N", "residual_moment_Nm"):
            assert got[c] == pytest.approx(ref.values[c], rel=1e-6, abs=1e-10 * big)
        assert got["balance_residual_N"] <= 1e-10 * big, (e.t, got["balance_residual_N"])
        assert got["balance_residual_Nm"] <= 1e-10 * big * 0.05
        seen[structure] = seen.get(structure, 0) + 1
        times.setdefault(e.view.name, []).append(e.t)
    assert set(seen) == {"free", "held", "locked"}, seen
    assert len(times) >= 4, list(times)  # several charts, not one
    # exact kinematics: every kernel read the evaluation's motion, none ran the trace again
    assert all(from_kinematics(sim, e) for e, _ in states)
    ks = kernels_of(sim.mechanism)
    assert {k[0].name for k in ks.views if len(k) == 3 and ks.views[k]} >= set(times)
    # the states next to every impact and chart change were among those compared
    marks = [
        ev["t"]
        for ev in sim.events
        if ev["kind"] in ("chart", "latch-closes", "stop-reached", "stop-release")
    ]
    assert len(marks) >= 5
    stepped = np.array([e.t for e, _ in states])
    for t in marks:
        assert np.min(np.abs(stepped - t)) <= DT


def test_central_kernel_equals_the_least_squares_and_its_residual(central_cycle):
    """The seed's central differences: q̈ leaves an O(Δ²) residual in the exact equations; the
    kernel's leftover is the general least squares' own, and so are the reactions."""
    sim, states = central_cycle
    largest_residual = 0.0
    for e, _structure in states:
        fast, ref = both(sim, e)
        assert fast is not None
        got = dict(zip(REACTION_COLUMNS, fast[0]))
        big = max(abs(ref.values[c]) for c in FORCES)
        bound = 1e-9 * big + ref.values["residual_force_N"] + ref.values["residual_moment_Nm"]
        for c in FORCES:
            assert abs(got[c] - ref.values[c]) <= bound, (c, e.t)
        for c in ("residual_force_N", "residual_moment_Nm"):
            assert got[c] == pytest.approx(ref.values[c], rel=1e-6, abs=1e-9 * big), (c, e.t)
        assert got["balance_residual_N"] <= 1e-10 * big
        largest_residual = max(largest_residual, ref.values["residual_force_N"] / big)
    assert largest_residual > 1e-8  # the residual is there (Δ = 0.1°), not round-off


def test_compute_reactions_takes_the_kernel_and_keeps_the_reference(exact_cycle):
    sim, states = exact_cycle
    e, _ = states[300]
    a = compute_reactions(sim.mechanism, sim.engine.effects, e.view, e.t, e.q, e.qd, e.qdd, kin=e.kin)
    b = compute_reactions(
        sim.mechanism, sim.engine.effects, e.view, e.t, e.q, e.qd, e.qdd, kin=e.kin, kernel=False
    )
    assert a.unknowns == b.unknowns and a.rank == b.rank
    big = max(abs(b.values[c]) for c in FORCES)
    for c in FORCES:
        assert a.values[c] == pytest.approx(b.values[c], abs=1e-9 * big)
    # a drive torque (kinetostatics) is the general path's alone: the same result either way
    d1 = compute_reactions(
        sim.mechanism, sim.engine.effects, e.view, e.t, e.q, e.qd, e.qdd, kin=e.kin, drive="crank"
    )
    d2 = compute_reactions(
        sim.mechanism,
        sim.engine.effects,
        e.view,
        e.t,
        e.q,
        e.qd,
        e.qdd,
        kin=e.kin,
        drive="crank",
        kernel=False,
    )
    assert d1.values == d2.values


def test_a_failed_guard_falls_back_to_the_general_path(exact_cycle, monkeypatch):
    sim, states = exact_cycle
    e, _ = states[500]
    ks = kernels_of(sim.mechanism)
    key = (e.view, ks.scale, True)
    assert (
        reaction_values(
            sim.mechanism, sim.engine.effects, e.view, e.t, e.q.tolist(), e.qd.tolist(), e.qdd.tolist(), e.kin
        )
        is not None
    )  # made here
    kernel, unknowns = ks.views[key]

    def singular(*a):
        raise Fallback("a pivot below its guard")

    monkeypatch.setitem(ks.views, key, (singular, unknowns))
    monkeypatch.setattr(ks, "last", {})  # the function made from the kernel replaced
    assert (
        reaction_values(
            sim.mechanism, sim.engine.effects, e.view, e.t, e.q.tolist(), e.qd.tolist(), e.qdd.tolist(), e.kin
        )
        is None
    )
    a = compute_reactions(sim.mechanism, sim.engine.effects, e.view, e.t, e.q, e.qd, e.qdd, kin=e.kin)
    b = compute_reactions(
        sim.mechanism, sim.engine.effects, e.view, e.t, e.q, e.qd, e.qdd, kin=e.kin, kernel=False
    )
    assert a.values == b.values
    # the guard itself: the pivots that vary with the state are checked against their size
    # (the constant ones, ±1 of a force balance, once when the kernel is written)
    assert kernel.source.count("_fallback()") >= 3
    assert 0.0 < PIVOT_GUARD < 1e-3


def test_a_kernel_holds_no_general_linear_algebra(exact_cycle):
    """Straight-line float code: no numpy, no least squares, no loops."""
    sim, states = exact_cycle
    ks = kernels_of(sim.mechanism)
    for kernel, _unknowns in (v for v in ks.views.values() if v is not None):
        src = kernel.source
        assert "np." not in src and "lstsq" not in src and "for " not in src
        assert math.isfinite(len(src))


@pytest.mark.parametrize("fixture", ["exact_cycle", "central_cycle"])
def test_traced_load_sums_are_the_loads_summed_one_by_one(fixture, request):
    """The known loads a kernel takes, by generated code (the effects' laws traced, their
    parameters and the controls folded in): the general sums bit for bit at every step of the
    cycle, the generated code answering nearly all of them."""
    sim, states = request.getfixturevalue(fixture)
    sums = kernels_of(sim.mechanism).loads(sim.engine.effects)
    original = sums.sums
    general = [0]

    def counted(t, kin, live=None):
        if isinstance(t, float):  # not a trace
            general[0] += 1
        return original(t, kin, live)

    sums.sums = counted
    try:
        for e, _structure in states:
            got = sums(e.t, e.kin)
            assert got == original(e.t, e.kin), e.t
    finally:
        del sums.sums
    assert sums._traced and general[0] < 0.1 * len(states)


@pytest.mark.parametrize("fixture", ["exact_cycle", "central_cycle"])
def test_the_kernel_with_its_loads_is_the_two_one_after_the_other(fixture, request):
    """The traced load sums and the reaction kernel as one function (with_loads): the kernel
    on the sums, bit for bit, at every step of the cycle; it answers nearly all of them."""
    from mps_core.codegen.reaction_kernels import with_loads

    sim, states = request.getfixturevalue(fixture)
    ks = kernels_of(sim.mechanism)
    sums = ks.loads(sim.engine.effects)
    answered = 0
    for e, _structure in states:
        ql, vl, al = e.q.tolist(), e.qd.tolist(), e.qdd.tolist()
        fast = reaction_values(sim.mechanism, sim.engine.effects, e.view, e.t, ql, vl, al, e.kin)
        moving = from_kinematics(sim, e)
        assert moving is (fixture == "exact_cycle")
        entry = ks.get(e.view, ql, ks.scale, moving)
        if fast is None or entry is None:
            continue
        apart = call(entry[0], sim, e, sums(e.t, e.kin))
        assert (fast[0], fast[1]) == apart, e.t
        traced = sums.first(e.view.n)
        if traced is None:
            continue
        lists = (e.kin._xl, e.kin._jl, e.kin._wl) + ((e.kin._conv,) if moving else ())
        try:
            joined = with_loads(entry[0], traced)(e.t, *ql, *vl, *al, *lists, e.kin._v())
        except BranchChanged:  # another branch of a force law: the two apart answer
            continue
        assert joined == apart, e.t
        answered += 1
    assert answered > 0.9 * len(states)
