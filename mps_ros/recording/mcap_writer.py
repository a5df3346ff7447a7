"""The recordings' MCAP writer: the MCAP format (version 0) written record for record as the
``mcap`` library's :class:`mcap.writer.Writer` writes it with its defaults (chunked, every
index, the schemas and channels repeated in the summary, statistics, summary offsets, CRCs of
the chunks and the summary), so that the same calls give the same bytes, and a message path
made for what the node records: many small messages, eleven a step at 1 kHz.

The library builds each message through a record object and a dozen stream writes (about
forty Python calls); here a message is one ``struct`` pack and two appends to the chunk in
progress, which is what lets the recording keep up with a run many times faster than real
time. Everything but the messages (the header, schemas, channels, metadata, chunks and
their indexes, the summary) is rare and written plainly from the specification
(https://mcap.dev/spec).
"""

from __future__ import annotations

import struct
import zlib

from mps_core.files.inputs import MCAP_MAGIC as MAGIC

#: the ROS 2 profile's well-known names (the ``mcap`` library's ``mcap.well_known``: Profile.ROS2,
#: SchemaEncoding.ROS2, MessageEncoding.CDR; tests/ros/test_mcap_writer.py holds them equal)
PROFILE_ROS2, SCHEMA_ROS2MSG, ENCODING_CDR = "ros2", "ros2msg", "cdr"

# record opcodes (the specification's table)
HEADER, FOOTER, SCHEMA, CHANNEL, MESSAGE, CHUNK = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
MESSAGE_INDEX, CHUNK_INDEX, ATTACHMENT_INDEX, STATISTICS = 0x07, 0x08, 0x0A, 0x0B
METADATA, METADATA_INDEX, SUMMARY_OFFSET, DATA_END = 0x0C, 0x0D, 0x0E, 0x0F

_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
#: a message record's head: opcode, length, channel id, sequence, log time, publish time
_MESSAGE = struct.Struct("<BQHIQQ")
_MESSAGE_FIXED = _MESSAGE.size - 9
_RECORD = struct.Struct("<BQ")
_CHUNK_HEAD = struct.Struct("<QQQI")
_CHUNK_INDEX_HEAD = struct.Struct("<QQQQ")
_STATISTICS_HEAD = struct.Struct("<QHIIIIQQ")
_SUMMARY_OFFSET = struct.Struct("<BQQ")
_FOOTER = struct.Struct("<BQQQ")


def _record(opcode: int, body: bytes) -> bytes:
    return _RECORD.pack(opcode, len(body)) + body


def _string(text: str) -> bytes:
    raw = text.encode()
    return _U32.pack(len(raw)) + raw


def _string_map(items: dict[str, str]) -> bytes:
    body = b"".join(_string(k) + _string(v) for k, v in items.items())
    return _U32.pack(len(body)) + body


def _compressor(compression: str):
    if compression == "zstd":
        import zstandard

        return zstandard.compress
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.compress
    if compression == "":
        return None
    raise ValueError(f"compression: {compression!r} is not one of 'zstd', 'lz4', '' (none)")


