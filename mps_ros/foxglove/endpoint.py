"""The Foxglove WebSocket endpoint (``foxglove-sdk``'s server): the node's topics as raw
channels, each message the very CDR bytes the node published and recorded.

Each topic is a channel of message encoding ``cdr`` whose schema is the recording's
(``ros2msg``, the definition with every one it depends on: :func:`mps_ros.wire.cdr.msgdef`, or
the text a recording holds), logged with the message's ``log_time`` (the simulated time, in ns,
as in the recording). A topic offered transient-local (``durability: transient_local`` in its
offered QoS: ``~/structure``, ``/tf_static``) is *latched* here as on the node: a client that
subscribes to it later gets its last message at once, sent to that client alone.

Services (``std_srvs/srv/Trigger``: an empty request, a response ``bool success``, ``string
message``) are named by their full names (``/press_twin/engage``) and answered by a function
of the caller's (:class:`Endpoint`'s ``services``); parameters are a read-only snapshot
(``/press_twin.dt``, as ``foxglove_bridge`` names a node's parameters).

How a message reaches one client alone: ``Channel.log(..., sink_id=...)`` sends to one sink, and
the SDK (0.30) makes each connected client a sink of its own, numbered as the clients are (the
n-th client is sink n in a process with no other sink: this module makes none). The Python API
gives the client's id only, so a latched message is logged to the sink of that id;
``tests/ros/test_foxglove.py`` holds it (a late client gets the latched messages, an early one
no second copy).
"""

from __future__ import annotations

import logging
import re
import struct
import sys
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import foxglove
from foxglove import Channel, MessageSchema, Parameter, ParameterType, Schema, Service, ServiceSchema
from foxglove.websocket import (
    Capability,
    ChannelView,
    Client,
    PlaybackControlRequest,
    PlaybackState,
    ServerListener,
    ServiceRequest,
    WebSocketServer,
)

from ..wire.cdr import msgdef

#: the channels' encodings (the recording's: mcap's ``ros2`` profile)
MESSAGE_ENCODING = "cdr"
SCHEMA_ENCODING = "ros2msg"
#: std_srvs/srv/Trigger, the type of the node's command services
TRIGGER = "std_srvs/srv/Trigger"
TRIGGER_RESPONSE_DEFINITION = "bool success\nstring message\n"
#: a topic offered so is latched (rosbag2's QoS YAML, as the recording's channels carry it)
TRANSIENT_LOCAL = "durability: transient_local"
#: messages queued for a client that reads slowly before its oldest are dropped: about 2.7 s of
#: the node's at 1 kHz (the SDK's default, 1024, is 85 ms of them: a client on a busy machine
#: lost messages with it)
BACKLOG = 32768


class _OncePerClient(logging.Filter):
    """The SDK's log lines about one client, once: a client gone mid-stream makes it say
    "Error sending message to client ADDR: ..." for every message it still had for it."""

    _CLIENT = re.compile(r"\bclient (\S+:\d+)")

    def __init__(self) -> None:
        super().__init__()
        self._seen: set[str] = set()
        self.dropped = 0

    def filter(self, record: logging.LogRecord) -> bool:
        m = self._CLIENT.search(record.getMessage())
        if m is None:
            return True
        key = m.group(1)  # the first line about a client says what became of it
        if key in self._seen:
            self.dropped += 1
            return False
        self._seen.add(key)
        return True


def sdk_logging() -> None:
    """The SDK's log lines (warnings and errors) to standard error, one line each, prefixed
    ``foxglove endpoint:``, those about a client once (:class:`_OncePerClient`). Once a
    process, before its server starts."""
    logger = logging.getLogger("foxglove")
    if any(isinstance(f, _OncePerClient) for h in logger.handlers for f in h.filters):
        return
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("foxglove endpoint: %(message)s"))
    handler.addFilter(_OncePerClient())
    logger.addHandler(handler)
    logger.setLevel(logging.WARNING)
    logger.propagate = False
    foxglove.set_log_level("WARNING")


class EndpointError(OSError):
    """The endpoint could not start (its address or port), with what was asked and why."""


@dataclass
class _Topic:
    channel: Channel
    topic: str
    latched: bool
    last: tuple[bytes, int] | None = None  # a latched topic's last message and its time


#: a service's function: () -> (success, message)
Answer = Callable[[], tuple[bool, str]]


