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

import io
import marshal
import os
import struct
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

from .cdr import encoder, generic_encoder, msgdef
from .mcap_writer import ENCODING_CDR, MAGIC, PROFILE_ROS2, SCHEMA_ROS2MSG, McapWriter
from .os_threads import widen_pipe
from .topics import BY_KEY, DEPTH, NODE_NAME, TYPE_HASHES, offered_qos, qos_yaml, resolve

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


class Recorder:
    """An MCAP recording being written. ``metadata``: extra key/values for the ``mps`` record;
    ``scene_text``: the scene's TOML (the ``scene`` record).

    A ``path`` that does not end in ``.mcap`` is a bag directory (:mod:`mps_ros.bag`): its
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
        #: the bag's files written so far (:class:`~mps_ros.bag.FileSpan`), and their topics'
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

    def write(self, topic: str, msgtype: str, data: bytes, t_ns: int, qos: str | None = None):
        """Record one message: its CDR bytes (see :func:`encoder`), at simulated time t_ns."""
        ch = self._channels.get(topic) or self.channel(topic, msgtype, qos)
        ch.count += 1
        self.messages += 1
        self._pending += 1
        self._w.add_message(ch.id, log_time=t_ns, data=data, publish_time=t_ns, sequence=ch.count)

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
        it on closing a bag: :mod:`~mps_ros.bag_metadata`), its summary; a bag's file among
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


class BackgroundRecorder:
    """A :class:`Recorder` that writes in a process of its own (the machine's second core),
    off the stepping loop's time: the loop hands it each message's CDR bytes, which it sends
    down a pipe in batches (every ``batch_period`` wall seconds, at :meth:`tick`); the other
    process (``python -m mps_ros.recording``) writes them (:class:`~mps_ros.mcap_writer.McapWriter`) in the
    order they were given. Same methods as :class:`Recorder`; ``messages`` and :meth:`counts`
    count what was handed over, ``written`` what the other process wrote (after
    :meth:`finish`).

    The writing process ignores SIGINT and SIGTERM (the stepping process stops on them and
    calls :meth:`finish`); it finishes the file when told, or when the pipe closes because the
    stepping process is gone, so a crashed run still leaves a complete file. Killed with its
    process group (SIGKILL), it leaves a file that :func:`recover` completes.

    The pipe's frames: one byte (``I`` the recorder's settings as JSON, ``C`` a channel as
    JSON, ``B`` a batch of messages, ``S`` a batch of steps, ``F`` flush, ``E`` finish), the
    payload's length (u32), the payload; a batch is records of (channel u16, time ns i64,
    length u32, CDR bytes); a batch of steps is the :mod:`marshal` dump (one interpreter
    writes and reads it) of (the keys' channel ids where they grew, else None; the steps'
    lists of (key, CDR bytes, t_ns, received)). The
    writing process answers on its standard output, one JSON line each: ``{"ready": true}``
    (or ``{"error": …}``) after the settings, ``{"done": N, "counts": {topic: n}}`` (or
    ``{"error": …}``) at the end.
    """

    def __init__(
        self,
        path,
        *,
        batch_period: float = 0.02,
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
        import json
        import subprocess
        import sys

        self.path = Path(path)
        self.batch_period = float(batch_period)
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "mps_ros.recording"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            bufsize=0,
        )
        self._out = self._proc.stdin
        widen_pipe(self._out.fileno())
        settings = {
            "path": str(path),
            "scene_name": scene_name,
            "scene_text": scene_text,
            "metadata": {k: str(v) for k, v in (metadata or {}).items()},
            "chunk_size": int(chunk_size),
            "flush_period": float(flush_period),
            "compression": compression,
            "max_bytes": int(max_bytes),
            "max_s": float(max_s),
            "file_name": file_name,
        }
        self._frame(b"I", json.dumps(settings).encode())
        reply = self._reply()
        if not reply.get("ready"):
            self._proc.wait(10)
            raise OSError(
                f"recording {str(self.path)!r}: {reply.get('error', 'the recording process failed')}"
            )
        self._ids: dict[str, int] = {}
        self._counts: list[int] = []
        self._batch: list = []
        self._steps: list = []  # write_steps(): the steps' message lists, as given
        self._ids_of_keys: dict | None = None
        self._ids_sent = 0
        self._written_counts: dict | None = None
        self._last = time.monotonic()
        self.messages = 0
        self.finished = False
        self.written: int | None = None
        #: what the writing process answered when it could not write (the disk full)
        self.error: str | None = None

    def _frame(self, kind: bytes, payload: bytes) -> None:
        data = kind + _FRAME_LEN(len(payload)) + payload
        view = memoryview(data)
        try:
            while view:
                view = view[self._out.write(view) :]
        except (BrokenPipeError, ConnectionResetError):
            self._check()  # its reason, where it gave one
            raise

    def _reply(self) -> dict:
        import json

        line = self._proc.stdout.readline()
        if not line:
            return {"error": "the recording process ended"}
        return json.loads(line)

    def channel(self, topic: str, msgtype: str, qos: str | None = None) -> int:
        import json

        cid = self._ids.get(topic)
        if cid is None:
            cid = self._ids[topic] = len(self._ids)
            self._counts.append(0)
            self._frame(b"C", json.dumps([cid, topic, msgtype, qos]).encode())
        return cid

    def write(self, topic: str, msgtype: str, data: bytes, t_ns: int, qos: str | None = None):
        if self._steps:
            self._send()  # what write_steps() was given goes first
        cid = self._ids.get(topic)
        if cid is None:
            cid = self.channel(topic, msgtype, qos)
        self._counts[cid] += 1
        self.messages += 1
        self._batch.append(_RECORD(cid, t_ns, len(data)))
        self._batch.append(data)

    def write_steps(self, msgs, ids: dict) -> None:
        """Record a step's messages: ``(key, CDR bytes, t_ns, received)`` each, in order, with
        ``ids`` the caller's map of keys to the channel ids :meth:`channel` gave. They are kept
        as they are and go down the pipe marshalled with the others of the batch (the work per
        message is then C code's), the map beside them where it grew."""
        if self._batch:
            self._send()  # what write() was given goes first
        self._steps.append(msgs)
        self._ids_of_keys = ids
        self.messages += len(msgs)

    def tick(self) -> None:
        if (self._batch or self._steps) and time.monotonic() - self._last >= self.batch_period:
            self._send()

    def _check(self) -> None:
        """An error the writing process has answered with already (OSError, once)."""
        import select

        if self.error is None and select.select([self._proc.stdout], [], [], 0)[0]:
            reply = self._reply()
            self.error = reply.get("error") or "the recording process ended"
        if self.error is not None:
            raise OSError(f"recording {str(self.path)!r}: {self.error}")

    def _send(self) -> None:
        self._check()
        if self._steps:
            ids = self._ids_of_keys
            grew = ids is not None and len(ids) != self._ids_sent
            self._ids_sent = len(ids) if ids is not None else 0
            self._frame(b"S", marshal.dumps((dict(ids) if grew else None, self._steps)))
            self._steps = []
        if self._batch:
            self._frame(b"B", b"".join(self._batch))
            self._batch = []
        self._last = time.monotonic()

    def flush(self) -> None:
        self._send()
        self._frame(b"F", b"")

    def counts(self) -> dict[str, int]:
        """Messages by topic: those the writing process wrote, once :meth:`finish` has its
        answer; before, those handed over by :meth:`write` (:meth:`write_steps` counts them
        in :attr:`messages` only)."""
        if self._written_counts is not None:
            return dict(self._written_counts)
        return {t: self._counts[c] for t, c in self._ids.items()}

    def __enter__(self) -> BackgroundRecorder:
        return self

    def __exit__(self, *exc) -> None:
        """``with BackgroundRecorder(path) as rec:``: the file finished however the block
        ends."""
        self.finish()

    def finish(self, timeout: float = 60.0) -> None:
        """Hand over what is left, have the file finished, wait for the writing process."""
        if self.finished:
            return
        self.finished = True
        try:
            if self.error is not None:
                reply = {"error": self.error}
                self._frame(b"E", b"")
                self._out.close()
            else:
                if self._batch or self._steps:
                    self._send()
                self._frame(b"E", b"")
                self._out.close()
                reply = self._reply()
        except (BrokenPipeError, ConnectionResetError, OSError):
            reply = {"error": self.error or "the recording process ended early"}
        finally:
            try:
                self._proc.wait(timeout)
            finally:
                self._proc.stdout.close()
        if "done" not in reply:
            raise OSError(f"recording {str(self.path)!r}: {reply.get('error')}")
        self.written = int(reply["done"])
        self._written_counts = reply.get("counts")


_FRAME_LEN = struct.Struct("<I").pack
_RECORD = struct.Struct("<HqI").pack
_RECORD_HEAD = struct.Struct("<HqI")


class _PipeFrames:
    """Whole frames from the stepping process's pipe (see :class:`BackgroundRecorder`)."""

    def __init__(self, fd: int):
        self.fd = fd
        self.buf = bytearray()
        self.eof = False  # the other end closed

    def read(self, timeout: float | None) -> list[tuple[bytes, bytes]]:
        """Whole frames read so far (waiting up to ``timeout`` for more)."""
        import select

        buf = self.buf
        if not self.eof and select.select([self.fd], [], [], timeout)[0]:
            chunk = os.read(self.fd, 1 << 20)
            if chunk:
                buf.extend(chunk)
            else:
                self.eof = True
        got = []
        pos = 0
        while len(buf) - pos >= 5:
            (n,) = struct.unpack_from("<I", buf, pos + 1)
            if len(buf) - pos - 5 < n:
                break
            got.append((bytes(buf[pos : pos + 1]), bytes(buf[pos + 5 : pos + 5 + n])))
            pos += 5 + n
        del buf[:pos]
        return got


def _write_from_pipe() -> int:
    """The writing process of :class:`BackgroundRecorder` (``python -m mps_ros.recording``)."""
    import json
    import signal
    import sys

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    frames = _PipeFrames(sys.stdin.fileno())
    out = sys.stdout

    def answer(obj) -> None:
        try:
            out.write(json.dumps(obj) + "\n")
            out.flush()
        except (BrokenPipeError, OSError):
            pass

    rec = None
    while rec is None:
        for kind, payload in frames.read(None):
            if kind != b"I":
                answer({"error": f"expected the settings first, got {kind!r}"})
                return 2
            settings = json.loads(payload)
            try:
                rec = Recorder(settings.pop("path"), **settings)
            except OSError as exc:
                answer({"error": exc.strerror or str(exc)})
                return 2
            except Exception as exc:
                answer({"error": f"{type(exc).__name__}: {exc}"})
                return 2
        if frames.eof and rec is None:
            return 2
    answer({"ready": True})
    error, done = None, False
    try:
        done = _write_frames(rec, frames)
    except OSError as exc:  # the disk full, the file system gone read-only
        error = f"{exc.strerror or exc}"
    except Exception as exc:
        error = f"{type(exc).__name__}: {exc}"
    if error is None:
        rec.finish()
        answer({"done": rec.messages, "counts": rec.counts()})
        return 0
    # said at once (the other side polls for it), then the file ended as far as it can be (the
    # chunks already written stay whole: mps recover copies them), then what still comes is
    # read and dropped, so that the other side never waits on a full pipe
    answer({"error": error, "written": rec.messages})
    try:
        rec.finish()
    except Exception:
        pass
    while not done and not frames.eof:
        done = any(kind == b"E" for kind, _ in frames.read(None))
    return 1


def _write_frames(rec: Recorder, frames: _PipeFrames) -> bool:
    """Write what comes down the pipe until the finish frame (True) or the pipe's end
    (False: the stepping process is gone; the file is finished all the same)."""
    import json

    channels: dict[int, tuple] = {}
    by_key: dict = {}  # a step's keys -> channel ids (the "S" frames)
    while True:
        got = frames.read(rec.flush_period)
        if not got:
            rec.tick()
            if frames.eof:  # the stepping process is gone: finish the file
                return False
            continue
        for kind, payload in got:
            if kind == b"B":
                write = rec.write
                pos, end = 0, len(payload)
                while pos < end:
                    cid, t_ns, n = _RECORD_HEAD.unpack_from(payload, pos)
                    pos += 14
                    topic, msgtype, qos = channels[cid]
                    write(topic, msgtype, payload[pos : pos + n], t_ns, qos)
                    pos += n
                rec.tick()
            elif kind == b"S":
                ids, steps = marshal.loads(payload)
                if ids is not None:
                    by_key = ids
                write = rec.write
                for msgs in steps:
                    for key, data, t_ns, _received in msgs:
                        topic, msgtype, qos = channels[by_key[key]]
                        write(topic, msgtype, data, t_ns, qos)
                rec.tick()
            elif kind == b"C":
                cid, topic, msgtype, qos = json.loads(payload)
                channels[cid] = (topic, msgtype, qos)
                rec.channel(topic, msgtype, qos)
            elif kind == b"F":
                rec.flush()
            elif kind == b"E":
                return True


class RecordingSink:
    """A :class:`~mps_ros.twin.Runner` sink that records every message under its full topic
    name (``names``: key -> topic, e.g. from the node's publishers; default: the node's default
    names) with the QoS it was offered with (``qos``: key -> YAML)."""

    def __init__(
        self,
        recorder: Recorder,
        names: dict | None = None,
        qos: dict | None = None,
        node: str = NODE_NAME,
        log=None,
    ):
        self.rec = recorder
        self.names = names or {}
        self.qos = qos or {}
        self.node = node
        self._ids: dict = {}  # key -> the recorder's channel id (emit_all)
        #: ``log(level, text)``: where the recording's failure is said (once); None: raised
        self.log = log
        #: why the recording stopped (the disk full...); the run goes on without it
        self.failure: str | None = None
        self.dropped = 0  # messages not recorded since it stopped
        #: the simulated time (s) of the messages that could not be written
        self.failed_at: float | None = None
        self._t_ns = 0

    def _failed(self, exc: Exception) -> None:
        if self.log is None:
            raise exc
        self.failure = str(exc)
        self.failed_at = self._t_ns * 1e-9
        path = getattr(self.rec, "path", None)
        self.log(
            "error",
            f"recording stopped at t = {self._t_ns * 1e-9:.6g} s: {exc}; the run "
            "goes on without it; the file keeps the whole chunks written before"
            + (
                f" (complete it with `mps recover {path} OUT.mcap` where there is room)"
                if path is not None
                else ""
            ),
        )

    def _topic(self, key):
        name = self.names.get(key)
        if name is None:
            name = self.names[key] = resolve(key, self.node)
        return name

    def prepare(self, keys) -> None:
        """Register the channels of ``keys`` now (schemas and channels head the file)."""
        for key in keys:
            self.rec.channel(self._topic(key), BY_KEY[key].msgtype, self.qos.get(key))

    def emit(self, key, data, t_ns):
        if self.failure is not None:
            self.dropped += 1
            return
        self._t_ns = t_ns
        try:
            self.rec.write(self._topic(key), BY_KEY[key].msgtype, data, t_ns, self.qos.get(key))
        except OSError as exc:
            self._failed(exc)

    received = emit

    def emit_all(self, msgs) -> None:
        """A released step's messages, ``(key, data, t_ns, received)`` each, in order: the
        commands as received are recorded like the others (:meth:`received` is :meth:`emit`).
        A recorder with ``write_steps`` takes the list as it is."""
        if self.failure is not None:
            self.dropped += len(msgs)
            return
        write_steps = getattr(self.rec, "write_steps", None)
        if write_steps is None:
            for key, data, t_ns, _received in msgs:
                self.emit(key, data, t_ns)
            return
        if msgs:
            self._t_ns = msgs[0][2]
        ids = self._ids
        try:
            for key, _data, _t, _r in msgs:
                if key not in ids:  # a key met for the first time: its channel first
                    ids[key] = self.rec.channel(self._topic(key), BY_KEY[key].msgtype, self.qos.get(key))
            write_steps(msgs, ids)
        except OSError as exc:
            self._failed(exc)

    def tick(self, deadline: float | None = None):
        if self.failure is not None:
            return
        try:
            self.rec.tick()
        except OSError as exc:
            self._failed(exc)

    def status(self, name: str, hardware: str) -> dict:
        """The recording's /diagnostics status (:func:`mps_ros.diagnostics.recording`): the
        file's bytes on disk so far (the chunks written), the messages handed to it."""
        from .diagnostics import recording

        path = Path(getattr(self.rec, "path", ""))
        try:
            parts = list(path.glob("*.mcap")) if path.is_dir() else [path]
            size = sum(p.stat().st_size for p in parts)
        except OSError:
            parts, size = [], 0
        return recording(
            name, hardware, path, size, self.rec.messages, self.failure, self.dropped, files=len(parts)
        )


# -- reading back and recovering --------------------------------------------------------------
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
    """:func:`recover` of each file of the bag ``src`` (:func:`mps_ros.bag.files`: those its
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
    spans, topics = [], {}
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


def record(
    scene,
    out,
    *,
    dt=None,
    t_end=None,
    outputs=None,
    publish_every: int = 1,
    pacing: str = "as_fast_as_possible",
    real_time_factor: float = 1.0,
    scene_commands: bool = True,
    flush_period: float = 1.0,
    log=None,
    stop_on_signals: bool = True,
    background: bool = True,
    compression: str = "zstd",
    progress: bool = False,
    max_bytes: int = 0,
    max_s: float = 0.0,
    file_name: str = "",
) -> tuple[Path, dict, dict]:
    """The node's recording made without ROS: run ``scene`` with the scene's own commands and
    write every message the node would publish to ``out``; ``background``: written by a
    :class:`BackgroundRecorder` (another process), else in this one; ``progress``: a progress
    line on standard error where it is a terminal (:class:`~mps_core.run.progress.Progress`);
    ``compression``: the chunks' (``zstd``, ``lz4``, ``none``); ``out`` a bag directory (not
    ending in ``.mcap``): its files split at ``max_bytes`` or ``max_s`` (:class:`Recorder`);
    ``file_name``: the name ``out`` is renamed to once finished, for its rosbag2 record.
    Returns (path, stats, counts); the stats say why the run stopped (``stop_reason``), and
    where the recording could not be written, why and from when (``recording_failure``,
    ``recording_failed_at``)."""
    import signal

    from .topics import OUTPUTS
    from .twin import Runner, Twin

    twin = Twin(scene, dt=dt, t_end=t_end, outputs=outputs or OUTPUTS, scene_commands=scene_commands)
    from mps_core.run.progress import Progress

    shown = Progress(twin.t0, twin.t_end, label=twin.scene.name, quiet=not progress)
    rec = (BackgroundRecorder if background else Recorder)(
        out,
        scene_name=twin.scene.name,
        scene_text=twin.scene.text,
        metadata=_run_metadata(twin, "mps record", pacing, real_time_factor, publish_every),
        flush_period=flush_period,
        compression=compression,
        max_bytes=max_bytes,
        max_s=max_s,
        file_name=file_name,
    )

    def recording_failed(_level, _text):  # a recording that cannot be written ends the run
        runner.request_stop("recording-failed")

    sink = RecordingSink(rec, qos=offered_qos(DEPTH), log=recording_failed)
    watch = _WatchSink(twin, shown)
    runner = Runner(
        twin,
        sinks=[sink, watch],
        pacing=pacing,
        real_time_factor=real_time_factor,
        publish_every=publish_every,
        log=log,
    )
    old = {}
    if stop_on_signals:

        def stop(signum, _frame):
            runner.request_stop(signal.Signals(signum).name)

        for sig in (signal.SIGINT, signal.SIGTERM):
            old[sig] = signal.signal(sig, stop)
    failed = True

    def outcome(stats: dict) -> dict:
        """``stats`` with why the run stopped, the recording's failure and the run's step."""
        stats["stop_reason"] = runner.stop_reason or "end"
        stats["recording_failure"] = sink.failure
        stats["recording_failed_at"] = sink.failed_at
        stats["fastest_rates"] = watch.fastest
        solver = twin.sim.settings
        stats["solver"] = solver.name
        stats["solver_step"] = solver.step if solver.step is not None else twin.dt
        return stats

    try:
        stats = runner.run()
        failed = False
    except BaseException as exc:  # what the run did up to its error, for the caller to say
        exc.record_stats = outcome({"t": twin.t, "steps": twin.k})  # type: ignore[attr-defined]
        raise
    finally:
        shown.done()
        try:
            rec.finish()
        except OSError:
            # the file could not be finished: what failed is said already (the recording's
            # failure, or the run's error on its way out)
            if not failed and sink.failure is None:
                raise
        finally:
            for sig, h in old.items():
                signal.signal(sig, h)
    return rec.path, outcome(stats), rec.counts()


class _WatchSink:
    """A run's sink that shows how far the run has got and keeps its fastest crank and rocker
    rates (for the coarse-step warning), at each step's tick."""

    def __init__(self, twin, progress):
        self.twin, self.progress = twin, progress
        #: the largest |phi_dot| and |psi_dot| so far (rad/s)
        self.fastest = [0.0, 0.0]

    def emit(self, key, data, t_ns) -> None:
        pass

    def emit_all(self, msgs) -> None:
        pass

    def tick(self, deadline: float | None = None) -> None:
        twin = self.twin
        self.progress(twin.t)
        _phi, phi_dot, _psi, psi_dot, _x, _x_dot = twin.sim.joint_state()
        fastest = self.fastest
        if abs(phi_dot) > fastest[0]:
            fastest[0] = abs(phi_dot)
        if abs(psi_dot) > fastest[1]:
            fastest[1] = abs(psi_dot)


def _run_metadata(twin, source, pacing, rtf, publish_every) -> dict:
    d = twin.describe()
    return {
        "source": source,
        "scene_origin": d["origin"],
        "t0_s": repr(d["t0"]),
        "t_end_s": repr(d["t_end"]),
        "dt_s": repr(d["dt"]),
        "steps": str(d["steps"]),
        "solver": d["solver"],
        "derivatives": d["derivatives"],
        "outputs": ",".join(d["outputs"]),
        "scene_commands": str(d["scene_commands"]).lower(),
        "pacing": pacing,
        "real_time_factor": repr(float(rtf)),
        "publish_every": str(int(publish_every)),
        "time": "simulated, ns from t = 0",
    }


__all__ = [
    "Recorder",
    "BackgroundRecorder",
    "RecordingSink",
    "recover",
    "intact",
    "record",
    "read_metadata",
    "msgdef",
    "encoder",
    "generic_encoder",
    "default_path",
    "new_recording",
    "reserve",
    "Recovered",
]


if __name__ == "__main__":
    import sys

    sys.exit(_write_from_pipe())
