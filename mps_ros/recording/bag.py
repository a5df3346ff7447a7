"""A recording as rosbag2 writes a bag: a directory of MCAP files split by size or by time,
``NAME_0.mcap``, ``NAME_1.mcap``… (NAME the directory's name), and ``metadata.yaml``, the
bag's ``BagMetadata`` (rosbag2_bagfile_information) that ``ros2 bag info``/``play`` and
rosbags' rosbag2 reader open. Each file is a whole recording of its own (header, the ``mps``
and ``scene`` metadata records, the schemas and channels it uses, its ``rosbag2`` record, its
summary), so a file read alone still says what it is.

A recording path names a bag where it does not end in ``.mcap`` (:func:`is_bag`). The files
of a bag whose writer was killed (no ``metadata.yaml``, its last file without an end) are
found by their names (:func:`files`).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

from .bag_metadata import TopicCount, serialized_metadata

METADATA = "metadata.yaml"


def is_bag(path) -> bool:
    """Whether a recording path names a bag directory (anything but a ``.mcap`` file)."""
    p = Path(path)
    return p.is_dir() or p.suffix.lower() != ".mcap"


def file_name(bag, index: int) -> str:
    """The name of a bag's ``index``-th file, as rosbag2 names them."""
    return f"{Path(bag).name}_{index}.mcap"


@dataclass
class FileSpan:
    """One file of a bag: its name (relative to the bag), its messages' first and last log
    times (ns) and their count."""

    name: str
    start_ns: int
    end_ns: int
    count: int


def files(bag) -> list[Path]:
    """A bag's files in their order: those its ``metadata.yaml`` lists, else (a bag whose writer
    was killed) every ``NAME_N.mcap`` in it by N, then any other ``.mcap``; a bag of rosbag2's
    sqlite3 storage likewise its ``.db3`` files."""
    bag = Path(bag)
    meta = bag / METADATA
    if meta.is_file():
        import yaml

        info = yaml.safe_load(meta.read_text()).get("rosbag2_bagfile_information", {})
        listed = info.get("relative_file_paths") or []
        if listed:
            return [bag / str(p) for p in listed]

    def order(p: Path):
        m = re.fullmatch(r"(.*)_(\d+)\.(mcap|db3)", p.name)
        return (0, int(m.group(2)), p.name) if m else (1, 0, p.name)

    found = [p for p in bag.iterdir() if p.suffix.lower() == ".mcap" and p.is_file()]
    found = found or [p for p in bag.iterdir() if p.suffix.lower() == ".db3" and p.is_file()]
    return sorted(found, key=order)


def write_metadata(bag, spans: list[FileSpan], topics: list[TopicCount], compression: str = "") -> Path:
    """``metadata.yaml`` of a bag of ``spans`` holding ``topics`` (their counts over all
    files), written to a temporary name and renamed (a reader never meets half of it)."""
    bag = Path(bag)
    starts = [s.start_ns for s in spans if s.count]
    ends = [s.end_ns for s in spans if s.count]
    body = serialized_metadata(
        [(s.name, s.start_ns, s.end_ns, s.count) for s in spans],
        topics,
        min(starts, default=0),
        max(ends, default=0),
        compression,
    )
    text = "rosbag2_bagfile_information:\n" + "".join("  " + line + "\n" for line in body.splitlines())
    path = bag / METADATA
    tmp = bag / f".{METADATA}.{os.getpid()}.partial"
    tmp.write_text(text)
    os.replace(tmp, path)
    return path


__all__ = ["METADATA", "is_bag", "file_name", "FileSpan", "files", "write_metadata"]
