"""The node's side of its Foxglove endpoint (``foxglove_port``): the endpoint's settings for the
recording process that serves it (:mod:`mps_ros.foxglove.live`), and the commands that come
back from it on a socket (:class:`FoxgloveLink`).

A Foxglove client's service call reaches the node as a command does from ``~/mode`` or the
node's own services: the words ``engage``, ``disengage``, ``stop``, ``start`` go to the
node's inbox (source ``foxglove``) and are answered where the run applies or refuses them,
with the JSON object ``~/mode/status`` carries (success: applied); ``pause`` and ``resume``
are the lifecycle's deactivate and activate, ``step`` its ``~/step``. One thread reads the
socket; each call is answered in a thread of its own, so that one waiting for its boundary
never holds another back.
"""

from __future__ import annotations

import dataclasses
import json
import socket
import threading
from types import SimpleNamespace
from typing import Any

from mps_core.scene.settings import COMMANDS as COMMAND_WORDS

from ..run.commands import Command
from ..wire.json_text import to_json

#: the endpoint's services besides the mode commands: the lifecycle's pause, resume and step
LIFECYCLE_WORDS = ("pause", "resume", "step")
#: wall seconds a mode command's answer is awaited (as the node's own services wait)
ANSWER_TIMEOUT = 10.0


def endpoint_settings(node: Any, fd: int) -> dict:
    """The tap's settings (:mod:`mps_ros.foxglove.live`) from the node's parameters:
    address, port, its name, the socket's descriptor in the child, the services, the
    parameters (read-only: a snapshot is exact)."""
    st = node.settings
    values = {f.name: getattr(st, f.name) for f in dataclasses.fields(st)}
    return {
        "host": st.foxglove_address,
        "port": st.foxglove_port,
        "node": node.get_fully_qualified_name(),
        "commands_fd": fd,
        "services": [*COMMAND_WORDS, *LIFECYCLE_WORDS],
        "parameters": {k: (list(v) if isinstance(v, list | tuple) else v) for k, v in values.items()},
        "linger": 5.0,
    }


class FoxgloveLink:
    """The socket to the recording process that serves the endpoint: a pair made here, its
    other end (:attr:`child_fd`) inherited by that process; once it has started,
    :meth:`start` reads the calls that come up and answers them. :attr:`ready` is the number
    of clients subscribed to every channel, as that process last said."""

    def __init__(self, node: Any) -> None:
        self.node = node
        self._mine, self._theirs = socket.socketpair()
        self.child_fd = self._theirs.fileno()
        self.ready = 0
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """The child has its end: close this process's copy and read the calls."""
        self._theirs.close()
        self._thread = threading.Thread(target=self._read, name="foxglove-link", daemon=True)
        self._thread.start()

    def close(self) -> None:
        for s in (self._mine, self._theirs):
            try:
                s.close()
            except OSError:
                pass

    def _send(self, obj: dict) -> None:
        data = (json.dumps(obj) + "\n").encode()
        try:
            with self._lock:
                self._mine.sendall(data)
        except OSError:
            pass

    def _read(self) -> None:
        with self._mine.makefile("rb") as f:
            for line in f:
                try:
                    msg = json.loads(line)
                except ValueError:
                    continue
                if "ready" in msg:
                    self.ready = int(msg["ready"])
                elif "call" in msg:
                    threading.Thread(
                        target=self._answer, args=(str(msg["call"]), msg.get("id")), daemon=True
                    ).start()

    def _answer(self, word: str, n: object) -> None:
        try:
            success, message = self.call(word)
        except Exception as exc:  # the call's own failure, said to the caller
            success, message = False, f"refused: {type(exc).__name__}: {exc}"
        self._send({"id": n, "success": success, "message": message})

    def call(self, word: str) -> tuple[bool, str]:
        """(success, message) for a service call ``word``."""
        node = self.node
        if word in COMMAND_WORDS:
            return self._command(word)
        if word == "step":
            r = node.commands.on_step(None, SimpleNamespace(success=False, message=""))
            return bool(r.success), str(r.message)
        if word in ("pause", "resume"):
            return self._transition(word)
        return (
            False,
            f"unknown service {word!r}: expected one of {', '.join((*COMMAND_WORDS, *LIFECYCLE_WORDS))}",
        )

    def _command(self, word: str) -> tuple[bool, str]:
        node = self.node
        if node.closed:
            return False, "refused: the run has ended"
        done, box = threading.Event(), {}

        def reply(ack: dict) -> None:
            box["ack"] = ack
            done.set()

        node.inbox.put(Command(word, "foxglove", reply))
        if not done.wait(ANSWER_TIMEOUT):
            return False, "no answer: the run is not stepping"
        ack = box["ack"]
        return bool(ack["accepted"]), to_json(ack)

    def _transition(self, word: str) -> tuple[bool, str]:
        from rclpy.lifecycle import TransitionCallbackReturn

        node = self.node
        if not node.activated.is_set():
            return False, "refused: the run has not started"
        if (word == "pause") == bool(node.inactive):
            return False, f"refused: already {'paused' if node.inactive else 'running'}"
        try:
            got = node.trigger_deactivate() if word == "pause" else node.trigger_activate()
        except Exception as exc:  # a transition the state machine refuses
            return False, f"refused: {exc}"
        if got != TransitionCallbackReturn.SUCCESS:
            return False, f"refused: {word} failed (see the node's log)"
        if word == "pause":
            return True, "paused: simulated time holds"
        return True, "resumed: the run goes on"


__all__ = ["ANSWER_TIMEOUT", "FoxgloveLink", "LIFECYCLE_WORDS", "endpoint_settings"]
