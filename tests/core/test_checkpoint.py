"""Checkpoints: a run that stepped ahead and came back to an earlier step boundary goes on
exactly (bit for bit) as a run that stopped there, through impacts, structure changes, chart
changes and commands (a live twin computes ahead and comes back when a command arrives)."""

from dataclasses import replace

import pytest

from mps_core import build, load_scene
from mps_core.dynamics.reaction_observer import ReactionObserver

DT = 1e-3


def _press(solver=None, scheme=None, observer=True):
    scene = load_scene("press-cycle")
    scene = replace(scene, commands=())
    if solver is not None or scheme is not None:
        scene = scene.with_overrides(solver=solver or scene.solver.name, scheme=scheme or scene.solver.scheme)
    sim = build(scene)
    if observer:
        sim.observers.append(ReactionObserver(defer_impacts=True))
    return sim


def _trace(sim, k0, k1, out):
    for k in range(k0, k1):
        sim.advance_to((k + 1) * DT)
        for ob in sim.observers:
            ob.resolve()
        out.append((sim.snapshot(), sim.view.name, list(sim.solver.q), list(sim.solver.qd)))
    return out


def _run(commands, ahead=None, **kw):
    """Steps of 1 ms to 0.2 s, ``commands`` {step: word} applied at those boundaries;
    ``ahead`` (step, n): at that boundary, take n steps, come back, and go on."""
    sim = _press(**kw)
    out = []
    k = 0
    while k < 200:
        if ahead is not None and k == ahead[0]:
            cp = sim.checkpoint()
            _trace(sim, k, min(200, k + ahead[1]), [])
            sim.restore(cp)
        if k in commands:
            sim.command(commands[k])
        _trace(sim, k, k + 1, out)
        k += 1
    return out, sim.events


# engage at 8 ms (the latch closes about 20 ms later), disengage at 90 ms
COMMANDS = {8: "engage", 90: "disengage"}


@pytest.fixture(scope="module")
def straight():
    return _run(COMMANDS)


@pytest.mark.parametrize(
    "at, n",
    [
        (8, 60),  # ahead without the engage: stop contacts and releases, no latch
        (20, 40),  # engaged, the latch's impact in the steps taken ahead
        (90, 50),  # locked, ahead without the disengage
        (3, 197),  # ahead to the end through everything
    ],
)
def test_coming_back_goes_on_bit_for_bit(straight, at, n):
    assert _run(COMMANDS, ahead=(at, n)) == straight


def test_the_steps_ahead_met_events_and_structure_changes(straight):
    kinds = {e["kind"] for e in straight[1]}
    assert {
        "chart",
        "stop-contact",
        "stop-release",
        "latch-closes",
        "latch-opens",
        "impulse",
        "cylinder-off",
    } <= kinds
    structures = {s["structure"] for s, *_ in straight[0]}
    assert structures == {"held", "free", "locked"}


def test_a_command_taken_in_the_steps_ahead_is_undone_by_coming_back(straight):
    """A stop given for a later time and taken in the steps ahead: coming back undoes it (the
    motor switched on again, the stop due again, then dropped) and the run goes on bit for bit
    as one that never had it."""
    sim = _press()
    out = []
    for k in range(200):
        if k == 30:
            cp = sim.checkpoint()
            sim.command("stop", 40 * DT)
            _trace(sim, k, 100, [])
            assert not sim.controls.motor_on
            sim.restore(cp)
            assert sim.controls.motor_on and sim.structures.parts.motor.enabled
        if k in COMMANDS:
            sim.command(COMMANDS[k])
        _trace(sim, k, k + 1, out)
    assert (out, sim.events) == straight


def test_exact_derivatives_and_rk4_come_back_too():
    for kw in (dict(scheme="autodiff"), dict(solver="rk4")):
        straight = _run(COMMANDS, **kw)
        assert _run(COMMANDS, ahead=(20, 40), **kw) == straight


def test_a_solver_that_cannot_be_rewound_says_so():
    sim = _press(solver="radau")
    assert not sim.rewindable
    with pytest.raises(NotImplementedError, match="radau"):
        sim.checkpoint()


def test_an_observer_without_checkpoint_makes_the_run_not_rewindable():
    sim = _press(observer=False)
    assert sim.rewindable
    sim.observers.append(object())
    assert not sim.rewindable


def test_joint_state_is_the_snapshots_numbers_at_every_boundary_and_after_coming_back():
    """``joint_state()`` (what the twin's joint messages carry) gives the snapshot's numbers
    at every step, through impacts, the latch and chart changes, asked once or twice, and
    after a restore to an earlier boundary."""
    sim = _press()

    def check():
        s = sim.snapshot()
        # ẋ_C: the analogs' product on floats (the snapshot's is numpy's, equal to round-off)
        want = (s["phi"], s["phi_dot"], s["psi"], s["psi_dot"], s["x_C"], sim.solver.current.kin.vxy("C")[0])
        assert abs(want[5] - s["x_C_dot"]) <= 1e-12 * (1.0 + abs(want[5]))
        assert sim.joint_state() == want
        assert sim.joint_state() == want

    kinds = set()
    cp = None
    for k in range(120):
        if k in COMMANDS:
            sim.command(COMMANDS[k])
        if k == 60:
            cp = sim.checkpoint()
            at = sim.joint_state()
        sim.advance_to((k + 1) * DT)
        check()
        kinds.update(e["kind"] for e in sim.events)
    assert {"chart", "latch-closes"} <= kinds
    sim.restore(cp)
    assert sim.joint_state() == at
    check()
