"""Rerun's web viewer on this machine's loopback (``mps view ... --web``): the ``rerun`` viewer
of the rerun-sdk wheel run as a server (``--serve-web``), its web viewer over HTTP and its gRPC
proxy both bound to 127.0.0.1, serving an ``.rrd`` file or whatever a live view streams to it;
:class:`WebViewer` gives the page's address to open in a browser (one on this machine, or
through an SSH tunnel: ``ssh -L 9090:127.0.0.1:9090 -L PORT:127.0.0.1:PORT``, both ports)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path
from urllib.parse import quote

from ..recording.replay import ReplayError
from .offline import rerun_executable

#: the only address the servers listen on
HOST = "127.0.0.1"
#: wall seconds the viewer has to start listening (its first start unpacks the web viewer)
START_TIMEOUT = 60.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind((HOST, 0))
        return int(s.getsockname()[1])


def _listening(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.5)
        return s.connect_ex((HOST, port)) == 0


class WebViewer:
    """``rerun [RRD] --serve-web --bind 127.0.0.1`` started, listening (on ``web_port``, 0: a
    free port, and a free gRPC port); :attr:`url` the page, :attr:`grpc` the address a live
    view streams to. A port in use, or a viewer that ends at once, is a :class:`ReplayError`
    that names it. :meth:`close` ends it."""

    def __init__(self, rrd: Path | None = None, web_port: int = 0) -> None:
        exe = rerun_executable()
        if exe is None:
            raise ReplayError("no rerun viewer found (pip install -e '.[view]')")
        if not (0 <= web_port <= 65535):
            raise ReplayError(f"--web-port {web_port}: expected a port from 0 (a free one) to 65535")
        if web_port and _listening(web_port):
            raise ReplayError(
                f"--web-port {web_port}: {HOST}:{web_port} is in use: give another (0: a free one)"
            )
        self.web_port = web_port or free_port()
        self.grpc_port = free_port()
        self.grpc = f"rerun+http://{HOST}:{self.grpc_port}/proxy"
        self.url = f"http://{HOST}:{self.web_port}/?url={quote(self.grpc, safe='')}"
        cmd = [exe, *([str(rrd)] if rrd is not None else []), "--serve-web", "--bind", HOST]
        cmd += ["--port", str(self.grpc_port), "--web-viewer-port", str(self.web_port)]
        self._log = tempfile.TemporaryFile()
        self.proc = subprocess.Popen(cmd, stdout=self._log, stderr=subprocess.STDOUT, start_new_session=True)
        end = time.monotonic() + START_TIMEOUT
        while not (_listening(self.web_port) and _listening(self.grpc_port)):
            if self.proc.poll() is not None or time.monotonic() > end:
                self.close()
                self._log.seek(0)
                said = self._log.read().decode(errors="replace").strip().splitlines()[-3:]
                raise ReplayError(f"the rerun web viewer did not start: {' | '.join(said)}")
            time.sleep(0.05)

    def wait(self) -> int:
        """Until the viewer ends (or Ctrl-C: KeyboardInterrupt): its exit status."""
        return self.proc.wait()

    def close(self) -> None:
        """End the viewer's process group (the ``rerun`` launcher and the viewer it starts)."""
        for sig, wait in ((signal.SIGTERM, 10.0), (signal.SIGKILL, 10.0)):
            try:
                os.killpg(self.proc.pid, sig)
            except ProcessLookupError:
                break
            try:
                self.proc.wait(wait)
                deadline = time.monotonic() + wait
                while time.monotonic() < deadline:  # the group's other members too
                    os.killpg(self.proc.pid, 0)
                    time.sleep(0.05)
            except ProcessLookupError:
                break
            except subprocess.TimeoutExpired:
                continue
        self._log.close()


__all__ = ["HOST", "WebViewer", "free_port"]
