"""A recording read back: an MCAP file of the twin (``mps record``, the node) as the run's columns,
its scene, its events. No ROS: mcap's stream reader and numpy only (rosbags for the odd message
of a type this module does not parse itself).

    rep = read_recording("run.mcap")
    rep.columns["t"], rep.columns["phi"], rep.columns["F_found_x"]   # by mps_core.names / reactions
    rep.scene, rep.scene_text, rep.version, rep.events, rep.commands

**Columns.** One row a ``joint_states`` message (a published step), named as
:mod:`mps_core.names` and :data:`mps_core.dynamics.reactions.REACTION_COLUMNS` name them: ``t`` (the
message's log time, s), ``phi``, ``psi``, ``x_C`` and their rates from the joints of
:data:`~mps_ros.wire.topics.JOINTS`, ``rod``/``rod_dot`` (the rod's angle), ``structure`` from
``~/structure``, and every reaction column that a wrench of :data:`~mps_ros.wire.topics.WRENCHES` or
:data:`~mps_ros.wire.topics.FOUNDATION` carries (``force.x``, ``force.y``, ``torque.z`` as the
wrench's table says). ``phi_ddot`` and ``psi_ddot`` are not in a recording (JointState has no
accelerations): they are the rates' central differences in time (``numpy.gradient``, second
order), marked as derived in :data:`DERIVED`.

**Speed.** Messages of one channel whose CDR payloads have the same length and the same bytes
outside their numbers (names, frame ids, sequence lengths) share one layout: their numbers are
read for all of them at once from one byte matrix (numpy), never message by message. A 10 s
recording at 1 kHz (about 120 000 messages) reads in well under a second.

**Bad input.** A missing file, a file that is not MCAP, an MCAP from another program (none of the
twin's topics), a recording cut short (no footer: its writer was killed) each raise
:class:`ReplayError` with a message that says what was found and what to do; the cut one points
at ``mps recover``.
"""

from __future__ import annotations

import hashlib
import importlib.util
import io
import json
import math
import struct
from collections.abc import Collection
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mps_core.errors import MpsError

from ..wire.topics import BY_KEY, FOUNDATION, JOINT_NAMES, MODE, NODE_NAME, WRENCHES, resolve
from . import sqlite_bag
from .mcap_writer import ENCODING_CDR, MAGIC

#: the recording's metadata records (as :mod:`mps_ros.recording.recorder` writes them)
META_SOFTWARE = "mps"
META_SCENE = "scene"

#: columns computed here, not read from the file, and how
DERIVED = {
    "phi_ddot": "central differences of phi_dot in time (numpy.gradient, second order)",
    "psi_ddot": "central differences of psi_dot in time (numpy.gradient, second order)",
}

#: joint -> (position column, velocity column)
JOINT_COLUMNS = {
    "crank": ("phi", "phi_dot"),
    "rod": ("rod", "rod_dot"),
    "rocker": ("psi", "psi_dot"),
    "slider": ("x_C", "x_C_dot"),
}
assert set(JOINT_COLUMNS) == set(JOINT_NAMES), "mps_ros.wire.topics.JOINTS changed: update this map"


class ReplayError(MpsError, ValueError):
    """A file that cannot be replayed, with what was found and what to do."""


@dataclass
class Replay:
    """A recording read back (see the module's doc)."""

    path: Path
    columns: dict
    metadata: dict
    events: list = field(default_factory=list)
    commands: list = field(default_factory=list)  # (t, word) received on ~/mode
    acks: list = field(default_factory=list)  # ~/mode/status: dicts
    diagnostics: list = field(default_factory=list)  # (t, level, name, message)
    topics: dict = field(default_factory=dict)  # full topic name -> message count
    series: dict = field(default_factory=dict)  # topic key -> (t (s), values dict)
    warnings: list = field(default_factory=list)
    digest: str = ""

    @property
    def scene_text(self) -> str | None:
        text = self.metadata.get(META_SCENE, {}).get("toml")
        return text or None

    @property
    def scene_name(self) -> str:
        return (
            self.metadata.get(META_SCENE, {}).get("name")
            or self.metadata.get(META_SOFTWARE, {}).get("scene")
            or self.path.stem
        )

    @property
    def version(self) -> str | None:
        return self.metadata.get(META_SOFTWARE, {}).get("version")

    @property
    def scene(self):
        """The recording's scene (validated), from its metadata; None if it has none."""
        if not hasattr(self, "_scene"):
            text = self.scene_text
            if text is None:
                self._scene = None
            else:
                from mps_core.scene import scene_from_text

                self._scene = scene_from_text(
                    text, name=self.scene_name, origin=f"{self.path.name} (metadata)"
                )
        return self._scene

    def __len__(self) -> int:
        return int(self.columns["t"].size)


