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
    # each a step or so after its time (more on a busy machine: the operator is another process)
    assert 0.008 < acks[0]["t"] < 0.3 and 0.4351 < acks[1]["t"] < 0.7
    kinds = [json.loads(m.data)["kind"] for _, m in msgs["/press_twin/events"]]
    assert "latch-closes" in kinds and "latch-opens" in kinds and kinds[-1] == "run-end"
    assert len(msgs["/joint_states"]) == 1001
