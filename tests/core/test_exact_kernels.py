"""Exact kernels (mps_core.codegen.exact_kernels): the jets' numbers, on floats."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from kernel_cases import close, scene_engines, state

from mps_core import build, load_scene
from mps_core.errors import ChartDomainError
from mps_core.model.mechanism import ChartView


def _scene_engines(name="press-cycle"):
    return scene_engines(name, "autodiff")


MECH, CONTROLS, KERNEL, JETS = _scene_engines()
VIEWS = [(s, v) for s in ("free", "locked", "held") for v in MECH.views(s)]


def _close(a, b, scale):
    return close(a, b, scale, 1e-10)


def _state(view, u, w, v0, v1):
    return np.array(state(view, u, w)), np.array([v0, v1][: view.n])


@settings(max_examples=80, deadline=None)
@given(
    k=st.integers(0, len(VIEWS) - 1),
    u=st.floats(-math.pi, math.pi),
    w=st.floats(-0.5, 0.5),
    v0=st.floats(-20, 20),
    v1=st.floats(-5, 5),
)
def test_exact_kernel_evaluation_equals_the_jets(k, u, w, v0, v1):
    structure, view = VIEWS[k]
    CONTROLS.structure = structure
    q, qd = _state(view, u, w, v0, v1)
    try:
        a = JETS.evaluate(view, 0.0, q, qd)
    except ChartDomainError:
        with pytest.raises(ChartDomainError):
            KERNEL.evaluate(view, 0.0, q, qd)
        return
    if view.regularity(a.kin.pose) < 0.05:
        return  # near a chart's singularity both lose digits differently
    e = KERNEL.evaluate(view, 0.0, q, qd)
    plan = KERNEL._plans[view]
    assert plan.exact_traced
    if "~" in view.name:
        # the continuation chart's positions call math's functions directly: not traceable
        assert plan.exact is None
    else:
        assert plan.exact is not None
        assert e.kin._conv is not None
    assert _close(e.A, a.A, np.abs(a.A).max())
    assert _close(e.h, a.h, np.abs(a.h).max() + np.abs(a.Q).max())
    assert _close(e.Q, a.Q, np.abs(a.Q).max() + 1.0)
    assert _close(e.qdd, a.qdd, np.abs(a.qdd).max() + 1.0)
    assert _close(e.kin.X, a.kin.X, 0.1)
    assert _close(e.kin.J, a.kin.J, np.abs(a.kin.J).max())
    assert _close(e.kin.W, a.kin.W, np.abs(a.kin.W).max())
    if plan.exact is not None:
        # the bodies' angular accelerations at q̈ = 0 against the jets'
        _, _, _, theta2 = JETS.exact.kinematics(view, 0.0, q, qd)
        conv = [e.kin._conv[k] for k in KERNEL.maps.rot]
        assert _close(conv, theta2, np.abs(theta2).max() + 1.0)


def test_exact_kernels_count_the_same_work():
    q, qd = np.array([0.3, -0.1]), np.array([10.0, 1.0])
    view = MECH.views("free")[0]
    CONTROLS.structure = "free"
    for eng in (KERNEL, JETS):
        before = dict(eng.counts)
        eng.evaluate(view, 0.0, q, qd)
        assert eng.counts["evaluations"] - before["evaluations"] == 1
        assert eng.counts["position_points"] - before["position_points"] == 1
        assert eng.counts["position_calls"] - before["position_calls"] == 1
    assert KERNEL._plans[view].exact is not None


def test_a_domain_error_at_the_first_point_builds_nothing_yet():
    mech, controls, eng, _ = _scene_engines("paper")
    view = mech.views("free")[0]
    with pytest.raises(ChartDomainError):
        eng.evaluate(view, 0.0, np.array([-1.5708, 1.5708]), np.array([1.0, 0.0]))  # rod across
    assert not eng._plans[view].exact_traced
    eng.evaluate(view, 0.0, np.array([0.3, -0.1]), np.array([10.0, 1.0]))
    assert eng._plans[view].exact is not None
    # outside the domain later: the position function's own error, from the kernel's guard
    with pytest.raises(ChartDomainError, match="rod across the guide"):
        eng.evaluate(view, 0.0, np.array([-1.5708, 1.5708]), np.array([1.0, 0.0]))


def test_another_branch_gets_a_kernel_of_its_own(monkeypatch):
    """A position function that branches: where the traced comparison comes out otherwise, that
    branch's kernel is traced there (once) and taken; back on the first branch the first kernel
    is taken again; the same numbers as the jets everywhere, and the jets never run."""
    from mps_core.dynamics.exact import ExactScheme

    mech, controls, eng, jets = _scene_engines("paper")
    view = mech.views("free")[0]
    flat = view.chart.flat
    calls = []

    def branching(phi, psi, cos=math.cos, sin=math.sin, sqrt=math.sqrt):
        calls.append(phi)
        if phi > 0.5:
            return flat(phi, psi, cos, sin, sqrt)
        return flat(phi, psi, cos=cos, sin=sin, sqrt=sqrt)

    v2 = ChartView(dataclasses.replace(view.chart, flat=branching))
    qd = np.array([10.0, 1.0])
    eng.evaluate(v2, 0.0, np.array([0.3, -0.1]), qd)  # traced with phi <= 0.5
    plan = eng._plans[v2]
    first = plan.exact
    assert first is not None
    ran_jets = []
    original = ExactScheme.jets_evaluate
    monkeypatch.setattr(
        ExactScheme,
        "jets_evaluate",
        lambda self, *a: (self.engine is eng and ran_jets.append(a)) or original(self, *a),
    )
    kernels = []
    for phi in (0.2, 0.9, 0.4, 0.95, 0.1):
        e = eng.evaluate(v2, 0.0, np.array([phi, -0.1]), qd)
        a = jets.evaluate(view, 0.0, np.array([phi, -0.1]), qd)
        assert _close(e.qdd, a.qdd, np.abs(a.qdd).max() + 1.0)
        kernels.append(plan.exact)
    assert not ran_jets
    assert kernels[0] is first and kernels[2] is first and kernels[4] is first
    assert kernels[1] is not first and kernels[3] is kernels[1]
    # one trace a branch
    assert sum(1 for c in calls if not isinstance(c, float)) == 2


def test_an_untraceable_chart_keeps_the_jets():
    mech, controls, eng, _ = _scene_engines("paper")
    view = mech.views("free")[0]
    flat = view.chart.flat

    def opaque(phi, psi, cos=math.cos, sin=math.sin, sqrt=math.sqrt):
        return flat(phi, psi, math.cos, math.sin, math.sqrt)  # math's own: no trace

    v2 = ChartView(dataclasses.replace(view.chart, flat=opaque))
    e = eng.evaluate(v2, 0.0, np.array([0.3, -0.1]), np.array([10.0, 1.0]))
    assert eng._plans[v2].exact_traced and eng._plans[v2].exact is None
    assert np.all(np.isfinite(e.qdd))


def test_a_run_with_exact_kernels_follows_the_jets():
    sc = load_scene("press-cycle").with_overrides(scheme="autodiff", t_end=0.5)
    a = build(sc).run(0.5, 1e-3)
    slow = build(dataclasses.replace(sc, solver=dataclasses.replace(sc.solver, kernels=False)))
    b = slow.run(0.5, 1e-3)
    assert [e["kind"] for e in a.events] == [e["kind"] for e in b.events]
    assert max(abs(x["t"] - y["t"]) for x, y in zip(a.events, b.events)) < 1e-12
    for name in ("phi", "psi", "phi_dot", "psi_dot"):
        x, y = getattr(a, name), getattr(b, name)
        assert np.abs(x - y).max() < 1e-9 * (1.0 + np.abs(y).max()), name
    for name in ("phi_ddot", "psi_ddot"):
        x, y = getattr(a, name), getattr(b, name)
        assert np.abs(x - y).max() < 1e-9 * np.abs(y).max(), name
    assert a.counts == b.counts


def test_kernels_are_shared_between_equal_mechanisms_only():
    """A second engine of the same scene takes the first one's kernel (no trace); a press
    with another rod length gets its own, whose numbers are its jets'."""
    from mps_core.codegen.emitter import function_key

    scene = load_scene("paper").with_overrides(scheme="autodiff")
    a, b = build(scene), build(scene)
    assert a.engine._plans[a.view].exact is b.engine._plans[b.view].exact
    longer = dataclasses.replace(
        scene, geometry=dataclasses.replace(scene.geometry, l2=scene.geometry.l2 * 1.1)
    )
    c = build(longer)
    assert function_key(c.view.chart.flat) != function_key(a.view.chart.flat)
    assert function_key(b.view.chart.flat) == function_key(a.view.chart.flat)
    kc = c.engine._plans[c.view].exact
    assert kc is not a.engine._plans[a.view].exact
    q, qd = c.solver.q, c.solver.qd + 0.3
    e = c.engine.evaluate(c.view, 0.0, q, qd)
    c.engine.kernels = False
    ref = c.engine.evaluate(c.view, 0.0, q, qd)
    assert _close(e.qdd, ref.qdd, np.abs(ref.qdd).max() + 1.0)
    a.engine.kernels = False
    other = a.engine.evaluate(a.view, 0.0, a.solver.q, qd)
    assert not _close(other.qdd, ref.qdd, np.abs(ref.qdd).max() + 1.0)


