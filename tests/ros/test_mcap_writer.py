"""The recordings' MCAP writer against the ``mcap`` library's own writer: the same calls give
the same file, byte for byte (chunks closed by size and by flush, metadata between chunks,
messages out of time order, every compression), and the library's reader (with its CRC
checks) and rosbags read it back."""

from __future__ import annotations

import io
import random

import pytest

pytest.importorskip("mcap")

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from mps_ros.recording.mcap_writer import McapWriter

LIBRARY_KINDS = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "": CompressionType.NONE}


def _script(seed: int, n: int = 3000) -> list[tuple]:
    """A run of writer calls: schemas and channels, metadata, messages of random sizes and
    times (mostly rising, some earlier), flushes."""
    rnd = random.Random(seed)
    calls: list[tuple] = [
        ("start", "ros2", "a library"),
        ("metadata", "mps", {"software": "mps", "é": "ü"}),
        ("schema", "geometry_msgs/msg/WrenchStamped", "ros2msg", b"x" * 40),
        ("channel", "/a", "cdr", 1, {"offered_qos_profiles": "- depth: 1"}),
        ("channel", "/b", "cdr", 1, {}),
    ]
    t, seq = 1_000, {1: 0, 2: 0}
    for i in range(n):
        t += rnd.choice((0, 1_000_000, 1_000_000, 999))
        cid = rnd.choice((1, 1, 2))
        seq[cid] += 1
        at = max(0, t - rnd.randrange(5_000_000)) if rnd.random() < 0.05 else t
        data = bytes(rnd.randrange(256) for _ in range(rnd.randrange(1, 300)))
        calls.append(("message", cid, at, data, at, seq[cid]))
        if i == n // 3:
            calls.append(("schema", "std_msgs/msg/String", "ros2msg", b"string data"))
            calls.append(("channel", "/c", "cdr", 2, {"k": "v"}))
            seq[3] = 0
        if i > n // 3 and rnd.random() < 0.1:
            seq[3] += 1
            calls.append(("message", 3, t, b"abc", t, seq[3]))
        if rnd.random() < 0.004:
            calls.append(("flush",))
        if rnd.random() < 0.002:
            calls.append(("metadata", f"m{i}", {"i": str(i)}))
    return calls


def _play(w, calls) -> None:
    for c in calls:
        if c[0] == "start":
            w.start(profile=c[1], library=c[2])
        elif c[0] == "metadata":
            w.add_metadata(c[1], c[2])
        elif c[0] == "schema":
            w.register_schema(c[1], c[2], c[3])
        elif c[0] == "channel":
            w.register_channel(c[1], c[2], c[3], c[4])
        elif c[0] == "message":
            w.add_message(c[1], log_time=c[2], data=c[3], publish_time=c[4], sequence=c[5])
        else:
            w.flush()
    w.finish()


@pytest.mark.parametrize("compression", ["zstd", "lz4", ""])
@pytest.mark.parametrize("chunk_size", [4096, 1 << 20])
def test_same_bytes_as_the_mcap_library(compression, chunk_size):
    calls = _script(seed=len(compression) * 7 + chunk_size)
    ours, theirs = io.BytesIO(), io.BytesIO()
    _play(McapWriter(ours, chunk_size=chunk_size, compression=compression), calls)
    _play(Writer(theirs, chunk_size=chunk_size, compression=LIBRARY_KINDS[compression]), calls)
    assert len(ours.getvalue()) > 10_000
    assert ours.getvalue() == theirs.getvalue()
    # read back with the library's reader: the summary, the index, every message in order
    reader = make_reader(io.BytesIO(ours.getvalue()), validate_crcs=True)
    summary = reader.get_summary()
    sent = [c for c in calls if c[0] == "message"]
    assert summary.statistics.message_count == len(sent)
    if chunk_size == 4096:
        assert summary.statistics.chunk_count > 10
    got = [
        (m.channel_id, m.log_time, m.data, m.sequence)
        for _s, _c, m in reader.iter_messages(log_time_order=False)
    ]
    assert got == [(c[1], c[2], c[3], c[5]) for c in sent]


def test_the_recorder_file_reads_in_rosbags(tmp_path):
    """A recording written through :class:`~mps_ros.recording.recorder.Recorder` (this writer) opens in
    rosbags, an independent reader, with every message."""
    pytest.importorskip("rosbags")
    from rosbags.highlevel import AnyReader

    from mps_ros.run.record import record

    path, stats, counts = record(
        "press-cycle", tmp_path / "r.mcap", dt=1e-3, t_end=0.05, background=False, stop_on_signals=False
    )
    with AnyReader([path]) as reader:
        n = {c.topic: 0 for c in reader.connections}
        for conn, _t, raw in reader.messages():
            reader.deserialize(raw, conn.msgtype)
            n[conn.topic] += 1
    assert n == counts and sum(n.values()) > 50


def test_the_ros2_profiles_names_are_the_libraries():
    from mcap.stream_reader import MAGIC_SIZE
    from mcap.well_known import MessageEncoding, Profile, SchemaEncoding

    from mps_ros.recording.mcap_writer import ENCODING_CDR, MAGIC, PROFILE_ROS2, SCHEMA_ROS2MSG

    assert (PROFILE_ROS2, SCHEMA_ROS2MSG, ENCODING_CDR) == (
        Profile.ROS2,
        SchemaEncoding.ROS2,
        MessageEncoding.CDR,
    )
    out = io.BytesIO()
    w = Writer(out)
    w.start(profile=Profile.ROS2, library="test")
    w.finish()
    assert len(MAGIC) == MAGIC_SIZE and out.getvalue()[:MAGIC_SIZE] == MAGIC
