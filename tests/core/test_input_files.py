"""Every way a named file can be wrong gives one line on stderr and exit status 2, for every
``mps`` subcommand that takes a file: no traceback, and the line names the file and what is
wrong with it."""

from __future__ import annotations

import pytest

from mps_core.cli import main

pytest.importorskip("mcap")  # recover and view are among the subcommands


@pytest.fixture
def bad(tmp_path):
    d = tmp_path
    (d / "folder").mkdir()
    (d / "folder.mcap").mkdir()
    (d / "some.bin").write_bytes(bytes(range(256)) * 2)
    (d / "some.mcap").write_bytes(b"\x00\x01 not a recording")
    (d / "some.csv").write_bytes(b"t,phi\x00\x01\x02")
    (d / "empty.toml").write_bytes(b"")
    (d / "empty.mcap").write_bytes(b"")
    (d / "empty.csv").write_bytes(b"")
    (d / "blank.toml").write_bytes(b"  \n\t\n")
    (d / "latin1.toml").write_bytes('name = "café"\n'.encode("latin-1"))
    return d


CASES = [
    # (arguments, what the one line must say)
    (["run", "some.bin"], "a binary file"),
    (["run", "folder"], "a directory"),
    (["run", "empty.toml"], "the file is empty"),
    (["run", "blank.toml"], "the file is empty"),
    (["run", "latin1.toml"], "not UTF-8 text: byte 0xe9"),
    (["run", "missing.toml"], "a preset name"),
    (["loads", "some.bin"], "a binary file"),
    (["loads", "folder"], "a directory"),
    (["loads", "some.mcap"], "not an MCAP file"),
    (["loads", "empty.mcap"], "not an MCAP file (empty)"),
    (["loads", "folder.mcap"], "a directory"),
    (["loads", "some.csv"], "a binary file"),
    (["loads", "empty.csv"], "the file is empty"),
    (["loads", "missing.csv"], "no such file"),
    (["loads", "paper", "--events", "some.bin"], "applies to a recording"),
    (["bench", "speed", "some.bin"], "a binary file"),
    (["bench", "accuracy", "empty.toml"], "the file is empty"),
    (["recover", "some.bin"], "not an MCAP file"),
    (["recover", "folder"], "a directory"),
    (["recover", "empty.mcap"], "the file is empty"),
    (["recover", "missing.mcap"], "no such file"),
    (["record", "some.bin", "--out", "x.mcap"], "a binary file"),
    (["record", "folder", "--out", "x.mcap"], "a directory"),
    (["record", "press-cycle", "--out", "folder", "--t-end", "0.01"], "recording 'folder'"),
]


@pytest.mark.parametrize("args, says", CASES, ids=[" ".join(a) for a, _ in CASES])
def test_a_bad_file_is_one_line_and_exit_2(bad, monkeypatch, capsys, args, says):
    if args[0] in ("recover", "record"):
        pytest.importorskip("rosbags")
    monkeypatch.chdir(bad)
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    assert len(err.splitlines()) == 1, err
    assert err.startswith("mps: error: ") and says in err, err


@pytest.mark.parametrize("name", ["some.bin", "folder", "empty.mcap", "some.mcap"])
def test_view_refuses_a_bad_recording_in_one_line(bad, monkeypatch, capsys, name):
    pytest.importorskip("rerun")
    monkeypatch.chdir(bad)
    assert main(["view", name, "--save", "out.rrd"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("mps: error: "), err
    assert "Traceback" not in err