#: at the change point (x_top = l2 - l3 + l1): the held four-bar passes φ = 2πk with ψ = 0, on
#: the continuation chart, whose branch flips with sin(φ/2) each turn (tests/core/test_structures.py)
CHANGE_POINT = "idle at the change point"


@pytest.mark.parametrize("name", [*__import__("mps_core").preset_names(), CHANGE_POINT])
def test_every_chart_of_every_preset_takes_the_exact_kernels(name, monkeypatch):
    """With exact derivatives, no evaluation of a preset's run (every chart it enters, the
    continuation charts and both branches of theirs included) falls back to the jets."""
    from mps_core.bench.common import change_point_scene
    from mps_core.dynamics.exact import ExactScheme

    scene = change_point_scene() if name == CHANGE_POINT else load_scene(name)
    scene = scene.with_overrides(scheme="autodiff", t_end=min(scene.t_end, 0.3), dt=max(scene.dt, 1e-4))
    sim = build(scene)
    jets = []
    original = ExactScheme.jets_evaluate
    monkeypatch.setattr(
        ExactScheme,
        "jets_evaluate",
        lambda self, view, *a: jets.append(view.name) or original(self, view, *a),
    )
    traj = sim.run(scene.t_end, scene.dt)
    assert sim.engine.counts["evaluations"] >= len(traj) - 1
    assert not jets, f"{len(jets)} evaluations by the jets, in {sorted(set(jets))}"
