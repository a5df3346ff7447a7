"""MCAP recordings of the twin, without ROS (mcap, mcap-ros2-support and rosbags only).

One module for the node and for ``mps record``: both hand the message dicts they publish to a
:class:`Recorder`, which serializes them to CDR with mcap-ros2-support's encoder (the same
values, the same bytes, whichever process made them).

The file: profile ``ros2``; one schema a type, encoding ``ros2msg``, the definition with all
the definitions it depends on (rosbags' Jazzy type store); channels ``cdr`` with
``offered_qos_profiles`` (rosbag2's YAML) in their metadata; messages in zstd-compressed chunks,
``log_time`` = ``publish_time`` = the simulated time at which the node published (or, for a
command, received) them, in nanoseconds; two metadata records at the start, ``mps`` (software,
version, run settings) and ``scene`` (the scene's TOML text), so a recording describes itself.

**Safety.** A chunk is written when it is full (``chunk_size``) or ``flush_period`` wall seconds
after the last one, straight to the file (no user-space buffer). On a normal end, Ctrl-C or
SIGTERM the caller calls :meth:`Recorder.finish`, which writes the summary and the footer. A
process killed hard (SIGKILL, power loss) leaves a file without a footer: every chunk written so
far is intact, and :func:`recover` (``mps recover IN OUT``) copies them into a complete file.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Protocol

from ..wire.cdr import encoder, generic_encoder, msgdef
from ..wire.topics import TYPE_HASHES, qos_yaml
from .mcap_writer import ENCODING_CDR, PROFILE_ROS2, SCHEMA_ROS2MSG, McapWriter

PROFILE = PROFILE_ROS2


def default_path(scene_name: str, directory: str | os.PathLike = "recordings") -> Path:
    """``DIRECTORY/SCENE-DATE-TIME.mcap``, the time to the millisecond (not created)."""
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S-%f")[:-3]
    return Path(directory) / f"{scene_name}-{stamp}.mcap"


def new_recording(scene_name: str, directory: str | os.PathLike = "recordings") -> Path:
    """A recording's path of its own, created empty (exclusively: two runs started in the same
    millisecond, in two processes, never get the same file): :func:`default_path`, or with
    ``-2``, ``-3``... where that exists. The folder is made where missing."""
    first = default_path(scene_name, directory)
    first.parent.mkdir(parents=True, exist_ok=True)
    return reserve_free(first)


def reserve_free(first: Path, start: int = 1) -> Path:
    """The first free one of ``first`` (``start`` 1) and ``first`` with ``-2``, ``-3``... before
    its suffix, claimed at once: a file created empty (:func:`reserve`), or, for a name not
    ending in ``.mcap`` (a bag), a directory created."""
    from .bag import is_bag

    for i in range(start, start + 1000):
        path = first if i == 1 else first.with_name(f"{first.stem}-{i}{first.suffix}")
        try:
            if is_bag(path):
                path.mkdir()
                return path
            return reserve(path)
        except FileExistsError:
            continue
    raise FileExistsError(f"no free recording name like {str(first)!r}")


def reserve(path) -> Path:
    """Create ``path`` empty, exclusively: FileExistsError where it exists (a recording is never
    written over another file)."""
    with open(path, "xb"):
        pass
    return Path(path)


class _Direct:
    """A file written straight through to the OS: what the MCAP writer has written is in the
    file even if the process is killed the next instant (no user-space buffer to lose)."""

    def __init__(self, path, exclusive: bool = False):
        self._f = open(path, "xb" if exclusive else "wb", buffering=0)

    def write(self, data) -> int:
        view = memoryview(data)
        done = 0
        while done < len(view):
            done += self._f.write(view[done:])
        return done

    def tell(self) -> int:
        return self._f.tell()

    def flush(self) -> None:
        pass

    def close(self) -> None:
        self._f.close()


@dataclass
class _Channel:
    id: int
    msgtype: str = ""
    qos: str = ""
    count: int = 0


def channel_metadata(msgtype: str, qos: str | None = None) -> dict[str, str]:
    """A channel's metadata as Jazzy's rosbag2 writes it: its offered QoS profiles (YAML) and
    its type's description hash."""
    meta = {"offered_qos_profiles": qos or qos_yaml()}
    if msgtype in TYPE_HASHES:
        meta["topic_type_hash"] = TYPE_HASHES[msgtype]
    return meta