# -- CDR: layouts of the few types the twin publishes ----------------------------------------
class _Cdr:
    """A walker over one CDR message (XCDR1 plain, either byte order): positions of fields."""

    def __init__(self, data: bytes):
        if len(data) < 4:
            raise ValueError("a CDR payload shorter than its 4-byte header")
        if data[1] not in (0, 1):
            raise ValueError(f"CDR encapsulation {data[:2].hex()}: expected plain CDR")
        self.e = "<" if data[1] == 1 else ">"
        self.d = data
        self.p = 4

    def align(self, n: int) -> None:
        self.p += (-(self.p - 4)) % n

    def u32(self) -> int:
        self.align(4)
        (v,) = struct.unpack_from(self.e + "I", self.d, self.p)
        self.p += 4
        return v

    def i32(self) -> int:
        self.align(4)
        (v,) = struct.unpack_from(self.e + "i", self.d, self.p)
        self.p += 4
        return v

    def string(self) -> str:
        n = self.u32()
        s = self.d[self.p : self.p + n]
        if len(s) != n:
            raise ValueError("string runs past the message")
        self.p += n
        return s[:-1].decode("utf-8", "replace") if n else ""

    def doubles(self, n: int) -> int:
        """Skip n float64, returning their offset."""
        if n:
            self.align(8)
        off = self.p
        self.p += 8 * n
        if self.p > len(self.d):
            raise ValueError("float64 array runs past the message")
        return off

    def stamp(self) -> int:
        off = self.p
        self.i32()
        self.u32()
        return off


def _layout(msgtype: str, data: bytes) -> dict:
    """Where a message's numbers are: name -> (offset, count); plus its strings."""
    c = _Cdr(data)
    out: dict = {"_endian": c.e}
    if msgtype in ("sensor_msgs/msg/JointState", "geometry_msgs/msg/WrenchStamped"):
        out["stamp"] = (c.stamp(), 1)
        out["_frame_id"] = c.string()
        if msgtype == "sensor_msgs/msg/JointState":
            out["_name"] = [c.string() for _ in range(c.u32())]
            for f in ("position", "velocity", "effort"):
                n = c.u32()
                out[f] = (c.doubles(n), n)
        else:
            out["force"] = (c.doubles(3), 3)
            out["torque"] = (c.doubles(3), 3)
    elif msgtype == "rosgraph_msgs/msg/Clock":
        out["stamp"] = (c.stamp(), 1)
    elif msgtype == "std_msgs/msg/String":
        out["_data"] = c.string()
    else:
        raise KeyError(msgtype)
    return out


def _numbers(msgtype: str, datas: list) -> list[tuple[dict, np.ndarray, dict]]:
    """The numeric fields of many messages of one type: [(layout, indices, {field: (k, n)
    array}), ...], a group of messages sharing a layout each. A group is read at once from one
    byte matrix."""
    groups: dict[int, list[int]] = {}
    for i, d in enumerate(datas):
        groups.setdefault(len(d), []).append(i)
    out = []
    for length, idx in groups.items():
        lay = _layout(msgtype, datas[idx[0]])
        M = np.frombuffer(b"".join(datas[i] for i in idx), dtype=np.uint8).reshape(len(idx), length)
        fixed = np.ones(length, dtype=bool)
        for f, v in lay.items():
            if f.startswith("_"):
                continue
            off, n = v
            fixed[off : off + 8 * n] = False
        same = (M[:, fixed] == M[0, fixed]).all(axis=1) if len(idx) > 1 else np.ones(1, bool)
        if not same.all():
            # a different layout hidden behind the same length: take those one by one
            for j in np.nonzero(~same)[0]:
                out.append(_read_group(msgtype, _layout(msgtype, datas[idx[j]]), M[j : j + 1], [idx[j]]))
            keep = np.nonzero(same)[0]
            M = M[keep]
            idx = [idx[j] for j in keep]
        out.append(_read_group(msgtype, lay, M, idx))
    return out


