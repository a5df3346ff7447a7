"""A recording read back (mps_ros.recording.replay) against an independent reader (rosbags)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mps_ros.recording.replay import DERIVED, read_recording
from mps_ros.wire.topics import BY_KEY, FOUNDATION, JOINT_NAMES, WRENCHES, resolve


def rosbags_read(path):
    """Every message of a recording by full topic: (log times ns, messages), by rosbags."""
    from rosbags.highlevel import AnyReader

    out = {}
    with AnyReader([Path(path)]) as r:
        for conn, t, raw in r.messages(connections=r.connections):
            ts, msgs = out.setdefault(conn.topic, ([], []))
            ts.append(t)
            msgs.append(r.deserialize(raw, conn.msgtype))
    return {k: (np.array(v[0], dtype=np.int64), v[1]) for k, v in out.items()}


def test_columns_equal_every_message(cycle_mcap):
    rep = read_recording(cycle_mcap)
    ref = rosbags_read(cycle_mcap)
    t_ns, js = ref[resolve("joint_states")]
    assert len(rep) == len(js) == 601
    assert np.array_equal(np.round(rep.columns["t"] * 1e9).astype(np.int64), t_ns)
    names = list(js[0].name)
    assert names == list(JOINT_NAMES)
    pos = np.array([m.position for m in js])
    vel = np.array([m.velocity for m in js])
    for j, (pc, vc) in {
        "crank": ("phi", "phi_dot"),
        "rod": ("rod", "rod_dot"),
        "rocker": ("psi", "psi_dot"),
        "slider": ("x_C", "x_C_dot"),
    }.items():
        k = names.index(j)
        assert np.array_equal(rep.columns[pc], pos[:, k]), pc
        assert np.array_equal(rep.columns[vc], vel[:, k]), vc
    for w in (*WRENCHES, FOUNDATION):
        tw, msgs = ref[resolve(w.key)]
        assert np.array_equal(tw, t_ns)
        for col, get in (
            (w.force[0], lambda m: m.wrench.force.x),
            (w.force[1], lambda m: m.wrench.force.y),
            (w.torque, lambda m: m.wrench.torque.z),
        ):
            if col is not None:
                assert np.array_equal(rep.columns[col], np.array([get(m) for m in msgs])), col
    ts, st = ref[resolve("~/structure")]
    # latched: a message where the structure changes, held on the steps between
    at = np.searchsorted(ts, t_ns, side="right") - 1
    assert at.min() == 0 and len(st) < len(js)
    assert list(rep.columns["structure"]) == [st[i].data for i in at]
    assert {"held", "free", "locked"} <= set(rep.columns["structure"])
    _, evs = ref[resolve("~/events")]
    assert len(rep.events) == len(evs)
    kinds = [e["kind"] for e in rep.events]
    for k in (
        "run-start",
        "command",
        "stop-release",
        "latch-closes",
        "latch-opens",
        "stop-contact",
        "run-end",
    ):
        assert k in kinds, k


def test_scene_and_version_from_metadata(cycle_mcap):
    from mps_core import __version__
    from mps_core.scene import load_scene

    rep = read_recording(cycle_mcap)
    assert rep.version == __version__
    assert rep.warnings == []
    sc = rep.scene
    ref = load_scene("press-cycle")
    assert sc.name == "press-cycle"
    assert sc.geometry == ref.geometry and sc.x_top == ref.x_top


def test_accelerations_are_derived_and_said_so(cycle_mcap):
    rep = read_recording(cycle_mcap)
    c = rep.columns
    assert set(DERIVED) == {"phi_ddot", "psi_ddot"}
    assert np.array_equal(c["phi_ddot"], np.gradient(c["phi_dot"], c["t"], edge_order=2))


def test_topics_by_suffix_under_another_namespace(tmp_path):
    """A node run in a namespace (/line1/press_twin/...) is still recognised."""
    import view_helpers as vh
    from mcap.writer import Writer

    p = tmp_path / "ns.mcap"
    with open(p, "wb") as fh:
        w = Writer(fh)
        w.start(profile="ros2", library="test")
        mt = BY_KEY["joint_states"].msgtype
        sid = w.register_schema(mt, "ros2msg", vh._msgdef(mt).encode())
        cid = w.register_channel("/line1/joint_states", "cdr", sid)
        for i in range(3):
            w.add_message(
                cid,
                log_time=i * 1000,
                publish_time=i * 1000,
                data=vh._encode(
                    mt,
                    {
                        "header": {"stamp": {"sec": 0, "nanosec": i * 1000}, "frame_id": "press"},
                        "name": list(JOINT_NAMES),
                        "position": [0.1 * i, 0.0, -0.5, 0.02],
                        "velocity": [1.0, 0.0, 0.0, 0.0],
                        "effort": [],
                    },
                ),
            )
        w.finish()
    rep = read_recording(p)
    assert np.array_equal(rep.columns["phi"], [0.0, 0.1, 0.2])
    assert rep.scene is None
    with pytest.raises(Exception, match="--scene"):
        from mps_ros.view.offline import convert

        pytest.importorskip("rerun")
        convert(rep)
