"""The load reports of a vectorised batch's runs at once (mps_core.analysis.batch_loads): each
run's figures as the load report of its own trajectory gives them."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mps_core import scene_from_text
from mps_core.analysis import batch_loads, loads
from mps_core.analysis.sweep import FIGURES, figures, plan
from mps_core.run.batch import run_batch, run_states
from tests.core.test_batch import BLANKING
from tests.core.test_sweep import EXACT_TEXT

#: working with exact derivatives, 0.35 s at 0.5 ms: 2.4 crank revolutions a run
EXACT = scene_from_text(EXACT_TEXT)
TIMES = dict(t_end=0.35, dt=5e-4)


def _scenes(vary, **times):
    return [r.scene for r in plan(EXACT, vary, **(times or TIMES))]


def _rows_of_trajectories(scenes):
    """Each run's figures from its trajectory (the batch's trajectories, reactions and all)."""
    out = []
    for tr in run_batch(scenes):
        try:
            out.append(figures(loads.load_report(tr.columns, events=tr.events)))
        except loads.LoadReportError as exc:
            out.append(exc)
    return out


def _as_row(res: batch_loads.RunFigures) -> dict:
    row = {"period_s": res.period, "crank_speed_rad_s": loads.TWO_PI / res.period}
    for name, v in zip(res.names, res.values.tolist()):
        row.update({f"{name}.{f}": x for f, x in zip(FIGURES, v)})
        row.update({f"{name}.A{k}": x for k, x in enumerate(v[len(FIGURES) :], 1)})
    return row


def test_each_run_has_the_figures_of_its_own_load_report():
    # the crank speeds differ: the runs' cycles span different numbers of steps (their splines
    # of different lengths in one block)
    scenes = _scenes(["bodies.slider.mass_kg=80:120:3", "effects.motor.crank_speed_rad_s=38,45"])
    got = batch_figures_of(scenes)
    want = _rows_of_trajectories(scenes)
    steps = set()
    for res, row in zip(got, want):
        assert isinstance(res, batch_loads.RunFigures)
        mine = _as_row(res)
        theirs = {k: v for k, v in row.items() if k not in ("impacts", "impulse_found_max_Ns")}
        assert mine.keys() == theirs.keys()
        for k, v in theirs.items():
            scale = max(abs(v), abs(theirs.get(k.rsplit(".", 1)[0] + ".peak", 0.0)))
            assert abs(mine[k] - v) <= 1e-11 * scale, (k, mine[k], v)
        steps.add(round(res.period / TIMES["dt"]))
    assert len(steps) > 1  # the cycles differ in length


def test_forces_along_the_guide_change_the_slider_s_and_the_frame_s_loads():
    # springs with damping and a blanking force act at C: the loads that no state changes
    # without them (the slider's weight along the guide, the frame's) change at every step
    text = EXACT_TEXT.replace("assembly = 1", "assembly = 1\nx_top_mm = 25.5").replace(
        "[solver]",
        """[[effects]]
type = "springs"
stiffness_n_m = 20000.0
preload_n = 2500.0
damping_n_s_m = 300.0

