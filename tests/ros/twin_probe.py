"""Helpers of the ROS tests: a node process that is always ended, and a listener (subscriber +
operator) living in the test's own process."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
import traceback
from pathlib import Path

from mps_ros.wire.topics import MODE, TOPICS, resolve


def mps_cmd(*args) -> list[str]:
    return [sys.executable, "-m", "mps_core.cli", *args]


class NodeProcess:
    """``mps node SCENE --ros-args -p ...`` in its own session; stdout+stderr to ``log``.
    Use as a context manager: on exit the whole process group is ended (SIGTERM, then
    SIGKILL)."""

    def __init__(self, tmp_path: Path, params: dict, scene: str = "press-cycle", name="node"):
        self.log_path = tmp_path / f"{name}.log"
        args = []
        for k, v in params.items():
            if isinstance(v, bool):
                v = str(v).lower()
            args += ["-p", f"{k}:={v}"]
        self.cmd = mps_cmd("node", scene, "--ros-args", *args)
        self.proc = None

    def __enter__(self):
        self._log = open(self.log_path, "wb")
        self.proc = subprocess.Popen(
            self.cmd,
            stdout=self._log,
            stderr=subprocess.STDOUT,
            env=dict(os.environ, PYTHONUNBUFFERED="1"),
            start_new_session=True,
        )
        return self

    @property
    def pid(self):
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def wait(self, timeout: float) -> int:
        return self.proc.wait(timeout)

    def signal(self, sig) -> None:
        os.killpg(self.proc.pid, sig)

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def __exit__(self, exc_type, exc, tb):
        stop_group(self.proc)
        self._log.close()
        if exc_type is not None:  # shown by pytest with the failure
            print(f"--- {self.cmd}\n{self.log()[-6000:]}")
        elif "starting without all peers" in self.log():
            # the node waited out wait_timeout: the test's subscriber missed a topic the node
            # publishes (a test that waits for nothing sets wait_for_subscribers 0)
            raise AssertionError(
                f"{self.log_path.name}: the node waited for peers in vain:\n" + self.log()[-3000:]
            )
        return False


def wait_until(cond, timeout: float, what: str, poll: float = 0.002):
    """``cond()``'s first true value, polled until ``timeout`` s; AssertionError naming
    ``what`` when it never comes."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        v = cond()
        if v:
            return v
        time.sleep(poll)
    raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")


def ask(client, request, spin, timeout: float, tries: int):
    """A service's answer, or None: ``request`` sent on ``client`` up to ``tries`` times, each
    answer waited for ``timeout`` s by ``spin(future, timeout)``; only for a request that
    asking again does not change. Also gives how many were sent."""
    for sent in range(1, tries + 1):
        fut = client.call_async(request)
        spin(fut, timeout)
        if fut.done():
            return fut.result(), sent
        client.remove_pending_request(fut)
    return None, tries


def stop_group(proc, grace: float = 5.0) -> None:
    """End a test's process group (None: nothing started)."""
    if proc is not None:
        from mps_ros.commands.demo import stop_group as _stop_group

        _stop_group(proc, grace)


def ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


