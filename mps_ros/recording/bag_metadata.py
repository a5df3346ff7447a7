"""The ``rosbag2`` metadata record that Jazzy's rosbag2 writes into an MCAP file as it closes
it: ``serialized_metadata``, the bag's ``BagMetadata`` (version 9) as YAML (its storage, start,
duration, message count, each topic with its type, serialization format, offered QoS profiles,
type description hash and message count, the file, the distribution). ``ros2 bag info`` and
``ros2 bag play`` read a bag's metadata from it where the bag has no ``metadata.yaml``.

The YAML is the one rosbag2's ``YAML::convert<BagMetadata>::encode`` gives (rosbag2_storage's
``yaml.hpp``), key for key; it is written here, not by a YAML library, so that recording needs
none."""

from __future__ import annotations

from dataclasses import dataclass

#: the ROS 2 distribution the recordings are written for
ROS_DISTRO = "jazzy"
#: rosbag2's BagMetadata version of that distribution
VERSION = 9


@dataclass
class TopicCount:
    """A recorded topic: its name, type (``pkg/msg/Name``), offered QoS (rosbag2's YAML, a
    list of profiles), type description hash and message count."""

    name: str
    msgtype: str
    qos: str
    type_hash: str
    count: int


def _quoted(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _indented(block: str, spaces: int) -> str:
    pad = " " * spaces
    return "\n".join(pad + line for line in block.splitlines())


def serialized_metadata(
    files, topics: list[TopicCount], start_ns: int, end_ns: int, compression: str = ""
) -> str:
    """``BagMetadata`` as YAML: the bag's ``files`` (a file's name, where it is the one file;
    else (name, first and last log time in ns, message count) each, in order) holding
    ``topics``, its messages from ``start_ns`` to ``end_ns`` (log times); ``compression``: the
    chunks' (rosbag2 says ``""`` for chunk compression done by the storage)."""
    total = sum(t.count for t in topics)
    duration = max(0, end_ns - start_ns) if total else 0
    start = start_ns if total else 0
    lines = [
        f"version: {VERSION}",
        "storage_identifier: mcap",
        "duration:",
        f"  nanoseconds: {duration}",
        "starting_time:",
        f"  nanoseconds_since_epoch: {start}",
        f"message_count: {total}",
    ]
    if topics:
        lines.append("topics_with_message_count:")
        for t in topics:
            lines += [
                "  - topic_metadata:",
                f"      name: {_quoted(t.name)}",
                f"      type: {t.msgtype}",
                "      serialization_format: cdr",
                "      offered_qos_profiles:",
                _indented(t.qos, 8),
                f"      type_description_hash: {t.type_hash}",
                f"    message_count: {t.count}",
            ]
    else:
        lines.append("topics_with_message_count: []")
    if isinstance(files, str):
        files = [(files, start_ns, end_ns, total)]
    lines += [
        f"compression_format: {_quoted(compression)}",
        'compression_mode: ""',
        "relative_file_paths:",
        *(f"  - {_quoted(name)}" for name, *_ in files),
        "files:",
    ]
    for name, t0, t1, n in files:
        lines += [
            f"  - path: {_quoted(name)}",
            "    starting_time:",
            f"      nanoseconds_since_epoch: {t0 if n else 0}",
            "    duration:",
            f"      nanoseconds: {max(0, t1 - t0) if n else 0}",
            f"    message_count: {n}",
        ]
    lines += ["custom_data: {}", f"ros_distro: {ROS_DISTRO}"]
    return "\n".join(lines) + "\n"


def record(
    file_name: str, topics: list[TopicCount], start_ns: int, end_ns: int, compression: str = ""
) -> dict[str, str]:
    """The ``rosbag2`` metadata record's key/values."""
    return {"serialized_metadata": serialized_metadata(file_name, topics, start_ns, end_ns, compression)}


__all__ = ["ROS_DISTRO", "VERSION", "TopicCount", "serialized_metadata", "record"]
