"""``mps serve RECORDING``: a recording played through the node's Foxglove endpoint
(:class:`~.endpoint.Endpoint`), so that Foxglove's live panels show a past run: every channel of
the file with its own schema, every message as the file holds it (its CDR bytes, its log time),
in the file's order, at real time or ``rate`` times it.

The endpoint offers playback control (the Foxglove app's play, pause, speed and seek): a seek
goes on from the first message at or after the time asked, the latched topics' messages in
force there sent first; the server's time follows the playback. A latched topic's last message
reaches a client that subscribes later, as on the node.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from foxglove.websocket import PlaybackCommand, PlaybackControlRequest, PlaybackState, PlaybackStatus
from mcap.reader import make_reader

from ..recording.bag import files as bag_files
from ..recording.bag import is_bag
from .endpoint import TRANSIENT_LOCAL, Endpoint

#: wall seconds between two of the server's time messages while playing
TIME_PERIOD = 0.02


class ServeError(ValueError):
    """A recording or an option ``mps serve`` cannot take: what was given, what was expected."""


@dataclass
class _Channel:
    topic: str
    msgtype: str
    definition: str
    qos: str
    latched: bool
    index: int = -1


@dataclass
class _Clock:
    """The playback's position (ns of the recording's log time) against the wall clock."""

    position: int
    speed: float
    playing: bool = True
    wall: float = field(default_factory=time.monotonic)

    def now(self) -> int:
        if not self.playing:
            return self.position
        return self.position + int((time.monotonic() - self.wall) * self.speed * 1e9)

    def set(self, position: int) -> None:
        self.position, self.wall = position, time.monotonic()


def parts(path: Path) -> list[Path]:
    """The recording's MCAP files, in order: the file, or a bag's files."""
    if path.is_dir():
        if not is_bag(path):
            raise ServeError(f"recording {str(path)!r}: a directory that is not a bag (no metadata.yaml)")
        found = bag_files(path)
        if not found:
            raise ServeError(f"recording {str(path)!r}: a bag with no .mcap file")
        if any(f.suffix.lower() == ".db3" for f in found):
            raise ServeError(
                f"recording {str(path)!r}: a bag of rosbag2's sqlite3 storage (.db3 files): expected "
                "MCAP files, which carry the message definitions a Foxglove client needs "
                "(mps loads, mps view and mps track --recording read a sqlite3 bag)"
            )
        return list(found)
    if not path.is_file():
        raise ServeError(f"recording {str(path)!r}: no such file: expected an .mcap file or a bag directory")
    return [path]


class Player:
    """Plays ``path`` (a file or a bag) through ``endpoint``'s channels: :meth:`run` until the
    end (or, with ``wait_at_end``, until :meth:`stop`), pausing and seeking as the clients
    ask (:meth:`control`)."""

    def __init__(self, path: Path, rate: float = 1.0) -> None:
        self.files = parts(path)
        self.channels: dict[tuple[int, int], _Channel] = {}  # (file, channel id) -> channel
        self.by_topic: dict[str, _Channel] = {}
        self.messages = 0
        self.start = self.end = None
        first, last, count = None, None, 0
        for i, f in enumerate(self.files):
            with open(f, "rb") as fh:
                try:
                    summary = make_reader(fh).get_summary()
                except Exception as exc:
                    raise ServeError(f"recording {str(f)!r}: not a readable MCAP file ({exc})") from None
            if summary is None or summary.statistics is None:
                raise ServeError(
                    f"recording {str(f)!r}: no summary (cut short?): complete it with `mps recover` first"
                )
            for cid, ch in summary.channels.items():
                sch = summary.schemas.get(ch.schema_id)
                if sch is None or sch.encoding != "ros2msg" or ch.message_encoding != "cdr":
                    continue
                topic = self.by_topic.get(ch.topic)
                if topic is None:
                    qos = ch.metadata.get("offered_qos_profiles", "")
                    topic = self.by_topic[ch.topic] = _Channel(
                        ch.topic, sch.name, sch.data.decode(), qos, TRANSIENT_LOCAL in qos
                    )
                self.channels[(i, cid)] = topic
            st = summary.statistics
            count += st.message_count
            if st.message_count:
                first = st.message_start_time if first is None else min(first, st.message_start_time)
                last = st.message_end_time if last is None else max(last, st.message_end_time)
        if not count:
            raise ServeError(f"recording {str(path)!r}: no message to serve")
        self.count = count
        self.range = (int(first or 0), int(last or 0))
        self.clock = _Clock(self.range[0], rate)
        self._cond = threading.Condition()
        self._seek: int | None = None
        self._stopped = False
        self.endpoint: Endpoint | None = None

    # -- the endpoint ---------------------------------------------------------------------------
    def attach(self, endpoint: Endpoint) -> None:
        self.endpoint = endpoint
        for ch in self.by_topic.values():
            ch.index = endpoint.add_channel(ch.topic, ch.msgtype, ch.qos, ch.definition)

    def control(self, req: PlaybackControlRequest) -> PlaybackState:
        """A client's play, pause, speed or seek (the server's thread)."""
        with self._cond:
            now = self.clock.now()
            if req.playback_speed > 0:
                self.clock.speed = float(req.playback_speed)
            self.clock.set(now)
            self.clock.playing = req.playback_command == PlaybackCommand.Play
            did_seek = req.seek_time is not None
            if did_seek:
                self._seek = max(self.range[0], min(int(req.seek_time or 0), self.range[1]))
                self.clock.set(self._seek)
            self._cond.notify_all()
            return self._state(did_seek, req.request_id)

    def _state(self, did_seek: bool = False, request_id: str | None = None) -> PlaybackState:
        status = PlaybackStatus.Playing if self.clock.playing else PlaybackStatus.Paused
        if self._ended:
            status = PlaybackStatus.Ended
        return PlaybackState(status, self.clock.now(), self.clock.speed, did_seek, request_id)

    def stop(self) -> None:
        with self._cond:
            self._stopped = True
            self._cond.notify_all()

    # -- the playback -----------------------------------------------------------------------------
    def _messages(self, start: int) -> Iterator[tuple[_Channel, bytes, int]]:
        for i, f in enumerate(self.files):
            with open(f, "rb") as fh:
                for _schema, ch, msg in make_reader(fh).iter_messages(starting_at=start, log_time_order=True):
                    c = self.channels.get((i, ch.id))
                    if c is not None:
                        yield c, msg.data, msg.log_time

    def _latched_before(self, t: int) -> list[tuple[_Channel, bytes, int]]:
        """The latched topics' last messages before ``t`` (a seek's state)."""
        last: dict[str, tuple[_Channel, bytes, int]] = {}
        for c, data, t_ns in self._messages(self.range[0]):
            if t_ns >= t:
                break
            if c.latched:
                last[c.topic] = (c, data, t_ns)
        return list(last.values())

    _ended = False

    def run(self, wait_at_end: bool = False) -> int:
        """Play to the end (and, with ``wait_at_end``, wait there for a seek or :meth:`stop`);
        the messages sent."""
        ep = self.endpoint
        assert ep is not None, "attach an endpoint first"
        it = self._messages(self.range[0])
        last_time = 0.0
        while True:
            with self._cond:
                if self._stopped:
                    return self.messages
                seek, self._seek = self._seek, None
            if seek is not None:
                self._ended = False
                for c, data, t_ns in self._latched_before(seek):
                    ep.log(c.index, data, t_ns)
                it = self._messages(seek)
            nxt = next(it, None)
            if nxt is None:
                self._ended = True
                ep.broadcast_playback_state(self._state())
                if not wait_at_end:
                    return self.messages
                with self._cond:
                    while self._seek is None and not self._stopped:
                        self._cond.wait()
                continue
            c, data, t_ns = nxt
            with self._cond:  # until its time comes on the playback's clock (or a seek)
                while not self._stopped and self._seek is None:
                    now = self.clock.now()
                    if now >= t_ns and self.clock.playing:
                        break
                    wait = (t_ns - now) / 1e9 / self.clock.speed if self.clock.playing else None
                    self._cond.wait(None if wait is None else min(max(wait, 0.0), TIME_PERIOD))
                    if time.monotonic() - last_time >= TIME_PERIOD:
                        ep.broadcast_time(self.clock.now())
                        last_time = time.monotonic()
                if self._stopped or self._seek is not None:
                    continue
            ep.log(c.index, data, t_ns)
            self.messages += 1
            if time.monotonic() - last_time >= TIME_PERIOD:
                ep.broadcast_time(t_ns)
                last_time = time.monotonic()


def serve(
    path: str | Path,
    *,
    host: str = "127.0.0.1",
    port: int = 8765,
    rate: float = 1.0,
    wait_clients: int = 0,
    wait_at_end: bool = True,
    say: Callable[..., None] = print,
) -> int:
    """Serve ``path`` on ``host:port`` at ``rate`` times real time; once ``wait_clients``
    clients are subscribed to every channel where asked; the messages sent."""
    if not (0 < rate <= 1000):
        raise ServeError(f"--rate {rate:g}: expected a number above 0, up to 1000")
    if not (0 <= port <= 65535):
        raise ServeError(f"--port {port}: expected a port from 0 (one the system picks) to 65535")
    player = Player(Path(path), rate)
    ready = threading.Event()
    ep = Endpoint(
        host,
        port,
        name="mps serve",
        playback=(player.range, player.control),
        on_ready=lambda n: ready.set() if n >= wait_clients else None,
        what="--port",
    )
    try:
        player.attach(ep)
        span = (player.range[1] - player.range[0]) / 1e9
        say(
            f"serving {path} ({player.count} messages, {len(player.by_topic)} topics, {span:.4g} s) "
            f"at {ep.url}, {rate:g}x real time: in Foxglove, Open connection -> Foxglove WebSocket "
            f"-> {ep.url}; Ctrl-C to stop",
            flush=True,
        )
        if wait_clients:
            say(f"waiting for {wait_clients} client(s) subscribed to every channel", flush=True)
            while not ready.wait(0.1):
                pass
            player.clock.set(player.range[0])
        try:
            sent = player.run(wait_at_end=wait_at_end)
        except KeyboardInterrupt:
            say(f"stopped (SIGINT) after {player.messages} messages of {player.count}", flush=True)
            raise
        say(f"served {sent} messages of {player.count} to the end of the recording", flush=True)
        return sent
    finally:
        player.stop()
        ep.close()


__all__ = ["Player", "ServeError", "parts", "serve"]