class Listener:
    """Subscribes to every topic of ``press_twin`` (or to ``keys``; reliable, deep history),
    keeps what arrives in order, sends mode commands, calls the Trigger services. Spins in a
    background thread."""

    def __init__(self, node_name: str = "press_twin", keys=None):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        from std_msgs.msg import String
        from std_srvs.srv import Trigger

        from mps_ros.ros.endpoints import MSG_CLASSES

        self.rclpy = rclpy
        self.node = Node(f"probe_{os.getpid()}_{int(time.monotonic() * 1e3) % 100000}")
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=20000, reliability=ReliabilityPolicy.RELIABLE)
        self.msgs: dict[str, list] = {}
        self.lock = threading.Lock()
        self.topics = {}
        for t in TOPICS:
            if keys is not None and t.key not in keys:
                continue  # a test that reads a few topics takes only those
            if t.msgtype not in MSG_CLASSES:
                continue  # not importable here: the node records it only
            name = resolve(t.key, node_name)
            self.topics[t.key] = name
            self.msgs[name] = []
            self.node.create_subscription(MSG_CLASSES[t.msgtype], name, self._cb(name), qos)
        self.mode_topic = resolve(MODE.key, node_name)
        self.mode = self.node.create_publisher(
            String, self.mode_topic, QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        )
        self.String = String
        # the services' clients on a node of their own, spun by the thread that calls them
        # (:meth:`call`), not by the executor thread that takes the topics
        self.client_node = Node(f"{self.node.get_name()}_calls")
        self.client_executor = SingleThreadedExecutor()
        self.client_executor.add_node(self.client_node)
        self.services = {
            w: self.client_node.create_client(Trigger, f"/{node_name}/{w}")
            for w in ("engage", "disengage", "stop", "start")
        }
        self.Trigger = Trigger
        self.calls = 0  # the service calls made
        self.spin_error: str | None = None  # why the executor's thread ended, if it did
        executor = SingleThreadedExecutor()
        executor.add_node(self.node)
        from mps_ros.ros.spinning import SpinThread

        self.spin = SpinThread(executor, "listener", self._failed)

    def _failed(self, exc: Exception) -> None:  # kept: a listener that stops taking messages says why
        self.spin_error = f"{type(exc).__name__}: {exc}\n{''.join(traceback.format_exception(exc))}"

    def _cb(self, name):
        def cb(msg):
            with self.lock:
                self.msgs[name].append(msg)

        return cb

    # -- reading ---------------------------------------------------------------------------
    def get(self, key: str) -> list:
        with self.lock:
            return list(self.msgs[self.topics.get(key, key)])

    def clock(self) -> float | None:
        """The last /clock received (s), without copying what came before it (a test polls it
        every few milliseconds over runs of tens of thousands of steps)."""
        with self.lock:
            c = self.msgs[self.topics.get("/clock", "/clock")]
            last = c[-1] if c else None
        return ns(last.clock) * 1e-9 if last is not None else None

    def events(self) -> list[dict]:
        return [json.loads(m.data) for m in self.get("~/events")]

    def acks(self) -> list[dict]:
        return [json.loads(m.data) for m in self.get("~/mode/status")]

    def ended(self) -> bool:
        return any(e.get("kind") == "run-end" for e in self.events())

    def wait_for(self, cond, timeout: float, what: str, poll: float = 0.002):
        try:
            return wait_until(cond, timeout, what, poll)
        except AssertionError as exc:
            if self.spin_error:
                raise AssertionError(f"{exc} (the listener's executor ended: {self.spin_error})") from None
            raise

    # -- sending ---------------------------------------------------------------------------
    def send(self, word: str) -> None:
        self.mode.publish(self.String(data=word))

    def call(self, word: str, timeout: float = 30.0, tries: int = 1):
        """A Trigger service's answer, asked up to ``tries`` times (``timeout`` each): only
        for a request that asking again does not change (a refusal). The calling thread spins
        the clients' own node until the answer comes: in clean clones' runs, a client spun by
        the executor thread that takes the topics, called from this thread, got no more
        answers after its first (the node's log showed every request answered)."""
        cli = self.services[word]
        assert cli.wait_for_service(timeout_sec=timeout), f"service {word} not available"
        answer, sent = ask(
            cli,
            self.Trigger.Request(),
            lambda fut, s: self.client_executor.spin_until_future_complete(fut, timeout_sec=s),
            timeout,
            tries,
        )
        self.calls += sent
        if answer is not None:
            return answer
        raise AssertionError(
            f"no answer from service {word} ({tries} asked; the listener's executor "
            + (f"ended: {self.spin_error})" if self.spin_error else f"alive: {self.spin.alive()})")
        )

    def close(self):
        """Stop the spinning thread, then destroy the nodes (rclpy: never a node another thread
        spins); one left spinning fails the test rather than the process."""
        from mps_ros.ros.spinning import close

        assert close(self.spin, [self.node]), "the listener's executor thread did not end"
        self.client_executor.shutdown()  # spun by the threads that call, none of them now
        self.client_node.destroy_node()


class RtpsSniffer:
    """Watches every interface for RTPS (DDS) packets, from creation to :meth:`stop`, which
    returns those seen off loopback (``on_loopback`` counts the others: proof that it sees DDS
    traffic at all). Needs a raw packet socket (root or CAP_NET_RAW); without one, :meth:`stop`
    returns None and the check is skipped."""

    def __init__(self):
        import socket

        self.found: list = []
        self.on_loopback = 0
        try:
            self.sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(0x0003))
        except (PermissionError, OSError, AttributeError):
            self.sock = None
            return
        self.sock.settimeout(0.1)
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        import socket
        import struct

        while not self._stop.is_set():
            try:
                data, addr = self.sock.recvfrom(65535)
            except TimeoutError:
                continue
            except OSError:
                return
            ifname, hatype = addr[0], addr[3]
            if hatype not in (1, 772):  # Ethernet and loopback frames
                continue
            etype = struct.unpack_from("!H", data, 12)[0]
            if etype == 0x0800 and len(data) > 34 and data[23] == 17:
                ihl = (data[14] & 0x0F) * 4
                udp = 14 + ihl
                dst = socket.inet_ntoa(data[30:34])
            elif etype == 0x86DD and len(data) > 62 and data[20] == 17:
                udp = 54
                dst = socket.inet_ntop(socket.AF_INET6, data[38:54])
            else:
                continue
            if data[udp + 8 : udp + 12] == b"RTPS":
                port = struct.unpack_from("!H", data, udp + 2)[0]
                if ifname == "lo":
                    self.on_loopback += 1
                else:
                    self.found.append((ifname, dst, port))

    def stop(self):
        if self.sock is None:
            return None
        self._stop.set()
        self.thread.join(2.0)
        self.sock.close()
        return list(self.found)
