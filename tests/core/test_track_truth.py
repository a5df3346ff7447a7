"""The truth to follow: a press that is not the nominal one, and the faults injected into it."""

from __future__ import annotations

import numpy as np
import pytest

from mps_core import load_scene
from mps_core.track import Fault, run_truth, truth_scene
from mps_core.track.truth import TruthChanges, with_blanking


@pytest.fixture(scope="module")
def working():
    return truth_scene(with_blanking(load_scene("working").with_overrides(scheme="autodiff")))


def test_a_double_blank_doubles_the_truth_force(working):
    healthy = run_truth(working, 0.25, seed=1)
    faulty = run_truth(working, 0.25, seed=1, faults=(Fault(0.1, "double-blank"),))
    first, second = healthy.t < 0.1, healthy.t >= 0.1
    assert faulty.force[first].max() == pytest.approx(healthy.force[first].max())
    assert faulty.force[second].max() > 1.8 * healthy.force[second].max()


def test_a_clutch_slip_changes_the_crank_speed_while_it_lasts(working):
    """Half the drive's torque for 50 ms: the crank's speed departs from the healthy run's (the
    motor drives below its synchronous speed and brakes above it, so either way)."""
    healthy = run_truth(working, 0.12, seed=1)
    faulty = run_truth(working, 0.12, seed=1, faults=(Fault(0.02, "clutch-slip", duration=0.05),))
    before, during = healthy.t < 0.02, (healthy.t > 0.02) & (healthy.t < 0.07)
    assert np.array_equal(faulty.phi_dot[before], healthy.phi_dot[before])
    assert np.max(np.abs(faulty.phi_dot[during] - healthy.phi_dot[during])) > 1.0  # rad/s


def test_a_broken_spring_changes_the_loads():
    truth = truth_scene(load_scene("press-cycle"))
    healthy = run_truth(truth, 0.08, seed=2)
    faulty = run_truth(truth, 0.08, seed=2, faults=(Fault(0.04, "broken-spring"),))
    before, after = healthy.t < 0.04, healthy.t > 0.05
    assert np.array_equal(faulty.foundation_x[before], healthy.foundation_x[before])
    assert np.max(np.abs(faulty.foundation_x[after] - healthy.foundation_x[after])) > 500.0  # N


def test_the_changes_are_what_they_say():
    nominal = with_blanking(load_scene("press-cycle"))
    changes = TruthChanges(slider_mass=0.9, rod_mass=1.1, motor_torque=1.03)
    truth = truth_scene(nominal, changes)
    assert truth.bodies["slider"].mass == pytest.approx(90.0)
    assert truth.bodies["rod"].mass == pytest.approx(22.0)
    motor = next(e.params for e in truth.effects if e.kind == "motor")
    assert motor["efficiency"] == pytest.approx(1.03)
    part = next(e.params for e in truth.effects if e.kind == "blanking")
    assert part["peak_force"] == pytest.approx(62.83 * 1.5 * 300.0)


def test_timed_kinds_reads_t_kind_values_and_names_a_bad_one():
    from mps_core.track.measurements import MeasurementError
    from mps_core.track.truth import FAULTS, timed_kinds

    assert timed_kinds(["0.25:clutch-slip", "1:double-blank"], "--fault", FAULTS) == [
        (0.25, "clutch-slip"),
        (1.0, "double-blank"),
    ]
    for bad in ("x:clutch-slip", "-1:clutch-slip", "0.5:nope", "0.5"):
        with pytest.raises(MeasurementError) as err:
            timed_kinds([bad], "--fault", FAULTS)
        assert str(err.value).startswith(f"--fault = {bad!r}: expected T:KIND")
