"""Bad input to ``mps view`` and ``mps loads``: each gets a clear message (exit 2), never a
traceback; a recording cut short gets a recovery hint that works."""

from __future__ import annotations

import sys

import pytest
from view_helpers import cut_before_end, foreign_mcap

from mps_core.cli import main
from mps_ros.recording.replay import ReplayError, read_recording


def _both(path, tmp_path, capsys) -> list[str]:
    """The error message of mps view and of mps loads on path."""
    errs = []
    for argv in (["view", str(path), "--save", str(tmp_path / "x.rrd"), "--no-spawn"], ["loads", str(path)]):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith("mps: error: ") and "Traceback" not in err
        errs.append(err)
    return errs


def test_not_mcap(tmp_path, capsys):
    p = tmp_path / "notes.mcap"
    p.write_text("t,phi\n0,1\n")
    for err in _both(p, tmp_path, capsys):
        assert "not an MCAP file" in err and "mps record" in err


def test_empty_file(tmp_path, capsys):
    p = tmp_path / "empty.mcap"
    p.write_bytes(b"")
    for err in _both(p, tmp_path, capsys):
        assert "not an MCAP file (empty)" in err


def test_missing_file(tmp_path, capsys):
    for err in _both(tmp_path / "nope.mcap", tmp_path, capsys):
        assert "no such file" in err


def test_mcap_of_another_program(tmp_path, capsys):
    p = foreign_mcap(tmp_path / "robot.mcap")
    for err in _both(p, tmp_path, capsys):
        assert "none of the press twin's topics" in err
        assert "/robot/pose" in err and "some-other-logger" in err


def test_truncated_recording_and_its_recovery(cycle_mcap, tmp_path, capsys):
    cut = cut_before_end(cycle_mcap, tmp_path / "cut.mcap")
    for err in _both(cut, tmp_path, capsys):
        assert "cut short" in err and "mps recover" in err
    # the hint works: recover, then replay
    fixed = tmp_path / "cut-recovered.mcap"
    assert main(["recover", str(cut), str(fixed)]) == 0
    capsys.readouterr()
    rep = read_recording(fixed)
    full = read_recording(cycle_mcap)
    assert 0 < len(rep) < len(full)
    assert (rep.columns["phi"] == full.columns["phi"][: len(rep)]).all()
    assert rep.scene.name == "press-cycle"


def test_summary_cut_still_reads_every_message(cycle_mcap, tmp_path):
    data = cycle_mcap.read_bytes()
    p = tmp_path / "nosummary.mcap"
    p.write_bytes(data[:-40])  # footer and part of the summary lost
    rep = read_recording(p)
    assert len(rep) == len(read_recording(cycle_mcap))
    assert any("no footer" in w for w in rep.warnings)


def test_a_directory(tmp_path):
    with pytest.raises(ReplayError, match="a directory"):
        read_recording(tmp_path)


def test_damaged_message(tmp_path, capsys):
    """A channel of the right type whose payload is not that type's CDR."""
    import view_helpers as vh
    from mcap.writer import Writer

    p = tmp_path / "damaged.mcap"
    with open(p, "wb") as fh:
        w = Writer(fh)
        w.start(profile="ros2", library="test")
        mt = "sensor_msgs/msg/JointState"
        sid = w.register_schema(mt, "ros2msg", vh._msgdef(mt).encode())
        cid = w.register_channel("/joint_states", "cdr", sid)
        w.add_message(cid, log_time=0, publish_time=0, data=b"\x00\x01\x00\x00\xff\xff\xff\xff")
        w.finish()
    for err in _both(p, tmp_path, capsys):
        assert "cannot be decoded" in err


def test_no_display_is_said_before_any_work(cycle_mcap, tmp_path, capsys, monkeypatch):
    """Without a display the viewer cannot open: one line at once, nothing written, neither
    for a recording nor for --live (with --save it works: the other tests)."""
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", None)
    if not sys.platform.startswith("linux"):
        pytest.skip("the display check is Linux's (DISPLAY, WAYLAND_DISPLAY)")
    for argv in (["view", str(cycle_mcap)], ["view", "--live", "--duration", "1"]):
        assert main(argv) == 2, argv
        out, err = capsys.readouterr()
        assert err.startswith("mps: error: no display to open the viewer on") and out == "", err
    assert list(tmp_path.iterdir()) == []  # no temporary .rrd left
