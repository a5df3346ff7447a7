"""A recording path that is not an ``.mcap`` file gives a bag as rosbag2 writes one: the files
split by size or by simulated time, each a whole recording of its own, and ``metadata.yaml``;
rosbags' rosbag2 reader and ``mps loads``/``read_recording`` read every message exactly once, in
order, across the files; ``mps recover`` completes a bag whose writer was killed; the node
writes one."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mcap")
pytest.importorskip("rosbags")
yaml = pytest.importorskip("yaml")

from sqlite_bags import as_sqlite3_bag  # noqa: E402
from test_bag_metadata import _holds_what_the_file_holds, _summary  # noqa: E402
from twin_probe import NodeProcess  # noqa: E402

from mps_core.cli import main as mps_main  # noqa: E402
from mps_ros.recording.replay import read_recording  # noqa: E402
from mps_ros.wire.topics import TYPE_HASHES  # noqa: E402


def _read_bag(path):
    """Every message of a bag through rosbags' rosbag2 reader: (topic, log time, bytes)."""
    from rosbags.rosbag2 import Reader

    with Reader(path) as r:
        return [(c.topic, t, bytes(raw)) for c, t, raw in r.messages()], r.message_count


def _read_file(path):
    from rosbags.highlevel import AnyReader

    with AnyReader([Path(path)]) as r:
        return [(c.topic, t, bytes(raw)) for c, t, raw in r.messages()]


def _info(bag: Path) -> dict:
    return yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]


def _metadata_says_what_the_files_hold(bag: Path) -> dict:
    info = _info(bag)
    assert info["version"] == 9 and info["storage_identifier"] == "mcap"
    names = info["relative_file_paths"]
    assert names == [f"{bag.name}_{i}.mcap" for i in range(len(names))]
    assert sorted(p.name for p in bag.iterdir()) == sorted([*names, "metadata.yaml"])
    totals: dict[str, int] = {}
    for entry, name in zip(info["files"], names):
        assert entry["path"] == name
        # each file a whole recording of its own, with its own rosbag2 record
        one = _holds_what_the_file_holds(bag / name, name)
        assert entry["message_count"] == one["message_count"] > 0
        assert entry["starting_time"] == one["starting_time"]
        assert entry["duration"] == one["duration"]
        _s, counts = _summary(bag / name)
        for t, n in counts.items():
            totals[t] = totals.get(t, 0) + n
    topics = {t["topic_metadata"]["name"]: t for t in info["topics_with_message_count"]}
    assert {n: t["message_count"] for n, t in topics.items()} == totals
    assert info["message_count"] == sum(totals.values())
    for t in topics.values():
        assert t["topic_metadata"]["type_description_hash"] == TYPE_HASHES[t["topic_metadata"]["type"]]
    return info


def test_a_bag_split_by_time_holds_every_message_once_in_order(tmp_path):
    one, bag = tmp_path / "one.mcap", tmp_path / "run"
    for out, extra in ((one, []), (bag, ["--max-s", "0.25"])):
        assert (
            mps_main(
                ["record", "press-cycle", "--out", str(out), "--dt", "0.001", "--t-end", "1.0", "-q", *extra]
            )
            == 0
        )
    info = _metadata_says_what_the_files_hold(bag)
    # a new file once one spans a quarter of a simulated second (the recording process looks
    # between the batches of steps it is handed, so a file may hold a batch more)
    assert len(info["files"]) >= 2
    for f in info["files"][:-1]:
        assert f["duration"]["nanoseconds"] >= 0.25e9 - 1e6
    got, count = _read_bag(bag)
    want = _read_file(one)
    assert count == len(got)
    # /diagnostics come once a wall second: a run slowed by a busy machine has one more
    assert sum(1 for m in got if m[0] != "/diagnostics") == sum(1 for m in want if m[0] != "/diagnostics")
    assert [t for _, t, _ in got] == sorted(t for _, t, _ in got)

    def by_topic(msgs):
        out: dict = {}
        for topic, t, data in msgs:
            if topic != "/diagnostics":  # wall-clock figures: another run's
                out.setdefault(topic, []).append((t, data))
        return out

    assert by_topic(got) == by_topic(want)
    # read back as one recording: the same columns as the single file's
    a, b = read_recording(bag), read_recording(one)
    assert a.columns.keys() == b.columns.keys() and len(a) == len(b) == 1001
    for k in a.columns:
        np.testing.assert_array_equal(np.asarray(a.columns[k]), np.asarray(b.columns[k]), k)
    assert [e["kind"] for e in a.events] == [e["kind"] for e in b.events]


