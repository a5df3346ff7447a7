"""The stepping process of a split run from the node's side (:class:`SteppingChild`: started,
ready, watched, ended) and the run's real-time scheduling (:class:`Scheduling`)."""

from __future__ import annotations

import json
import marshal
import signal
import subprocess
import sys

from ..os_threads import widen_pipe
from ..wire.pipe import Frame, FrameReader, FrameWriter
from .stepping import HOW_TO_ALLOW, ask_fifo, fifo_for_the_others


class SteppingChild:
    """The stepping process itself (``python -m mps_ros.run.stepping``), from the node's side:
    started with its settings (``spec``), ready once it has built its twin and its kernels
    (:meth:`wait_ready`), its frames written (``out``) and read (``reader``), its end waited
    for (:meth:`wait`) and its pipes closed (:meth:`close`)."""

    def __init__(self, spec: dict):
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "mps_ros.run.stepping"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            bufsize=0,
        )
        stdin, stdout = self.proc.stdin, self.proc.stdout
        assert stdin is not None and stdout is not None  # both are pipes
        self.out = FrameWriter(stdin.fileno())
        widen_pipe(stdin.fileno())
        self.reader = FrameReader(stdout.fileno())
        self.out.frame(Frame.SETTINGS, json.dumps(spec).encode())
        self.pid: int | None = None

    def wait_ready(self, log) -> None:
        """Until it says it is ready (its log lines said meanwhile); OSError with its reason
        where it ended or failed first."""
        while True:
            got = self.reader.read()
            if not got:
                self.proc.wait(10)
                raise OSError(
                    f"the stepping process ended before it was ready ({exit_words(self.proc.returncode)})"
                )
            for kind, payload in got:
                if kind == Frame.LOG:
                    log(*marshal.loads(payload))
                elif kind == Frame.READY:
                    reply = json.loads(payload)
                    if not reply.get("ready"):
                        self.proc.wait(10)
                        raise OSError(reply.get("error", "the stepping process failed"))
                    self.pid = reply["pid"]
                    return

    def wait(self, timeout: float) -> None:
        """Until it has ended; killed where it has not within ``timeout`` s."""
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(10)

    def close(self) -> None:
        for f in (self.proc.stdin, self.proc.stdout):
            try:
                if f is not None:
                    f.close()
            except OSError:
                pass


class Scheduling:
    """The real-time scheduling of a split run: ``priority``, the SCHED_FIFO priority asked
    for the stepping process and this process's publishing thread (0: none); this process's
    scheduling for the run (:meth:`apply`); what the stepping process said it got
    (:meth:`said`; ``got``: the run's ``realtime_priority``)."""

    def __init__(self, priority: int, log):
        self.priority = int(priority)
        self.log = log
        self.got: int | None = None
        self.refused_here: str | None = None  # why SCHED_FIFO was refused this process
        #: the publishing thread's scheduler slice as granted (s; 0: none, the system's own)
        self.slice_granted = 0.0

    def apply(self, release_slice: float) -> None:
        """This process's scheduling for the run: SCHED_FIFO where asked and allowed (its
        other threads one below), else a short slice (``release_slice`` s; 0: none) for the
        publishing thread; the objects made so far frozen out of the collector's passes."""
        import gc

        from ..os_threads import name_thread, short_slice

        if self.priority:
            self.refused_here = ask_fifo(self.priority)
            if not self.refused_here:
                # the rest of this process one below: never ahead of the releases, never
                # behind an ordinary process while holding what the releases need
                fifo_for_the_others(max(1, self.priority - 1))
        if not self.priority or self.refused_here:
            # under the fair scheduler: a short slice, so that this thread, woken at each
            # deadline, preempts a busy neighbour at once (Linux 6.12 on; elsewhere nothing)
            if release_slice and short_slice(release_slice):
                self.slice_granted = release_slice
        name_thread("mps-publish")
        # what the node made so far (rclpy, the publishers, the scene) out of the collector's
        # passes: a full collection during the run scans only what the run made since
        gc.collect()
        gc.freeze()

    def said(self, got: dict) -> None:
        """What the stepping process said of its priority (frame ``PRIORITY``), logged."""
        prio = self.priority
        if not prio:
            return
        why = got.get("refused") or self.refused_here
        if why is None:
            self.got = prio
            self.log("info", f"stepping process and publishing thread: SCHED_FIFO, priority {prio}")
        else:
            self.got = 0
            self.log(
                "warn",
                f"realtime_priority {prio}: SCHED_FIFO refused here ({why}); "
                f"stepping at normal priority; {HOW_TO_ALLOW}",
            )


def exit_words(code: int | None) -> str:
    if code is None:
        return "still running"
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit status {code}"
