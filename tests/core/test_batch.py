"""Batch mode: many scenes in one numpy pass per step, the same trajectories as one by one."""

from dataclasses import replace

import numpy as np
import pytest

from mps_core import load_scene, scene_from_text, simulate
from mps_core.model import BodyData
from mps_core.run.batch import simulate_many

COLS = ("phi", "phi_dot", "phi_ddot", "psi", "x_C", "T", "V", "W")


#: a blanking force's effect table, to put before a scene file's [solver]
BLANKING = """[[effects]]
type = "blanking"
perimeter_mm = 62.83
thickness_mm = 1.0
shear_strength_mpa = 320.0
contact_mm = -3.0

"""


def sweep(n, t_end=0.05):
    """working with the slider's mass, the motor's reduction and a blanking force swept."""
    base = load_scene("working").with_overrides(t_end=t_end, dt=1e-4)
    blank = scene_from_text(base.text.replace("[solver]", BLANKING + "[solver]")).with_overrides(
        t_end=t_end, dt=1e-4
    )
    out = []
    for i in range(n):
        sc = blank if i % 2 else base
        b = dict(sc.bodies)
        b["slider"] = BodyData(80.0 + 10.0 * i, 0.0, b["slider"].com)
        out.append(replace(sc, bodies=b, name=f"sweep-{i}"))
    return out


def assert_same(a, b, rtol=1e-9):
    for c in COLS:
        scale = max(np.abs(b[c]).max(), 1e-12)
        assert np.abs(a[c] - b[c]).max() <= rtol * scale, c
    assert list(a.structure) == list(b.structure)


def test_batch_equals_one_by_one_to_round_off():
    scenes = sweep(4)
    res = simulate_many(scenes)
    assert res.vectorised == [True] * 4
    for sc, tr in zip(scenes, res):
        assert_same(tr, simulate(sc))
    # the blanking scenes did work on a part: their crank ran slower than the others
    assert res[1].phi[-1] != res[0].phi[-1]


def _exact(scene):
    return replace(scene, solver=replace(scene.solver, scheme="autodiff"))


def test_exact_derivatives_are_vectorised_and_equal_one_by_one_to_round_off():
    """With exact derivatives a pass runs the chart's exact kernel on arrays: the locked
    working press (one coordinate) and the free one (two, the seed's free fall before it
    reaches its chart's branch point), masses differing scene by scene."""
    scenes = [_exact(sc) for sc in sweep(4)]
    base = _exact(load_scene("free-fall").with_overrides(t_end=0.004))
    for i in range(3):
        b = dict(base.bodies)
        b["rod"] = BodyData(20.0 + 2.0 * i, 0.036 + 0.004 * i, b["rod"].com)
        scenes.append(replace(base, bodies=b, name=f"free-{i}"))
    res = simulate_many(scenes)
    assert res.vectorised == [True] * len(scenes)
    for sc, tr in zip(scenes, res):
        ref = simulate(sc)
        assert_same(tr, ref)
        assert np.abs(tr.psi - ref.psi).max() <= 1e-9 * np.abs(ref.psi).max()
    assert res[5].phi[-1] != res[4].phi[-1]


def test_one_vectorised_pass_per_stage_whatever_the_number_of_scenes():
    for n in (1, 6):
        res = simulate_many(sweep(n, t_end=0.01))
        # two groups (with and without blanking), each stepped in one pass per stage
        sizes = {tr.counts["batch_size"] for tr in res}
        assert sum(sizes) == n or sizes == {n // 2}
        for tr in res:
            assert tr.counts["batch_evaluations"] == 1 + 2 * tr.counts["steps"]


def test_scenes_that_cannot_share_a_pass_run_on_their_own():
    scenes = [load_scene("paper"), load_scene("press-cycle").with_overrides(t_end=0.05)]
    scenes += sweep(2, t_end=0.01)
    res = simulate_many(scenes)
    assert res.vectorised == [False, False, True, True]
    for sc, tr in zip(scenes[:2], res):
        ref = simulate(sc)
        assert np.array_equal(tr.phi, ref.phi) and tr.events == ref.events


def test_batches_on_a_local_dask_cluster():
    distributed = pytest.importorskip("distributed")
    scenes = sweep(4, t_end=0.01)
    # in-process workers and transport: the distributed scheduler, no socket opened
    with (
        distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None
        ) as cluster,
        distributed.Client(cluster) as client,
    ):
        res = simulate_many(scenes, client=client, batch_size=2)
    assert res.vectorised == [True] * 4
    local = simulate_many(scenes)
    for a, b in zip(res, local):
        assert_same(a, b, rtol=0.0)


def test_a_scene_with_a_step_apart_from_its_outputs_runs_on_its_own():
    """A solver step apart from the outputs (``solver.step_s``) is the scene's own run, never
    the vectorised pass (which steps at the outputs)."""
    scenes = sweep(2, t_end=0.01)
    scenes[0] = scenes[0].with_overrides(step=2.5e-5)
    res = simulate_many(scenes)
    assert res.vectorised == [False, True]
    ref = simulate(scenes[0])
    assert np.array_equal(res[0].phi, ref.phi)
    assert res[0].counts["steps"] == 4 * res[1].counts["steps"]


