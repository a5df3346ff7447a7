"""The documentation runs as written: every fenced ``sh`` and ``python`` block of README.md,
docs/*.md and recordings/README.md.

Shell blocks: each line that starts with ``.venv/bin/mps`` or ``mps`` is run by bash in a
temporary folder (holding a copy of the sample recording under ``recordings/`` and a link to the
virtual environment as ``.venv``; ``mps`` on the PATH is the environment's), with loopback-only
ROS discovery and a ROS domain of this module's own, under a timeout, and must exit 0. A line
that must not run here (long-running, opens a viewer, needs a live ROS graph) carries the
marker ``# not run in tests: <why>``; any other line fails the test. Python blocks
are executed in a fresh namespace with the same temporary folder as working directory, unless
their first line is that marker (they are still compiled). The blocks of one file run in their
order, in one folder, so a later block may use what an earlier one wrote.

``MPS_DOCS_ROS_DOMAIN_ID`` sets the ROS domain (default: one picked from the process id, free
on this machine, not the session's own).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
DOC_FILES = [README, *sorted((ROOT / "docs").glob("*.md")), ROOT / "recordings" / "README.md"]
SAMPLE = ROOT / "recordings" / "sample_press-cycle.mcap"

MARKER = "# not run in tests:"
RUNNABLE = (".venv/bin/mps ", "mps ")
RUN_LANGS = {"sh", "python"}
#: fence languages that would hide a command or a program from this test
FORBIDDEN_LANGS = {"bash", "shell", "console", "zsh", "py", "python3", "pycon", "ipython"}
LINE_TIMEOUT_S = 120
MAX_README_LINES = 250


@dataclass
class Block:
    path: Path
    line: int  # 1-based line of the block's first content line
    lang: str
    lines: list[str]

    @property
    def where(self) -> str:
        return f"{self.path.relative_to(ROOT)}:{self.line}"


def blocks(path: Path) -> list[Block]:
    """The fenced code blocks of a Markdown file, in order."""
    out, cur = [], None
    for i, raw in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        s = raw.strip()
        if cur is None:
            if s.startswith("```"):
                cur = Block(path, i + 1, s[3:].strip().lower(), [])
        elif s == "```":
            out.append(cur)
            cur = None
        else:
            cur.lines.append(raw)
    assert cur is None, f"{path.relative_to(ROOT)}: a fence opened at line {cur.line - 1} is not closed"
    return out


def marker_reason(line: str) -> str | None:
    """The reason of a ``# not run in tests: <why>`` marker on the line ("" if empty), or None."""
    i = line.find(MARKER)
    return None if i < 0 else line[i + len(MARKER) :].strip()


def classify(line: str) -> str:
    """'blank', 'comment', 'skip' (marked), 'run', or 'bad' for one line of a sh block."""
    s = line.strip()
    if not s:
        return "blank"
    reason = marker_reason(s)
    if reason is not None:
        return "skip" if reason else "bad"
    if s.startswith("#"):
        return "comment"
    if s == "make" or s.startswith("make "):
        return "skip"  # the set-up itself: CI runs `make test`, which runs this test
    if s.endswith("\\"):
        return "bad"  # continuation lines are not run one by one: write one line
    return "run" if s.startswith(RUNNABLE) else "bad"


def python_marked(block: Block) -> bool:
    first = next((ln for ln in block.lines if ln.strip()), "")
    reason = marker_reason(first)
    return bool(reason) and first.strip().startswith("#")


# -- the environment of the commands ------------------------------------------------------------
def pick_domain_id() -> int:
    """A ROS domain for these commands: MPS_DOCS_ROS_DOMAIN_ID, else one in 1..101 from the
    session's base (``ros_domains.session_base``) plus 50, not 42 (make's), 43 (the tests'
    default) or the session's own, whose first participant ports are free here."""
    from ros_domains import free_domain, session_base

    given = os.environ.get("MPS_DOCS_ROS_DOMAIN_ID")
    if given:
        return int(given)
    taken = {42, 43, int(os.environ.get("ROS_DOMAIN_ID", "43") or 43)}
    return free_domain((session_base() + 50) % 101, taken)


DOMAIN_ID = pick_domain_id()


def venv_dir() -> Path:
    """The virtual environment the tests run in (its bin holds ``mps``)."""
    here = Path(sys.executable).parent
    if (here / "mps").exists():
        return here.parent
    return ROOT / ".venv"


def workdir(tmp: Path) -> Path:
    """A folder laid out as the docs expect: .venv (a link), recordings/sample_press-cycle.mcap."""
    (tmp / ".venv").symlink_to(venv_dir(), target_is_directory=True)
    (tmp / "recordings").mkdir()
    shutil.copy(SAMPLE, tmp / "recordings" / SAMPLE.name)
    return tmp


