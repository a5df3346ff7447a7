"""Scalar kernels (mps_core.codegen.kernels): the same numbers as the engine's array code."""

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
from mps_core.model.press import PressMechanism


def _scene_engines(name="press-cycle"):
    return scene_engines(name, "central")


MECH, CONTROLS, KERNEL, ARRAY = _scene_engines()
VIEWS = [(s, v) for s in ("free", "locked", "held") for v in MECH.views(s)]


def _close(a, b, scale):
    return close(a, b, scale, 1e-9)


@settings(max_examples=60, deadline=None)
@given(
    k=st.integers(0, len(VIEWS) - 1),
    u=st.floats(-math.pi, math.pi),
    w=st.floats(-0.5, 0.5),
    v0=st.floats(-20, 20),
    v1=st.floats(-5, 5),
)
def test_kernel_evaluation_equals_the_array_code(k, u, w, v0, v1):
    structure, view = VIEWS[k]
    CONTROLS.structure = structure
    q, qd = np.array(state(view, u, w)), np.array([v0, v1][: view.n])
    try:
        a = ARRAY.evaluate(view, 0.0, q, qd)
    except ChartDomainError:
        with pytest.raises(ChartDomainError):
            KERNEL.evaluate(view, 0.0, q, qd)
        return
    if view.regularity(a.kin.pose) < 0.05:
        return  # near a chart's singularity both lose digits differently
    e = KERNEL.evaluate(view, 0.0, q, qd)
    assert KERNEL._plans[view].kernel is not None
    assert _close(e.A, a.A, np.abs(a.A).max())
    assert _close(e.h, a.h, np.abs(a.h).max() + np.abs(a.Q).max())
    assert _close(e.Q, a.Q, np.abs(a.Q).max() + 1.0)
    assert _close(e.qdd, a.qdd, np.abs(a.qdd).max() + 1.0)
    assert _close(e.kin.X, a.kin.X, 0.1)
    assert _close(e.kin.J, a.kin.J, np.abs(a.kin.J).max())
    assert _close(e.kin.W, a.kin.W, np.abs(a.kin.W).max())


def test_kernels_count_the_same_work():
    q, qd = np.array([0.3, -0.1]), np.array([10.0, 1.0])
    view = MECH.views("free")[0]
    for eng in (KERNEL, ARRAY):
        before = dict(eng.counts)
        eng.evaluate(view, 0.0, q, qd)
        assert eng.counts["evaluations"] - before["evaluations"] == 1
        assert eng.counts["position_points"] - before["position_points"] == 13


@pytest.mark.parametrize("x_top", [None, 0.0255, 0.025])
def test_flat_positions_equal_the_chart_positions(x_top):
    mech = PressMechanism(x_top=x_top)
    rng = np.random.default_rng(3)
    seen = 0
    for chart in mech.charts:
        for _ in range(200):
            q = [rng.uniform(-math.pi, math.pi), rng.uniform(-0.02, 0.06)]
            if chart.coordinates[1].name == "psi":
                q[1] = rng.uniform(-0.6, 0.6)
            try:
                pose = chart.positions(q)
            except ChartDomainError:
                with pytest.raises(ChartDomainError):
                    chart.flat(*q)
                continue
            flat = chart.flat(*q)
            ref = [float(c) for p in mech.points for c in pose[p]]
            assert np.allclose(flat, ref, rtol=1e-14, atol=1e-17)
            seen += 1
    assert seen > 500


def test_a_run_with_kernels_follows_the_array_run():
    sc = load_scene("press-cycle")
    a = build(sc).run(0.5, 1e-3)
    slow = build(dataclasses.replace(sc, solver=dataclasses.replace(sc.solver, kernels=False)))
    assert slow.engine.kernels is False
    b = slow.run(0.5, 1e-3)
    assert [e["kind"] for e in a.events] == [e["kind"] for e in b.events]
    assert np.abs(a.phi - b.phi).max() < 1e-8
    assert np.abs(a.psi - b.psi).max() < 1e-8
    # reported rates of an angle that is no coordinate of the chart: the kernel's central
    # differences against the array code's exact jets: apart by the scheme's O(Δ²), no more
    for name in ("phi_dot", "psi_dot", "phi_ddot", "psi_ddot"):
        x, y = getattr(a, name), getattr(b, name)
        assert np.abs(x - y).max() < 1e-5 * np.abs(y).max(), name


def test_no_flat_positions_means_the_array_code():
    mech, controls, eng, _ = _scene_engines("paper")
    view = mech.views("free")[0]
    chart = dataclasses.replace(view.chart, flat=None)
    from mps_core.model.mechanism import ChartView

    v2 = ChartView(chart)
    e = eng.evaluate(v2, 0.0, np.array([0.3, -0.1]), np.array([10.0, 1.0]))
    assert eng._plans[v2].kernel is None
    assert np.all(np.isfinite(e.qdd))


@settings(max_examples=40, deadline=None)
@given(k=st.integers(0, len(VIEWS) - 1), u=st.floats(-math.pi, math.pi), w=st.floats(-0.5, 0.5))
def test_the_inlined_kernel_equals_the_calling_kernel(k, u, w):
    """The traced position function written out at each stencil point gives the numbers of the
    kernel that calls it there."""
    structure, view = VIEWS[k]
    CONTROLS.structure = structure
    q = state(view, u, w)
    plan = KERNEL._plan(view)
    from mps_core.codegen.kernels import central_kernel

    try:
        calling = plan.kernel(*q, *[3.0, -1.0][: view.n])
    except (ChartDomainError, ValueError, ZeroDivisionError):
        return
    try:
        inline = central_kernel(KERNEL, view, plan, q)
    except ChartDomainError:
        return  # the stencil reaches outside the domain at the traced q
    if "~" in view.name:
        assert inline is None  # the continuation chart's math functions: not traced
        return
    out = inline(*q, *[3.0, -1.0][: view.n])
    for a, b in zip(out, calling):
        assert np.allclose(np.asarray(a, float), np.asarray(b, float), rtol=1e-14, atol=1e-300)


def test_an_inlined_kernel_on_another_branch_hands_over_to_the_calling_one():
    mech, controls, eng, arr = _scene_engines("paper")
    view = mech.views("free")[0]
    flat = view.chart.flat

    def branching(phi, psi, cos=math.cos, sin=math.sin, sqrt=math.sqrt):
        if phi > 0.5:
            return flat(phi, psi, cos, sin, sqrt)
        return flat(phi, psi, cos=cos, sin=sin, sqrt=sqrt)

    from mps_core.model.mechanism import ChartView

    v2 = ChartView(dataclasses.replace(view.chart, flat=branching))
    qd = np.array([10.0, 1.0])
    eng.evaluate(v2, 0.0, np.array([0.3, -0.1]), qd)
    assert eng._plans[v2].inline is not None
    for phi in (0.2, 0.9, 0.499):  # 0.499: only some stencil points cross
        e = eng.evaluate(v2, 0.0, np.array([phi, -0.1]), qd)
        a = arr.evaluate(view, 0.0, np.array([phi, -0.1]), qd)
        assert _close(e.qdd, a.qdd, np.abs(a.qdd).max() + 1.0)
