"""A recording copied into a bag of rosbag2's sqlite3 storage, by rosbags (an independent
writer), for the readers' tests."""

from __future__ import annotations

from pathlib import Path


def as_sqlite3_bag(mcap: Path, bag: Path) -> Path:
    """Write every message of ``mcap``, in the file's order, to a bag of rosbag2's sqlite3
    storage at ``bag``: its ``metadata.yaml`` and ``NAME.db3``."""
    from mcap.reader import make_reader
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    with open(mcap, "rb") as fh, Writer(bag, version=8, storage_plugin=StoragePlugin.SQLITE3) as writer:
        conns: dict[int, object] = {}
        for schema, channel, message in make_reader(fh).iter_messages(log_time_order=False):
            if channel.id not in conns:
                conns[channel.id] = writer.add_connection(channel.topic, schema.name, typestore=store)
            writer.write(conns[channel.id], message.log_time, message.data)
    return bag
