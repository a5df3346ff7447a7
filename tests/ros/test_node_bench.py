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


def test_the_tracking_bench_s_plain_loop_takes_the_slider_and_the_mode_signals_as_the_node_does():
    from mps_ros.bench.track import plain_run

    run, cpu_ms = plain_run("press-cycle", 10, measurements=300, slider=True, modes=True)
    tracker = run.tracker
    assert run.received == run.estimates == 299 and cpu_ms > 0.0  # stamps 1 ms to 299 ms
    assert tracker.accepted == 2 * 299  # the crank's and the slider's at each stamp
    assert tracker.signalled and tracker.sim.structure == "locked"  # engaged by its signal
    assert tracker.timing is not None  # searched for over the node's default latency
    crank_only, _ = plain_run("press-cycle", 10, measurements=300, modes=True)
    assert crank_only.tracker.accepted == 299 and crank_only.tracker.signalled
    unsignalled, _ = plain_run("working", 10, measurements=100)
    assert unsignalled.tracker.accepted == 99 and unsignalled.tracker.timing is None
