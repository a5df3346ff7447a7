"""Brent's root finder (mps_core.run.roots) against scipy's brentq, the same tolerance; and a
run's start without scipy's integrators and optimizers (their packages are most of a process's
start)."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import brentq

from mps_core.run.roots import brent_root

XTOL, RTOL = 1e-13, 4 * np.finfo(float).eps
FUNCTIONS = {
    "sin": lambda x: math.sin(x) - 0.3,
    "cubic": lambda x: x**3 - 2 * x - 5,
    "triple root": lambda x: (x - 0.7) ** 3,
    "steep": lambda x: math.atan(50 * (x - 0.123456)),
    "fixed point": lambda x: math.cos(x) - x,
    "step": lambda x: -1.0 if x < 0.25 else 1.0,
}


@settings(max_examples=60, deadline=None)
@given(
    name=st.sampled_from(sorted(FUNCTIONS)),
    a=st.floats(-3.0, 0.1),
    b=st.floats(0.8, 4.0),
)
def test_the_root_is_scipys_within_the_tolerance(name, a, b):
    f = FUNCTIONS[name]
    if f(a) * f(b) >= 0:
        return
    mine = brent_root(f, a, b, XTOL, RTOL)
    theirs = brentq(f, a, b, xtol=XTOL, rtol=RTOL, maxiter=200)
    assert a <= mine <= b
    assert abs(mine - theirs) <= 2 * (XTOL + RTOL * abs(theirs))


def test_an_end_that_is_a_root_is_returned():
    assert brent_root(lambda x: x - 1.0, 1.0, 2.0, XTOL, RTOL) == 1.0
    assert brent_root(lambda x: x - 2.0, 1.0, 2.0, XTOL, RTOL) == 2.0


def test_no_bracket_is_a_clear_error():
    with pytest.raises(ValueError, match="opposite signs"):
        brent_root(lambda x: x * x + 1.0, -1.0, 1.0, XTOL, RTOL)


def test_too_few_evaluations_is_a_clear_error():
    with pytest.raises(RuntimeError, match="no root found"):
        brent_root(FUNCTIONS["step"], 0.0, 1.0, 1e-15, 0.0, maxiter=3)


def test_a_value_that_is_not_finite_is_a_clear_error():
    for bad in (math.nan, math.inf):
        with pytest.raises(ValueError, match="expected a finite value"):
            brent_root(lambda x, bad=bad: bad if x > 0.5 else -1.0, 0.0, 1.0, XTOL, RTOL)
        with pytest.raises(ValueError, match="expected a finite value"):
            brent_root(lambda x, bad=bad: bad if 0.4 < x < 0.6 else x - 0.5, 0.0, 1.0, XTOL, RTOL)


def test_an_event_time_not_found_stops_the_run_with_its_name_and_state(monkeypatch):
    """A root the finder cannot give (here: it fails at once) is a NumericalError naming the
    event and its step, with the time and configuration, not a bare exception."""
    import mps_core.run.events as events
    from mps_core.errors import NumericalError
    from mps_core.run.build import build
    from mps_core.scene import load_scene

    def fails(*_a, **_k):
        raise RuntimeError("no root found")

    monkeypatch.setattr(events, "brent_root", fails)
    s = load_scene("press-cycle").with_overrides(t_end=0.5)
    with pytest.raises(NumericalError, match=r"event [\w-]+: its time in the step \[") as err:
        build(s).run(s.t_end, s.dt)
    assert 0.0 < err.value.t <= 0.5 and "phi_deg" in err.value.config


def test_a_run_with_events_imports_no_scipy_package():
    code = (
        "import sys\n"
        "import mps_core.run.events as events\n"
        "from mps_core.run.build import build\n"
        "from mps_core.scene import load_scene\n"
        "roots = []\n"
        "def counted(*a, find=events.brent_root, **k):\n"
        "    roots.append(find(*a, **k))\n"
        "    return roots[-1]\n"
        "events.brent_root = counted\n"
        "s = load_scene('press-cycle').with_overrides(t_end=0.5)\n"
        "build(s).run(s.t_end, s.dt)\n"
        "assert roots, 'no event root located'\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] == 'scipy'))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
