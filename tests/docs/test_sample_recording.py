"""recordings/sample_press-cycle.mcap, which the README's tour and the docs use, still reads back
with today's code: the replay, rosbags' AnyReader (every topic of the node present, with its
type), and ``mps loads`` on it."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mcap")
pytest.importorskip("rosbags")

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "recordings" / "sample_press-cycle.mcap"


def test_sample_is_small_and_complete():
    assert SAMPLE.is_file(), "recordings/sample_press-cycle.mcap is missing (see recordings/README.md)"
    assert SAMPLE.stat().st_size < 1_000_000
    from mps_ros.recording.recover import read_metadata

    meta = read_metadata(SAMPLE)
    assert meta["scene"]["name"] == "press-cycle"
    assert "[mechanism]" in meta["scene"]["toml"]
    assert meta["mps"]["version"]
    assert meta["mps"]["source"] == "mps record"


def test_sample_reads_back_with_the_replay():
    from mps_ros.recording.replay import read_recording

    rep = read_recording(SAMPLE)
    assert rep.scene.name == "press-cycle"
    c = rep.columns
    assert len(rep) == 1001 and c["t"][0] == 0.0 and c["t"][-1] == pytest.approx(1.0)
    # idle on the stop, engaged and working, free again: every structure, every step filled in
    assert set(c["structure"]) == {"held", "locked", "free"}
    kinds = [ev["kind"] for ev in rep.events]
    for kind in ("run-start", "command", "latch-closes", "latch-opens", "stop-contact", "run-end"):
        assert kind in kinds, kind
    # at least one whole working stroke: the crank turns a full revolution while locked
    locked = c["structure"] == "locked"
    assert np.ptp(c["phi"][locked]) > 2 * np.pi
    for col in ("phi", "psi", "x_C", "phi_dot", "F_found_x", "F_O_x", "M_motor"):
        assert np.all(np.isfinite(c[col])), col


def test_sample_reads_back_with_rosbags():
    from rosbags.highlevel import AnyReader

    from mps_ros.wire.topics import BY_KEY, resolve

    expected = {resolve(k): t.msgtype for k, t in BY_KEY.items()}
    with AnyReader([SAMPLE]) as reader:
        found = {c.topic: c.msgtype for c in reader.connections}
        assert found == expected
        counts = {c.topic: c.msgcount for c in reader.connections}
        for topic in (
            "/joint_states",
            "/clock",
            "/press_twin/foundation",
            "/press_twin/reactions/O",
            "/press_twin/reactions/stop",
        ):
            assert counts[topic] == 1001, topic
        assert counts["/press_twin/structure"] >= 4  # latched: at its changes
        seen = set()
        for conn, _t, raw in reader.messages():
            if conn.topic not in seen:
                reader.deserialize(raw, conn.msgtype)
                seen.add(conn.topic)
        assert seen == {t for t, n in counts.items() if n}


def test_mps_loads_on_the_sample(tmp_path):
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", MPLBACKEND="Agg")
    mps = Path(sys.executable).parent / "mps"
    cmd = [str(mps)] if mps.exists() else [sys.executable, "-m", "mps_core.cli"]
    r = subprocess.run(
        [*cmd, "loads", str(SAMPLE), "--json", str(tmp_path / "loads.json")],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    assert "F_found_x" in r.stdout
    assert (tmp_path / "loads.json").stat().st_size > 1000
