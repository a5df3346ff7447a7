"""``mps operator``: its schedule checked before anything starts (a bad word or time is one line,
exit status 2, rclpy not even imported); no node on the mode topic is said as such; SIGINT and
SIGTERM end it with one line saying what was sent and what was not, and 130 or 143, no
traceback. Each test waits on what the operator prints, never on the clock."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading

import pytest
from twin_probe import NodeProcess, mps_cmd, stop_group, wait_until

from mps_core.scene.settings import COMMANDS

#: a node name no other test uses: nothing in this session's domain subscribes to its topic
NOBODY = "/operator_test_nobody"
WORDS = ", ".join(COMMANDS)


@pytest.mark.parametrize(
    "at,message",
    [
        ("0.5:engag", f"'0.5:engag': WORD = 'engag': expected one of {WORDS}"),
        ("0.5:", f"'0.5:': WORD = '': expected one of {WORDS}"),
        ("x:engage", "'x:engage': T = 'x': expected a time in seconds >= 0"),
        ("-1:engage", "'-1:engage': T = '-1': expected a time in seconds >= 0"),
        ("inf:stop", "'inf:stop': T = 'inf': expected a time in seconds >= 0"),
        ("0.5engage", "'0.5engage': expected T:WORD, e.g. 0.008:engage"),
    ],
)
def test_a_bad_command_is_refused_before_anything_starts(at, message):
    # in a fresh interpreter, to see that rclpy was never imported (nothing sent, no node made)
    code = (
        "import sys; from mps_core.cli import main; "
        f"rc = main(['operator', '--at', '0.2:engage', '--at={at}', '--node', '{NOBODY}']); "
        "print('rclpy imported:', 'rclpy' in sys.modules); sys.exit(rc)"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r
    assert r.stdout == "rclpy imported: False\n", r
    assert r.stderr == f"mps operator: error: argument --at: {message}\n", r


def test_a_misspelt_word_on_the_command_line_exits_2_in_one_line():
    r = subprocess.run(mps_cmd("operator", "--at", "0.2:engag"), capture_output=True, text=True, timeout=120)
    assert (r.returncode, r.stdout) == (2, ""), r
    assert r.stderr.splitlines() == [
        f"mps operator: error: argument --at: '0.2:engag': WORD = 'engag': expected one of {WORDS}"
    ]


class Operator:
    """``mps operator ARGS`` in a session of its own, its output read line by line as it comes;
    ended (its process group) on exit."""

    def __init__(self, *args):
        self.proc = subprocess.Popen(
            mps_cmd("operator", *args),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env=dict(os.environ, PYTHONUNBUFFERED="1"),
            start_new_session=True,
        )
        self.lines: list[str] = []
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self):
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def wait_for_line(self, start: str, timeout: float = 120.0) -> int:
        """The index of the first line that starts with ``start``, waited for."""
        wait_until(
            lambda: any(s.startswith(start) for s in self.lines) or self.proc.poll() is not None,
            timeout,
            f"a line {start!r}",
            poll=0.02,
        )
        found = [i for i, s in enumerate(self.lines) if s.startswith(start)]
        assert found, f"the operator ended without {start!r}: {self.lines}"
        return found[0]

    def finish(self, timeout: float = 120.0) -> int:
        rc = self.proc.wait(timeout)
        self.reader.join(timeout)
        return rc

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        stop_group(self.proc)
        self.proc.stdout.close()
        return False


def test_no_node_on_the_mode_topic_is_said_as_such():
    pytest.importorskip("rclpy")
    with Operator("--at", "0.1:engage", "--node", NOBODY, "--wait", "1") as op:
        rc = op.finish()
    assert rc == 1, op.lines
    assert op.lines == [
        f"operator: will send 'engage' at t = 0.1 s on {NOBODY}/mode",
        f"operator: no node answered on {NOBODY}/mode in 1 s: sent nothing; not sent: engage",
    ]


@pytest.mark.parametrize("sig,code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_a_signal_to_a_waiting_operator_ends_it_in_one_line(sig, code):
    pytest.importorskip("rclpy")
    with Operator("--at", "0.1:engage", "--at", "0.2:stop", "--node", NOBODY, "--wait", "600") as op:
        first = op.wait_for_line("operator: will send ")
        op.proc.send_signal(sig)
        rc = op.finish()
    assert rc == code, op.lines
    assert op.lines[first + 1 :] == [f"operator: stopped by {sig.name}: sent nothing; not sent: engage, stop"]


def test_sigterm_after_a_command_was_applied_says_what_was_sent_and_what_was_not(tmp_path):
    pytest.importorskip("rclpy")
    # a long run in real time that waits for the operator: the disengage is due 25 simulated
    # seconds after the engage, long after the operator has been told to stop
    params = dict(
        pacing="realtime",
        dt=0.001,
        t_end=30.0,
        scene_commands=False,
        recording="none",
        wait_for_commanders=1,
        wait_timeout=60.0,
    )
    with NodeProcess(tmp_path, params, name="operated") as node:
        with Operator("--at", "0.01:engage", "--at", "25:disengage", "--wait", "120") as op:
            op.wait_for_line("operator: 'engage' applied at t = ")
            op.proc.send_signal(signal.SIGTERM)
            rc = op.finish()
        assert node.alive(), node.log()
    assert rc == 143, op.lines
    assert op.lines[-1] == "operator: stopped by SIGTERM: sent engage; not sent: disengage", op.lines
    assert not any("Traceback" in s for s in op.lines), op.lines
