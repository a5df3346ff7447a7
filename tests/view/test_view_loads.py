"""``mps loads RECORDING.mcap``: the load report from the file alone (its columns, events and
scene metadata), the same figures as on the live run of the same scene; mps_core never imports
mcap or rerun at module level."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from mps_core.analysis import loads
from mps_core.cli import main


def _report(args, tmp_path, name, capsys):
    out = tmp_path / f"{name}.json"
    assert main(["loads", *args, "--json", str(out)]) == 0
    text = capsys.readouterr().out
    return json.loads(out.read_text()), text


def test_recording_gives_the_live_runs_figures(working_mcap, tmp_path, capsys):
    rec, text = _report([str(working_mcap)], tmp_path, "rec", capsys)
    live, _ = _report(["working", "--t-end", "0.3", "--dt", "2e-4"], tmp_path, "live", capsys)
    assert text.startswith("load report working.mcap: cycle t = ")
    for k in ("t0_s", "t1_s", "period_s", "crank_speed_mean_rad_s", "steps", "resampled_points"):
        assert rec["cycle"][k] == pytest.approx(live["cycle"][k], rel=1e-12, abs=1e-12), k
    names = [q["name"] for q in live["quantities"]]
    assert [q["name"] for q in rec["quantities"]] == names
    assert {"F_found_x", "|F_found|", "M_found_O", "|F_A|"} <= set(names)
    for a, b in zip(rec["quantities"], live["quantities"]):
        for k in ("mean", "peak", "rms", "rms_dynamic"):
            assert a[k] == pytest.approx(b[k], rel=1e-9, abs=1e-9 * b["peak"]), (a["name"], k)
        for ha, hb in zip(a["harmonics"], b["harmonics"]):
            assert ha["amplitude"] == pytest.approx(hb["amplitude"], rel=1e-9, abs=1e-9 * b["peak"]), (
                a["name"],
                ha["k"],
            )
    fx = loads.quantity(rec, "F_found_x")
    assert fx["mean"] == pytest.approx(-1399, rel=2e-3)  # the weight (README)


def test_recording_options_that_do_not_apply(working_mcap, capsys):
    assert main(["loads", str(working_mcap), "--t-end", "1"]) == 2
    assert "apply to scenes" in capsys.readouterr().err
    assert main(["loads", str(working_mcap), "--events", "x.jsonl"]) == 2
    assert "holds its own event log" in capsys.readouterr().err


def test_mcap_sniffed_by_its_magic(working_mcap, tmp_path, capsys):
    other = tmp_path / "run.bin"
    other.write_bytes(working_mcap.read_bytes())
    assert main(["loads", str(other)]) == 0
    assert "load report run.bin" in capsys.readouterr().out


def test_missing_package_says_what_to_install(monkeypatch, capsys):
    from mps_core.analysis import loads_cli

    class Missing:  # the reader's entry point, its package's dependency not installed
        def load(self):
            raise ModuleNotFoundError("No module named 'mcap'", name="mcap")

    for found in (Missing(), None):  # a reader that cannot load; no reader at all
        monkeypatch.setattr(loads_cli, "reader", lambda fmt, found=found: found)
        assert main(["loads", "some.mcap"]) == 2
        err = capsys.readouterr().err
        assert "needs the package 'mcap'" in err and "pip install" in err


def test_core_imports_no_mcap_rerun_or_ros():
    code = (
        "import sys, mps_core, mps_core.analysis.loads_cli, mps_core.cli, mps_core.dynamics.reactions\n"
        "from mps_core.cli import _parser\n_parser()\n"
        "bad = [m for m in ('mcap', 'mcap_ros2', 'rerun', 'rclpy', 'pyarrow') "
        "if m in sys.modules]\nprint(bad)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout.strip()
    assert out == "[]"


def test_recording_holds_the_impulses_of_the_live_run(recordings, tmp_path, capsys):
    """press-cycle has plastic impacts (latch, stop): the recording carries their impulses and
    its report lists the same transients as the live run of the same scene and step."""
    from mps_ros.run.record import record

    path, _, _ = record("press-cycle", recordings / "press-cycle-impulses.mcap", dt=1e-3, t_end=0.6)
    rec, _ = _report([str(path)], tmp_path, "rec", capsys)
    live, _ = _report(["press-cycle", "--t-end", "0.6", "--dt", "1e-3"], tmp_path, "live", capsys)
    assert len(live["transients"]) >= 2
    assert len(rec["transients"]) == len(live["transients"])
    for a, b in zip(rec["transients"], live["transients"]):
        assert a["t"] == pytest.approx(b["t"], abs=1e-12)
        assert a["energy_loss_J"] == pytest.approx(b["energy_loss_J"], rel=1e-9)
        for k in ("F_O_x", "F_found_x", "M_found_O"):
            assert a["impulses_Ns"][k] == pytest.approx(b["impulses_Ns"][k], rel=1e-9, abs=1e-9)
