"""Outputs never destroy: a path checked before the run, never an input, never an existing file
unless --force, written whole (a temporary name renamed when complete)."""

from importlib import resources

import pytest

from mps_core.cli import main
from mps_core.files.outputs import OutputFileError, check_outputs, partial_name, written_whole


@pytest.fixture
def scene_copy(tmp_path):
    s = tmp_path / "s.toml"
    s.write_bytes(resources.files("mps_core.scene.presets").joinpath("paper.toml").read_bytes())
    return s


@pytest.mark.parametrize("flag", ["--csv", "--events"])
def test_an_output_that_is_the_scene_is_refused_before_the_run(scene_copy, capsys, flag):
    before = scene_copy.read_bytes()
    assert main(["run", str(scene_copy), flag, str(scene_copy), "--force"]) == 2
    out, err = capsys.readouterr()
    assert out == ""  # nothing ran
    assert err.count("\n") == 1 and f"{flag} {str(scene_copy)!r}" in err
    assert "the command's input" in err and "destroy" in err
    assert scene_copy.read_bytes() == before


def test_an_existing_output_needs_force(tmp_path, capsys):
    csv = tmp_path / "p.csv"
    csv.write_text("keep me\n")
    assert main(["run", "paper", "--csv", str(csv)]) == 2
    out, err = capsys.readouterr()
    assert out == "" and "exists" in err and "--force" in err
    assert csv.read_text() == "keep me\n"
    assert main(["run", "paper", "--csv", str(csv), "--force"]) == 0
    assert csv.read_text().startswith("t,")
    assert list(tmp_path.iterdir()) == [csv]  # no temporary file left


def test_output_paths_are_checked_before_the_run(tmp_path, capsys):
    cases = [
        (["--csv", str(tmp_path / "nodir" / "x.csv")], "no directory"),
        (["--events", str(tmp_path)], "a directory, expected a file path"),
        (["--csv", str(tmp_path / "a"), "--events", str(tmp_path / "a")], "also the --csv"),
    ]
    for args, words in cases:
        assert main(["run", "paper", *args]) == 2, args
        out, err = capsys.readouterr()
        assert out == "" and words in err, (args, err)
    assert list(tmp_path.iterdir()) == []


def test_written_whole_leaves_the_target_as_it_was_on_an_error(tmp_path):
    target = tmp_path / "x.csv"
    target.write_text("old")
    with pytest.raises(RuntimeError):
        with written_whole(target) as tmp:
            assert tmp == partial_name(target) and tmp.parent == tmp_path
            tmp.write_text("half")
            raise RuntimeError("the disk is full")
    assert target.read_text() == "old" and list(tmp_path.iterdir()) == [target]
    with written_whole(target) as tmp:
        tmp.write_text("new")
    assert target.read_text() == "new" and list(tmp_path.iterdir()) == [target]


def test_check_outputs_ignores_absent_ones_and_preset_names(tmp_path):
    got = check_outputs({"--csv": None, "--events": tmp_path / "e.jsonl"}, inputs=["paper"])
    assert got == {"--events": tmp_path / "e.jsonl"}
    with pytest.raises(OutputFileError, match="not a file name"):
        check_outputs({"--csv": ""})


def test_a_run_that_fails_keeps_what_it_computed_marked_partial(tmp_path, capsys):
    import json

    from mps_core.dynamics.reactions import read_csv

    csv, ev = tmp_path / "p.csv", tmp_path / "p.jsonl"
    assert (
        main(
            [
                "run",
                "press-cycle",
                "--no-chart-switching",
                "--dt",
                "0.001",
                "--reactions",
                "--csv",
                str(csv),
                "--events",
                str(ev),
            ]
        )
        == 2
    )
    out, err = capsys.readouterr()
    assert err.startswith("mps: error: t = ") and err.count("\n") == 1
    assert "(partial: up to t = " in out
    last = csv.read_text().splitlines()[-1]
    assert last.startswith("# partial: the run stopped at t = ") and "chart switching is off" in last
    cols = read_csv(csv)  # our reader skips the comment
    t_stop = cols["t"][-1]
    assert 0.1 < t_stop < 1.0 and len(cols["t"]) == round(t_stop / 0.001) + 1
    assert "F_found_x" in cols
    events = [json.loads(line) for line in ev.read_text().splitlines()]
    assert events[-1]["kind"] == "run-failed" and events[-1]["t"] == t_stop
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.csv", "p.jsonl"]


def test_mps_loads_checks_its_outputs_before_the_run(tmp_path, capsys):
    kept = tmp_path / "w.json"
    kept.write_text("{}")
    for args, words in (
        (["--png", str(tmp_path / "nodir" / "w.png")], "no directory"),
        (["--json", str(kept)], "exists"),
    ):
        assert main(["loads", "working", *args]) == 2
        out, err = capsys.readouterr()
        assert out == "" and words in err, err
    assert kept.read_text() == "{}"
    assert (
        main(
            [
                "loads",
                "working",
                "--t-end",
                "0.3",
                "--json",
                str(kept),
                "--png",
                str(tmp_path / "w.png"),
                "--force",
            ]
        )
        == 0
    )
    assert kept.read_text().startswith("{\n") or len(kept.read_text()) > 2
    assert (tmp_path / "w.png").read_bytes()[:4] == b"\x89PNG"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["w.json", "w.png"]


def test_mps_view_save_is_checked_before_reading(tmp_path, capsys):
    pytest.importorskip("rerun")
    from pathlib import Path

    sample = tmp_path / "s.mcap"
    repo = Path(__file__).resolve().parents[2]
    sample.write_bytes((repo / "recordings" / "sample_press-cycle.mcap").read_bytes())
    for save, words in ((tmp_path, "a directory"), (sample, "the command's input")):
        assert main(["view", str(sample), "--save", str(save), "--no-spawn", "--force"]) == 2
        assert words in capsys.readouterr().err
