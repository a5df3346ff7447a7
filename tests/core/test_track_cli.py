"""``mps emulate`` and ``mps track``: the measurements' file written and read back, the
estimates and the per-stroke table written, a malformed file named."""

from __future__ import annotations

import csv

import pytest

from mps_core.cli import main
from mps_core.track import Encoder
from mps_core.track.measurement_csv import read_measurements


def test_emulate_then_track(tmp_path, capsys):
    m, truth = tmp_path / "m.csv", tmp_path / "truth.csv"
    assert main(["emulate", "working", "--t-end", "0.16", "--csv", str(m), "--truth", str(truth)]) == 0
    measurements, modes = read_measurements(m, {"crank_angle": Encoder().variance})
    assert len(measurements) == 159 and not modes
    assert all(0.0 <= x.value < 6.2832 for x in measurements)
    out, strokes = tmp_path / "est.csv", tmp_path / "strokes.csv"
    args = ["track", "working", "--csv", str(m), "--out", str(out), "--strokes", str(strokes), "--loads"]
    assert main(args) == 0
    said = capsys.readouterr().out
    assert "159 taken; rejected or reported: none" in said
    assert "tracking OK throughout (mean NIS" in said
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == 159 and float(rows[-1]["t"]) == pytest.approx(measurements[-1].t)
    assert {"force", "force_sigma", "F_found_x", "F_found_x_sigma"} <= set(rows[0])
    assert {r["tracking"] for r in rows} == {"OK"}
    table = list(csv.DictReader(strokes.open()))
    assert [r["stroke"] for r in table] == ["0.0"]
    assert 20e3 < float(table[0]["peak_force_N"]) < 40e3  # the truth's part: 28.3 kN
    assert main(args) == 2  # the outputs exist: refused without --force
    assert "exists" in capsys.readouterr().err


def test_a_malformed_measurements_file_is_named(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("t,crank_angle_rad,pressure\n0.001,0.5,3\n")
    assert main(["track", "working", "--csv", str(bad)]) == 2
    assert "column = 'pressure': expected one of t, crank_angle_rad" in capsys.readouterr().err
    bad.write_text("t,crank_angle_rad\n0.001,half\n")
    assert main(["track", "working", "--csv", str(bad)]) == 2
    assert ":2: crank_angle_rad = 'half': expected a number" in capsys.readouterr().err