def _read_group(msgtype, lay, M, idx):
    e = lay["_endian"]
    vals = {}
    for f, v in lay.items():
        if f.startswith("_"):
            continue
        off, n = v
        if f == "stamp":
            sec = np.ascontiguousarray(M[:, off : off + 4]).view(e + "i4")[:, 0].astype(np.int64)
            ns = np.ascontiguousarray(M[:, off + 4 : off + 8]).view(e + "u4")[:, 0].astype(np.int64)
            vals[f] = sec * 1_000_000_000 + ns
        else:
            vals[f] = (
                np.ascontiguousarray(M[:, off : off + 8 * n])
                .view(e + "f8")
                .reshape(len(idx), n)
                .astype(float)
            )
    return lay, np.asarray(idx), vals


def _string(data: bytes) -> str:
    return _Cdr(data).string()


def string_data(data: bytes) -> str:
    """Return a CDR ``std_msgs/String``'s text."""
    return _string(data)


def joint_state_readings(data: bytes) -> tuple[int, int, list[str], list[float], list[float]]:
    """Return a CDR ``sensor_msgs/JointState``'s stamp (sec, nanosec), joint names, positions
    and efforts (the velocities skipped).

    A message cut short or not plain CDR raises ValueError (or struct.error).
    """
    c = _Cdr(data)
    sec, nanosec = c.i32(), c.u32()
    c.string()  # the frame id
    names = [c.string() for _ in range(c.u32())]
    n = c.u32()
    off = c.doubles(n)
    positions = list(struct.unpack_from(f"{c.e}{n}d", data, off))
    c.doubles(c.u32())  # the velocities
    m = c.u32()
    off = c.doubles(m)
    return sec, nanosec, names, positions, list(struct.unpack_from(f"{c.e}{m}d", data, off))


# -- reading the file -------------------------------------------------------------------------
@dataclass
class _Channel:
    id: int
    topic: str
    schema: str
    encoding: str
    times: list = field(default_factory=list)
    datas: list = field(default_factory=list)
    #: each kept message's place among all the file's (a bag's files' in order) messages
    seqs: list = field(default_factory=list)
    #: the messages of the channel, kept or not
    count: int = 0


def _head(path: Path) -> bytes:
    with open(path, "rb") as fh:
        return fh.read(16)


def _scan(path: Path, data: bytes, keep: Collection[str] | None = None):
    """(metadata, channels by id, schemas by id, library, complete, messages) of an MCAP file's
    bytes; ``keep``: the topics whose messages are kept (None: all), the others counted."""
    from mcap.exceptions import McapError
    from mcap.records import Channel, DataEnd, Footer, Header, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader

    meta: dict[str, dict[str, str]] = {}
    schemas: dict[int, tuple[str, str]] = {}
    channels: dict[int, _Channel] = {}
    library = ""
    seen_end = False
    footer = False
    messages = 0
    reader = StreamReader(io.BytesIO(data), validate_crcs=True)
    try:
        for r in reader.records:
            if isinstance(r, Message):
                ch = channels.get(r.channel_id)
                if ch is not None:
                    ch.count += 1
                    if keep is None or ch.topic in keep:
                        ch.times.append(r.log_time)
                        ch.datas.append(r.data)
                        ch.seqs.append(messages)
                messages += 1
            elif isinstance(r, Channel):
                if r.id not in channels:
                    s = schemas.get(r.schema_id, ("", ""))
                    channels[r.id] = _Channel(r.id, r.topic, s[0], r.message_encoding)
            elif isinstance(r, Schema):
                schemas.setdefault(r.id, (r.name, r.encoding))
            elif isinstance(r, Metadata):
                meta[r.name] = dict(r.metadata)
            elif isinstance(r, Header):
                library = r.library
            elif isinstance(r, DataEnd):
                seen_end = True
            elif isinstance(r, Footer):
                footer = True
    except (McapError, struct.error, EOFError, ValueError) as exc:
        if not seen_end:
            where = f"after {messages} messages" if messages else "before its first message"
            raise ReplayError(
                f"{path}: the recording is cut short ({where}; {type(exc).__name__}"
                f"{': ' + str(exc) if str(exc) else ''}): its writer was probably stopped "
                f"hard (killed, power lost) before it wrote the file's end. Recover its whole "
                f"chunks into a complete file with `mps recover {path} "
                f"{path.with_name(path.stem + '-recovered.mcap')}`, then open that one"
            ) from None
    complete = footer
    return meta, channels, schemas, library, complete, messages


