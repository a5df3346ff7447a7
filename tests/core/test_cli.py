"""The `mps` command line: runs, CSV columns, clear errors."""

import csv
import subprocess
import sys

import numpy as np

from mps_core.names import COLUMNS


def mps(*args):
    return subprocess.run(
        [sys.executable, "-m", "mps_core.cli", *args], capture_output=True, text=True, timeout=120
    )


def test_run_paper_writes_the_csv(tmp_path):
    out = tmp_path / "paper.csv"
    p = mps("run", "paper", "--csv", str(out))
    assert p.returncode == 0, p.stderr
    assert "scene paper" in p.stdout and "phi_ddot" in p.stdout
    rows = list(csv.reader(out.open()))
    assert rows[0] == list(COLUMNS)
    for col in ("t", "phi", "psi", "phi_dot", "psi_dot", "phi_ddot", "psi_ddot", "x_C", "T", "V"):
        assert col in rows[0]
    assert len(rows) == 1 + 41
    t = np.array([float(r[0]) for r in rows[1:]])
    assert t[0] == 0.0 and abs(t[-1] - 0.05) < 1e-15


def test_run_options_and_events(tmp_path):
    ev = tmp_path / "events.jsonl"
    p = mps(
        "run",
        "paper",
        "--t-end",
        "0.1",
        "--dt",
        "1e-4",
        "--solver",
        "rk4",
        "--derivatives",
        "autodiff",
        "--events",
        str(ev),
    )
    assert p.returncode == 0, p.stderr
    assert "charts: phi-psi+ ->" in p.stdout
    assert ev.read_text().count('"kind": "chart"') >= 2


def test_errors_are_clear_and_exit_2(tmp_path):
    p = mps("run", "paper", "--t-end", "0.1", "--dt", "1e-4", "--no-chart-switching")
    assert p.returncode == 2 and "chart switching is off" in p.stderr
    bad = tmp_path / "bad.toml"
    bad.write_text("[mechanism]\nl1_mm = -1\n[initial]\nphi_deg = 0\n[solver]\nt_end_s = 1\n")
    p = mps("run", str(bad))
    assert p.returncode == 2 and "mechanism.l1_mm = -1" in p.stderr
    p = mps("run", "paper", "--delta-deg", "90")
    assert p.returncode == 2 and "solver.delta_deg" in p.stderr


def test_a_coarse_step_is_said_with_the_largest_sensible_one():
    """press-cycle at 5 ms a step: the crank turns about 14 deg a step and the trajectory is
    another (another chart sequence than at 0.5 ms): one warning naming the step, the turn and
    the largest step within 10 deg; at 1 ms, none."""
    coarse = mps("run", "press-cycle", "--t-end", "1", "--dt", "0.005")
    assert coarse.returncode == 0, coarse.stderr
    warn = [ln for ln in coarse.stderr.splitlines() if ln.startswith("mps: warning:")]
    assert len(warn) == 1, coarse.stderr
    assert "the step 0.005 s is coarse" in warn[0] and "Largest step within it: 0.0034 s" in warn[0], warn
    fine = mps("run", "press-cycle", "--t-end", "1", "--dt", "0.001")
    assert fine.returncode == 0 and "warning" not in fine.stderr, fine.stderr


def test_corrections_bounded_from_the_command_line_too():
    p = mps("run", "paper", "--iterations", "100000")
    assert p.returncode == 2 and p.stdout == ""
    assert p.stderr.strip() == (
        "mps: error: solver.corrector_iterations = 100000: expected an integer from 1 to 50"
    )


def test_progress_line_on_a_terminal_only():
    """The progress line: simulated time, share, rate and time left, rewritten in place on a
    terminal, cleared at the end; nothing on a file or pipe, or when quiet."""
    import io

    from mps_core.run.progress import Progress

    class Tty(io.StringIO):
        def isatty(self):
            return True

    out = Tty()
    p = Progress(0.0, 10.0, label="press-cycle", stream=out, every=0.0, check=1)
    for k in range(1, 6):
        p(k * 1.0)
    p.done()
    lines = [s for s in out.getvalue().split("\r") if s.strip()]
    assert len(lines) == 4  # the first look only starts the rate's clock
    assert (
        lines[-1].startswith("press-cycle: t = 5 of 10 s (50 %), ")
        and "x real time, " in lines[-1]
        and lines[-1].rstrip().endswith(" left")
    ), lines
    assert out.getvalue().endswith("\r") and out.getvalue().split("\r")[-2].strip() == ""
    for stream, quiet in ((io.StringIO(), False), (Tty(), True)):
        q = Progress(0.0, 10.0, stream=stream, quiet=quiet, every=0.0, check=1)
        for k in range(1, 6):
            q(k * 1.0)
        q.done()
        assert stream.getvalue() == ""
    # a run to a pipe: the summary only
    r = mps("run", "paper")
    assert r.returncode == 0 and "\r" not in r.stdout + r.stderr and r.stderr == ""


def test_a_signal_while_mps_starts_is_one_line():
    """Ctrl-C (or SIGTERM) while ``mps`` imports what its command needs: one line, exit 128 +
    the signal, no traceback. The signal is made to come at the import of the solvers (what
    most of the start's second is spent on), in a process of its own."""
    for name in ("SIGINT", "SIGTERM"):
        code = (
            "import os, signal, sys\n"
            "class Arrives:\n"
            "    def find_spec(self, fullname, path=None, target=None):\n"
            "        if fullname == 'mps_core.solvers':\n"
            f"            os.kill(os.getpid(), signal.{name})\n"
            "        return None\n"
            "sys.meta_path.insert(0, Arrives())\n"
            "from mps_core.cli import main\n"
            "sys.exit(main(['run', 'paper', '--t-end', '0.01']))\n"
        )
        p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
        assert p.returncode == 128 + {"SIGINT": 2, "SIGTERM": 15}[name], (name, p.stderr)
        assert p.stderr == f"mps: interrupted ({name}) while starting: nothing done\n" and p.stdout == ""