def rosbag2_record(file_name: str, writer: McapWriter, channels: dict) -> dict[str, str]:
    """The ``rosbag2`` metadata record of what ``writer`` has written (flushed): ``channels``,
    by channel id, as (topic, type, offered QoS YAML)."""
    from .bag_metadata import TopicCount, record

    _total, start, end, per = writer.written()
    topics = [
        TopicCount(topic, msgtype, qos, TYPE_HASHES.get(msgtype, ""), per.get(cid, 0))
        for cid, (topic, msgtype, qos) in sorted(channels.items())
    ]
    return record(file_name, topics, start, end)


#: a step's message as a run hands it over: (topic key, CDR bytes, simulated time ns, received:
#: a command as it came in)
Message = tuple[str, bytes, int, bool]


class RecordingWriter(Protocol):
    """What writes a recording: :class:`Recorder` in this process,
    :class:`~mps_ros.recording.background.BackgroundRecorder` in a process of its own."""

    path: Path
    #: messages handed over so far
    messages: int

    def channel(self, topic: str, msgtype: str, qos: str | None = None) -> Any:
        """Register a topic's channel; return its handle for :meth:`write_steps`."""
        ...

    def write(self, topic: str, msgtype: str, data: bytes, t_ns: int, qos: str | None = None) -> None:
        """Record one message's CDR bytes at simulated time ``t_ns``."""
        ...

    def write_steps(self, msgs: Sequence[Message], ids: dict[str, Any]) -> None:
        """Record a step's messages in order; ``ids`` maps each key to its channel's handle."""
        ...

    def tick(self) -> None:
        """Do what is due at a step's end (a chunk closed, a batch sent, a bag's file split)."""
        ...

    def counts(self) -> dict[str, int]:
        """Return the messages recorded so far by topic."""
        ...

    def finish(self) -> None:
        """Complete the recording."""
        ...


