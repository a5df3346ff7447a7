"""A rosbag2 bag's file in its sqlite3 storage (``NAME_0.db3``), read as MCAP files are.

The replay (:mod:`mps_ros.recording.replay`) reads it beside MCAP files. rosbag2's ``sqlite3``
storage plugin (the default before Iron) keeps a bag file's topics in a table ``topics``
(``id``, ``name``, ``type``, ``serialization_format``) and its messages in a table ``messages``
(``id``, ``topic_id``, ``timestamp`` in ns, ``data``: the serialized message), read here in the
order written (by ``id``), as an MCAP file is read in its own; rosbag2 records in the order
messages come, stamped as they come, so its bags read the same by ``timestamp``. Python's own
``sqlite3`` opens it read-only; no ROS and no rosbags. Such a file has no metadata records: a
recording of the twin's own (its scene, its tuning) is MCAP.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Callable, Collection
from pathlib import Path
from typing import Any

__all__ = ["MAGIC", "scan"]

#: the first bytes of an SQLite 3 database file
MAGIC = b"SQLite format 3\x00"


def scan(path: Path, make_channel: Callable[..., Any], keep: Collection[str] | None, error: type[Exception]):
    """Return (channels by id, messages) of the bag file ``path``.

    Each channel is ``make_channel(id, topic, type, serialization format)``, whose ``times``,
    ``datas`` and ``seqs`` get the messages of the topics in ``keep`` (None: all) and whose
    ``count`` counts them all. ``error``: what a file that is not such a bag file raises, with
    what was found and what was expected.
    """
    try:
        con = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True)
    except sqlite3.Error as exc:
        raise error(f"{path}: cannot be opened as a rosbag2 sqlite3 file ({exc})") from None
    try:
        try:
            topics = con.execute("SELECT id, name, type, serialization_format FROM topics").fetchall()
            rows = con.execute("SELECT topic_id, timestamp, data FROM messages ORDER BY id")
            channels = {tid: make_channel(tid, name, msgtype, fmt) for tid, name, msgtype, fmt in topics}
            messages = 0
            for tid, t_ns, data in rows:
                ch = channels.get(tid)
                if ch is not None:
                    ch.count += 1
                    if keep is None or ch.topic in keep:
                        ch.times.append(int(t_ns))
                        ch.datas.append(bytes(data))
                        ch.seqs.append(messages)
                messages += 1
        except sqlite3.Error as exc:
            raise error(
                f"{path}: an SQLite file that is not a rosbag2 bag file ({exc}): expected the tables "
                "topics (id, name, type, serialization_format) and messages (topic_id, timestamp, data)"
            ) from None
    finally:
        con.close()
    return channels, messages