class McapWriter:
    """An MCAP file written to ``stream`` (anything with ``write``; ``flush`` is called by
    :meth:`flush`). ``compression``: ``"zstd"``, ``"lz4"`` or ``""``; a chunk is closed once
    it holds more than ``chunk_size`` bytes (uncompressed), or at :meth:`flush`."""

    def __init__(self, stream, chunk_size: int = 1024 * 1024, compression: str = "zstd"):
        self._stream = stream
        self._pos = 0  # bytes written to the stream
        self.chunk_size = int(chunk_size)
        self.compression = compression
        self._compress = _compressor(compression)
        self._schemas: list[bytes] = []  # records, for the summary
        self._channels: list[bytes] = []
        self._chunk_indexes: list[bytes] = []
        self._metadata_indexes: list[bytes] = []
        self._metadata_count = 0
        # the statistics, gathered from each chunk as it is closed
        self.message_count = 0
        self._start = self._end = 0
        self._per_channel: dict[int, int] = {}  # in the order channels first had one
        # the chunk in progress
        self._chunk = bytearray()
        self._chunk_messages = 0
        self._chunk_start = self._chunk_end = 0
        self._index: dict[int, list[int]] = {}  # channel id -> log time, offset, ...

    def _out(self, data: bytes) -> None:
        self._stream.write(data)
        self._pos += len(data)

    # -- the data section -----------------------------------------------------------------
    def start(self, profile: str = "", library: str = "") -> None:
        self._out(MAGIC + _record(HEADER, _string(profile) + _string(library)))

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        """A schema (in the chunk in progress, and in the summary); its id."""
        sid = len(self._schemas) + 1
        rec = _record(
            SCHEMA, _U16.pack(sid) + _string(name) + _string(encoding) + _U32.pack(len(data)) + bytes(data)
        )
        self._schemas.append(rec)
        self._into_chunk(rec)
        return sid

    def register_channel(
        self, topic: str, message_encoding: str, schema_id: int, metadata: dict[str, str] | None = None
    ) -> int:
        """A channel (in the chunk in progress, and in the summary); its id."""
        cid = len(self._channels) + 1
        rec = _record(
            CHANNEL,
            _U16.pack(cid)
            + _U16.pack(schema_id)
            + _string(topic)
            + _string(message_encoding)
            + _string_map(metadata or {}),
        )
        self._channels.append(rec)
        self._into_chunk(rec)
        return cid

    def _into_chunk(self, rec: bytes) -> None:
        self._chunk += rec
        if len(self._chunk) > self.chunk_size:
            self._close_chunk()

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """A metadata record, written at once (between chunks), and indexed."""
        rec = _record(METADATA, _string(name) + _string_map(data))
        self._metadata_indexes.append(
            _record(METADATA_INDEX, _U64.pack(self._pos) + _U64.pack(len(rec)) + _string(name))
        )
        self._metadata_count += 1
        self._out(rec)

    def add_message(
        self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int = 0
    ) -> None:
        """One message into the chunk in progress (closed once it is full)."""
        chunk = self._chunk
        if self._chunk_messages:
            if log_time < self._chunk_start:
                self._chunk_start = log_time
            if log_time > self._chunk_end:
                self._chunk_end = log_time
        else:
            self._chunk_start = log_time
            self._chunk_end = log_time if log_time > self._chunk_end else self._chunk_end
        self._chunk_messages += 1
        index = self._index.get(channel_id)
        if index is None:
            index = self._index[channel_id] = []
        index += (log_time, len(chunk))
        chunk += _MESSAGE.pack(
            MESSAGE, _MESSAGE_FIXED + len(data), channel_id, sequence, log_time, publish_time
        )
        chunk += data
        if len(chunk) > self.chunk_size:
            self._close_chunk()

    def _close_chunk(self) -> None:
        if not self._chunk_messages:
            return
        raw = bytes(self._chunk)
        packed = self._compress(raw) if self._compress else raw
        chunk = _record(
            CHUNK,
            _CHUNK_HEAD.pack(self._chunk_start, self._chunk_end, len(raw), zlib.crc32(raw))
            + _string(self.compression)
            + _U64.pack(len(packed))
            + packed,
        )
        chunk_at = self._pos
        self._out(chunk)
        indexes = bytearray()
        offsets = bytearray()
        for cid, flat in self._index.items():
            offsets += _U16.pack(cid) + _U64.pack(self._pos + len(indexes))
            indexes += _record(
                MESSAGE_INDEX,
                _U16.pack(cid) + _U32.pack(len(flat) * 8) + struct.pack(f"<{len(flat)}Q", *flat),
            )
        self._out(bytes(indexes))
        # the file's statistics: the chunk's range and counts folded in (channels in the
        # order they first had a message, as the chunk's index keeps them)
        if self.message_count:
            self._start = min(self._start, self._chunk_start)
        else:
            self._start = self._chunk_start
        self._end = max(self._end, self._chunk_end)
        self.message_count += self._chunk_messages
        per = self._per_channel
        for cid, flat in self._index.items():
            per[cid] = per.get(cid, 0) + len(flat) // 2
        self._chunk_indexes.append(
            _record(
                CHUNK_INDEX,
                _CHUNK_INDEX_HEAD.pack(self._chunk_start, self._chunk_end, chunk_at, len(chunk))
                + _U32.pack(len(offsets))
                + offsets
                + _U64.pack(len(indexes))
                + _string(self.compression)
                + _U64.pack(len(packed))
                + _U64.pack(len(raw)),
            )
        )
        self._chunk = bytearray()
        self._chunk_messages = 0
        self._chunk_start = self._chunk_end = 0
        self._index = {}

    @property
    def size(self) -> int:
        """Bytes written to the stream so far (the chunk in progress not among them)."""
        return self._pos

    def span(self) -> tuple[int, int]:
        """The first and the last log time of the messages so far, the chunk in progress
        included ((0, 0) before the first)."""
        if not self.message_count:
            return self._chunk_start, self._chunk_end
        if not self._chunk_messages:
            return self._start, self._end
        return min(self._start, self._chunk_start), max(self._end, self._chunk_end)

    def written(self) -> tuple[int, int, int, dict[int, int]]:
        """What the closed chunks hold: (messages, the first and the last log time, messages
        by channel id); after :meth:`flush`, every message."""
        return self.message_count, self._start, self._end, dict(self._per_channel)

    def flush(self) -> None:
        """Close the chunk in progress (if it holds a message) and flush the stream."""
        self._close_chunk()
        self._stream.flush()

    # -- the end ----------------------------------------------------------------------------
    def finish(self) -> None:
        """The last chunk, the data end, the summary, the footer and the closing magic (the
        stream is left open)."""
        self._close_chunk()
        self._out(_record(DATA_END, _U32.pack(0)))
        summary_start = self._pos
        summary = bytearray()
        offsets = bytearray()

        def group(opcode: int, records) -> None:
            at = len(summary)
            for rec in records:
                summary.extend(rec)
            offsets.extend(
                _record(SUMMARY_OFFSET, _SUMMARY_OFFSET.pack(opcode, summary_start + at, len(summary) - at))
            )

        counts = b"".join(_U16.pack(c) + _U64.pack(n) for c, n in self._per_channel.items())
        statistics = _record(
            STATISTICS,
            _STATISTICS_HEAD.pack(
                self.message_count,
                len(self._schemas),
                len(self._channels),
                0,
                self._metadata_count,
                len(self._chunk_indexes),
                self._start,
                self._end,
            )
            + _U32.pack(len(counts))
            + counts,
        )
        group(SCHEMA, self._schemas)
        group(CHANNEL, self._channels)
        group(STATISTICS, [statistics])
        group(CHUNK_INDEX, self._chunk_indexes)
        group(ATTACHMENT_INDEX, [])
        group(METADATA_INDEX, self._metadata_indexes)
        offsets_start = summary_start + len(summary)
        summary += offsets
        start = summary_start if summary else 0
        crc = zlib.crc32(_FOOTER.pack(FOOTER, 20, start, offsets_start), zlib.crc32(summary))
        self._out(bytes(summary))
        self._out(_record(FOOTER, _U64.pack(start) + _U64.pack(offsets_start) + _U32.pack(crc)) + MAGIC)


__all__ = ["McapWriter", "MAGIC", "PROFILE_ROS2", "SCHEMA_ROS2MSG", "ENCODING_CDR"]
