"""``mps view RECORDING --web`` and ``mps view --live --web``: Rerun's web viewer served on
127.0.0.1 only (its HTTP page and its gRPC proxy), its address printed, until Ctrl-C; and,
where Debian's ``chromium`` is installed, a headless browser on that address shows the press
drawn (found in the page's pixels, polled with a deadline, not after a sleep)."""

from __future__ import annotations

import json
import re
import shutil
import signal
import subprocess
import urllib.request
from pathlib import Path

import pytest

pytest.importorskip("rerun")

from js_packages import JS, npm_ci
from twin_probe import NodeProcess, mps_cmd, stop_group, wait_until

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "recordings" / "sample_press-cycle.mcap"
URL = re.compile(
    r"web viewer: (http://127\.0\.0\.1:(\d+)/\?url=rerun%2Bhttp%3A%2F%2F127\.0\.0\.1%3A(\d+)%2Fproxy)"
)


def listening_on(port: int) -> list[str]:
    """The local addresses a TCP socket listens on at ``port`` (IPv4 and IPv6, /proc/net)."""
    found = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            local, state = line.split()[1], line.split()[3]
            addr, _, p = local.partition(":")
            if state == "0A" and int(p, 16) == port:  # LISTEN
                found.append("127.0.0.1" if addr == "0100007F" else addr)
    return found


def started(proc, log: Path, what: str) -> re.Match:
    return wait_until(
        lambda: URL.search(log.read_text(errors="replace")) or (proc.poll() is not None and log.read_text()),
        120,
        what,
        poll=0.05,
    )


def check_served(m: re.Match) -> None:
    url, web, grpc = m.group(1), int(m.group(2)), int(m.group(3))
    assert listening_on(web) == ["127.0.0.1"] and listening_on(grpc) == ["127.0.0.1"], (
        listening_on(web),
        listening_on(grpc),
    )
    with urllib.request.urlopen(url, timeout=60) as page:
        assert b"Rerun" in page.read()


def _web_view(log_path: Path, *args: str) -> tuple[subprocess.Popen, re.Match]:
    """Start ``mps view ARGS --web`` (its own process group, its output in ``log_path``) and
    return it with the match of the address it printed, once its viewer serves on loopback."""
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(
            mps_cmd("view", *args, "--web", "--web-port", "0"),
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    try:
        m = started(proc, log_path, "the web viewer's address")
        assert isinstance(m, re.Match), log_path.read_text()
        check_served(m)
    except BaseException:
        stop_group(proc)
        raise
    return proc, m


def test_a_recording_on_the_web_viewer(tmp_path):
    log_path = tmp_path / "web.log"
    proc, m = _web_view(log_path, str(SAMPLE))
    try:
        web = int(m.group(2))
        shot = browser_sees_the_press(m.group(1), tmp_path)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(60) == 130
    finally:
        stop_group(proc)
    text = log_path.read_text()
    assert "mps view: interrupted (SIGINT)" in text and "Traceback" not in text, text
    # the viewer's process group ended with it
    assert listening_on(web) == [], "the web viewer still listens after mps view ended"
    if shot is not None:
        print(f"screenshot: {shot}")


def test_the_live_view_on_the_web_viewer(tmp_path):
    log_path = tmp_path / "live.log"
    proc, m = _web_view(log_path, "--live", "--duration", "120")
    try:
        wait_until(lambda: b"following" in log_path.read_bytes(), 120, "the live view following")
        params = dict(
            pacing="realtime",
            dt=1e-3,
            t_end=0.3,
            recording="none",
            outputs="[joint_states,reactions,foundation,structure,events,diagnostics]",
            wait_for_subscribers=1,
            wait_timeout=60.0,
            start_delay=0.5,
        )
        with NodeProcess(tmp_path, params) as node:
            assert node.wait(120) == 0, node.log()
        wait_until(lambda: b"live view:" in log_path.read_bytes(), 120, "the live view's end line")
        # the web viewer stays after the run, until Ctrl-C
        check_served(m)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(60) == 130
    finally:
        stop_group(proc)
    text = log_path.read_text()
    steps = int(re.search(r"live view: \d+ frames, (\d+) steps logged", text).group(1))
    assert steps > 0.8 * 300, text
    assert "mps view: interrupted (SIGINT)" in text and "Traceback" not in text, text


def browser_sees_the_press(url: str, tmp_path: Path) -> Path | None:
    """Where ``chromium`` and node are installed: a headless chromium (puppeteer-core, from
    tests/js) loads ``url`` and polls its screenshots until the crank, rod and rocker are drawn
    in their colours (the mechanism view), with a deadline; the screenshot's path. None where
    chromium is not installed (the rest of the test still holds)."""
    chromium = shutil.which("chromium")
    if chromium is None:
        print("no browser check: chromium is not installed (apt-get install chromium)")
        return None
    why = npm_ci()
    if why is not None:
        print(f"no browser check: {why}")
        return None
    out = tmp_path / "web.png"
    p = subprocess.run(
        [
            shutil.which("node"),
            str(JS / "screenshot.mjs"),
            json.dumps({"url": url, "chromium": chromium, "out": str(out)}),
        ],
        capture_output=True,
        text=True,
        timeout=400,
    )
    assert p.returncode == 0, (p.stdout, p.stderr)
    found = json.loads(p.stdout.strip().splitlines()[-1])
    assert found["drawn"], found
    return out


def test_a_bad_web_port_is_one_line():
    p = subprocess.run(
        mps_cmd("view", str(SAMPLE), "--web", "--web-port", "70000"),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert p.returncode == 2 and "--web-port 70000: expected a port" in p.stderr, p.stderr
    assert "Traceback" not in p.stderr
