"""The Foxglove endpoint with the protocol's own client: ``@foxglove/ws-protocol`` (npm) and
``@foxglove/rosmsg2-serialization`` decode every message a running node's endpoint sends, and
they match the node's recording of the same run, message for message and value for value; the
engage service is applied; a client that joins late gets the latched structure and static
frames, an early one no second copy. The same client against ``mps serve`` on the sample
recording gets every message of the file, in order. Bad input: a port in use, an endpoint
without a recording, a client that calls a service that is not there and then drops its
connection mid-run.

The Node.js client lives in ``tests/js`` (its ``package.json`` and ``package-lock.json``); its
packages are installed there with ``npm ci`` once a session. Skipped, with the reason, where
``node`` or ``npm`` is missing or the install fails."""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
import shutil
import signal
import socket
import struct
import subprocess
import threading
from pathlib import Path

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("foxglove")
pytest.importorskip("websockets")

from js_packages import JS, npm_ci
from twin_probe import NodeProcess, mps_cmd, stop_group, wait_until

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "recordings" / "sample_press-cycle.mcap"


@pytest.fixture(scope="session")
def js_client():
    """The command of the Node.js client, its packages installed (``npm ci``), or a skip."""
    why = npm_ci()
    if why is not None:
        pytest.skip(why)
    return [shutil.which("node"), str(JS / "foxglove_client.mjs")]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run_client(cmd, out: Path, timeout: float = 300, **opts) -> tuple[dict, list[dict]]:
    out.mkdir(parents=True, exist_ok=True)
    p = subprocess.run(
        [*cmd, json.dumps({"out": str(out), **opts})], capture_output=True, text=True, timeout=timeout
    )
    summary = json.loads((out / "summary.json").read_text()) if (out / "summary.json").is_file() else {}
    assert p.returncode == 0, (p.stdout, p.stderr, summary.get("errors"))
    msgs = [json.loads(line) for line in (out / "messages.jsonl").read_text().splitlines()]
    return summary, msgs


