"""Recordings carry what Jazzy's rosbag2 writes into an MCAP bag: each channel's
``topic_type_hash`` (the same as rclpy's and rosbags' for the type) and a ``rosbag2`` metadata
record whose ``serialized_metadata`` is the bag's BagMetadata (version 9) and says what the
file holds; a recovered file gets one for what it recovered."""

from __future__ import annotations

import pytest

pytest.importorskip("mcap")
pytest.importorskip("rosbags")
yaml = pytest.importorskip("yaml")

from mps_ros.recording.recorder import Recorder  # noqa: E402
from mps_ros.recording.recover import read_metadata, recover  # noqa: E402
from mps_ros.run.runner import Runner  # noqa: E402
from mps_ros.run.sinks import RecordingSink  # noqa: E402
from mps_ros.run.twin import Twin  # noqa: E402
from mps_ros.wire.topics import MSGTYPES, TYPE_HASHES  # noqa: E402


def test_type_hashes_are_rosbags_jazzy_ones():
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    assert set(TYPE_HASHES) == set(MSGTYPES)
    assert {m: ts.hash_rihs01(m) for m in MSGTYPES} == TYPE_HASHES


def test_type_hashes_are_what_rclpy_offers(ros):
    """Of the types importable here (tf2_msgs is not among the PyPI wheels: rosbags' hash
    alone vouches for it)."""
    from mps_ros.ros.endpoints import MSG_CLASSES

    node = ros.create_node("type_hashes")
    importable = [m for m in MSGTYPES if m in MSG_CLASSES]
    assert len(importable) >= len(MSGTYPES) - 1
    try:
        got = {}
        for i, m in enumerate(importable):
            node.create_publisher(MSG_CLASSES[m], f"/mps_type_hash_{i}", 1)
            info = node.get_publishers_info_by_topic(f"/mps_type_hash_{i}")
            got[m] = str(info[0].topic_type_hash)
    finally:
        node.destroy_node()
    assert got == {m: TYPE_HASHES[m] for m in importable}


def _summary(path):
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        s = make_reader(f).get_summary()
    by_topic = {ch.topic: s.statistics.channel_message_counts.get(cid, 0) for cid, ch in s.channels.items()}
    return s, by_topic


def _bag(path) -> dict:
    return yaml.safe_load(read_metadata(path)["rosbag2"]["serialized_metadata"])


def _holds_what_the_file_holds(path, name):
    s, counts = _summary(path)
    bag = _bag(path)
    assert bag["version"] == 9 and bag["storage_identifier"] == "mcap"
    assert bag["ros_distro"] == "jazzy"
    assert bag["message_count"] == s.statistics.message_count == sum(counts.values())
    assert bag["starting_time"]["nanoseconds_since_epoch"] == s.statistics.message_start_time
    assert bag["duration"]["nanoseconds"] == (s.statistics.message_end_time - s.statistics.message_start_time)
    assert bag["relative_file_paths"] == [name]
    assert bag["files"][0]["path"] == name
    assert bag["files"][0]["message_count"] == bag["message_count"]
    topics = {t["topic_metadata"]["name"]: t for t in bag["topics_with_message_count"]}
    assert {n: t["message_count"] for n, t in topics.items()} == counts
    for ch in s.channels.values():
        meta = topics[ch.topic]["topic_metadata"]
        msgtype = s.schemas[ch.schema_id].name
        assert meta["type"] == msgtype and meta["serialization_format"] == "cdr"
        assert meta["type_description_hash"] == TYPE_HASHES[msgtype]
        assert ch.metadata["topic_type_hash"] == TYPE_HASHES[msgtype]
        # the profiles as a list, the channel's YAML parsed
        assert meta["offered_qos_profiles"] == yaml.safe_load(ch.metadata["offered_qos_profiles"])
        assert meta["offered_qos_profiles"][0]["reliability"] == "reliable"
    return bag


def _recorded(path, t_end: float):
    """press-cycle at 1 kHz to ``t_end`` recorded to ``path`` (small chunks)."""
    twin = Twin("press-cycle", dt=0.001, t_end=t_end)
    rec = Recorder(path, scene_name="press-cycle", scene_text=twin.scene.text, chunk_size=16 * 1024)
    Runner(twin, sinks=[RecordingSink(rec)]).run()
    rec.finish()
    return path


def test_a_recording_says_what_it_holds_as_rosbag2_does(tmp_path):
    bag = _holds_what_the_file_holds(_recorded(tmp_path / "bag.mcap", 0.1), "bag.mcap")
    assert bag["message_count"] > 1000


def test_a_recovered_recording_says_what_it_recovered(tmp_path):
    full = _recorded(tmp_path / "full.mcap", 0.2)
    data = full.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    out = tmp_path / ".back.tmp"
    rep = recover(cut, out, name="back.mcap")
    assert not rep.complete and rep.messages > 0
    bag = _holds_what_the_file_holds(out, "back.mcap")
    assert bag["message_count"] == rep.messages
    # a whole file keeps its own record, once
    again = tmp_path / "again.mcap"
    recover(full, again)
    assert _bag(again) == _bag(full)
