"""The processes a benchmark measures, read from ``/proc``: CPU times, threads, children,
command lines, memory (:class:`Usage`: a run's, from outside); the busy neighbours started
beside the node (:func:`neighbours`)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path


def _stat_cpu(stat: str) -> float:
    """User + system CPU seconds of a ``/proc/.../stat`` line."""
    fields = stat.rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _cpu_seconds(pid: int) -> float:
    return _stat_cpu(Path(f"/proc/{pid}/stat").read_text())


def _threads(pid: int) -> dict:
    """Every thread of the process: tid -> (name, CPU s, voluntary and involuntary context
    switches), from ``/proc``."""
    out = {}
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            stat = (task / "stat").read_text()
            status = (task / "status").read_text()
        except (FileNotFoundError, ProcessLookupError):
            continue
        name = stat[stat.index("(") + 1 : stat.rindex(")")]
        sw = dict(line.split(":", 1) for line in status.splitlines() if "ctxt_switches" in line)
        out[int(task.name)] = (
            name,
            _stat_cpu(stat),
            int(sw["voluntary_ctxt_switches"]),
            int(sw["nonvoluntary_ctxt_switches"]),
        )
    return out


def _thread_table(a: dict, b: dict, wall: float) -> list[dict]:
    """Per thread name (the Python threads but the publishing one are all ``python``; the
    middleware's are Fast DDS's ``dds.*``), between two :func:`_threads` readings ``wall``
    seconds apart at 1 kHz: CPU µs a step, voluntary and involuntary switches a step."""
    steps = wall * 1e3
    rows: dict = {}
    for tid, (name, cpu, vol, inv) in b.items():
        _, cpu0, vol0, inv0 = a.get(tid, (name, 0.0, 0, 0))
        r = rows.setdefault(name, {"thread": name, "cpu_us": 0.0, "voluntary": 0.0, "involuntary": 0.0})
        r["cpu_us"] += (cpu - cpu0) / steps * 1e6
        r["voluntary"] += (vol - vol0) / steps
        r["involuntary"] += (inv - inv0) / steps
    return sorted(
        (r for r in rows.values() if r["cpu_us"] > 0.5 or r["voluntary"] > 0.01), key=lambda r: -r["cpu_us"]
    )


def _children(pid: int) -> list[int]:
    out = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            out += [int(c) for c in (task / "children").read_text().split()]
        except (FileNotFoundError, ProcessLookupError, ValueError):
            pass
    return out


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def _recording(cmdline: str) -> bool:
    """The recording process's command line (with the Foxglove endpoint: ``mps_ros.foxglove.live``)."""
    return "mps_ros.recording.background" in cmdline or "mps_ros.foxglove.live" in cmdline


def _node_processes(pid: int) -> tuple[list[int], list[int]]:
    """(the node's processes: itself and its stepping process, where it has one; its recording
    processes), from ``/proc``."""
    node, rec = [pid], []
    for kid in _children(pid):
        line = _cmdline(kid)
        if "mps_ros.run.stepping" in line:
            node.append(kid)
            rec += [k for k in _children(kid) if _recording(_cmdline(k))]
        elif _recording(line):
            rec.append(kid)
    return node, rec


def _all_threads(pids: list[int]) -> dict:
    """:func:`_threads` of several processes, keyed by thread id."""
    out = {}
    for pid in pids:
        try:
            out.update(_threads(pid))
        except (FileNotFoundError, ProcessLookupError):
            pass
    return out


def neighbours(n: int) -> list[subprocess.Popen]:
    """``n`` pure-Python busy loops, each a process of its own session (what a user's machine
    also runs beside the node); end them with :func:`stop_group`."""
    return [
        subprocess.Popen([sys.executable, "-c", "while True: pass"], start_new_session=True)
        for _ in range(max(0, n))
    ]


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


class Usage:
    """The CPU, threads and memory of the node's processes (the node, its stepping process;
    its recording processes apart) and of the subscriber's, from ``/proc``: read first at
    construction (the run's start), then at each :meth:`read` up to the run's end."""

    def __init__(self, node_pid: int, probe_pid: int):
        self.node_pid, self.probe_pid = node_pid, probe_pid
        self.mine, self.kids = _node_processes(node_pid)  # the node's; the recording process
        self.cpu0, self.wall0 = sum(_cpu_seconds(k) for k in self.mine), time.monotonic()
        self.kid0 = sum(_cpu_seconds(k) for k in self.kids)
        self.sub0 = _cpu_seconds(probe_pid)
        self.threads0 = _all_threads(self.mine)
        self.threads1, self.wall_t = dict(self.threads0), self.wall0  # the last reading of each thread
        self.cpu1: float | None = None
        self.wall1: float | None = None
        self.kid1: float | None = None
        self.sub1: float | None = None
        self.rss0: float | None = None
        self.rss1: float | None = None

    def read(self, ended: bool) -> None:
        """A reading (``ended``: the run has ended, its threads' last readings kept); raises
        FileNotFoundError or ProcessLookupError where a process is gone."""
        mine, kids = self.mine, self.kids
        self.cpu1, self.wall1 = sum(_cpu_seconds(k) for k in mine), time.monotonic()
        self.kid1 = sum(_cpu_seconds(k) for k in kids)
        self.sub1 = _cpu_seconds(self.probe_pid)
        if not ended:  # a thread that ends keeps its last reading
            self.threads1.update(_all_threads(mine))
            self.wall_t = time.monotonic()
        self.rss1 = _rss_mb(self.node_pid)
        if self.rss0 is None and self.wall1 - self.wall0 >= 5.0:
            self.rss0 = self.rss1

    def figures(self, st: dict) -> None:
        """The shares of a core (the node's, its recording's, the subscriber's), the node's
        processes, its CPU a step and its memory at 5 s and at the end, into ``st``."""
        wall0, wall1, nan = self.wall0, self.wall1, float("nan")
        cpu1, kid1, sub1 = self.cpu1, self.kid1, self.sub1
        read = wall1 is not None
        span = (wall1 - wall0) if wall1 is not None else nan
        st["cpu_share"] = (cpu1 - self.cpu0) / span if read and cpu1 is not None else nan
        kids = read and kid1 is not None and self.kids
        st["recorder_cpu_share"] = (kid1 - self.kid0) / span if kids and kid1 is not None else nan
        st["subscriber_cpu_share"] = (sub1 - self.sub0) / span if read and sub1 is not None else nan
        st["node_processes"] = len(self.mine)
        st["cpu_per_step_us"] = st["cpu_share"] * 1e3  # at 1 kHz, realtime x1
        st["rss_start_mb"], st["rss_end_mb"] = self.rss0, self.rss1

    def threads(self) -> list[dict]:
        """:func:`_thread_table` from the first reading to each thread's last."""
        if self.wall_t > self.wall0:
            return _thread_table(self.threads0, self.threads1, self.wall_t - self.wall0)
        return []
