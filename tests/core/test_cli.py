"""The `mps` command line: runs, CSV columns, clear errors."""

import csv
import subprocess
import sys

import numpy as np

from mps_core.names import COLUMNS


def mps(*args):
    return subprocess.run([sys.executable, "-m", "mps_core.cli", *args], capture_output=True,
                          text=True, timeout=120)


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
    p = mps("run", "paper", "--t-end", "0.1", "--dt", "1e-4", "--solver", "rk4",
            "--derivatives", "autodiff", "--events", str(ev))
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