def _suffix(key: str) -> str:
    return key[1:] if key.startswith("~/") else (key if key.startswith("/") else "/" + key)


def _match(channels: dict, key: str, node: str = NODE_NAME) -> _Channel | None:
    """The channel of topic key: its default name, or else the one channel of the key's type
    whose name ends like it (a node run under another name or namespace)."""
    msgtype = BY_KEY[key].msgtype
    want = resolve(key, node)
    for ch in channels.values():
        if ch.topic == want and ch.schema == msgtype:
            return ch
    suf = _suffix(key)
    cands = [ch for ch in channels.values() if ch.schema == msgtype and ch.topic.endswith(suf)]
    if len(cands) > 1:  # prefer the node's own depth (~/x under one namespace level)
        cands = [ch for ch in cands if ch.topic.count("/") == want.count("/")]
    return cands[0] if len(cands) == 1 else None


def _stamped(times: list) -> np.ndarray:
    return np.asarray(times, dtype=np.int64)


def _parts(path: Path) -> list[Path]:
    """The files of a recording: the file itself, or a bag directory's files in order (MCAP, or
    rosbag2's sqlite3 storage: :mod:`~mps_ros.recording.sqlite_bag`)."""
    if not path.is_dir():
        return [path]
    from .bag import files

    parts = files(path)
    if not parts:
        raise ReplayError(
            f"{path}: a directory without a recording in it (expected a bag: "
            "metadata.yaml and its .mcap files, as the node writes where its "
            "recording path does not end in .mcap, or rosbag2's .db3 files; or an .mcap file)"
        )
    return parts


def _scan_all(parts: list[Path], keep: Collection[str] | None = None):
    """:func:`_scan` of each file, in order, their channels joined by topic and type (a
    bag's files number them each their own way): (metadata of the first, channels,
    library of the first, whether every file is complete, messages, sha256 of all)."""
    digest = hashlib.sha256()
    joined: dict[tuple, _Channel] = {}
    first = None
    complete, nmsg = True, 0
    for part in parts:
        head = _head(part)
        if head[:16] == sqlite_bag.MAGIC:  # a bag file of rosbag2's sqlite3 storage
            digest.update(part.read_bytes())
            channels, n = sqlite_bag.scan(part, _Channel, keep, ReplayError)
            meta, library, done = {}, "rosbag2 sqlite3", True
        elif head[:8] != MAGIC:
            what = "empty" if not head else f"it starts with {head[:8]!r}"
            raise ReplayError(
                f"{part}: not an MCAP file ({what}): expected a recording made by "
                "`mps record SCENE --out FILE.mcap` or the node's recorder (or a rosbag2 bag's "
                "file, MCAP or sqlite3)"
            )
        else:
            data = part.read_bytes()
            digest.update(data)
            meta, channels, _schemas, library, done, n = _scan(part, data, keep)
        first = first or (meta, library)
        complete, nmsg = complete and done, nmsg + n
        for ch in channels.values():
            into = joined.setdefault(
                (ch.topic, ch.schema, ch.encoding), _Channel(len(joined), ch.topic, ch.schema, ch.encoding)
            )
            into.times += ch.times
            into.datas += ch.datas
            into.seqs += [nmsg - n + k for k in ch.seqs]
            into.count += ch.count
    if first is None:
        raise ReplayError("no MCAP file to read: expected a recording's file or a bag's")
    channels = {ch.id: ch for ch in joined.values()}
    return first[0], channels, first[1], complete, nmsg, digest.hexdigest()


