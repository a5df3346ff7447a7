"""Cuts fitted in a process of their own: the fitting process.

A cut's fit (:mod:`~mps_core.track.cut_fit`: the part's force curve from a stroke's crank
angles, some 15–30 ms of CPU on the nominal press's model) made where the measurements are
taken holds every measurement behind it up by as much: a node at 1 kHz published some twenty
estimates a stroke more than 1 ms late, and ``mps track`` spent as much CPU in its fits as in
its filter. So a tracker hands each cut's job out (:attr:`~mps_core.track.Tracker.defer_fits`)
and :class:`CutFits` has it fitted in the fitting process (``python -m
mps_core.track.fit_process``, started at the first cut or before), the fit taken back
(:meth:`CutFits.poll`) as it comes. That process makes the same fitter from the same scene and
settings as a tracker makes in its own, so the fits are the same numbers; the next cut's fit
begins at the last's, and the tracker waits for it where it has not come (a machine far
behind). A stroke whose fit is out says so (``fit_pending``) until it comes.

**Messages** (:mod:`mps_core.child_process`: pickles): to the process the nominal scene and
the tracker's settings, then (number, :class:`~mps_core.track.cut_fit.CutJob`) each; from it
``("ready", pid)`` (or ``("error", text)``), then (number, fit) for each job (the fit None where
it did not converge). It ends at the end of its input, or its parent's.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
from typing import TYPE_CHECKING, Any

from ..child_process import MessageReader, die_with_parent, write_message

if TYPE_CHECKING:
    from ..scene import Scene
    from .cut_fit import CutFit, CutJob
    from .settings import TrackSettings
    from .tracker import Tracker

__all__ = ["CutFits", "serve"]


class CutFits:
    """Have a tracker's cuts fitted in the fitting process (see the module).

    ``log(level, text)`` says a process that failed (its cuts then keep the filter's peak).
    """

    def __init__(self, scene: Scene, settings: TrackSettings, log: Any = None) -> None:
        self.scene, self.settings = scene, settings
        self.log = log or (lambda level, text: None)
        self._proc: subprocess.Popen | None = None
        self._fd: int | None = None
        #: the jobs sent, in order, each with the number it was sent under (a job made again
        #: after a late signal's search has its serial again: the numbers are this process's)
        self.out: list[tuple[int, CutJob]] = []
        self._sent = 0
        #: the fits come back, by their numbers (the reader thread's)
        self._fits: dict[int, CutFit | None] = {}
        self._came = threading.Condition()
        self._ended = False  # the process's output ended
        self.failed = False
        self._tracker: Tracker | None = None
        self._reader: threading.Thread | None = None

    def start(self) -> None:
        """Start the fitting process (it makes its model meanwhile)."""
        if self._proc is not None or self.failed:
            return
        command = [sys.executable, "-m", "mps_core.track.fit_process"]
        self._proc = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        stdin, stdout = self._proc.stdin, self._proc.stdout
        assert stdin is not None and stdout is not None  # both are pipes
        self._fd = stdin.fileno()
        write_message(self._fd, (self.scene, self.settings))
        reader = MessageReader(stdout.fileno())
        self._reader = threading.Thread(target=self._listen, args=(reader,), name="mps-cut-fits", daemon=True)
        self._reader.start()

    def _listen(self, reader: MessageReader) -> None:
        """Take the process's messages as they come (a thread of its own)."""
        while True:
            got = reader.read()
            if not got:
                break
            for msg in got:
                if msg[0] == "error":
                    self._fail(msg[1])
                elif msg[0] != "ready":
                    number, fit = msg
                    with self._came:
                        self._fits[number] = fit
                        self._came.notify_all()
        with self._came:
            self._ended = True
            self._came.notify_all()

    def attach(self, tracker: Tracker) -> None:
        """Have ``tracker`` hand its cuts' jobs out to this process and wait on it.

        Its model must be the one this process was given: the same derivatives.
        """
        if tracker.settings.derivatives != self.settings.derivatives:
            raise ValueError(
                f"track.derivatives = {tracker.settings.derivatives!r}: expected the fitting process's "
                f"{self.settings.derivatives!r}"
            )
        tracker.defer_fits = True
        tracker.await_fit = self.wait
        self._tracker = tracker

    def submit(self, tracker: Tracker) -> None:
        """Send the process the jobs ``tracker`` has put out."""
        jobs = tracker.cut_jobs
        while jobs:
            job = jobs.pop(0)
            self.start()
            self._sent += 1
            if self.failed or self._fd is None or not write_message(self._fd, (self._sent, job)):
                self._fail("its input is closed")
                tracker.take_fit(job, None)
                continue
            self.out.append((self._sent, job))

    def poll(self, tracker: Tracker) -> None:
        """Give ``tracker`` the fits that have come back, in order."""
        while self.out and (self.out[0][0] in self._fits or self._ended):
            number, job = self.out.pop(0)
            tracker.take_fit(job, self._take(number))

    def wait(self, job: CutJob) -> CutFit | None:
        """Return ``job``'s fit, waiting for it (the tracker's ``await_fit``).

        The tracker's jobs put out and not yet sent are sent first.
        """
        if self._tracker is not None:
            self.submit(self._tracker)
        number = next((n for n, j in self.out if j is job), None)
        if number is None:
            return None
        self.out = [(n, j) for n, j in self.out if n != number]
        with self._came:
            self._came.wait_for(lambda: number in self._fits or self._ended)
        return self._take(number)

    def finish(self, tracker: Tracker) -> None:
        """Wait for every fit out and give them to ``tracker``."""
        while self.out:
            job = self.out[0][1]
            tracker.take_fit(job, self.wait(job))

    def close(self) -> None:
        """End the fitting process: its input closed, waited for (killed after 5 s)."""
        proc, self._proc = self._proc, None
        if proc is None:
            return
        if proc.stdin is not None:
            with contextlib.suppress(OSError):
                proc.stdin.close()
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
        # the thread that reads it has read to its end before the pipe is closed: never a read of
        # a closed (or reused) descriptor, never a thread still running as the interpreter ends
        reader, self._reader = self._reader, None
        if reader is not None:
            reader.join(10)
        if proc.stdout is not None:
            proc.stdout.close()

    def _take(self, number: int) -> CutFit | None:
        """Return the fit of the job sent under ``number`` (None where the process ended without it)."""
        with self._came:
            if number in self._fits:
                return self._fits.pop(number)
        self._fail("it ended")
        return None

    def _fail(self, why: str) -> None:
        if not self.failed:
            self.failed = True
            self.log(
                "error",
                f"tracking: the cuts' fitting process failed ({why}); the strokes keep the filter's peak",
            )


def serve(fd_in: int = 0, fd_out: int = 1) -> int:
    """Serve as the fitting process (``python -m mps_core.track.fit_process``): see the module."""
    die_with_parent()
    # Ctrl-C reaches a terminal's whole process group: the process that started this one
    # decides, and ends it by closing its input (after the fits it waits for)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if fd_out == 1:  # the messages keep the pipe; whatever else prints goes to stderr
        fd_out = os.dup(1)
        os.dup2(2, 1)
    reader = MessageReader(fd_in)
    got = reader.read()
    if not got:
        return 2
    try:
        from .cut_fit import CutFitter

        scene, settings = got[0]
        fitter = CutFitter(scene, settings)
    except Exception as exc:
        write_message(fd_out, ("error", f"{type(exc).__name__}: {exc}"))
        return 2
    write_message(fd_out, ("ready", os.getpid()))
    pending = got[1:]
    while True:
        for number, job in pending:
            write_message(fd_out, (number, fitter.fit(job)))
        pending = reader.read()
        if not pending:
            return 0


if __name__ == "__main__":
    sys.exit(serve())
