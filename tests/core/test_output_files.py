"""Outputs never destroy: a path checked before the run, never an input, never an existing file
unless --force, written whole (a temporary name renamed when complete)."""

import json
import os
import pty
import select
import signal
import socket
import stat
import subprocess
import sys
import threading
import time
from importlib import resources
from pathlib import Path

import pytest

from mps_core.cli import main
from mps_core.files.outputs import OutputFileError, check_outputs, partial_name, written_whole


@pytest.fixture
def scene_copy(tmp_path):
    s = tmp_path / "s.toml"
    s.write_bytes(resources.files("mps_core.scene.presets").joinpath("paper.toml").read_bytes())
    return s


@pytest.mark.parametrize("flag", ["--csv", "--events"])
def test_an_output_that_is_the_scene_is_refused_before_the_run(scene_copy, capsys, flag):
    before = scene_copy.read_bytes()
    assert main(["run", str(scene_copy), flag, str(scene_copy), "--force"]) == 2
    out, err = capsys.readouterr()
    assert out == ""  # nothing ran
    assert err.count("\n") == 1 and f"{flag} {str(scene_copy)!r}" in err
    assert "the command's input" in err and "destroy" in err
    assert scene_copy.read_bytes() == before


def test_an_existing_output_needs_force(tmp_path, capsys):
    csv = tmp_path / "p.csv"
    csv.write_text("keep me\n")
    assert main(["run", "paper", "--csv", str(csv)]) == 2
    out, err = capsys.readouterr()
    assert out == "" and "exists" in err and "--force" in err
    assert csv.read_text() == "keep me\n"
    assert main(["run", "paper", "--csv", str(csv), "--force"]) == 0
    assert csv.read_text().startswith("t,")
    assert list(tmp_path.iterdir()) == [csv]  # no temporary file left


def test_output_paths_are_checked_before_the_run(tmp_path, capsys):
    cases = [
        (["--csv", str(tmp_path / "nodir" / "x.csv")], "no directory"),
        (["--events", str(tmp_path)], "a directory, expected a file path"),
        (["--csv", str(tmp_path / "a"), "--events", str(tmp_path / "a")], "also the --csv"),
    ]
    for args, words in cases:
        assert main(["run", "paper", *args]) == 2, args
        out, err = capsys.readouterr()
        assert out == "" and words in err, (args, err)
    assert list(tmp_path.iterdir()) == []


def test_written_whole_leaves_the_target_as_it_was_on_an_error(tmp_path):
    target = tmp_path / "x.csv"
    target.write_text("old")
    with pytest.raises(RuntimeError):
        with written_whole(target) as tmp:
            assert tmp == partial_name(target) and tmp.parent == tmp_path
            tmp.write_text("half")
            raise RuntimeError("the disk is full")
    assert target.read_text() == "old" and list(tmp_path.iterdir()) == [target]
    with written_whole(target) as tmp:
        tmp.write_text("new")
    assert target.read_text() == "new" and list(tmp_path.iterdir()) == [target]


def test_check_outputs_ignores_absent_ones_and_preset_names(tmp_path):
    got = check_outputs({"--csv": None, "--events": tmp_path / "e.jsonl"}, inputs=["paper"])
    assert got == {"--events": tmp_path / "e.jsonl"}
    with pytest.raises(OutputFileError, match="not a file name"):
        check_outputs({"--csv": ""})


def test_a_run_that_fails_keeps_what_it_computed_marked_partial(tmp_path, capsys):
    import json

    from mps_core.dynamics.reaction_csv import read_csv

    csv, ev = tmp_path / "p.csv", tmp_path / "p.jsonl"
    assert (
        main(
            [
                "run",
                "press-cycle",
                "--no-chart-switching",
                "--dt",
                "0.001",
                "--reactions",
                "--csv",
                str(csv),
                "--events",
                str(ev),
            ]
        )
        == 2
    )
    out, err = capsys.readouterr()
    assert err.startswith("mps: error: t = ") and err.count("\n") == 1
    assert "(partial: up to t = " in out
    last = csv.read_text().splitlines()[-1]
    assert last.startswith("# partial: the run stopped at t = ") and "chart switching is off" in last
    cols = read_csv(csv)  # our reader skips the comment
    t_stop = cols["t"][-1]
    assert 0.1 < t_stop < 1.0 and len(cols["t"]) == round(t_stop / 0.001) + 1
    assert "F_found_x" in cols
    events = [json.loads(line) for line in ev.read_text().splitlines()]
    assert events[-1]["kind"] == "run-failed" and events[-1]["t"] == t_stop
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.csv", "p.jsonl"]


