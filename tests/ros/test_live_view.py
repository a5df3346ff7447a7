"""``mps view --live --save X.rrd`` against a short node run: a process of its own follows the
node and writes a Rerun recording that Rerun's own reader reads back with the mechanism, the
arrows and the plots under the offline view's entity paths, one sample a step received."""

from __future__ import annotations

import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("rerun")

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "view"))

from twin_probe import NodeProcess, mps_cmd, stop_group
from view_helpers import read_rrd

from mps_ros.view.offline import FAMILIES
from mps_ros.wire.topics import FOUNDATION, WRENCHES

DT = 1e-3
T_END = 0.5


def test_live_view_saves_what_the_offline_view_draws(ros, tmp_path):
    rrd = tmp_path / "live.rrd"
    log = open(tmp_path / "live.log", "wb")
    viewer = subprocess.Popen(
        mps_cmd("view", "--live", "--save", str(rrd), "--duration", "60"),
        stdout=log,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    try:
        # the follower is ready (subscribed, its sink open) before the node starts
        end = time.monotonic() + 120
        while b"following" not in (tmp_path / "live.log").read_bytes():
            assert viewer.poll() is None and time.monotonic() < end, (tmp_path / "live.log").read_text()
            time.sleep(0.05)
        # the topics the follower takes (not /clock, not the markers), so that the node can
        # wait until it has subscribed to every one of them, however slow discovery is
        params = dict(
            pacing="realtime",
            dt=DT,
            t_end=T_END,
            recording="none",
            outputs="[joint_states,reactions,foundation,structure,events,diagnostics]",
            wait_for_subscribers=1,
            wait_timeout=60.0,
            start_delay=0.5,
        )
        with NodeProcess(tmp_path, params) as node:
            assert node.wait(60) == 0, node.log()
        assert viewer.wait(60) == 0, (tmp_path / "live.log").read_text()
    finally:
        stop_group(viewer)
        log.close()
    text = (tmp_path / "live.log").read_text()
    assert "live view:" in text and "frames" in text, text
    d = read_rrd(rrd)
    # the plots: every step it received, once, in order, on the step grid, to the run's end
    t = d["/plots/crank_angle/phi"]["time_ns"]
    assert len(t) > 0.8 * round(T_END / DT) and np.all(np.diff(t) > 0), len(t)
    assert np.allclose(t % round(DT * 1e9), 0) and t[-1] == round(T_END * 1e9)
    for fam, _, series in FAMILIES:
        for col, _name in series:
            assert np.array_equal(d[f"/plots/{fam}/{col}"]["time_ns"], t), col
    # the drawing: at those steps, or at some of them and each frame's last where the view
    # had fallen behind the run (a frame of more than DRAW_MAX steps), to the run's end
    drawn = d["/mechanism/links"]["time_ns"]
    assert np.all(np.isin(drawn, t)) and np.all(np.diff(drawn) > 0) and drawn[-1] == t[-1]
    frames = int(re.search(r"live view: (\d+) frames", text).group(1))
    assert len(drawn) >= min(len(t), frames), (len(drawn), len(t), frames)
    for ent in ("/mechanism/frame", "/mechanism/slider", "/mechanism/joints", "/mechanism/latch"):
        assert ent in d, ent
    for w in (*WRENCHES, FOUNDATION):
        if any(c is not None for c in w.force):
            assert np.array_equal(d[f"/mechanism/reactions/{w.name}"]["time_ns"], drawn), w.name
    assert "/events" in d


def test_live_view_refuses_a_save_it_cannot_write(tmp_path):
    """--save is checked before anything starts: a folder that is not there, and an existing
    file without --force (left as it was), are one line each and status 2."""
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    p = subprocess.run(
        mps_cmd("view", "--live", "--save", str(blocker / "x.rrd"), "--duration", "1"),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert p.returncode == 2, p.stderr
    assert "--save" in p.stderr and "no directory" in p.stderr
    assert "Traceback" not in p.stderr
    kept = tmp_path / "kept.rrd"
    kept.write_bytes(b"an earlier view")
    p = subprocess.run(
        mps_cmd("view", "--live", "--save", str(kept), "--duration", "1"),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert p.returncode == 2 and "exists" in p.stderr and "--force" in p.stderr, p.stderr
    assert kept.read_bytes() == b"an earlier view" and "Traceback" not in p.stderr


def test_live_view_refuses_a_recording_and_a_bad_rate():
    for args, words in ((["rec.mcap", "--live"], "give no recording"), (["--live", "--hz", "0"], "--hz 0.0")):
        p = subprocess.run(mps_cmd("view", *args), capture_output=True, text=True, timeout=120)
        assert p.returncode != 0 and words in p.stderr + p.stdout, p.stderr
        assert "Traceback" not in p.stderr