def test_reactions_in_the_batch_equal_one_by_one():
    """The joint reactions and the foundation load of a batch (the view's reaction kernel on
    arrays, the masses scene by scene) are the scalar run's, with central differences and with
    exact derivatives, locked (working) and free (the seed's free fall, the rod's mass and
    inertia swept); the checks' columns (round-off, or the scheme's error) to round-off of the
    forces."""
    from mps_core.dynamics.reactions import REACTION_COLUMNS

    free = load_scene("free-fall").with_overrides(t_end=0.004)
    for scheme in ("central", "autodiff"):
        scenes = sweep(4, t_end=0.02)
        for i in range(2):
            b = dict(free.bodies)
            b["rod"] = BodyData(20.0 + 2.0 * i, 0.036 + 0.004 * i, b["rod"].com)
            scenes.append(replace(free, bodies=b, name=f"free-{i}"))
        scenes = [replace(sc, reactions=True, solver=replace(sc.solver, scheme=scheme)) for sc in scenes]
        res = simulate_many(scenes)
        assert res.vectorised == [True] * 6
        for sc, tr in zip(scenes, res):
            ref = simulate(sc)
            force = max(np.abs(ref[c]).max() for c, u in REACTION_COLUMNS.items() if u == "N")
            moment = max(np.abs(ref[c]).max() for c, u in REACTION_COLUMNS.items() if u == "N*m")
            for c, unit in REACTION_COLUMNS.items():
                floor = 1e-9 * (force if unit == "N" else moment)
                assert np.all(np.abs(tr[c] - ref[c]) <= 1e-9 * np.abs(ref[c]) + floor), (scheme, c)
            assert np.abs(ref["F_found_x"]).max() > 1e3  # the loads, not zeros
        # a heavier slider, a larger foundation load: the masses are each scene's own
        assert np.abs(res[2]["F_found_x"]).max() > np.abs(res[0]["F_found_x"]).max()


def test_a_batch_whose_step_the_springs_would_subdivide_runs_one_by_one(monkeypatch):
    """The retention springs' shortest period against the solver's stability limit, checked at
    every step for every scene (one coordinate: k j² / A): past it the group runs one by one,
    where each run subdivides its steps."""
    from mps_core.solvers import SOLVERS

    text = (
        load_scene("working")
        .text.replace("assembly = 1", "assembly = 1\nx_top_mm = 25.5")
        .replace(
            "[solver]",
            '[[effects]]\ntype = "springs"\nstiffness_n_m = 20000.0\npreload_n = 2500.0\n\n[solver]',
        )
    )
    scenes = [scene_from_text(text).with_overrides(t_end=0.002, dt=1e-4)] * 2
    assert simulate_many(scenes).vectorised == [True, True]
    # the springs' period 2π sqrt(A / (k j²)) is seconds near φ = 0 (infinite at it, where
    # j = ∂x_C/∂φ = 0): a limit of a billionth of it puts a step of 0.1 ms past it
    monkeypatch.setattr(SOLVERS["linear-acceleration"], "stability_limit", 1e-9)
    assert simulate_many(scenes).vectorised == [False, False]


@pytest.mark.parametrize("bad", ["a singular A", "a NaN in h", "both signs of infinity"])
def test_a_scene_whose_accelerations_are_not_finite_takes_its_group_one_by_one(bad):
    """One scene's q̈ not finite ends the group's pass (NotVectorisable: the group runs one
    by one), whatever the other scenes' values."""
    from mps_core.run.batch import NotVectorisable, _Batch

    scenes = sweep(5)[0::2]  # three without blanking: one group
    batch = _Batch(scenes)
    qdd, A, kin, _ = batch.evaluate(0.0, batch.q0, batch.qd0)
    assert np.isfinite(qdd).all()
    A, h = A.copy(), np.zeros_like(qdd)
    batch._solve(0.0, kin, batch.qd0, A, h)  # finite
    if bad == "a NaN in h":
        h[1, 0] = np.nan
    else:  # (Q − h) / 0, of each sign where asked
        A[1] = 0.0
        if bad == "both signs of infinity":
            A[2] = 0.0
            h[1, 0], h[2, 0] = -1e9, 1e9
    with pytest.raises(NotVectorisable, match="non-finite"), np.errstate(all="ignore"):
        batch._solve(0.0, kin, batch.qd0, A, h)


def test_group_keys_follow_each_scenes_own_effects():
    """The effects' kinds are kept by the effects' tuple a scene holds (batch._KINDS): scenes
    alike but for their effects get keys of their own effects, in any order."""
    from mps_core.run.batch import group_key
    from mps_core.scene import EffectSpec

    base, blank = sweep(2)
    latch = replace(base, effects=base.effects + (EffectSpec("latch", {}),))
    for sc in (base, blank, latch, base, latch, blank):
        assert group_key(sc) == group_key(replace(sc, effects=tuple(list(sc.effects))))
    assert group_key(latch) is None and None not in (group_key(base), group_key(blank))
    assert group_key(base) != group_key(blank)