@dataclass
class TopicMessages:
    """Some topics' messages of a recording, in the file's order (a bag's files in turn).

    ``channels``: every channel of the file as (topic, type, encoding, messages);
    ``messages``: (topic, type, log time in ns, CDR bytes) of the topics asked for."""

    path: Path
    channels: list[tuple[str, str, str, int]]
    messages: list[tuple[str, str, int, bytes]]
    warnings: list[str] = field(default_factory=list)
    #: the metadata records of the (first) file, by name
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)


def _readable(path) -> Path:
    """Return ``path`` as a Path, or raise :class:`ReplayError` where it is not there or the
    mcap package is missing (what reading any recording needs first)."""
    path = Path(path)
    if not path.exists():
        raise ReplayError(f"{path}: no such file or directory")
    if importlib.util.find_spec("mcap") is None:
        raise ReplayError(
            "reading a recording needs the mcap package, which is not installed: pip install -e '.[view]'"
        )
    return path


def read_topics(path, topics: Collection[str]) -> TopicMessages:
    """Read the messages of ``topics`` of an MCAP file or a bag directory, in the file's order.

    The other topics' messages are counted, not kept. Bad files raise :class:`ReplayError` as
    :func:`read_recording` does (not MCAP, cut short, an empty bag).
    """
    path = _readable(path)
    meta, channels, _library, complete, _n, _digest = _scan_all(_parts(path), keep=set(topics))
    channel_list = [(c.topic, c.schema, c.encoding, c.count) for c in channels.values()]
    out = TopicMessages(path, channel_list, [], metadata=meta)
    if not complete:
        out.warnings.append(
            "the file has no footer (its summary is missing or cut short); every message was read"
        )
    kept = [
        (seq, ch.topic, ch.schema, t, d)
        for ch in channels.values()
        for seq, t, d in zip(ch.seqs, ch.times, ch.datas)
    ]
    kept.sort(key=lambda m: m[0])
    out.messages = [(topic, schema, t, d) for _seq, topic, schema, t, d in kept]
    return out


def read_recording(path, *, check_version: bool = True) -> Replay:
    """Read a recording of the twin (see the module's doc): an MCAP file, or a bag directory
    (:mod:`mps_ros.recording.bag`) whose files are read in order as one."""
    path = _readable(path)
    meta, channels, library, complete, nmsg, digest = _scan_all(_parts(path))
    rep = Replay(path=path, columns={}, metadata=meta, digest=digest)
    rep.topics = {ch.topic: len(ch.times) for ch in channels.values()}
    if not complete:
        rep.warnings.append(
            "the file has no footer (its summary is missing or cut short); every message was read"
        )

    js = _match(channels, "joint_states")
    if js is None or not js.times:
        ours = [k for k in BY_KEY if _match(channels, k) is not None]
        have = ", ".join(f"{t} ({n})" for t, n in sorted(rep.topics.items())) or "no channels"
        who = f", written by {library!r}" if library else ""
        if not ours:
            raise ReplayError(
                f"{path}: an MCAP file{who} with none of the press twin's topics (expected "
                f"{resolve('joint_states')} of type sensor_msgs/msg/JointState and the others "
                f"of mps_ros.wire.topics); it has: {have}"
            )
        raise ReplayError(
            f"{path}: a recording{who} without joint states ({resolve('joint_states')}, "
            f"sensor_msgs/msg/JointState, with messages): nothing to replay; it has: {have}"
        )
    if js.encoding != ENCODING_CDR:
        raise ReplayError(f"{path}: {js.topic} is encoded as {js.encoding!r}: expected {ENCODING_CDR}")
    if check_version:
        sw = meta.get(META_SOFTWARE, {})
        from mps_core import __version__

        if sw.get("version") and sw["version"] != __version__:
            rep.warnings.append(f"recorded by mps {sw['version']}, read by mps {__version__}")
    _read_channels(rep, channels, js)
    return rep


