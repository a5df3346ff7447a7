"""Costs measured without ROS: one wake-up from a 1 ms timed wait (:func:`wakeup_costs`), and
the recording's MCAP writer against the ``mcap`` library's (:func:`writer_costs`)."""

from __future__ import annotations

import math
import time


def wakeup_costs(n: int = 2000) -> dict:
    """CPU time (µs, the waiting thread's own) of one wake-up from a 1 ms timed wait, by the
    primitives the node's threads wait in: what each deadline costs the publishing thread
    beside its publishing."""
    import threading

    cond, event, lock = threading.Condition(), threading.Event(), threading.Lock()
    lock.acquire()

    def cond_wait():
        with cond:
            cond.wait(0.001)

    out = {}
    for name, wait in (
        ("threading.Condition.wait(0.001)", cond_wait),
        ("threading.Event.wait(0.001)", lambda: event.wait(0.001)),
        ("threading.Lock.acquire(timeout=0.001)", lambda: lock.acquire(timeout=0.001)),
        ("time.sleep(0.001)", lambda: time.sleep(0.001)),
    ):
        t0 = time.thread_time()
        for _ in range(n):
            wait()
        out[name] = (time.thread_time() - t0) / n * 1e6
    return out


def writer_costs(rounds: int = 5, steps: int = 2000) -> dict:
    """CPU µs a message of the recording's MCAP writer (:class:`~mps_ros.recording.mcap_writer.McapWriter`)
    and of the ``mcap`` library's ``Writer``, given the same messages (press-cycle at 1 kHz,
    every output, ``steps`` steps: what the recording process writes) into memory, zstd chunks
    of 512 KiB; the two interleaved, best of ``rounds``; and whether the files were the same."""
    import io

    from mcap.writer import CompressionType, Writer

    from ..recording.mcap_writer import ENCODING_CDR, PROFILE_ROS2, SCHEMA_ROS2MSG, McapWriter
    from ..run.twin import Twin
    from ..wire.topics import OUTPUTS

    tw = Twin("press-cycle", dt=1e-3, t_end=steps * 1e-3, outputs=OUTPUTS)
    msgs: list = []
    while not tw.done:
        tw.step()
        msgs.extend((key, data, tw.k * 1_000_000) for key, data in tw.state_payloads())
    ids = {key: n + 1 for n, key in enumerate(dict.fromkeys(k for k, _d, _t in msgs))}

    def write(w) -> tuple[float, bytes]:
        out = io.BytesIO()
        w = w(out)
        w.start(profile=PROFILE_ROS2, library="bench")
        sid = w.register_schema("s", SCHEMA_ROS2MSG, b"")
        for key in ids:
            w.register_channel(str(key), ENCODING_CDR, sid, {})
        seq = dict.fromkeys(ids.values(), 0)
        add = w.add_message
        t0 = time.process_time()
        for key, data, t_ns in msgs:
            cid = ids[key]
            seq[cid] += 1
            add(cid, log_time=t_ns, data=data, publish_time=t_ns, sequence=seq[cid])
        w.finish()
        return (time.process_time() - t0) / len(msgs) * 1e6, out.getvalue()

    def ours(out):
        return McapWriter(out, chunk_size=512 * 1024)

    def theirs(out):
        return Writer(out, chunk_size=512 * 1024, compression=CompressionType.ZSTD)

    best = {"mps": math.inf, "mcap": math.inf}
    same = True
    for _ in range(rounds):
        a, fa = write(ours)
        b, fb = write(theirs)
        best["mps"], best["mcap"] = min(best["mps"], a), min(best["mcap"], b)
        same = same and fa == fb
    return {
        "messages": len(msgs),
        "per_step": len(msgs) / steps,
        "mps_us": best["mps"],
        "mcap_us": best["mcap"],
        "same_bytes": same,
    }