def recorded(path: Path) -> list[tuple[str, str, int, bytes]]:
    """(topic, type, log time, bytes) of every message of a recording, in the file's order."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        return [
            (ch.topic, sch.name, m.log_time, m.data)
            for sch, ch, m in make_reader(f).iter_messages(log_time_order=False)
        ]


def plain(v):
    """A value decoded by rosbags, as the client writes its own in JSON (NaN as a string)."""
    import numpy as np

    if dataclasses.is_dataclass(v):  # its fields, not its constants (upper case) nor its type's name
        names = [f.name for f in dataclasses.fields(v)]
        return {k: plain(getattr(v, k)) for k in names if k != "__msgtype__" and not k.isupper()}
    if isinstance(v, np.ndarray):
        return [plain(x) for x in v.tolist()]
    if isinstance(v, list | tuple):
        return [plain(x) for x in v]
    if isinstance(v, float | np.floating):
        return "NaN" if math.isnan(v) else float(v)
    if isinstance(v, np.integer):
        return int(v)
    return v


@functools.cache
def _typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def decoded(msgtype: str, data: bytes):
    return plain(_typestore().deserialize_cdr(data, msgtype))


class RawClient(threading.Thread):
    """A client of our own over plain websockets: subscribes to every channel, reads
    ``take`` messages, calls a service id that is not there (the server's answer kept), then
    pause, step, step, resume (their answers kept), then drops its connection without a
    word."""

    def __init__(self, url: str, take: int):
        super().__init__(daemon=True)
        self.url, self.take = url, take
        self.got = 0
        self.answers: list[dict] = []
        self.calls: list[tuple[str, bool, str]] = []
        self.services: dict[str, int] = {}
        self.error: Exception | None = None
        self.address = ""

    def run(self):
        from websockets.sync.client import connect

        try:
            with connect(self.url, subprotocols=["foxglove.sdk.v1"], max_size=None) as ws:
                host, port = ws.local_address[:2]
                self.address = f"{host}:{port}"
                self._talk(ws)
        except Exception as exc:
            self.error = exc

    def _next(self, ws):
        """The next message: JSON ones kept where they answer or advertise, a data message
        counted; a service's response returned."""
        m = ws.recv(timeout=120)
        if isinstance(m, str):
            j = json.loads(m)
            if j["op"] == "advertise":
                subs = [{"id": c["id"], "channelId": c["id"]} for c in j["channels"]]
                ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
            elif j["op"] == "advertiseServices":
                self.services.update({sv["name"]: sv["id"] for sv in j["services"]})
            elif j["op"] in ("status", "serviceCallFailure"):
                self.answers.append(j)
        elif m[0] == 1:
            self.got += 1
        elif m[0] == 3:  # a service call's response: std_srvs/srv/Trigger_Response in CDR
            enc = struct.unpack_from("<I", m, 9)[0]
            data = m[13 + enc :]
            n = struct.unpack_from("<I", data, 8)[0]
            return bool(data[4]), data[12 : 12 + n - 1].decode()
        return None

    def _call(self, ws, name: str, call_id: int) -> None:
        ws.send(struct.pack("<BIII", 2, self.services[name], call_id, 3) + b"cdr" + b"\x00\x01\x00\x00")
        for _ in range(100_000):
            got = self._next(ws)
            if got is not None:
                self.calls.append((name, *got))
                return

    def _talk(self, ws):
        while self.got < self.take:
            self._next(ws)
        ws.send(struct.pack("<BIII", 2, 99999, 1, 3) + b"cdr" + b"\x00\x01\x00\x00")
        for _ in range(100_000):
            if self.answers:
                break
            self._next(ws)
        for i, word in enumerate(("pause", "step", "step", "resume")):
            self._call(ws, f"/press_twin/{word}", 10 + i)
        ws.socket.close()  # dropped, no closing handshake


def test_a_foxglove_client_gets_what_the_node_records(js_client, tmp_path):
    port = free_port()
    rec = tmp_path / "run.mcap"
    params = dict(
        pacing="realtime",
        dt=1e-3,
        t_end=1.0,
        recording=str(rec),
        scene_commands=False,
        foxglove_port=port,
        wait_for_foxglove=1,
        wait_timeout=120.0,
    )
    url = f"ws://127.0.0.1:{port}"
    with NodeProcess(tmp_path, params) as node:
        wait_until(lambda: "foxglove endpoint" in node.log() or not node.alive(), 120, "the endpoint")
        assert f"foxglove endpoint: {url}" in node.log(), node.log()
        raw = RawClient(url, take=3000)
        raw.start()
        summary, msgs = run_client(
            js_client,
            tmp_path / "js",
            url=url,
            endOnRunEnd=True,
            engageAfterNs=0,  # at once: answered while the run goes, however far behind the client
            lateAfterNs=500_000_000,
            lateTopics=["/tf_static", "/press_twin/structure"],
            timeoutS=240,
        )
        assert node.wait(120) == 0, node.log()
        raw.join(60)
    assert summary["errors"] == [] and summary["subprotocol"] == "foxglove.sdk.v1", summary
    file = recorded(rec)
    types = {t: m for t, m, _, _ in file}
    # every channel the recording has, each cdr with the recording's ros2msg schema
    for topic, msgtype in types.items():
        ch = summary["channels"][topic]
        assert (ch["encoding"], ch["schemaEncoding"], ch["schemaName"]) == ("cdr", "ros2msg", msgtype), topic
    assert "/tf" in types and "/tf_static" in types
    # every message, in the recording's order, the same bytes and log time, and the values
    # the client decoded are rosbags' decoding of the recorded bytes
    assert len(msgs) == len(file), (len(msgs), len(file))
    for got, (topic, _msgtype, t, data) in zip(msgs, file):
        assert (got["topic"], got["t"], got["sha"]) == (topic, t, hashlib.sha256(data).hexdigest())
    for got, (topic, msgtype, _t, data) in zip(msgs, file):
        assert got["value"] == decoded(msgtype, data), topic
    # the engage service: applied, and answered with what ~/mode/status says
    answer = summary["engage"]["value"]
    ack = json.loads(answer["message"])
    assert answer["success"] is True and ack["command"] == "engage" and ack["accepted"] is True
    assert ack["source"] == "foxglove"
    statuses = [json.loads(decoded(m, d)["data"]) for tp, m, _, d in file if tp == "/press_twin/mode/status"]
    assert statuses == [ack]
    events = [json.loads(decoded(m, d)["data"]) for tp, m, _, d in file if tp == "/press_twin/events"]
    assert any(e.get("kind") == "command" and e.get("command") == "engage" for e in events), events
    # the late client: the static frames and the structure in force when it joined, once each
    late = summary["late"]["messages"]
    assert sorted(m["topic"] for m in late) == ["/press_twin/structure", "/tf_static"], late
    tf_static = [(t, decoded(m, d)) for tp, m, t, d in file if tp == "/tf_static"]
    structures = [(t, decoded(m, d)) for tp, m, t, d in file if tp == "/press_twin/structure"]
    got = {m["topic"]: (m["t"], m["value"]) for m in late}
    assert got["/tf_static"] == tf_static[-1]
    in_force = [s for s in structures if s[0] <= summary["late"]["joinedAfterNs"]][-1]
    assert got["/press_twin/structure"] in structures and got["/press_twin/structure"][0] >= in_force[0]
    # the parameters, readable
    params_got = {p["name"]: p["value"] for p in summary["parameters"]}
    assert params_got["/press_twin.foxglove_port"] == port and params_got["/press_twin.dt"] == 1e-3
    # the client of our own: served, answered about the service that is not there, dropped:
    # the run went on unharmed (the node ended 0, the Node.js client got every message)
    assert raw.error is None and raw.got >= 3000, raw.error
    assert raw.answers and "99999" in json.dumps(raw.answers), raw.answers
    # its dropping out: one line of the node's log at most (the SDK's, once for that client);
    # a subscription sent back within the instant a channel is advertised may meet the SDK
    # before it knows the channel ("attempted to subscribe to unknown channel", about one run
    # in four here: the SDK's race, not the drop), a line of its own
    said = [
        line
        for line in node.log().splitlines()
        if raw.address in line and "attempted to subscribe to unknown channel" not in line
    ]
    assert len(said) <= 1, said
    # the lifecycle's pause, two steps and resume from Foxglove: the run held, stepped, went on
    # (its recording the one above: every message, as the Node.js client got them)
    words = [(w.rsplit("/", 1)[1], ok) for w, ok, _ in raw.calls]
    assert words == [("pause", True), ("step", True), ("step", True), ("resume", True)], raw.calls
    t1, t2 = (float(m.split("t = ")[1].split(" s")[0]) for _, _, m in raw.calls[1:3])
    assert t2 == pytest.approx(t1 + 1e-3), raw.calls


def test_mps_serve_plays_every_message_of_the_sample(js_client, tmp_path):
    port = free_port()
    file = recorded(SAMPLE)
    log = open(tmp_path / "serve.log", "wb")
    serve = subprocess.Popen(
        mps_cmd("serve", str(SAMPLE), "--port", str(port), "--rate", "5", "--wait-clients", "1"),
        stdout=log,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    try:
        wait_until(
            lambda: b"serving" in (tmp_path / "serve.log").read_bytes() or serve.poll() is not None,
            120,
            "mps serve",
        )
        summary, msgs = run_client(
            js_client, tmp_path / "js", url=f"ws://127.0.0.1:{port}", expect=len(file), timeoutS=240
        )
        serve.send_signal(signal.SIGINT)
        assert serve.wait(60) == 130
    finally:
        stop_group(serve)
        log.close()
    text = (tmp_path / "serve.log").read_text()
    assert f"stopped (SIGINT) after {len(file)} messages of {len(file)}" in text, text
    # the one error: the 0.8.0 client does not know the playback state (binary opcode 5)
    assert all("opcode in binary message: 5" in e for e in summary["errors"]), summary["errors"]
    assert "playbackControl" in summary["serverInfo"]["capabilities"]
    assert [(m["topic"], m["t"], m["sha"]) for m in msgs] == [
        (topic, t, hashlib.sha256(data).hexdigest()) for topic, _, t, data in file
    ]


def test_the_endpoint_refuses_a_port_in_use_and_no_recording(tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        rec = tmp_path / "r.mcap"
        with NodeProcess(
            tmp_path, dict(recording=str(rec), foxglove_port=port, t_end=0.1), name="busy"
        ) as node:
            assert node.wait(120) == 2, node.log()
        text = node.log()
        assert f"press_twin: error: foxglove_port {port}: cannot listen on 127.0.0.1:{port}" in text, text
        assert "Traceback" not in text and not rec.exists()
        p = subprocess.run(
            mps_cmd("serve", str(SAMPLE), "--port", str(port)), capture_output=True, text=True, timeout=120
        )
        assert p.returncode == 2 and f"mps serve: error: --port {port}: cannot listen" in p.stderr, p.stderr
    with NodeProcess(
        tmp_path, dict(recording="none", foxglove_port=free_port(), t_end=0.1), name="none"
    ) as node:
        assert node.wait(120) == 2, node.log()
    assert "press_twin: error: parameter foxglove_port" in node.log() and "expected a recording" in node.log()
    for args, words in (
        (["--rate", "0"], "--rate 0: expected a number above 0"),
        (["--port", "70000"], "--port 70000: expected a port"),
    ):
        p = subprocess.run(mps_cmd("serve", str(SAMPLE), *args), capture_output=True, text=True, timeout=120)
        assert p.returncode == 2 and words in p.stderr and "Traceback" not in p.stderr, p.stderr
    p = subprocess.run(
        mps_cmd("serve", str(tmp_path / "no.mcap")), capture_output=True, text=True, timeout=120
    )
    assert p.returncode == 2 and "no such file" in p.stderr, p.stderr


def test_mps_serve_names_a_bag_of_sqlite3_files_as_one_it_cannot_play(tmp_path):
    """A rosbag2 bag in its sqlite3 storage carries no message definitions for a Foxglove client:
    refused by name, with the commands that do read it."""
    from sqlite_bags import as_sqlite3_bag

    from mps_ros.foxglove.serve import ServeError, parts

    bag = as_sqlite3_bag(SAMPLE, tmp_path / "sample-sqlite")
    with pytest.raises(ServeError, match=r"rosbag2.s sqlite3 storage \(\.db3 files\): expected MCAP"):
        parts(bag)


def test_mps_serve_seeks_where_a_client_asks(tmp_path):
    """A client's seek (the protocol's playback control, as the Foxglove app sends it): played
    at 0.01 of real time, then asked to play from 0.9 s at 1000 times: it gets the latched
    topics' messages in force there, then every message of the file from 0.9 s on, in order."""
    from websockets.sync.client import connect

    port = free_port()
    file = recorded(SAMPLE)
    seek = 900_000_000
    log = open(tmp_path / "serve.log", "wb")
    serve = subprocess.Popen(
        mps_cmd("serve", str(SAMPLE), "--port", str(port), "--rate", "0.01", "--wait-clients", "1"),
        stdout=log,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    got: list[tuple[str, int, bytes]] = []
    try:
        wait_until(
            lambda: b"serving" in (tmp_path / "serve.log").read_bytes() or serve.poll() is not None,
            120,
            "mps serve",
        )
        with connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"], max_size=None) as ws:
            topics: dict[int, str] = {}
            asked = False
            while not got or got[-1][:2] != (file[-1][0], file[-1][2]):  # until the file's last
                m = ws.recv(timeout=120)
                if isinstance(m, str):
                    j = json.loads(m)
                    if j["op"] == "advertise":
                        topics.update({c["id"]: c["topic"] for c in j["channels"]})
                        subs = [{"id": c["id"], "channelId": c["id"]} for c in j["channels"]]
                        ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                    continue
                if m[0] != 1:
                    continue
                sub, t = struct.unpack_from("<IQ", m, 1)
                got.append((topics[sub], t, m[13:]))
                if not asked:  # playing (every channel subscribed): play from 0.9 s, 1000x
                    asked = True
                    req = b"seek-1"
                    ws.send(struct.pack("<BBfBQI", 3, 0, 1000.0, 1, seek, len(req)) + req)
        serve.send_signal(signal.SIGINT)
        assert serve.wait(60) == 130
    finally:
        stop_group(serve)
        log.close()
    tail = [(tp, t, d) for tp, _, t, d in file if t >= seek]
    assert got[-len(tail) :] == tail
    before = got[: -len(tail)]
    # what came before the seek was taken (early in the file, at 0.01 of real time), then the
    # latched topics' messages in force at 0.9 s
    latched = {
        tp: (tp, t, d) for tp, _, t, d in file if t < seek and tp in ("/tf_static", "/press_twin/structure")
    }
    assert before[-2:] == sorted(latched.values(), key=lambda m: [x[0] for x in file].index(m[0]))
    assert all(t < 100_000_000 for _, t, _ in before[:-2]), [t for _, t, _ in before[:-2]][-5:]


class _Collecting:
    """An endpoint stand-in for :class:`~mps_ros.foxglove.serve.Player`: what it is given."""

    def __init__(self):
        self.topics: list[str] = []
        self.got: list[tuple[str, int, bytes]] = []

    def add_channel(self, topic, msgtype, qos=None, definition=None):
        self.topics.append(topic)
        return len(self.topics) - 1

    def log(self, index, data, t_ns):
        self.got.append((self.topics[index], t_ns, bytes(data)))

    def broadcast_time(self, t_ns):
        pass

    def broadcast_playback_state(self, state):
        pass


def test_mps_serve_plays_a_bag_as_one_recording(tmp_path):
    """A bag of several files (``max_s``): played through as one, every message of its files in
    their order."""
    from mps_ros.foxglove.serve import Player
    from mps_ros.run.record import record

    bag = tmp_path / "run"
    # written in this process, its split looked at every step (the writing process looks
    # between the batches it is handed, as many or as few as the machine's load makes them)
    record("press-cycle", bag, dt=1e-3, t_end=0.2, max_s=0.08, background=False, stop_on_signals=False)
    files = sorted(bag.glob("*.mcap"))
    assert len(files) == 3, files
    player = Player(bag, rate=1000.0)
    ep = _Collecting()
    player.attach(ep)
    assert player.run() == player.count
    want = [(topic, t, data) for f in files for topic, _, t, data in recorded(f)]
    # each file in log-time order, the files one after the other
    assert ep.got == want
