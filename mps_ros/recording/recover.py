"""Recordings read back and recovered: their metadata records, a file's intact chunks, and a
file or bag killed before its end copied into a complete one (``mps recover``)."""

from __future__ import annotations

import io
import struct
from dataclasses import dataclass, field
from pathlib import Path

from ..wire.topics import TYPE_HASHES, qos_yaml
from .mcap_writer import MAGIC, McapWriter
from .recorder import PROFILE, rosbag2_record


def read_metadata(path) -> dict[str, dict[str, str]]:
    """The metadata records of a recording (complete or cut short), by name."""
    out = {}
    for rec in _records(Path(path)):
        if rec[0] == "metadata":
            out[rec[1].name] = dict(rec[1].metadata)
    return out


@dataclass
class Recovered:
    messages: int = 0
    chunks: int = 0
    complete: bool = False
    truncated_at: int | None = None
    topics: dict = field(default_factory=dict)
    #: the messages' first and last log time (ns), and each topic's (type, offered QoS)
    start_ns: int = 0
    end_ns: int = 0
    types: dict = field(default_factory=dict)


def _records(path: Path, report: Recovered | None = None):
    """Records of an MCAP file in order, chunks opened; stops quietly at the first record that
    is cut short or damaged (a file whose writer was killed). Yields ("header", Header),
    ("metadata", Metadata), ("schema", Schema), ("channel", Channel), ("message", Message),
    ("end", None)."""
    from mcap.data_stream import ReadDataStream
    from mcap.records import Channel, Chunk, Header, Message, Metadata, Schema
    from mcap.stream_reader import breakup_chunk

    data = path.read_bytes()
    if data[:8] != MAGIC:
        raise ValueError(f"{path}: not an MCAP file (bad magic)")
    pos, size = 8, len(data)
    while True:
        if pos + 9 > size:
            break
        opcode = data[pos]
        (length,) = struct.unpack_from("<Q", data, pos + 1)
        body_start = pos + 9
        if body_start + length > size:
            break
        body = data[body_start : body_start + length]
        stream = ReadDataStream(io.BytesIO(body))
        try:
            if opcode == 0x01:
                yield "header", Header.read(stream)
            elif opcode == 0x02:  # footer: the file is complete
                if report is not None:
                    report.complete = True
                yield "end", None
                return
            elif opcode == 0x03:
                yield "schema", Schema.read(stream)
            elif opcode == 0x04:
                yield "channel", Channel.read(stream)
            elif opcode == 0x05:
                yield "message", Message.read(stream, length)
            elif opcode == 0x06:
                chunk = Chunk.read(stream)
                inner = breakup_chunk(chunk, validate_crc=True)
                if report is not None:
                    report.chunks += 1
                for r in inner:
                    kind = {Schema: "schema", Channel: "channel", Message: "message"}.get(type(r))
                    if kind:
                        yield kind, r
            elif opcode == 0x0C:
                yield "metadata", Metadata.read(stream)
            elif opcode == 0x0F:  # data end
                pass
        except Exception:
            break
        pos = body_start + length
    if report is not None:
        report.truncated_at = pos


def intact(path) -> Recovered:
    """Return what :func:`recover` would copy of ``path`` (its messages, their last log time,
    whether the file is complete), without writing anything."""
    report = Recovered()
    first = None
    for kind, r in _records(Path(path), report):
        if kind == "message":
            report.messages += 1
            first = r.log_time if first is None else min(first, r.log_time)
            report.end_ns = max(report.end_ns, r.log_time)
            report.topics[r.channel_id] = report.topics.get(r.channel_id, 0) + 1
    report.start_ns = first or 0
    return report


