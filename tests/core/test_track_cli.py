"""``mps emulate`` and ``mps track``: the measurements' file written and read back, the
estimates and the per-stroke table written, a malformed file named."""

from __future__ import annotations

import csv
import re
import signal
import subprocess
import sys

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


def test_the_cuts_fitted_in_the_fitting_process_are_the_trackers_own(tmp_path, capsys):
    """``mps track`` fits its cuts in a process of their own (the filter goes on meanwhile): its
    stroke table is the one a tracker that fits them itself makes, number for number; with
    ``--no-fit-cuts`` the peaks are the filter's."""
    from mps_core.scene import load_scene
    from mps_core.track import Tracker
    from mps_core.track.truth import nominal_scene

    m, strokes, plain = tmp_path / "m.csv", tmp_path / "strokes.csv", tmp_path / "plain.csv"
    assert main(["emulate", "working", "--t-end", "0.45", "--seed", "3", "--csv", str(m)]) == 0
    assert main(["track", "working", "--csv", str(m), "--strokes", str(strokes)]) == 0
    assert "cuts fitted whole: 3" in capsys.readouterr().out
    assert main(["track", "working", "--csv", str(m), "--strokes", str(plain), "--no-fit-cuts"]) == 0
    measurements, _ = read_measurements(m, {"crank_angle": Encoder().variance})
    tracker = Tracker(nominal_scene(load_scene("working")))
    for x in measurements:
        tracker.update(x)
        tracker.observe_stroke()
    table, unfitted = list(csv.DictReader(strokes.open())), list(csv.DictReader(plain.open()))
    assert len(table) == len(tracker.strokes.strokes) >= 2
    for row, off, s in zip(table, unfitted, tracker.strokes.strokes, strict=True):
        assert float(row["peak_force_N"]) == s.peak_force and float(row["contact_m"]) == s.fit.contact
        assert float(off["peak_force_N"]) == s.filter_peak_force and off["contact_m"] == "nan"


def test_late_signals_emulated_and_searched_for(tmp_path, capsys):
    m, truth = tmp_path / "m.csv", tmp_path / "truth.csv"
    emulate = [
        "emulate",
        "press-cycle",
        "--t-end",
        "0.06",
        "--slider",
        "--csv",
        str(m),
        "--truth",
        str(truth),
    ]
    assert main([*emulate, "--signals-late", "0.004"]) == 0
    _, modes = read_measurements(m, {"crank_angle": 1.0, "slider_position": 1.0})
    assert modes[0].command == "engage" and modes[0].t == pytest.approx(0.008 + 0.004)
    locked = [r["locked"] for r in csv.DictReader(truth.open())]
    assert locked[0] == "0" and locked[-1] == "1"  # the latch closed within the 60 ms
    assert main(["track", "press-cycle", "--csv", str(m)]) == 0
    said = capsys.readouterr().out
    assert "rejected or reported: none" in said
    found = float(said.split("their commands found (ms before their stamps) ")[1].split()[0].rstrip(","))
    assert abs(found - 4.0) < 1.0, said
    assert main(["track", "press-cycle", "--csv", str(m), "--signal-latency", "0"]) == 0
    assert "outlier" in capsys.readouterr().out  # applied at its stamp: the model behind the press
    assert main(["track", "press-cycle", "--csv", str(m), "--signal-latency", "0.5"]) == 2
    assert "--signal-latency = 0.5: expected a time in [0, 0.1] s" in capsys.readouterr().err


def test_a_malformed_measurements_file_is_named(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("t,crank_angle_rad,pressure\n0.001,0.5,3\n")
    assert main(["track", "working", "--csv", str(bad)]) == 2
    assert "column = 'pressure': expected one of t, crank_angle_rad" in capsys.readouterr().err
    bad.write_text("t,crank_angle_rad\n0.001,half\n")
    assert main(["track", "working", "--csv", str(bad)]) == 2
    assert ":2: crank_angle_rad = 'half': expected a number" in capsys.readouterr().err


@pytest.fixture(scope="module")
def four_seconds(tmp_path_factory):
    """Four seconds of ``working``'s encoder (a few seconds to follow with a recording)."""
    m = tmp_path_factory.mktemp("track") / "m.csv"
    assert main(["emulate", "working", "--t-end", "4", "--seed", "3", "--csv", str(m)]) == 0
    return m


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_mps_track_interrupted_writes_what_it_followed_marked_partial(tmp_path, four_seconds, sig):
    """A signal once ``mps track`` says it is following: it stops before the next measurement,
    writes its estimates, strokes and recording with what it followed, each marked partial
    (the CSVs' last line, the recording's metadata), says so in one line and exits 128 + the
    signal; the recording is whole (its summary read back)."""
    from mcap.reader import make_reader

    est, strokes, rec = tmp_path / "est.csv", tmp_path / "strokes.csv", tmp_path / "rec.mcap"
    cmd = [sys.executable, "-m", "mps_core.cli", "track", "working", "--csv", str(four_seconds)]
    cmd += ["--out", str(est), "--out", str(rec), "--strokes", str(strokes)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        first = proc.stderr.readline()  # said before the first measurement is taken
        assert first.startswith("following 3999 measurements"), first
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=300)
    finally:
        proc.kill()
    name = signal.Signals(sig).name
    assert proc.returncode == 128 + sig, (out, err)
    assert "Traceback" not in err
    line = err.strip().splitlines()[-1]
    assert line.startswith(
        f"mps track: interrupted ({name}): {est}, {strokes}, {rec} written, marked partial"
    )
    followed = re.search(r"\((followed to .*, (\d+) of 3999 measurements)\)$", line)
    assert followed, line
    taken = int(followed.group(2))
    assert taken < 3999
    partial = f"# partial: {followed.group(1)}: interrupted ({name})"
    rows = est.read_text().splitlines()
    assert rows[-1] == partial and len(rows) - 2 <= taken
    assert strokes.read_text().splitlines()[-1] == partial
    with rec.open("rb") as f:
        reader = make_reader(f)
        assert reader.get_summary() is not None
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    assert meta["mps"]["partial"] == partial[len("# partial: ") :]


def test_mps_emulate_interrupted_writes_the_press_it_emulated(tmp_path):
    """A signal once ``mps emulate`` says it is emulating: it ends the emulation where it is and
    writes its measurements and truth to there, files a tracker reads, says so in one line and
    exits 128 + the signal."""
    m, truth = tmp_path / "m.csv", tmp_path / "truth.csv"
    cmd = [sys.executable, "-m", "mps_core.cli", "emulate", "working", "--t-end", "60"]
    cmd += ["--csv", str(m), "--truth", str(truth)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        first = proc.stderr.readline()  # said before the truth's first step
        assert first.startswith("emulating 60 s of working's truth"), first
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=300)
    finally:
        proc.kill()
    assert proc.returncode == 128 + signal.SIGTERM, (out, err)
    line = err.strip().splitlines()[-1]
    reached = re.fullmatch(
        rf"mps emulate: interrupted \(SIGTERM\): {m}, {truth} written, the emulation to t = (\S+) s of 60",
        line,
    )
    assert reached, line
    measurements, _modes = read_measurements(m, {"crank_angle": Encoder().variance})
    assert f"wrote {len(measurements)} rows" in out
    t_reached = float(reached.group(1))  # said to six digits
    assert all(x.t <= t_reached * (1 + 1e-5) for x in measurements)
    rows = list(csv.DictReader(truth.open()))
    assert rows and float(rows[-1]["t"]) == pytest.approx(t_reached, rel=1e-5)