def trigger_response(success: bool, message: str) -> bytes:
    """A std_srvs/srv/Trigger response in CDR (little endian): the bool, the string aligned to
    4 (its length with the terminating NUL, its bytes, the NUL)."""
    text = message.encode()
    return b"\x00\x01\x00\x00" + struct.pack("<?3xI", success, len(text) + 1) + text + b"\x00"


def parameter(name: str, value: object) -> Parameter:
    """A Foxglove parameter of a ROS parameter's value (a real number hinted as such, so that
    1.0 stays a float on the wire)."""
    if isinstance(value, float):
        return Parameter(name, value=value, type=ParameterType.Float64)
    if isinstance(value, list | tuple):
        return Parameter(name, value=[str(v) for v in value])
    if isinstance(value, bool | int | str):
        return Parameter(name, value=value)
    return Parameter(name, value=str(value))


class Endpoint(ServerListener):
    """A Foxglove WebSocket server on ``host:port`` (0: a port the system picks: :attr:`port`)
    with its own SDK context: channels (:meth:`add_channel`), messages (:meth:`log`), the
    services ``services`` (full name -> :data:`Answer`), the read-only ``parameters`` (name ->
    value). ``playback``: a recording's time range (ns) and the function that takes the
    client's play, pause, speed and seek requests (``mps serve``). ``on_ready(n)`` is told how
    many clients are subscribed to every channel whenever that changes.

    :class:`EndpointError` where the server cannot listen (the port in use, an address not of
    this machine), naming the address."""

    def __init__(
        self,
        host: str,
        port: int,
        *,
        name: str = "press_twin",
        services: Mapping[str, Answer] | None = None,
        parameters: Mapping[str, object] | None = None,
        playback: tuple[tuple[int, int], Callable[[PlaybackControlRequest], PlaybackState | None]]
        | None = None,
        on_ready: Callable[[int], None] | None = None,
        backlog: int = BACKLOG,
        what: str = "foxglove_port",
    ) -> None:
        sdk_logging()
        self._ctx = foxglove.Context()
        self._topics: list[_Topic] = []
        self._by_channel: dict[int, _Topic] = {}
        self._lock = threading.Lock()
        self._subs: dict[int, set[int]] = {}  # client id -> the channel ids it takes
        self._ready = 0
        self._on_ready = on_ready
        self._answers = dict(services or {})
        self._parameters = [parameter(k, v) for k, v in (parameters or {}).items()]
        self._playback = playback[1] if playback else None
        self._clock_sent: int | None = None
        self._clock: int | None = None
        #: messages logged; latched messages sent again to a client that joined late
        self.messages = 0
        self.resent = 0
        caps = [Capability.Services, Capability.Parameters, Capability.Time]
        svc = [self._service(n) for n in self._answers]
        try:
            self._server: WebSocketServer = foxglove.start_server(
                name=name,
                host=host,
                port=port,
                capabilities=caps,
                server_listener=self,
                supported_encodings=[MESSAGE_ENCODING],
                services=svc,
                context=self._ctx,
                message_backlog_size=backlog,
                playback_time_range=playback[0] if playback else None,
            )
        except Exception as exc:  # the SDK's RuntimeError: the bind's failure, in its words
            raise EndpointError(
                f"{what} {port}: cannot listen on {host}:{port}: {exc}; give another port "
                "(0: one the system picks) or stop what listens there"
            ) from None
        self.host = host
        self.port = self._server.port

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    # -- channels and messages ----------------------------------------------------------------
    def add_channel(
        self, topic: str, msgtype: str, qos: str | None = None, definition: str | None = None
    ) -> int:
        """A channel for ``topic`` of ROS type ``msgtype`` (``pkg/msg/Name``), its schema
        ``definition`` (default: the recording's, :func:`msgdef`); latched where ``qos`` offers
        transient-local durability. Its index for :meth:`log`."""
        text = msgdef(msgtype) if definition is None else definition
        schema = Schema(name=msgtype, encoding=SCHEMA_ENCODING, data=text.encode())
        meta = {"offered_qos_profiles": qos} if qos else None
        ch = Channel(
            topic, message_encoding=MESSAGE_ENCODING, schema=schema, context=self._ctx, metadata=meta
        )
        t = _Topic(ch, topic, bool(qos and TRANSIENT_LOCAL in qos))
        with self._lock:
            self._topics.append(t)
            self._by_channel[ch.id()] = t
        self._recount()
        return len(self._topics) - 1

    def log(self, index: int, data: bytes, t_ns: int) -> None:
        """Send a message (its CDR bytes, its time in ns) to the clients subscribed to it."""
        t = self._topics[index]
        self.messages += 1
        if t.latched:
            with self._lock:  # a late client's copy and a new message never cross
                t.last = (data, t_ns)
                t.channel.log(data, log_time=t_ns)
            return
        t.channel.log(data, log_time=t_ns)
        if t.topic == "/clock":
            self._clock = t_ns

    def tick(self) -> None:
        """The server's time to the clients: the last ``/clock`` logged, where it moved (once a
        batch, not once a message: each is a message to every client)."""
        if self._clock is not None and self._clock != self._clock_sent:
            self._clock_sent = self._clock
            self._server.broadcast_time(self._clock)

    def broadcast_time(self, t_ns: int) -> None:
        self._server.broadcast_time(t_ns)

    def broadcast_playback_state(self, state: PlaybackState) -> None:
        self._server.broadcast_playback_state(state)

    def clients(self) -> int:
        """Clients with a subscription."""
        with self._lock:
            return sum(1 for s in self._subs.values() if s)

    def close(self, linger: float = 0.0) -> None:
        """Stop the server, once every client has unsubscribed or after ``linger`` wall
        seconds (what is queued for a client still connected is sent meanwhile)."""
        end = time.monotonic() + linger
        while self.clients() and time.monotonic() < end:
            time.sleep(0.02)
        self._server.stop()

    # -- the server's listener (its threads) --------------------------------------------------
    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        with self._lock:
            self._subs.setdefault(client.id, set()).add(channel.id)
            t = self._by_channel.get(channel.id)
            if t is not None and t.latched and t.last is not None:
                # the SDK makes client n its sink n (see the module's docstring)
                t.channel.log(t.last[0], log_time=t.last[1], sink_id=client.id)
                self.resent += 1
        self._recount()

    def on_unsubscribe(self, client: Client, channel: ChannelView) -> None:
        with self._lock:
            subs = self._subs.get(client.id)
            if subs is not None:
                subs.discard(channel.id)
                if not subs:
                    del self._subs[client.id]
        self._recount()

    def on_get_parameters(
        self, client: Client, param_names: list[str], request_id: str | None = None
    ) -> list[Parameter]:
        if not param_names:
            return list(self._parameters)
        wanted = set(param_names)
        return [p for p in self._parameters if p.name in wanted]

    def on_set_parameters(
        self, client: Client, parameters: list[Parameter], request_id: str | None = None
    ) -> list[Parameter]:
        # read-only: the values as they are
        names = {p.name for p in parameters}
        return [p for p in self._parameters if p.name in names]

    def on_playback_control_request(
        self, playback_control_request: PlaybackControlRequest
    ) -> PlaybackState | None:
        if self._playback is None:
            return None
        return self._playback(playback_control_request)

    def _recount(self) -> None:
        with self._lock:
            every = {t.channel.id() for t in self._topics}
            ready = sum(1 for s in self._subs.values() if every and every <= s)
            changed = ready != self._ready
            self._ready = ready
        if changed and self._on_ready is not None:
            self._on_ready(ready)

    def _service(self, name: str) -> Service:
        empty = Schema(name=f"{TRIGGER}_Request", encoding=SCHEMA_ENCODING, data=b"")
        response = Schema(
            name=f"{TRIGGER}_Response", encoding=SCHEMA_ENCODING, data=TRIGGER_RESPONSE_DEFINITION.encode()
        )
        schema = ServiceSchema(
            name=TRIGGER,
            request=MessageSchema(encoding=MESSAGE_ENCODING, schema=empty),
            response=MessageSchema(encoding=MESSAGE_ENCODING, schema=response),
        )
        answer = self._answers[name]

        def handler(request: ServiceRequest) -> bytes:
            success, message = answer()
            return trigger_response(success, message)

        return Service(name, schema=schema, handler=handler)


__all__ = ["BACKLOG", "Endpoint", "EndpointError", "TRIGGER", "parameter", "sdk_logging", "trigger_response"]