def test_mps_loads_checks_its_outputs_before_the_run(tmp_path, capsys):
    kept = tmp_path / "w.json"
    kept.write_text("{}")
    for args, words in (
        (["--png", str(tmp_path / "nodir" / "w.png")], "no directory"),
        (["--json", str(kept)], "exists"),
    ):
        assert main(["loads", "working", *args]) == 2
        out, err = capsys.readouterr()
        assert out == "" and words in err, err
    assert kept.read_text() == "{}"
    assert (
        main(
            [
                "loads",
                "working",
                "--t-end",
                "0.3",
                "--json",
                str(kept),
                "--png",
                str(tmp_path / "w.png"),
                "--force",
            ]
        )
        == 0
    )
    assert kept.read_text().startswith("{\n") or len(kept.read_text()) > 2
    assert (tmp_path / "w.png").read_bytes()[:4] == b"\x89PNG"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["w.json", "w.png"]


def test_mps_view_save_is_checked_before_reading(tmp_path, capsys):
    pytest.importorskip("rerun")
    from pathlib import Path

    sample = tmp_path / "s.mcap"
    repo = Path(__file__).resolve().parents[2]
    sample.write_bytes((repo / "recordings" / "sample_press-cycle.mcap").read_bytes())
    for save, words in ((tmp_path, "a directory"), (sample, "the command's input")):
        assert main(["view", str(sample), "--save", str(save), "--no-spawn", "--force"]) == 2
        assert words in capsys.readouterr().err


# -- streams: written into, never renamed over ------------------------------------------------
def _read_fifo_in_background(fifo):
    """Open ``fifo`` for reading in a thread; the thread and a list that gets its bytes."""
    got = []
    t = threading.Thread(target=lambda: got.append(fifo.read_bytes()), daemon=True)
    t.start()
    return t, got


def test_a_fifo_is_written_into_and_stays_a_fifo(tmp_path, capsys):
    fifo = tmp_path / "ff"
    os.mkfifo(fifo)
    reader, got = _read_fifo_in_background(fifo)
    # no --force needed (nothing is replaced); with it, the same
    assert main(["run", "paper", "--t-end", "0.01", "--dt", "0.001", "--csv", str(fifo), "--force"]) == 0
    reader.join(60)
    assert stat.S_ISFIFO(fifo.stat().st_mode)
    rows = got[0].decode().splitlines()
    assert rows[0].startswith("t,phi,") and len(rows) == 12
    assert f"wrote 11 rows to {fifo}" in capsys.readouterr().out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ff"]  # no temporary file beside it


def test_a_full_device_is_an_error_and_stays_a_device(tmp_path, capsys):
    full = tmp_path / "full"
    try:  # a /dev/full of the test's own (1, 7), so that nothing of the machine's is at stake
        os.mknod(full, 0o666 | stat.S_IFCHR, os.makedev(1, 7))
    except (PermissionError, OSError) as exc:
        pytest.skip(f"cannot make a device node here: {exc}")
    assert main(["run", "paper", "--t-end", "0.01", "--dt", "0.001", "--csv", str(full), "--force"]) == 2
    out, err = capsys.readouterr()
    assert "wrote" not in out and f"{full}: No space left on device" in err
    assert stat.S_ISCHR(full.stat().st_mode)


def test_dash_is_standard_output_and_the_summary_goes_to_standard_error(capsys):
    assert main(["run", "paper", "--t-end", "0.01", "--dt", "0.001", "--csv", "-"]) == 0
    out, err = capsys.readouterr()
    rows = out.splitlines()
    assert rows[0].startswith("t,phi,") and len(rows) == 12 and all(r.count(",") == 13 for r in rows)
    assert "scene paper" in err and "wrote 11 rows to standard output" in err
    assert main(["run", "paper", "--events", "-", "--csv", "-"]) == 2
    assert "also the --" in capsys.readouterr().err


