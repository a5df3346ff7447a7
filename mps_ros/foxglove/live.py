"""The node's Foxglove endpoint, served by its recording process
(``python -m mps_ros.foxglove.live``): the recorder's writing process
(:func:`mps_ros.recording.background.serve_pipe`) with an :class:`~.endpoint.Endpoint` beside
the file, fed every channel and message the file gets, in the same order, as the same bytes.

That process already receives every message the node released, as CDR bytes with its channel,
in batches (every 20 ms), off the stepping and the publishing: serving them from there costs
the node's stepping and publishing nothing but what the recorder already costs. The mode
commands go back to the node on a socket the node passed down (``commands_fd``), one JSON line
each way: ``{"call": WORD, "id": N}`` up, ``{"id": N, "success": ..., "message": ...}`` down;
and ``{"ready": N}`` up whenever the number of clients subscribed to every channel changes
(the node's ``wait_for_foxglove``). The node's side is :mod:`mps_ros.ros.foxglove_link`.

The tap's settings (JSON, from the node): ``host``, ``port``, ``node`` (its full name),
``commands_fd``, ``services`` (their words), ``parameters`` (name -> value), ``linger`` (wall
seconds the endpoint stays up at the run's end for a client still subscribed).
"""

from __future__ import annotations

import itertools
import json
import socket
import sys
import threading

from ..recording.background import TapError, serve_pipe
from .endpoint import BACKLOG, Endpoint, EndpointError

#: wall seconds a service call waits for the node's answer (a command's is its boundary's,
#: ``command_delay`` after it arrives; a paused node's step a step's)
CALL_TIMEOUT = 30.0


class CommandLine:
    """This process's end of the node's command socket: calls sent up, their answers matched
    by id (a service call's thread waits on its own), readiness counts sent up."""

    def __init__(self, fd: int) -> None:
        self._sock = socket.socket(fileno=fd)
        self._file = self._sock.makefile("rb")
        self._ids = itertools.count(1)
        self._waiting: dict[int, tuple[threading.Event, dict[str, object]]] = {}
        self._lock = threading.Lock()
        self.closed = False
        self._reader = threading.Thread(target=self._read, name="foxglove-commands", daemon=True)
        self._reader.start()

    def _send(self, obj: dict) -> bool:
        data = (json.dumps(obj) + "\n").encode()
        try:
            with self._lock:
                self._sock.sendall(data)
            return True
        except OSError:
            return False

    def _read(self) -> None:
        for line in self._file:
            try:
                answer = json.loads(line)
            except ValueError:
                continue
            waiting = self._waiting.pop(int(answer.get("id", 0)), None)
            if waiting is not None:
                waiting[1].update(answer)
                waiting[0].set()
        self.closed = True
        for done, box in list(self._waiting.values()):
            box.setdefault("message", "no answer: the node is gone")
            done.set()

    def call(self, word: str) -> tuple[bool, str]:
        """The node's answer to ``word``: (success, message)."""
        n = next(self._ids)
        done, box = threading.Event(), dict[str, object]()
        self._waiting[n] = (done, box)
        if self.closed or not self._send({"call": word, "id": n}):
            self._waiting.pop(n, None)
            return False, "no answer: the node is gone"
        if not done.wait(CALL_TIMEOUT):
            self._waiting.pop(n, None)
            return False, f"no answer from the node in {CALL_TIMEOUT:g} s"
        return bool(box.get("success")), str(box.get("message", ""))

    def ready(self, n: int) -> None:
        self._send({"ready": n})

    def close(self) -> None:
        try:
            self._sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self._sock.close()


class LiveTap:
    """The endpoint as the writing process's tap (:class:`~mps_ros.recording.background.Tap`)."""

    def __init__(self, settings: dict) -> None:
        fd = settings.get("commands_fd")
        self.line = CommandLine(int(fd)) if fd is not None else None
        node = str(settings.get("node", "/press_twin"))
        line = self.line
        services = {}
        if line is not None:
            for word in settings.get("services", ()):
                services[f"{node}/{word}"] = (lambda w: lambda: line.call(w))(word)
        try:
            self.endpoint = Endpoint(
                str(settings.get("host", "127.0.0.1")),
                int(settings.get("port", 0)),
                name=node.lstrip("/"),
                services=services,
                parameters={f"{node}.{k}": v for k, v in settings.get("parameters", {}).items()},
                on_ready=line.ready if line is not None else None,
                backlog=int(settings.get("backlog", BACKLOG)),
            )
        except EndpointError as exc:
            raise TapError(str(exc)) from None
        self.linger = float(settings.get("linger", 5.0))
        self._index: dict[int, int] = {}
        self.log = self.endpoint.log

    def channel(self, cid: int, topic: str, msgtype: str, qos: str | None) -> None:
        if cid not in self._index:
            self._index[cid] = self.endpoint.add_channel(topic, msgtype, qos)

    def message(self, cid: int, data: bytes, t_ns: int) -> None:
        self.log(self._index[cid], data, t_ns)

    def tick(self) -> None:
        self.endpoint.tick()

    def info(self) -> dict:
        return {"url": self.endpoint.url, "port": self.endpoint.port}

    def close(self) -> None:
        self.endpoint.close(self.linger)
        if self.line is not None:
            self.line.close()


def main() -> int:
    return serve_pipe(LiveTap)


__all__ = ["CALL_TIMEOUT", "CommandLine", "LiveTap", "main"]


if __name__ == "__main__":
    sys.exit(main())
