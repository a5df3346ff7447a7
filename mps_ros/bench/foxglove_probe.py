"""The benchmark's Foxglove client (``python -m mps_ros.bench foxglove URL [--slow]``): connects
to the node's endpoint, subscribes to every channel, counts what arrives by topic until the
run's ``run-end`` event or the connection's end, and prints one JSON line (messages, by topic,
its own CPU). ``--slow``: a client that cannot keep up, taking a message every millisecond at
most (the server drops the oldest of its backlog for it alone)."""

from __future__ import annotations

import json
import os
import struct
import sys
import time


def main(url: str, slow: bool = False, timeout: float = 600.0) -> int:
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect
    from websockets.typing import Subprotocol

    topics: dict[int, str] = {}
    counts: dict[str, int] = {}
    got, first, last = 0, None, None
    c0 = time.process_time()
    end = time.monotonic() + timeout
    try:
        with connect(url, subprotocols=[Subprotocol("foxglove.sdk.v1")], max_size=None) as ws:
            while time.monotonic() < end:
                m = ws.recv(timeout=timeout)
                if isinstance(m, str):
                    j = json.loads(m)
                    if j["op"] == "advertise":
                        subs = [{"id": c["id"], "channelId": c["id"]} for c in j["channels"]]
                        topics.update({c["id"]: c["topic"] for c in j["channels"]})
                        ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                    continue
                if m[0] != 1:
                    continue
                sub = struct.unpack_from("<I", m, 1)[0]
                topic = topics.get(sub, "?")
                counts[topic] = counts.get(topic, 0) + 1
                got += 1
                now = time.monotonic()
                first = now if first is None else first
                last = now
                if topic.endswith("/events") and b'"run-end"' in m:
                    break
                if slow:
                    time.sleep(0.001)
    except (ConnectionClosed, TimeoutError, OSError):
        pass
    span = (last - first) if first is not None and last is not None else 0.0
    print(
        json.dumps(
            {
                "received": got,
                "by_topic": counts,
                "cpu_s": time.process_time() - c0,
                "span_s": span,
                "pid": os.getpid(),
            }
        ),
        flush=True,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], "--slow" in sys.argv[2:]))