def _read_channels(rep: Replay, channels: dict, js: _Channel) -> None:
    try:
        _joint_columns(rep, js)
        _wrench_columns(rep, channels)
        _structure(rep, channels)
        _events(rep, channels)
    except (ValueError, KeyError, IndexError, struct.error) as exc:
        if isinstance(exc, ReplayError):
            raise
        raise ReplayError(
            f"{rep.path}: a message of the twin's topics cannot be decoded as its "
            f"type says ({type(exc).__name__}: {exc}): the file is damaged or "
            "was written by another program"
        ) from None


def replay_of_messages(name: str, messages: dict, node: str = NODE_NAME) -> Replay | None:
    """A stretch of a live run as a :class:`Replay`: ``messages`` by full topic name, each a
    list of (stamp in ns, CDR bytes), as a subscriber took them (the same columns as a
    recording's; None without joint states)."""
    channels = {}
    for i, (topic, msgs) in enumerate(messages.items()):
        key = next((k for k in BY_KEY if resolve(k, node) == topic), None)
        if key is None or not msgs:
            continue
        ch = channels[i] = _Channel(i, topic, BY_KEY[key].msgtype, ENCODING_CDR)
        ch.times = [t for t, _ in msgs]
        ch.datas = [d for _, d in msgs]
    js = _match(channels, "joint_states", node)
    if js is None:
        return None
    rep = Replay(path=Path(name), columns={}, metadata={})
    _read_channels(rep, channels, js)
    return rep


def _joint_columns(rep: Replay, ch: _Channel) -> None:
    t_ns = _stamped(ch.times)
    order = np.argsort(t_ns, kind="stable")
    if np.any(np.diff(t_ns[order]) == 0):
        raise ReplayError(
            f"{rep.path}: {ch.topic} has two messages at the same time: not a recording of one run"
        )
    n = len(ch.datas)
    cols = {"t": t_ns[order] / 1e9}
    pos = {c: np.full(n, np.nan) for c in JOINT_COLUMNS}
    vel = {c: np.full(n, np.nan) for c in JOINT_COLUMNS}
    eff = {c: np.full(n, np.nan) for c in JOINT_COLUMNS}
    for lay, idx, vals in _numbers("sensor_msgs/msg/JointState", ch.datas):
        names = lay["_name"]
        for j, name in enumerate(names):
            if name not in JOINT_COLUMNS:
                continue
            for arr, f in ((pos, "position"), (vel, "velocity"), (eff, "effort")):
                if j < vals[f].shape[1]:
                    arr[name][idx] = vals[f][:, j]
    missing = [j for j in ("crank", "rocker", "slider") if np.isnan(pos[j]).all()]
    if missing:
        raise ReplayError(
            f"{rep.path}: {ch.topic} has no joint {', '.join(missing)} (expected "
            f"the joints {', '.join(JOINT_NAMES)})"
        )
    for joint, (pc, vc) in JOINT_COLUMNS.items():
        cols[pc] = pos[joint][order]
        cols[vc] = vel[joint][order]
    t = cols["t"]
    for q in ("phi", "psi"):
        cols[q + "_ddot"] = np.gradient(cols[q + "_dot"], t, edge_order=2) if t.size > 2 else np.zeros_like(t)
    rep.series["joint_states"] = (t, {"effort_" + j: eff[j][order] for j in JOINT_COLUMNS})
    rep.columns = cols


def _align(rep: Replay, key: str, ch: _Channel, t_ns: np.ndarray, values: np.ndarray):
    """values (one a message of ch, at t_ns) on the joint states' rows; NaN where none."""
    base = np.round(rep.columns["t"] * 1e9).astype(np.int64)
    out = np.full(base.size, np.nan, dtype=values.dtype if values.dtype.kind == "f" else object)
    pos = np.searchsorted(base, t_ns)
    ok = (pos < base.size) & (base[np.minimum(pos, base.size - 1)] == t_ns)
    out[pos[ok]] = values[ok]
    if not ok.all():
        rep.warnings.append(
            f"{ch.topic}: {int((~ok).sum())} messages at times without joint "
            "states (kept in the series, not in the columns)"
        )
    return out


