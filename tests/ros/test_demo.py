"""``make run``'s path: ``mps demo`` starts the node on press-cycle in realtime and an operator
client in another process that sends engage and disengage on /press_twin/mode; both end with
the run; the recording holds the commands as received and the machine's answer to them."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("rosbags")

from twin_probe import mps_cmd


def test_demo_runs_the_default_scene_with_an_operator(tmp_path):
    from rosbags.highlevel import AnyReader

    out = tmp_path / "demo.mcap"
    proc = subprocess.Popen(
        mps_cmd("demo", "--out", str(out)),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=tmp_path,
        env=dict(os.environ, PYTHONUNBUFFERED="1"),
        start_new_session=True,
    )
    try:
        text, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, 9)
            proc.wait(5)
    assert proc.returncode == 0, text
    assert f"Recording: {out.resolve()}" in text and "How to view it" in text
    assert "operator: 'engage' applied at t = " in text
    with AnyReader([Path(out)]) as r:
        msgs = {}
        for conn, t, raw in r.messages(connections=r.connections):
            msgs.setdefault(conn.topic, []).append((t, r.deserialize(raw, conn.msgtype)))
    assert [m.data for _, m in msgs["/press_twin/mode"]] == ["engage", "disengage"]
    acks = [json.loads(m.data) for _, m in msgs["/press_twin/mode/status"]]
    assert [(a["command"], a["accepted"]) for a in acks] == [("engage", True), ("disengage", True)]
    # each after its time, a step or so on a quiet machine (the operator is another process,
    # which a busy machine can hold back by tenths of a second), in order, before the end
    assert 0.008 < acks[0]["t"] < acks[1]["t"] < 1.0 and acks[1]["t"] > 0.4351
    kinds = [json.loads(m.data)["kind"] for _, m in msgs["/press_twin/events"]]
    assert "latch-closes" in kinds and kinds[-1] == "run-end"
    if acks[1]["t"] < 0.7:  # disengaged in time for the latch to open before the end
        assert "latch-opens" in kinds
    assert len(msgs["/joint_states"]) == 1001