class Recorder:
    """An MCAP recording being written. ``metadata``: extra key/values for the ``mps`` record;
    ``scene_text``: the scene's TOML (the ``scene`` record).

    A ``path`` that does not end in ``.mcap`` is a bag directory (:mod:`mps_ros.recording.bag`): its
    files are split at the first :meth:`tick` (a step's end) where one holds ``max_bytes`` in
    whole chunks or spans ``max_s`` of simulated time (0: never), and :meth:`finish` writes
    its ``metadata.yaml``."""

    def __init__(
        self,
        path,
        *,
        scene_name: str = "",
        scene_text: str = "",
        metadata: dict | None = None,
        chunk_size: int = 512 * 1024,
        flush_period: float = 1.0,
        compression: str = "zstd",
        max_bytes: int = 0,
        max_s: float = 0.0,
        file_name: str = "",
    ):
        from mps_core import __version__

        from .bag import is_bag

        self.path = Path(path)
        #: the name its rosbag2 record gives a file that is renamed once finished (not a bag's)
        self.file_name = file_name
        self.bag = is_bag(self.path)
        self.max_bytes = int(max_bytes) if self.bag else 0
        self.max_ns = int(round(float(max_s) * 1e9)) if self.bag else 0
        if self.bag:
            self.path.mkdir(parents=True, exist_ok=True)
        else:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        self.chunk_size = chunk_size
        self.compression = "" if compression == "none" else compression
        meta = {
            "software": "mps",
            "version": __version__,
            "scene": scene_name,
            "created": datetime.now(UTC).isoformat(timespec="seconds"),
        }
        meta.update({k: str(v) for k, v in (metadata or {}).items()})
        self._records = (("mps", meta), ("scene", {"name": scene_name, "toml": scene_text}))
        self._library = f"mps {__version__} (mcap writer)"
        self._channels: dict[str, _Channel] = {}
        #: the bag's files written so far (:class:`~mps_ros.recording.bag.FileSpan`), and their topics'
        #: counts (topic -> (type, QoS, messages))
        self.spans: list = []
        self._bag_topics: dict[str, list] = {}
        self.flush_period = float(flush_period)
        self._last_flush = time.monotonic()
        self._pending = 0
        self.finished = False
        self.messages = 0
        self._open(0)

    def _open(self, index: int) -> None:
        """Start file ``index`` (the recording's one file, or the bag's next), the channels
        known so far registered in it."""
        from .bag import file_name

        self.file = self.path / file_name(self.path, index) if self.bag else self.path
        self._stream = _Direct(self.file, exclusive=self.bag)
        self._w = McapWriter(self._stream, chunk_size=self.chunk_size, compression=self.compression)
        self._w.start(profile=PROFILE, library=self._library)
        for name, data in self._records:
            self._w.add_metadata(name, data)
        self._schemas: dict[str, int] = {}
        for topic, ch in self._channels.items():
            ch.id = self._register(topic, ch.msgtype, ch.qos)
        self._opened_at = self.messages  # a file holds a message before it is split

    def _register(self, topic: str, msgtype: str, qos: str) -> int:
        sid = self._schemas.get(msgtype)
        if sid is None:
            sid = self._schemas[msgtype] = self._w.register_schema(
                msgtype, SCHEMA_ROS2MSG, msgdef(msgtype).encode()
            )
        return self._w.register_channel(topic, ENCODING_CDR, sid, channel_metadata(msgtype, qos))

    def channel(self, topic: str, msgtype: str, qos: str | None = None) -> _Channel:
        ch = self._channels.get(topic)
        if ch is None:
            qos = qos or qos_yaml()
            ch = self._channels[topic] = _Channel(self._register(topic, msgtype, qos), msgtype, qos)
        return ch

    def write(self, topic: str, msgtype: str, data: bytes, t_ns: int, qos: str | None = None) -> None:
        """Record one message: its CDR bytes (see :func:`encoder`), at simulated time t_ns."""
        ch = self._channels.get(topic) or self.channel(topic, msgtype, qos)
        ch.count += 1
        self.messages += 1
        self._pending += 1
        self._w.add_message(ch.id, log_time=t_ns, data=data, publish_time=t_ns, sequence=ch.count)

    def write_steps(self, msgs: Sequence[Message], ids: dict[str, Any]) -> None:
        """Record a step's messages in order: ``(key, CDR bytes, t_ns, received)`` each, with
        ``ids`` the caller's map of keys to the channels :meth:`channel` gave."""
        add = self._w.add_message
        for key, data, t_ns, _received in msgs:
            ch = ids[key]
            ch.count += 1
            add(ch.id, log_time=t_ns, data=data, publish_time=t_ns, sequence=ch.count)
        self.messages += len(msgs)
        self._pending += len(msgs)

    def tick(self) -> None:
        """Close the chunk in progress if it is older than ``flush_period`` (wall time); in a
        bag, go on in a new file where this one is full."""
        if self._pending and time.monotonic() - self._last_flush >= self.flush_period:
            self.flush()
        if (self.max_bytes or self.max_ns) and self.messages > self._opened_at:
            start, end = self._w.span()
            if (self.max_bytes and self._w.size >= self.max_bytes) or (
                self.max_ns and end - start >= self.max_ns
            ):
                self._close_file()
                self._open(len(self.spans))

    def flush(self) -> None:
        self._w.flush()
        self._pending = 0
        self._last_flush = time.monotonic()

    def counts(self) -> dict[str, int]:
        return {t: c.count for t, c in self._channels.items()}

    def _close_file(self) -> None:
        """The file's last chunk, its ``rosbag2`` metadata record (as Jazzy's rosbag2 writes
        it on closing a bag: :mod:`~mps_ros.recording.bag_metadata`), its summary; a bag's file among
        its spans, its topics' counts added."""
        from .bag import FileSpan

        try:
            self._w.flush()
            by_id = {c.id: (t, c.msgtype, c.qos) for t, c in self._channels.items()}
            name = self.file_name if self.file_name and not self.bag else self.file.name
            self._w.add_metadata("rosbag2", rosbag2_record(name, self._w, by_id))
            self._w.finish()
        finally:
            self._stream.close()
        if self.bag:
            n, start, end, per = self._w.written()
            self.spans.append(FileSpan(self.file.name, start, end, n))
            for cid, (topic, msgtype, qos) in by_id.items():
                got = self._bag_topics.setdefault(topic, [msgtype, qos, 0])
                got[2] += per.get(cid, 0)

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc) -> None:
        """``with Recorder(path) as rec:``: the file finished however the block ends (an
        error included: what was written reads back)."""
        self.finish()

    def finish(self) -> None:
        """The last file closed; a bag's ``metadata.yaml`` (a last file without a message,
        where a split fell at the very end, removed)."""
        if self.finished:
            return
        self.finished = True
        self._close_file()
        if not self.bag:
            return
        from .bag import write_metadata
        from .bag_metadata import TopicCount

        if len(self.spans) > 1 and not self.spans[-1].count:
            self.spans.pop()
            self.file.unlink()
        write_metadata(
            self.path,
            self.spans,
            [TopicCount(t, m, q, TYPE_HASHES.get(m, ""), n) for t, (m, q, n) in self._bag_topics.items()],
        )


__all__ = [
    "Message",
    "Recorder",
    "RecordingWriter",
    "channel_metadata",
    "rosbag2_record",
    "msgdef",
    "encoder",
    "generic_encoder",
    "default_path",
    "new_recording",
    "reserve",
    "reserve_free",
]