def test_a_bag_split_by_size_and_the_load_report(tmp_path, capsys):
    bag = tmp_path / "big"
    assert (
        mps_main(
            [
                "record",
                "press-cycle",
                "--out",
                str(bag),
                "--dt",
                "0.001",
                "--t-end",
                "1.0",
                "-q",
                "--max-mb",
                "0.15",
            ]
        )
        == 0
    )
    info = _metadata_says_what_the_files_hold(bag)
    assert len(info["files"]) >= 2
    for name in info["relative_file_paths"][:-1]:
        assert (bag / name).stat().st_size >= 0.15e6
    capsys.readouterr()
    assert mps_main(["loads", str(bag)]) == 0
    assert "load report big:" in capsys.readouterr().out


def test_a_bag_of_rosbag2_s_sqlite3_storage_reads_as_its_mcap(tmp_path, capsys):
    """A recording copied into a bag of rosbag2's sqlite3 storage (the default before Iron) reads
    as the file: every column the same, and the same load report."""
    mcap = tmp_path / "run.mcap"
    args = ["record", "press-cycle", "--out", str(mcap), "--dt", "0.001", "--t-end", "1.0", "-q"]
    assert mps_main(args) == 0
    bag = as_sqlite3_bag(mcap, tmp_path / "run-sqlite")
    assert sorted(p.suffix for p in bag.iterdir()) == [".db3", ".yaml"]
    a, b = read_recording(mcap), read_recording(bag)
    # (the copy has the topics with messages: the file also names two the run never wrote to)
    assert sorted(a.columns) == sorted(b.columns) and {k: n for k, n in a.topics.items() if n} == b.topics
    for name, col in a.columns.items():
        assert np.array_equal(col, b.columns[name], equal_nan=col.dtype.kind == "f"), name
    capsys.readouterr()
    reports = []
    for path in (mcap, bag):
        assert mps_main(["loads", str(path)]) == 0
        reports.append(capsys.readouterr().out.replace(path.name, "NAME"))
    assert reports[0] == reports[1] and "load report NAME:" in reports[0]


def test_a_bag_is_never_written_over_and_a_file_is_not_split(tmp_path, capsys):
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "x.txt").write_text("keep")
    assert mps_main(["record", "press-cycle", "--out", str(bag), "--t-end", "0.01", "--force"]) == 2
    assert "a bag is never written into one that is there" in capsys.readouterr().err
    assert [p.name for p in bag.iterdir()] == ["x.txt"]
    assert mps_main(["record", "press-cycle", "--out", str(tmp_path / "f.mcap"), "--max-s", "1"]) == 2
    assert "--max-mb and --max-s split a bag" in capsys.readouterr().err
    assert not (tmp_path / "f.mcap").exists()
    empty = tmp_path / "empty"
    empty.mkdir()  # an empty directory too, as rosbag2 refuses it
    assert mps_main(["record", "press-cycle", "--out", str(empty), "--t-end", "0.01"]) == 2
    assert "exists; expected a new directory" in capsys.readouterr().err
    assert not any(empty.iterdir())


def test_a_bag_cut_short_is_recovered(tmp_path, capsys):
    """A writer killed mid-file leaves its earlier files whole, the last without its end, and
    no metadata.yaml: mps recover makes a new bag of what is whole."""
    bag = tmp_path / "cut"
    assert (
        mps_main(
            [
                "record",
                "press-cycle",
                "--out",
                str(bag),
                "--dt",
                "0.001",
                "--t-end",
                "1.0",
                "-q",
                "--max-s",
                "0.4",
            ]
        )
        == 0
    )
    names = _info(bag)["relative_file_paths"]
    (bag / "metadata.yaml").unlink()
    last = bag / names[-1]
    data = last.read_bytes()
    last.write_bytes(data[: len(data) // 2])
    capsys.readouterr()
    assert mps_main(["recover", str(bag)]) == 0
    out = tmp_path / "cut-recovered"
    assert f"-> {out}" in capsys.readouterr().out
    info = _metadata_says_what_the_files_hold(out)
    assert len(info["files"]) == len(names)
    got, count = _read_bag(out)
    assert count == len(got) and [t for _, t, _ in got] == sorted(t for _, t, _ in got)
    assert math.isclose(read_recording(out).columns["t"][-1], 0.8, abs_tol=0.2)
    assert mps_main(["recover", str(bag)]) == 2  # never over the first
    assert "exists; expected a new directory" in capsys.readouterr().err


def test_the_node_records_a_bag(ros, tmp_path):
    bag = tmp_path / "nodebag"
    params = dict(pacing="as_fast_as_possible", dt=0.001, t_end=0.6, recording=str(bag), recording_max_s=0.2)
    with NodeProcess(tmp_path, params, name="bag") as node:
        assert node.wait(120) == 0, node.log()
        log = node.log()
    assert f"recording finished: {bag}" in log
    info = _metadata_says_what_the_files_hold(bag)
    assert len(info["files"]) >= 2
    got, count = _read_bag(bag)
    assert count == len(got)
    assert len(read_recording(bag).columns["t"]) == 601
