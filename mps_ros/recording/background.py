"""The recorder's writing process: a :class:`~.recorder.Recorder` in a process of its own,
fed down a pipe (``python -m mps_ros.recording.background``), off the stepping loop's time."""

from __future__ import annotations

import marshal
import struct
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Protocol

from ..os_threads import widen_pipe
from ..wire.pipe import HEAD, Frame, PolledFrameReader
from .recorder import Message, Recorder


class BackgroundRecorder:
    """A :class:`Recorder` that writes in a process of its own (the machine's second core),
    off the stepping loop's time: the loop hands it each message's CDR bytes, which it sends
    down a pipe in batches (every ``batch_period`` wall seconds, at :meth:`tick`); the other
    process (``python -m mps_ros.recording.background``) writes them
    (:class:`~mps_ros.recording.mcap_writer.McapWriter`) in the order they were given. Same
    methods as :class:`Recorder`; ``messages`` and :meth:`counts` count what was handed over,
    ``written`` what the other process wrote (after :meth:`finish`).

    The writing process ignores SIGINT and SIGTERM (the stepping process stops on them and
    calls :meth:`finish`); it finishes the file when told, or when the pipe closes because the
    stepping process is gone, so a crashed run still leaves a complete file. Killed with its
    process group (SIGKILL), it leaves a file that :func:`recover` completes.

    The pipe's frames (:mod:`mps_ros.wire.pipe`): ``Frame.SETTINGS`` the recorder's settings as
    JSON, ``CHANNEL`` a channel as JSON, ``BATCH`` a batch of messages, ``STEPS`` a batch of
    steps, ``FLUSH`` flush, ``END`` finish; a batch is records of (channel u16, time ns i64,
    length u32, CDR bytes); a batch of steps is the :mod:`marshal` dump (one interpreter
    writes and reads it) of (the keys' channel ids where they grew, else None; the steps, each
    a list of (key, CDR bytes, t_ns, received) or the bytes of a marshalled tuple whose last
    item is that list: :meth:`write_encoded`). The
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
        module: str = "mps_ros.recording.background",
        tap: dict | None = None,
        pass_fds: tuple[int, ...] = (),
    ):
        import json
        import subprocess
        import sys

        self.path = Path(path)
        self.batch_period = float(batch_period)
        # ``module``: the writing process's module, one that serves this one's pipe with a
        # tap beside the file (:func:`serve_pipe`; ``tap``: its settings, ``pass_fds`` the
        # descriptors it inherits)
        self._proc = subprocess.Popen(
            [sys.executable, "-m", module],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            bufsize=0,
            pass_fds=pass_fds,
        )
        stdin, stdout = self._proc.stdin, self._proc.stdout
        assert stdin is not None and stdout is not None  # both are pipes
        self._out, self._in = stdin, stdout
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
        if tap is not None:
            settings["tap"] = tap
        self._frame(Frame.SETTINGS, json.dumps(settings).encode())
        reply = self._reply()
        if not reply.get("ready"):
            self._proc.wait(10)
            if reply.get("tap_error"):  # the tap's own line (it names what it was given)
                raise OSError(reply["tap_error"])
            raise OSError(
                f"recording {str(self.path)!r}: {reply.get('error', 'the recording process failed')}"
            )
        #: what the tap said when it started (e.g. where it serves)
        self.tap_info: dict = reply.get("tap", {})
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
        data = HEAD.pack(kind, len(payload)) + payload
        view = memoryview(data)
        try:
            while view:
                view = view[self._out.write(view) :]
        except (BrokenPipeError, ConnectionResetError):
            self._check()  # its reason, where it gave one
            raise

    def _reply(self) -> dict:
        import json

        line = self._in.readline()
        if not line:
            return {"error": "the recording process ended"}
        return json.loads(line)

    def channel(self, topic: str, msgtype: str, qos: str | None = None) -> int:
        import json

        cid = self._ids.get(topic)
        if cid is None:
            cid = self._ids[topic] = len(self._ids)
            self._counts.append(0)
            self._frame(Frame.CHANNEL, json.dumps([cid, topic, msgtype, qos]).encode())
        return cid

    def write(self, topic: str, msgtype: str, data: bytes, t_ns: int, qos: str | None = None) -> None:
        if self._steps:
            self._send()  # what write_steps() was given goes first
        cid = self._ids.get(topic)
        if cid is None:
            cid = self.channel(topic, msgtype, qos)
        self._counts[cid] += 1
        self.messages += 1
        self._batch.append(_RECORD(cid, t_ns, len(data)))
        self._batch.append(data)

    def write_steps(self, msgs: Sequence[Message], ids: dict) -> None:
        """Record a step's messages: ``(key, CDR bytes, t_ns, received)`` each, in order, with
        ``ids`` the caller's map of keys to the channel ids :meth:`channel` gave. They are kept
        as they are and go down the pipe marshalled with the others of the batch (the work per
        message is then C code's), the map beside them where it grew."""
        if self._batch:
            self._send()  # what write() was given goes first
        self._steps.append(msgs)
        self._ids_of_keys = ids
        self.messages += len(msgs)

    def write_encoded(self, encoded: bytes, n: int, ids: dict) -> None:
        """Record a step of ``n`` messages handed over as the stepping process encoded it:
        ``encoded`` the :mod:`marshal` dump of a tuple whose last item is the step's messages
        (a frame ``MESSAGES``'s payload, :mod:`mps_ros.run.stepping`); ``ids`` as in
        :meth:`write_steps`. The bytes go down the pipe with the batch as they are; the
        writing process takes the messages out of them."""
        if self._batch:
            self._send()  # what write() was given goes first
        self._steps.append(encoded)
        self._ids_of_keys = ids
        self.messages += n

    def tick(self) -> None:
        if (self._batch or self._steps) and time.monotonic() - self._last >= self.batch_period:
            self._send()

    def _check(self) -> None:
        """An error the writing process has answered with already (OSError, once)."""
        import select

        if self.error is None and select.select([self._in], [], [], 0)[0]:
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
            self._frame(
                Frame.STEPS, marshal.dumps((dict(ids) if grew and ids is not None else None, self._steps))
            )
            self._steps = []
        if self._batch:
            self._frame(Frame.BATCH, b"".join(self._batch))
            self._batch = []
        self._last = time.monotonic()

    def flush(self) -> None:
        self._send()
        self._frame(Frame.FLUSH, b"")

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
        reply: dict | None = None
        try:
            if self.error is None and (self._batch or self._steps):
                self._send()
            self._frame(Frame.END, b"")
        except (BrokenPipeError, ConnectionResetError, OSError):
            pass  # the error it answered is in self.error; the pipe is closed below all the same
        try:
            # closed however the hand-over ended: the writing process reads to the pipe's end
            self._out.close()
        except OSError:
            pass
        try:
            if self.error is None:
                reply = self._reply()
        except (OSError, ValueError):
            pass
        finally:
            try:
                self._proc.wait(timeout)
            finally:
                self._in.close()
        if reply is None:
            reply = {"error": self.error or "the recording process ended early"}
        if "done" not in reply:
            raise OSError(f"recording {str(self.path)!r}: {reply.get('error')}")
        self.written = int(reply["done"])
        self._written_counts = reply.get("counts")


_RECORD = struct.Struct("<HqI").pack
_RECORD_HEAD = struct.Struct("<HqI")


class Tap(Protocol):
    """What the writing process hands every channel and message to besides the file (the
    Foxglove endpoint): the same channels and CDR bytes, in the same order."""

    def channel(self, cid: int, topic: str, msgtype: str, qos: str | None) -> None: ...
    def message(self, cid: int, data: bytes, t_ns: int) -> None: ...
    def tick(self) -> None: ...
    def info(self) -> dict: ...
    def close(self) -> None: ...


class TapError(Exception):
    """A tap that could not start: its message is the line said (it names what it was given)."""


def _write_from_pipe() -> int:
    """The writing process of :class:`BackgroundRecorder` (``python -m mps_ros.recording.background``)."""
    return serve_pipe(None)


def serve_pipe(make_tap: Callable[[dict], Tap] | None) -> int:
    """Serve :class:`BackgroundRecorder`'s pipe on standard input: write the file, and hand
    every channel and message to the tap that ``make_tap`` makes of the settings' ``tap``
    (where both are there; :class:`TapError` where it cannot start)."""
    import json
    import signal
    import sys

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    frames = PolledFrameReader(sys.stdin.fileno())
    out = sys.stdout

    def answer(obj) -> None:
        try:
            out.write(json.dumps(obj) + "\n")
            out.flush()
        except (BrokenPipeError, OSError):
            pass

    rec = None
    tap: Tap | None = None
    while rec is None:
        for kind, payload in frames.read(None):
            if kind != Frame.SETTINGS:
                answer({"error": f"expected the settings first, got {kind!r}"})
                return 2
            settings = json.loads(payload)
            tap_settings = settings.pop("tap", None)
            if make_tap is not None and tap_settings is not None:
                try:
                    tap = make_tap(tap_settings)
                except TapError as exc:
                    answer({"tap_error": str(exc)})
                    return 2
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
    answer({"ready": True, "tap": tap.info() if tap is not None else {}})
    error, done = None, False
    try:
        done = _write_frames(rec, frames, tap)
    except OSError as exc:  # the disk full, the file system gone read-only
        error = f"{exc.strerror or exc}"
    except Exception as exc:
        error = f"{type(exc).__name__}: {exc}"
    if error is None:
        rec.finish()
        answer({"done": rec.messages, "counts": rec.counts()})
        if tap is not None:
            tap.close()
        return 0
    # said at once (the other side polls for it), then the file ended as far as it can be (the
    # chunks already written stay whole: mps recover copies them), then what still comes is
    # read and dropped, so that the other side never waits on a full pipe
    answer({"error": error, "written": rec.messages})
    try:
        rec.finish()
    except Exception:
        pass
    if tap is not None:
        tap.close()
    while not done and not frames.eof:
        done = any(kind == Frame.END for kind, _ in frames.read(None))
    return 1


def _write_frames(rec: Recorder, frames: PolledFrameReader, tap: Tap | None = None) -> bool:
    """Write what comes down the pipe until the finish frame (True) or the pipe's end
    (False: the stepping process is gone; the file is finished all the same); each channel
    and message to ``tap`` too."""
    import json

    channels: dict[int, tuple] = {}
    by_key: dict = {}  # a step's keys -> channel ids (the "S" frames)
    tap_message = tap.message if tap is not None else None
    while True:
        got = frames.read(rec.flush_period)
        if not got:
            rec.tick()
            if frames.eof:  # the stepping process is gone: finish the file
                return False
            continue
        for kind, payload in got:
            if kind == Frame.BATCH:
                write = rec.write
                pos, end = 0, len(payload)
                while pos < end:
                    cid, t_ns, n = _RECORD_HEAD.unpack_from(payload, pos)
                    pos += 14
                    topic, msgtype, qos = channels[cid]
                    data = payload[pos : pos + n]
                    write(topic, msgtype, data, t_ns, qos)
                    if tap_message is not None:
                        tap_message(cid, data, t_ns)
                    pos += n
                rec.tick()
            elif kind == Frame.STEPS:
                ids, steps = marshal.loads(payload)
                if ids is not None:
                    by_key = ids
                write = rec.write
                loads = marshal.loads
                if tap_message is None:
                    for msgs in steps:
                        if msgs.__class__ is bytes:  # as the stepping process encoded it
                            msgs = loads(msgs)[-1]
                        for key, data, t_ns, _received in msgs:
                            topic, msgtype, qos = channels[by_key[key]]
                            write(topic, msgtype, data, t_ns, qos)
                else:
                    for msgs in steps:
                        if msgs.__class__ is bytes:
                            msgs = loads(msgs)[-1]
                        for key, data, t_ns, _received in msgs:
                            cid = by_key[key]
                            topic, msgtype, qos = channels[cid]
                            write(topic, msgtype, data, t_ns, qos)
                            tap_message(cid, data, t_ns)
                rec.tick()
            elif kind == Frame.CHANNEL:
                cid, topic, msgtype, qos = json.loads(payload)
                channels[cid] = (topic, msgtype, qos)
                rec.channel(topic, msgtype, qos)
                if tap is not None:
                    tap.channel(cid, topic, msgtype, qos)
            elif kind == Frame.FLUSH:
                rec.flush()
            elif kind == Frame.END:
                return True
        if tap is not None:
            tap.tick()


__all__ = ["BackgroundRecorder", "Tap", "TapError", "serve_pipe"]


if __name__ == "__main__":
    import sys

    sys.exit(_write_from_pipe())
