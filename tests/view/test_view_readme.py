"""The README's replay examples run as written; ``mps view`` opens its viewer on loopback."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[2] / "README.md"


def _section_blocks(title: str) -> list[str]:
    text = README.read_text()
    start = text.index(f"## {title}")
    nxt = text.find("\n## ", start + 3)
    sec = text[start : nxt if nxt >= 0 else None]
    return re.findall(r"```python\n(.*?)```", sec, flags=re.S)


def test_viewer_spawned_on_loopback_only(cycle_mcap, tmp_path, monkeypatch, capsys):
    pytest.importorskip("rerun")
    from mps_core.cli import main
    from mps_ros.view import offline as view

    started = []

    class FakePopen:  # a viewer that starts and keeps running
        def __init__(self, cmd, **kw):
            started.append(cmd)

        def wait(self, timeout=None):
            raise view.subprocess.TimeoutExpired(started[-1], timeout)

    monkeypatch.setattr(view.subprocess, "Popen", FakePopen)
    monkeypatch.setenv("DISPLAY", ":99")  # a display to open on (none is used)
    monkeypatch.setattr(view.tempfile, "mkdtemp", lambda prefix="": str(tmp_path))
    assert main(["view", str(cycle_mcap)]) == 0
    (cmd,) = started
    assert cmd[1:3] == ["--bind", "127.0.0.1"]
    assert cmd[-1] == str(tmp_path / "press-cycle.rrd")
    assert (tmp_path / "press-cycle.rrd").stat().st_size > 0
    assert "listening on 127.0.0.1 only" in capsys.readouterr().out
    assert main(["view", str(cycle_mcap), "--no-spawn"]) == 2
    assert "--no-spawn without --save" in capsys.readouterr().err


def test_a_viewer_that_ends_at_once_is_an_error(cycle_mcap, tmp_path, monkeypatch, capsys):
    pytest.importorskip("rerun")
    from mps_core.cli import main
    from mps_ros.view import offline as view

    class DeadViewer:  # e.g. no usable display: it exits with an error at once
        def __init__(self, cmd, **kw):
            pass

        def wait(self, timeout=None):
            return 1

    monkeypatch.setattr(view.subprocess, "Popen", DeadViewer)
    monkeypatch.setenv("DISPLAY", ":99")
    monkeypatch.setattr(view.tempfile, "mkdtemp", lambda prefix="": str(tmp_path))
    assert main(["view", str(cycle_mcap)]) == 2
    out, err = capsys.readouterr()
    assert "opened the viewer" not in out
    assert "the viewer ended at once (exit status 1)" in err and "press-cycle.rrd" in err