def _wrench_columns(rep: Replay, channels: dict) -> None:
    for w in (*WRENCHES, FOUNDATION):
        ch = _match(channels, w.key)
        if ch is None or not ch.times:
            continue
        t_ns = _stamped(ch.times)
        n = len(ch.datas)
        force = np.full((n, 3), np.nan)
        torque = np.full((n, 3), np.nan)
        for _lay, idx, vals in _numbers("geometry_msgs/msg/WrenchStamped", ch.datas):
            force[idx] = vals["force"]
            torque[idx] = vals["torque"]
        series = {}
        for col, arr in ((w.force[0], force[:, 0]), (w.force[1], force[:, 1]), (w.torque, torque[:, 2])):
            if col is None:
                continue
            series[col] = arr
            if col not in rep.columns:  # a column two wrenches carry: the first one's
                rep.columns[col] = _align(rep, w.key, ch, t_ns, arr)
        rep.series[w.key] = (t_ns / 1e9, series)


def _structure(rep: Replay, channels: dict) -> None:
    ch = _match(channels, "~/structure")
    if ch is None or not ch.times:
        return
    t_ns = _stamped(ch.times)
    cache: dict[bytes, str] = {}
    vals = np.empty(len(ch.datas), dtype=object)
    for i, d in enumerate(ch.datas):
        s = cache.get(d)
        if s is None:
            s = cache[d] = _string(d)
        vals[i] = s
    col = _align(rep, "~/structure", ch, t_ns, vals)
    # a step without a structure message keeps the one before (the structure is a state)
    last = None
    for i in range(col.size):
        if col[i] is None or (isinstance(col[i], float) and math.isnan(col[i])):
            col[i] = last if last is not None else ""
        else:
            last = col[i]
    rep.columns["structure"] = col.astype(str)
    rep.series["~/structure"] = (t_ns / 1e9, {"structure": vals})


def _events(rep: Replay, channels: dict) -> None:
    ch = _match(channels, "~/events")
    if ch is not None:
        for t, d in zip(ch.times, ch.datas):
            text = _string(d)
            try:
                ev = json.loads(text)
            except json.JSONDecodeError:
                ev = {"kind": "text", "text": text}
            if not isinstance(ev, dict):
                ev = {"kind": "text", "text": text}
            ev.setdefault("t", t / 1e9)
            rep.events.append(ev)
        rep.events.sort(key=lambda e: _num(e.get("t")))
    ch = _match(channels, MODE.key)
    if ch is not None:
        rep.commands = [(t / 1e9, _string(d)) for t, d in zip(ch.times, ch.datas)]
    ch = _match(channels, "~/mode/status")
    if ch is not None:
        for t, d in zip(ch.times, ch.datas):
            try:
                ack = json.loads(_string(d))
            except json.JSONDecodeError:
                continue
            if isinstance(ack, dict):
                ack.setdefault("t", t / 1e9)
                rep.acks.append(ack)
    ch = _match(channels, "/diagnostics")
    if ch is not None and ch.times:
        try:
            from rosbags.typesys import Stores, get_typestore

            ts = get_typestore(Stores.ROS2_JAZZY)
            for t, d in zip(ch.times, ch.datas):
                msg: Any = ts.deserialize_cdr(d, "diagnostic_msgs/msg/DiagnosticArray")
                for s in msg.status:
                    rep.diagnostics.append((t / 1e9, int(s.level), s.name, s.message))
        except Exception as exc:  # diagnostics are a nicety: never fail a replay on them
            rep.warnings.append(f"/diagnostics not read ({type(exc).__name__}: {exc})")


def _num(v) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.inf


def load_columns(path) -> tuple[dict, list, str]:
    """(columns, events, name) of a recording, for the load report (``mps loads FILE.mcap``);
    its notes (a missing footer, another software version) go to stderr."""
    import sys

    rep = read_recording(path)
    for w in rep.warnings:
        print(f"mps: note: {rep.path.name}: {w}", file=sys.stderr)
    return rep.columns, rep.events, rep.path.name


__all__ = [
    "Replay",
    "ReplayError",
    "TopicMessages",
    "joint_state_readings",
    "read_recording",
    "read_topics",
    "string_data",
    "load_columns",
    "DERIVED",
    "JOINT_COLUMNS",
    "META_SCENE",
    "META_SOFTWARE",
]