"""
        + BLANKING
        + "[solver]",
    )
    scenes = [
        r.scene for r in plan(scene_from_text(text), ["effects.blanking.thickness_mm=0.5,1.5"], **TIMES)
    ]
    states = run_states(scenes)
    got = batch_loads.batch_figures(states)
    want = _rows_of_trajectories(scenes)
    for res, row in zip(got, want):
        mine = _as_row(res)
        for k in ("|F_found|.peak", "F_found_x.rms", "F_C_x.A1", "N_guide.peak"):
            assert math.isclose(mine[k], row[k], rel_tol=1e-11), k
    assert got[0].values.tolist() != got[1].values.tolist()


def batch_figures_of(scenes):
    return batch_loads.batch_figures(run_states(scenes))


def test_the_cycles_are_the_reports_cycles():
    # 2.4 to 4 revolutions: the first run has no revolution before its last (no change)
    scenes = _scenes(["effects.motor.crank_speed_rad_s=30,40,50"], t_end=0.5, dt=5e-4)
    states = run_states(scenes)
    phi, phi_dot = states.coordinate("phi"), states.coordinate("phi", 1)  # (step, run)
    cyc = batch_loads.cycles(states.t, phi, phi_dot)
    assert not cyc.errors and math.isnan(cyc.change[0]) and not math.isnan(cyc.change[2])
    for r in range(len(scenes)):
        want = loads.last_cycle(states.t, phi[:, r], phi_dot[:, r])
        assert abs(cyc.t0[r] - want.t0) <= 2e-15 and abs(cyc.period[r] - want.period) <= 4e-15
        assert (cyc.i0[r], cyc.i1[r]) == (want.i0, want.i1)
        if math.isnan(want.period_change):
            assert math.isnan(cyc.change[r])
        else:
            assert math.isclose(cyc.change[r], want.period_change, rel_tol=1e-9, abs_tol=1e-15)


def test_a_run_without_a_full_revolution_gets_the_reports_error():
    # from 0 deg the crank passes 360 deg once in 0.2 s; from 300 deg, twice
    scenes = _scenes(["initial.phi_deg=0,300"], t_end=0.2, dt=5e-4)
    got = batch_figures_of(scenes)
    want = _rows_of_trajectories(scenes)
    assert isinstance(got[0], loads.LoadReportError) and isinstance(want[0], loads.LoadReportError)
    assert str(got[0]) == str(want[0]) and "no full crank revolution" in str(got[0])
    assert isinstance(got[1], batch_loads.RunFigures) and isinstance(want[1], dict)
    assert math.isclose(got[1].period, want[1]["period_s"], rel_tol=1e-12)


def test_a_batch_in_another_structure_is_refused():
    states = run_states(_scenes(["bodies.slider.mass_kg=80,90"]))
    with pytest.raises(ValueError, match="'free'"):
        batch_loads.batch_figures(states, mode="free")


@pytest.mark.parametrize(
    "lengths",
    [
        [4, 5, 7],  # the fewest knots
        [4, 19, 20, 21, 22],
        [600, 797, 800],  # a cycle's, in a block of unequal lengths
        [851, 850, 851, 851, 850],  # runs of one length share a system
    ],
)
def test_the_splines_slopes_are_scipys_not_a_knot_splines(lengths):
    from scipy.interpolate import CubicSpline

    rng = np.random.default_rng(len(lengths))
    h, L = 2e-4, max(lengths)
    Y = np.sin(np.arange(L) * h * 60.0 + rng.uniform(0, 6, (3, len(lengths), 1))) * rng.uniform(
        1e2, 1e5, (3, len(lengths), 1)
    ) + rng.normal(0, 1.0, (3, len(lengths), L))
    s = batch_loads._slopes(Y, np.array(lengths), h)
    for r, k in enumerate(lengths):
        x = np.arange(k) * h
        for q in range(3):
            want = CubicSpline(x, Y[q, r, :k])(x, 1)
            assert np.max(np.abs(s[q, r, :k] - want)) <= 1e-12 * np.max(np.abs(want)), (k, q)
            assert not s[q, r, k:].any()  # a run's rows beyond its own


def test_the_reports_reactions_are_the_full_kernels_columns_bit_for_bit():
    # the reports' kernel computes only the columns they read (no residuals): those the same
    from mps_core.dynamics.reactions import REACTION_COLUMNS

    states = run_states(_scenes(["bodies.slider.mass_kg=80,90,100"]))
    steps = np.broadcast_to(np.arange(0, states.k, 7), (3, len(range(0, states.k, 7))))
    every = states.reactions(steps)
    some = states.reactions(steps, columns=batch_loads.COLUMNS)
    assert set(some) == set(batch_loads.COLUMNS) < set(every) == set(REACTION_COLUMNS)
    assert "residual_force_N" not in some
    for c, v in some.items():
        assert np.array_equal(v, every[c]), c