def recover(src, dst, name: str | None = None, renamed: bool = False) -> Recovered:
    """Copy what is intact in ``src`` (e.g. a recording whose writer was killed: no footer, the
    last chunk cut short) into a complete MCAP file ``dst``: header, metadata, schemas, channels
    and every message of every whole chunk, in their order; and the ``rosbag2`` metadata
    record of what it holds where ``src`` has none (``name``: the file's name it gives, where
    ``dst`` is a temporary one; ``renamed``: a new record in any case, as the file is now
    another bag's)."""
    src, dst = Path(src), Path(dst)
    if src.resolve() == dst.resolve():
        raise ValueError("recover writes a new file: give an output path other than the input")
    report = Recovered()
    dst.parent.mkdir(parents=True, exist_ok=True)
    with open(dst, "wb") as fh:
        w = McapWriter(fh)
        started = False
        schemas: dict[int, int] = {}
        schema_names: dict[int, str] = {}
        channels: dict[int, int] = {}
        topics: dict[int, str] = {}
        described: dict[int, tuple] = {}  # new channel id: (topic, type, offered QoS)
        rosbag2 = False
        for kind, r in _records(src, report):
            if kind == "header":
                w.start(profile=r.profile, library=r.library)
                started = True
                continue
            if not started:
                w.start(profile=PROFILE, library="mps recover")
                started = True
            if kind == "metadata":
                if r.name == "rosbag2" and renamed:
                    continue
                w.add_metadata(r.name, dict(r.metadata))
                rosbag2 = rosbag2 or r.name == "rosbag2"
            elif kind == "schema" and r.id not in schemas:
                schemas[r.id] = w.register_schema(r.name, r.encoding, r.data)
                schema_names[r.id] = r.name
            elif kind == "channel" and r.id not in channels:
                channels[r.id] = w.register_channel(
                    r.topic, r.message_encoding, schemas.get(r.schema_id, 0), dict(r.metadata)
                )
                topics[r.id] = r.topic
                described[channels[r.id]] = (
                    r.topic,
                    schema_names.get(r.schema_id, ""),
                    dict(r.metadata).get("offered_qos_profiles", qos_yaml()),
                )
            elif kind == "message" and r.channel_id in channels:
                w.add_message(
                    channels[r.channel_id],
                    log_time=r.log_time,
                    data=r.data,
                    publish_time=r.publish_time,
                    sequence=r.sequence,
                )
                report.messages += 1
                t = topics[r.channel_id]
                report.topics[t] = report.topics.get(t, 0) + 1
        if not started:
            w.start(profile=PROFILE, library="mps recover")
        if not rosbag2:  # written as the file closes: cut off with its end
            w.flush()
            w.add_metadata("rosbag2", rosbag2_record(name or dst.name, w, described))
        w.finish()
    _n, report.start_ns, report.end_ns, _per = w.written()
    report.types = {topic: (msgtype, qos) for topic, msgtype, qos in described.values()}
    return report


def recover_bag(src, dst, name: str | None = None) -> Recovered:
    """:func:`recover` of each file of the bag ``src`` (:func:`mps_ros.recording.bag.files`: those its
    ``metadata.yaml`` lists, else the files a killed writer left) into a new bag ``dst``:
    its files named after it (or ``name``, where ``dst`` is a temporary directory), in their
    order, and its ``metadata.yaml``. The report sums the files' (``complete``: every one
    was)."""
    from .bag import FileSpan, file_name, files, write_metadata
    from .bag_metadata import TopicCount

    src, dst = Path(src), Path(dst)
    parts = files(src)
    if not parts:
        raise ValueError(
            f"{src}: a directory without a recording in it (expected a bag: "
            "metadata.yaml and its .mcap files)"
        )
    dst.mkdir(exist_ok=True)
    total = Recovered(complete=True)
    spans: list = []
    topics: dict = {}
    for i, part in enumerate(parts):
        part_name = file_name(name or dst, i)
        rep = recover(part, dst / part_name, renamed=True)
        total.messages += rep.messages
        total.chunks += rep.chunks
        total.complete = total.complete and rep.complete
        spans.append(FileSpan(part_name, rep.start_ns, rep.end_ns, rep.messages))
        for topic, (msgtype, qos) in rep.types.items():
            n = rep.topics.get(topic, 0)
            if n:
                total.topics[topic] = total.topics.get(topic, 0) + n
            topics.setdefault(topic, [msgtype, qos, 0])[2] += n
    write_metadata(
        dst, spans, [TopicCount(t, m, q, TYPE_HASHES.get(m, ""), n) for t, (m, q, n) in topics.items()]
    )
    return total


__all__ = ["read_metadata", "Recovered", "intact", "recover", "recover_bag"]