def command_env(tmp: Path) -> dict:
    env = dict(os.environ)
    for k in ("ROS_LOCALHOST_ONLY", "ROS_STATIC_PEERS"):
        env.pop(k, None)
    env.update(
        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
        ROS_DOMAIN_ID=str(DOMAIN_ID),
        ROS_LOG_DIR=str(tmp / "ros-log"),
        MPLBACKEND="Agg",
        PATH=str(venv_dir() / "bin") + os.pathsep + env.get("PATH", ""),
    )
    return env


# -- the tests ------------------------------------------------------------------------------------
def test_every_shell_line_is_runnable_or_marked():
    bad = []
    for path in DOC_FILES:
        for b in blocks(path):
            if b.lang in FORBIDDEN_LANGS:
                bad.append(f"{b.where}: a ```{b.lang} block: write ```sh or ```python")
            if b.lang != "sh":
                continue
            for k, line in enumerate(b.lines):
                if classify(line) == "bad":
                    bad.append(f"{b.path.relative_to(ROOT)}:{b.line + k}: {line.strip()!r}")
    assert not bad, (
        f"lines neither runnable (.venv/bin/mps …, mps …) nor marked '{MARKER} <why>':\n" + "\n".join(bad)
    )


def test_marked_python_blocks_compile():
    for path in DOC_FILES:
        for b in blocks(path):
            if b.lang == "python":
                compile("\n".join(b.lines), b.where, "exec")


def test_readme_is_the_front_door():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= MAX_README_LINES, f"README.md has {len(lines)} lines"
    assert lines[0].startswith("# ")
    first = blocks(README)[0]
    assert first.line == 4 and first.lang == "sh", "the set-up block must follow the title"
    commands = [ln.split("#", 1)[0].strip() for ln in first.lines]
    assert commands == ["make run", "make test"]
    assert "](docs/viewer.png)" in "\n".join(lines)


_LINK = re.compile(r"\]\(([^)\s]+)\)")


def _anchor(heading: str) -> str:
    s = heading.strip().lower()
    s = re.sub(r"[^\w\- ]", "", s)
    return s.replace(" ", "-")


def test_links_point_at_files_and_headings():
    bad = []
    for path in DOC_FILES:
        text = path.read_text(encoding="utf-8")
        text = re.sub(r"```.*?```", "", text, flags=re.S)
        for target in _LINK.findall(text):
            if re.match(r"[a-z]+:", target):
                continue
            file, _, anchor = target.partition("#")
            dest = (path.parent / file).resolve() if file else path
            if not dest.exists():
                bad.append(f"{path.relative_to(ROOT)}: {target} (no such file)")
                continue
            if anchor:
                heads = {_anchor(h) for h in re.findall(r"^#+ (.*)$", dest.read_text(), re.M)}
                if anchor not in heads:
                    bad.append(f"{path.relative_to(ROOT)}: {target} (no such heading)")
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("path", DOC_FILES, ids=[str(p.relative_to(ROOT)) for p in DOC_FILES])
def test_doc_runs(path, tmp_path, monkeypatch):
    work = workdir(tmp_path)
    env = command_env(work)
    monkeypatch.chdir(work)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    ran = 0
    for b in blocks(path):
        if b.lang == "sh":
            for k, line in enumerate(b.lines):
                kind = classify(line)
                assert kind != "bad", f"{b.path.relative_to(ROOT)}:{b.line + k}: not runnable, not marked"
                if kind != "run":
                    continue
                where = f"{b.path.relative_to(ROOT)}:{b.line + k}"
                t0 = time.perf_counter()
                try:
                    r = subprocess.run(
                        ["bash", "-c", line.strip()],
                        cwd=work,
                        env=env,
                        capture_output=True,
                        text=True,
                        timeout=LINE_TIMEOUT_S,
                        start_new_session=True,
                    )
                except subprocess.TimeoutExpired:
                    pytest.fail(f"{where}: {line.strip()!r} ran past {LINE_TIMEOUT_S} s")
                assert r.returncode == 0, (
                    f"{where}: {line.strip()!r} exited {r.returncode}\n"
                    f"stdout:\n{r.stdout[-3000:]}\nstderr:\n{r.stderr[-3000:]}"
                )
                print(f"{where}: ok in {time.perf_counter() - t0:.2f} s: {line.strip()[:90]}")
                ran += 1
        elif b.lang == "python":
            code = "\n".join(b.lines)
            compiled = compile(code, b.where, "exec")
            if python_marked(b):
                continue
            t0 = time.perf_counter()
            try:
                exec(compiled, {"__name__": "__docs__"})
            finally:
                plt = sys.modules.get("matplotlib.pyplot")
                if plt is not None:
                    plt.close("all")
            print(f"{b.where}: python block ok in {time.perf_counter() - t0:.2f} s")
            ran += 1
    if path in (README, ROOT / "docs" / "model.md"):
        assert ran, f"{path.relative_to(ROOT)}: no example ran"
