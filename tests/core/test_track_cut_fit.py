"""Each stroke's cut fitted whole: the part's force curve from the crank angles over the work
window finds the truth's peak where the filter's random walk overshoots it, and the fit leaves
the filter exactly as it found it."""

from __future__ import annotations

import contextlib
import math

import numpy as np
import pytest

from mps_core import load_scene
from mps_core.track import Fault, Tracker, TrackSettings, run_truth, truth_scene
from mps_core.track.evaluation import truth_strokes
from mps_core.track.truth import TruthChanges, with_blanking

#: the truth's part (TruthChanges' default): 1.5 mm at 300 MPa touching at -2 mm, breaking
#: through at 60 % of its thickness
TRUE_CONTACT, TRUE_DEPTH = -0.002, 0.6 * 0.0015


@pytest.fixture(scope="module")
def nominal():
    return with_blanking(load_scene("working").with_overrides(scheme="autodiff"))


def _followed(nominal, truth, settings=None):
    tracker = Tracker(nominal, settings)
    for m in truth.measurements:
        tracker.update(m)
        tracker.observe_stroke()
    return tracker


@pytest.mark.parametrize("seed", [0, 1])
def test_the_cut_fitted_whole_finds_the_truths_peak(nominal, seed):
    """Three strokes of another press (masses, friction, motor, part all off the nominal): each
    cut fitted, its peak within 3.5 % of the truth's and within three of its 1-sigma, the worst
    of them nearer than the filter's worst; the part's contact and depth found within a few
    hundredths of a mm."""
    truth = run_truth(truth_scene(nominal), 0.45, seed=seed)
    tracker = _followed(nominal, truth)
    true = truth_strokes(truth)
    strokes = [s for s in tracker.strokes.strokes if true.get(s.index, {}).get("complete")]
    assert len(strokes) >= 2
    assert tracker.cuts_unfitted == 0 and tracker.cuts_without_part == 0
    for s in strokes:
        peak = true[s.index]["peak_force_N"]
        assert s.fit is not None
        err = s.peak_force - peak
        assert abs(err) <= 0.035 * peak
        assert abs(err) <= 3.0 * s.peak_force_sigma
        assert 0.2 * s.filter_peak_force_sigma < s.peak_force_sigma < 0.04 * peak
        assert abs(s.fit.contact - TRUE_CONTACT) < 5e-5
        assert abs(s.fit.depth - TRUE_DEPTH) < 8e-5
        assert s.fit.chi2 / s.fit.dof < 5.0  # the model's own error: a few times the noise
        assert s.row()["peak_force_N"] == s.peak_force
        assert s.row()["filter_peak_force_N"] == s.filter_peak_force
        # the foundation's peak over the fitted run: the model's masses (not the truth's) put
        # it some 4 % low, far nearer than the filter's overshooting force would
        found = true[s.index]["peak_foundation_N"]
        assert -0.07 * found < s.peak_foundation - found < 0.0 and s.peak_foundation == s.fit.peak_foundation
        assert 0.0 < s.peak_foundation_sigma < 0.03 * found
    worst = max(abs(s.peak_force / true[s.index]["peak_force_N"] - 1) for s in strokes)
    assert worst < max(abs(s.filter_peak_force / true[s.index]["peak_force_N"] - 1) for s in strokes)


def test_with_the_model_exact_the_fit_is_as_good_as_the_noise(nominal):
    """The truth the nominal press but for its part: the residuals are the encoder's noise
    (chi-square about its degrees of freedom), the peak within 2.5 of its 1-sigma, the
    foundation's peak within 2.5 %."""
    same = {"slider_mass": 1.0, "rod_mass": 1.0, "friction": 1.0, "motor_torque": 1.0}
    exact = TruthChanges(**same, joint_friction_nm=1e-9, guide_friction_n=1e-9)
    truth = run_truth(truth_scene(nominal, exact), 0.3, seed=4)
    tracker = _followed(nominal, truth)
    true = truth_strokes(truth)
    complete = [s for s in tracker.strokes.strokes if true.get(s.index, {}).get("complete")]
    fitted = [s for s in complete if s.fit is not None]
    assert fitted
    for s in fitted:
        assert s.fit.chi2 / s.fit.dof < 2.0
        assert abs(s.peak_force - true[s.index]["peak_force_N"]) <= 2.5 * s.peak_force_sigma
        assert abs(s.peak_foundation / true[s.index]["peak_foundation_N"] - 1) < 0.025


def test_fitting_the_cuts_leaves_the_filter_as_it_was(nominal):
    """The fit rewinds the tracker's run and puts it back: every estimate, covariance and event
    the same, bit for bit, with and without it."""
    truth = run_truth(truth_scene(nominal), 0.2, seed=5)
    with_fit, without = Tracker(nominal), Tracker(nominal, TrackSettings(fit_cuts=False))
    for m in truth.measurements:
        for tracker in (with_fit, without):
            tracker.update(m)
        assert np.array_equal(with_fit.x, without.x)
        assert np.array_equal(with_fit.P, without.P)
        assert with_fit.take_events() == without.take_events()
    assert with_fit.cuts_fitted == 1 and without.cuts_fitted == 0
    a, b = with_fit.strokes.strokes[0], without.strokes.strokes[0]
    assert a.work == b.work and a.filter_peak_force == b.filter_peak_force
    assert b.fit is None and math.isnan(b.row()["contact_m"])


