"""The load report: harmonics of a known signal, the steady cycle, and `mps loads`."""

import json
import math

import numpy as np
import pytest

from mps_core.analysis.loads import LoadReportError, harmonics, last_cycle, load_report, quantity, resample
from mps_core.cli import main

AMPS = [3.0, 1.5, 0.0, 0.25, 0.125, 0.0625]
PHASES = [0.3, -2.0, 0.0, 1.0, 3.0, -0.5]


def synthetic(tau, omega, mean=-7.0):
    return mean + sum(a * np.cos((k + 1) * omega * tau + p) for k, (a, p) in enumerate(zip(AMPS, PHASES)))


def test_harmonics_of_one_uniformly_sampled_period_are_exact():
    N = 64
    y = synthetic(2 * math.pi * np.arange(N) / N, 1.0)
    mean, amp, ph = harmonics(y)
    assert mean == pytest.approx(-7.0, abs=1e-13)
    assert np.allclose(amp, AMPS, atol=1e-13)
    for a, p, p0 in zip(AMPS, ph, PHASES):
        if a:
            assert math.remainder(p - p0, 2 * math.pi) == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(LoadReportError, match="more than 12 samples"):
        harmonics(y[:10])


def test_report_of_a_recorded_signal_finds_the_cycle_and_its_harmonics():
    """A crank turning at a speed that is no multiple of the step: the cycle is located between
    passages of phi = 0 and the harmonics come back through the spline resampling."""
    w = 2 * math.pi * 7.3
    t = np.arange(0.0, 0.5 + 1e-12, 1e-4)
    phi = w * t - 0.4  # passes phi = 0 (mod 2 pi) at t = (0.4 + 2 pi k) / w
    cols = {"t": t, "phi": phi, "phi_dot": np.full_like(t, w), "structure": np.array(["locked"] * t.size)}
    k_last = math.floor((phi[-1]) / (2 * math.pi))
    t0 = (0.4 + 2 * math.pi * (k_last - 1)) / w
    cols["F_found_x"] = synthetic(t - t0, w)
    cols["F_found_y"] = np.zeros_like(t)
    rep = load_report(cols, source="synthetic")
    c = rep["cycle"]
    assert c["t0_s"] == pytest.approx(t0, abs=1e-12)
    assert c["period_s"] == pytest.approx(2 * math.pi / w, rel=1e-12)
    q = quantity(rep, "F_found_x")
    assert q["mean"] == pytest.approx(-7.0, abs=1e-8)
    for h, a, p in zip(q["harmonics"], AMPS, PHASES):
        assert h["amplitude"] == pytest.approx(a, abs=1e-8)
        if a:
            assert math.remainder(math.radians(h["phase_deg"]) - p, 2 * math.pi) == pytest.approx(
                0.0, abs=1e-7
            )
        else:
            assert h["phase_deg"] is None
    assert q["rms"] == pytest.approx(math.sqrt(49 + sum(a * a for a in AMPS) / 2), rel=1e-9)
    assert q["peak"] == pytest.approx(np.abs(cols["F_found_x"]).max(), rel=1e-6)
    assert [x["name"] for x in rep["quantities"]] == ["F_found_x", "|F_found|"]  # y is all zero
    # only the working structure counts
    cols["structure"][-1500:] = "free"
    c2 = load_report(cols)["cycle"]
    assert c2["t1_s"] <= t[-1500]
    with pytest.raises(LoadReportError, match="no full crank revolution"):
        last_cycle(t[:1000], phi[:1000])
    with pytest.raises(LoadReportError, match="not inside the data"):
        resample(t[:10], t[:10], 0.0, 1.0, 16)


def test_mps_loads_on_a_scene_and_on_its_recording(tmp_path, capsys):
    js, cs, png, rec = (tmp_path / n for n in ("r.json", "r.csv", "r.png", "rec.csv"))
    args = ["--t-end", "0.42", "--dt", "5e-4"]
    assert main(["loads", "working", *args, "--json", str(js), "--csv", str(cs), "--png", str(png)]) == 0
    out = capsys.readouterr().out
    assert "F_found_x" in out and "transients: none" in out
    rep = json.loads(js.read_text())
    fx = quantity(rep, "F_found_x")
    assert len(fx["harmonics"]) == 6
    # unbalanced crank-slider: first harmonic ~ (sum of the moving masses) r w^2
    w = rep["cycle"]["crank_speed_mean_rad_s"]
    assert fx["harmonics"][0]["amplitude"] == pytest.approx(142.6 * 0.015 * w * w, rel=0.02)
    assert fx["mean"] == pytest.approx(-9.81 * 142.6, rel=1e-3)
    assert rep["checks"]["max_balance_residual_N"] < 1e-9
    assert rep["cycle"]["period_change"] < 1e-6
    assert cs.read_text().splitlines()[0].startswith("quantity,unit,mean,peak,rms,rms_dynamic,A1")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000
    # the same report from a recording of the same run
    assert main(["run", "working", *args, "--reactions", "--csv", str(rec)]) == 0
    assert main(["loads", str(rec), "--json", str(js)]) == 2  # it exists: --force
    assert main(["loads", str(rec), "--json", str(js), "--force"]) == 0
    rep2 = json.loads(js.read_text())
    assert quantity(rep2, "F_found_x")["harmonics"] == fx["harmonics"]
    # a recording's impulse events are listed as transients, not folded into the cycle
    ev = tmp_path / "events.jsonl"
    ev.write_text(
        json.dumps({"t": 0.01, "kind": "impulse", "duration_s": 0.0, "impulses_Ns": {"M_latch": 0.5}})
        + "\n"
        + json.dumps({"t": 0.02, "kind": "chart"})
        + "\n"
    )
    capsys.readouterr()
    assert main(["loads", str(rec), "--events", str(ev), "--json", str(js), "--force"]) == 0
    assert "transients (impulses, N*s)" in capsys.readouterr().out
    assert json.loads(js.read_text())["transients"][0]["impulses_Ns"] == {"M_latch": 0.5}
    # no working structure, no full revolution: clear errors, exit 2
    capsys.readouterr()
    assert main(["loads", "paper"]) == 2
    assert "no step of the run is in the 'locked' structure" in capsys.readouterr().err
    assert main(["loads", "paper", "--structure", "free"]) == 2
    assert "no full crank revolution" in capsys.readouterr().err
