"""The node benchmark's bookkeeping (mps_ros.bench; the benchmarks themselves are not tests):
messages by topic from a recording, and the published-less-received differences by topic."""

import shutil
from pathlib import Path

import pytest
from rosbags.highlevel import AnyReader

from mps_ros.bench.cli import _lost_line
from mps_ros.bench.suite import keep_logs, lost_by_topic, recorded_counts

SAMPLE = Path(__file__).resolve().parents[2] / "recordings" / "sample_press-cycle.mcap"


def test_recorded_counts_are_the_recordings_messages_by_topic():
    """The summary's counts, against an independent reader going through every message."""
    counts = recorded_counts(SAMPLE)
    with AnyReader([SAMPLE]) as reader:
        want = {c.topic: c.msgcount for c in reader.connections}
        total = sum(1 for _ in reader.messages())
    assert counts == want
    assert sum(counts.values()) == total and counts["/joint_states"] > 1000


def test_an_unfinished_recording_has_no_counts_and_says_so(tmp_path):
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(SAMPLE.read_bytes()[: SAMPLE.stat().st_size // 2])
    with pytest.raises(RuntimeError, match="cut.mcap.*no summary"):
        recorded_counts(cut)


def test_lost_by_topic_names_each_topic_that_differs_and_no_other():
    published = {"/clock": 1000, "/joint_states": 1000, "/press_twin/events": 25}
    received = {"/clock": 1000, "/joint_states": 998, "/press_twin/extra": 3}
    assert lost_by_topic(published, received) == {
        "/joint_states": 2,
        "/press_twin/events": 25,
        "/press_twin/extra": -3,
    }
    assert lost_by_topic(published, dict(published)) == {}
    # printed only where some differ
    assert _lost_line({"lost_by_topic": {}}) == ""
    assert "/joint_states 2" in _lost_line({"lost_by_topic": {"/joint_states": 2}})
    assert "no summary" in _lost_line({"lost_by_topic": None, "recording_error": "recording 'x': no summary"})


def test_keep_logs_copies_the_runs_logs_and_figures(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "rt.log").write_text("node log\n")
    (run / "probe.log").write_text("subscriber log\n")
    keep = tmp_path / "kept" / "soak1"
    keep_logs(run, keep, "soak", {"messages": 3, "lost_by_topic": {"/clock": 1}})
    assert (keep / "soak-node.log").read_text() == "node log\n"
    assert (keep / "soak-subscriber.log").read_text() == "subscriber log\n"
    assert '"/clock": 1' in (keep / "soak.json").read_text()
    shutil.rmtree(run)  # kept after the run's own folder is gone
    assert (keep / "soak-node.log").exists()