def test_a_stream_is_refused_where_an_output_must_be_a_file(tmp_path):
    fifo = tmp_path / "ff"
    os.mkfifo(fifo)
    with pytest.raises(OutputFileError, match="a FIFO; expected a file path"):
        check_outputs({"recording": fifo}, force=True)
    with pytest.raises(OutputFileError, match="standard output; expected a file path"):
        check_outputs({"recording": "-"})
    sock = socket.socket(socket.AF_UNIX)
    try:
        sock.bind(str(tmp_path / "s"))
        with pytest.raises(OutputFileError, match="a socket; expected a file path, a FIFO"):
            check_outputs({"--csv": tmp_path / "s"}, force=True, streams={"--csv"})
    finally:
        sock.close()
    assert stat.S_ISFIFO(fifo.stat().st_mode)


# -- interrupted: one line, what was kept, exit 128 + the signal ------------------------------
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_mps_run_interrupted_keeps_what_it_computed_and_says_so_in_one_line(tmp_path, sig):
    """A long run interrupted once its progress line shows (on a terminal): exit 128 + the
    signal, one line naming what was kept where, no traceback; the CSV and the event log hold
    the rows computed, marked partial."""
    csv, events = tmp_path / "c.csv", tmp_path / "e.jsonl"
    cmd = [sys.executable, "-m", "mps_core.cli", "run", "press-cycle", "--t-end", "100", "--dt", "1e-4"]
    cmd += ["--csv", str(csv), "--events", str(events)]
    master, slave = pty.openpty()  # the progress line is shown on a terminal only
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=slave, cwd=tmp_path)
    os.close(slave)
    said = b""
    try:
        end = time.monotonic() + 120
        while b"%" not in said:  # the progress line: the run is stepping
            assert time.monotonic() < end and proc.poll() is None, said
            if select.select([master], [], [], 1.0)[0]:
                said += os.read(master, 4096)
        proc.send_signal(sig)
        proc.wait(120)
        while True:
            try:
                chunk = os.read(master, 4096)
            except OSError:  # the terminal's other end closed
                break
            if not chunk:
                break
            said += chunk
    finally:
        proc.kill()
        os.close(master)
    lines = [ln for ln in said.decode(errors="replace").replace("\r", "\n").splitlines() if "mps" in ln]
    assert proc.returncode == 128 + sig, said
    name = signal.Signals(sig).name
    assert len(lines) == 1 and lines[0].startswith(f"mps run: interrupted ({name}): "), lines
    assert f"rows in {csv}" in lines[0] and f"events in {events}" in lines[0] and "marked partial" in lines[0]
    assert b"Traceback" not in said
    rows = csv.read_text().splitlines()
    assert rows[-1].startswith("# partial: the run stopped at t = ") and rows[-1].endswith(
        f"interrupted ({name})"
    )
    assert len(rows) >= 3 and f"{len(rows) - 2} rows in" in lines[0]
    assert json.loads(events.read_text().splitlines()[-1])["error"] == f"interrupted ({name})"


def test_mps_loads_writes_its_json_to_standard_output(capsys):
    sample = Path(__file__).parents[2] / "recordings" / "sample_press-cycle.mcap"
    pytest.importorskip("mcap")
    assert main(["loads", str(sample), "--json", "-"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["source"] == "sample_press-cycle.mcap"
    assert "wrote standard output" in err and "foundation" in err


def test_a_reader_that_stops_reading_standard_output_ends_the_command_quietly(tmp_path):
    """``mps run --csv - | head -1``: the table (about a megabyte, more than a pipe holds) goes
    out until the reader closes its end; the command then ends with status 0 and no error."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "mps_core.cli", "run", "press-cycle", "--t-end", "0.5", "--dt", "1e-4"]
        + ["--csv", "-", "-q"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        cwd=tmp_path,
    )
    first = proc.stdout.readline()
    proc.stdout.close()  # the reader stops here
    err = proc.stderr.read().decode()
    assert proc.wait(120) == 0, err
    assert first.startswith(b"t,phi,") and "error" not in err and "Traceback" not in err