def test_fits_made_elsewhere_are_the_fits_made_here(nominal):
    """``defer_fits``: each cut's job handed out and its fit, made by a fitter of its own (as a
    process of its own would), given back some measurements later; the next cut waits for the
    last fit. The strokes are those of the tracker that fits its cuts itself, bit for bit, and
    a stroke whose fit is out says so until it comes."""
    from mps_core.track.cut_fit import CutFitter

    truth = run_truth(truth_scene(nominal), 0.45, seed=6)
    here = _followed(nominal, truth)
    there = Tracker(nominal)
    there.defer_fits = True
    fitter = CutFitter(nominal, there.settings)
    waited: list[int] = []

    def await_fit(job):
        waited.append(job.serial)
        return fitter.fit(job)

    there.await_fit = await_fit
    out: list = []  # (job, when its fit comes back: so many measurements on)
    seen_pending = False
    for k, m in enumerate(truth.measurements):
        there.update(m)
        there.observe_stroke()
        for job in there.cut_jobs:
            out.append((job, k + (7 if job.serial % 2 else 200)))  # the second cut's fit late
        there.cut_jobs.clear()
        seen_pending |= any(s.fit_pending for s in [*there.strokes.strokes, there.strokes.current] if s)
        for job, due in [o for o in out if o[1] <= k]:
            out.remove((job, due))
            there.take_fit(job, fitter.fit(job))
    for job, _ in out:
        there.take_fit(job, fitter.fit(job))
    assert seen_pending and waited == [2]  # the third cut waited for the second's fit
    assert there.cuts_fitted == here.cuts_fitted >= 3
    assert [s.row() for s in there.strokes.strokes] == [s.row() for s in here.strokes.strokes]


def test_the_fitting_process_gives_each_job_its_own_fit(nominal):
    """A job made again with its serial (a late signal's search took its cut's measurements
    again) and the first one are both fitted by the fitting process; the tracker takes the one
    it waits for, ignores the other, and the process ends with its input."""
    from dataclasses import replace

    with _fitted_elsewhere(nominal, 0.1) as (truth, tracker, fits):
        for m in truth.measurements:
            tracker.update(m)
            if tracker.cut_jobs:
                break
        (stale,) = tracker.cut_jobs
        again = replace(stale)  # the same cut, the same serial, made again
        tracker.cut_jobs.append(again)
        tracker._pending = again
        fits.submit(tracker)
        assert [n for n, _ in fits.out] == [1, 2] and not tracker.cut_jobs
        fits.finish(tracker)
        assert not fits.failed and tracker.cuts_fitted == 1 and tracker.cuts_unfitted == 0
        assert tracker.strokes.current.fit is not None and not tracker.strokes.current.fit_pending


def test_the_fitting_process_outlives_ctrl_c(nominal):
    """Ctrl-C reaches a terminal's whole process group: the fitting process takes no notice (the
    process that started it decides, and ends it with its input), so the cuts sent after it are
    still fitted."""
    import os
    import signal

    with _fitted_elsewhere(nominal, 0.3) as (truth, tracker, fits):
        for m in truth.measurements:
            tracker.update(m)
            fits.submit(tracker)
            if fits.out and tracker.cuts_fitted == 0:
                fits.finish(tracker)  # the first cut fitted: the process is past its start
                assert tracker.cuts_fitted == 1
                os.kill(fits._proc.pid, signal.SIGINT)
            fits.poll(tracker)
        fits.finish(tracker)
        assert not fits.failed and tracker.cuts_unfitted == 0 and tracker.cuts_fitted >= 2


@contextlib.contextmanager
def _fitted_elsewhere(nominal, seconds: float):
    """(truth, tracker, fits): ``seconds`` of the truth of ``nominal`` (seed 7), a tracker of it
    whose cuts the fitting process fits; the process ended after, with status 0."""
    from mps_core.track.fit_process import CutFits

    truth = run_truth(truth_scene(nominal), seconds, seed=7)
    tracker = Tracker(nominal)
    fits = CutFits(nominal, tracker.settings)
    fits.attach(tracker)
    try:
        yield truth, tracker, fits
        proc = fits._proc
    finally:
        fits.close()
    assert proc is not None and proc.returncode == 0


def test_a_double_blank_is_fitted_from_the_filters_work(nominal):
    """Two parts in the die: the cut's work is twice the last's, so its search begins at the
    last curve scaled to the filter's work (from the last curve alone it did not converge), and
    finds the double force's peak."""
    truth = run_truth(truth_scene(nominal), 0.45, faults=(Fault(0.2, "double-blank"),), seed=0)
    tracker = _followed(nominal, truth)
    true = truth_strokes(truth)
    double = tracker.strokes.strokes[2]
    assert tracker.cuts_unfitted == 0 and double.fit is not None
    assert true[2]["peak_force_N"] > 1.8 * true[1]["peak_force_N"]
    assert abs(double.peak_force / true[2]["peak_force_N"] - 1) < 0.03


def test_a_stroke_without_its_part_is_not_fitted(nominal):
    """A part missing from the die: the filter finds no work in that cut, which is not fitted
    (its stroke keeps the filter's figures); the next cut is fitted again."""
    truth = run_truth(truth_scene(nominal), 0.45, faults=(Fault(0.15, "missed-part"),), seed=2)
    tracker = _followed(nominal, truth)
    assert tracker.cuts_without_part == 1 and tracker.cuts_unfitted == 0
    fits = [s.fit is not None for s in tracker.strokes.strokes]
    assert fits[:3] == [True, False, True]
