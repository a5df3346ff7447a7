"""CDR (XCDR1, little endian) encoders for the twin's per-step message types, from the message
dicts :mod:`mps_ros.run.twin` builds.

The node publishes these bytes (``Publisher.publish`` of a serialized message) and the recorder
writes the same bytes into the MCAP file, so what goes on the wire and what is recorded are one
thing. Padding is always zero. They give exactly the bytes of mcap-ros2-support's generic encoder
(``tests/ros/test_recording.py`` checks that, and rclpy's deserialization of them), at a fraction
of its cost: the per-step types only; anything else goes through the generic encoder
(:func:`encoder` picks), mcap-ros2-support's, built from rosbags' Jazzy definitions
(:func:`msgdef`, the definitions a recording's schemas carry). :class:`Preset` keeps a
per-step message encoded and packs each step's values into it.
"""

from __future__ import annotations

import functools
import struct

_HEAD = b"\x00\x01\x00\x00"  # encapsulation: CDR little endian
_u32 = struct.Struct("<I").pack
_time = struct.Struct("<iI").pack
_vec6 = struct.Struct("<6d").pack


def _align(buf: bytearray, n: int) -> None:
    r = (len(buf) - 4) % n
    if r:
        buf += b"\x00" * (n - r)


def _string(buf: bytearray, s: str) -> None:
    b = s.encode()
    _align(buf, 4)
    buf += _u32(len(b) + 1)
    buf += b
    buf += b"\x00"


def _f64s(buf: bytearray, vals) -> None:
    _align(buf, 4)
    buf += _u32(len(vals))
    if vals:
        _align(buf, 8)
        buf += struct.pack(f"<{len(vals)}d", *vals)


def _header(buf: bytearray, h: dict) -> None:
    st = h["stamp"]
    buf += _time(st["sec"], st["nanosec"])
    _string(buf, h["frame_id"])


def clock(d: dict) -> bytes:
    st = d["clock"]
    return _HEAD + _time(st["sec"], st["nanosec"])


def string(d: dict) -> bytes:
    buf = bytearray(_HEAD)
    _string(buf, d["data"])
    return bytes(buf)


def wrench_stamped(d: dict) -> bytes:
    buf = bytearray(_HEAD)
    _header(buf, d["header"])
    _align(buf, 8)
    f, t = d["wrench"]["force"], d["wrench"]["torque"]
    buf += _vec6(f["x"], f["y"], f["z"], t["x"], t["y"], t["z"])
    return bytes(buf)


def joint_state(d: dict) -> bytes:
    buf = bytearray(_HEAD)
    _header(buf, d["header"])
    names = d["name"]
    _align(buf, 4)
    buf += _u32(len(names))
    for n in names:
        _string(buf, n)
    _f64s(buf, d["position"])
    _f64s(buf, d["velocity"])
    _f64s(buf, d["effort"])
    return bytes(buf)


ENCODERS = {
    "rosgraph_msgs/msg/Clock": clock,
    "std_msgs/msg/String": string,
    "geometry_msgs/msg/WrenchStamped": wrench_stamped,
    "sensor_msgs/msg/JointState": joint_state,
}


class Preset:
    """A message of fixed layout, kept encoded: only its stamp (in every header it has) and
    floats change from one step to the next (the strings and sequence lengths stay).
    ``encode``: one of the encoders above; ``make(stamp, floats)``: the message dict with those
    values. The offsets of the stamps and floats are found once, from the encoder's own output;
    ``pack(sec, nanosec, floats)`` is then one ``struct`` call, with the bytes between them as
    constants, and gives exactly ``encode(make(...))``. ``take``: float k of the message is
    ``floats[take[k]]`` (0.0 where None) instead of ``floats[k]``, so that one list of values
    (a step's reactions) fills several messages without a list for each."""

    def __init__(self, encode, make, nfloats: int, take=None):
        # sentinels: distinct values whose bytes occur once in the encoded message
        marks = [float.fromhex(f"0x1.{k + 1:04x}5a5a5a5a5p-1000") for k in range(nfloats)]
        sec, nsec = 0x5A5A5A5A, 0x3C3C3C3C
        probe = encode(make({"sec": sec, "nanosec": nsec}, marks))
        stamps = []  # every header's stamp (a message of several headers)
        at = probe.find(_time(sec, nsec))
        while at >= 0:
            stamps.append(at)
            at = probe.find(_time(sec, nsec), at + 1)
        if not stamps:
            raise ValueError("Preset: the stamp is not found in the encoded message")
        offsets = []
        for m in marks:
            b = struct.pack("<d", m)
            at = probe.find(b)
            if at < 0 or probe.find(b, at + 1) >= 0:
                raise ValueError("Preset: a float is not found once in the encoded message")
            offsets.append(at)
        # one struct for the whole message: the probe's bytes between the fields as constants
        fields = sorted([(at, None) for at in stamps] + [(at, k) for k, at in enumerate(offsets)])
        consts: dict = {}
        fmt, args, pos = "<", [], 0
        for at, k in fields:
            if at < pos:
                raise ValueError("Preset: two fields overlap in the encoded message")
            if at > pos:
                name = f"_c{len(consts)}"
                consts[name] = bytes(probe[pos:at])
                fmt += f"{at - pos}s"
                args.append(name)
            fmt += "iI" if k is None else "d"
            if k is None:
                args += ["sec", "nanosec"]
            elif take is None:
                args.append(f"floats[{k}]")
            else:
                args.append("0.0" if take[k] is None else f"floats[{int(take[k])}]")
            pos = at + 8
        if pos < len(probe):
            consts["_tail"] = bytes(probe[pos:])
            fmt += f"{len(probe) - pos}s"
            args.append("_tail")
        namespace = {"_pack": struct.Struct(fmt).pack, **consts}
        exec(f"def pack(sec, nanosec, floats):\n    return _pack({', '.join(args)})\n", namespace)
        #: ``pack(sec, nanosec, floats)``: the message's bytes with these values
        self.pack = namespace["pack"]
        self.nfloats = nfloats


def planar_wrench(sec: int, nanosec: int, frame_id: str, fx: float, fy: float, mz: float) -> bytes:
    """Return a WrenchStamped's bytes in ``frame_id``: force (fx, fy, 0), torque (0, 0, mz).

    Its layout is kept per frame (:class:`Preset`: the encoder's bytes exactly).
    """
    pack = _PLANAR.get(frame_id)
    if pack is None:

        def make(stamp: dict, f: list) -> dict:
            return {
                "header": {"stamp": stamp, "frame_id": frame_id},
                "wrench": {
                    "force": {"x": f[0], "y": f[1], "z": 0.0},
                    "torque": {"x": 0.0, "y": 0.0, "z": f[2]},
                },
            }

        pack = _PLANAR[frame_id] = Preset(wrench_stamped, make, 3).pack
    return pack(sec, nanosec, (fx, fy, mz))


#: the planar wrenches' layouts by frame (:func:`planar_wrench`)
_PLANAR: dict = {}


# -- every other type: mcap-ros2-support's encoder, from rosbags' definitions ---------------
_msgdefs: dict[str, str] = {}
_encoders: dict[str, object] = {}


def msgdef(msgtype: str) -> str:
    """The ros2msg definition of ``msgtype`` with every definition it depends on: rosbags'
    Jazzy definitions, kept in the disk cache of generated code
    (:mod:`mps_core.codegen.disk_cache`) under the type's name and rosbags' own files, so that a
    new process does not load rosbags' type store (about 80 ms of CPU) for the types it has met
    before."""
    text = _msgdefs.get(msgtype)
    if text is None:
        from mps_core.codegen import disk_cache

        entry = disk_cache.entry("ros2msg definition", (msgtype, _rosbags_files()))
        items = None if entry is None else entry.read()
        if items is not None and len(items) == 1:
            try:
                text = items[0].decode()
            except UnicodeDecodeError:
                text = None
        if text is None:
            from rosbags.typesys import Stores, get_typestore

            text, _ = get_typestore(Stores.ROS2_JAZZY).generate_msgdef(msgtype, ros_version=2)
            if entry is not None:
                entry.write([text.encode()])
        _msgdefs[msgtype] = text
    return text


@functools.cache
def _rosbags_files() -> tuple:
    """What rosbags' definitions are made of: its type system's files, by name, size and time of
    change (another rosbags, or a file changed, is another key); () where it cannot be found.
    Looked at once a process (about 1 ms)."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.find_spec("rosbags")
    if spec is None or not spec.submodule_search_locations:
        return ()
    root = Path(list(spec.submodule_search_locations)[0]) / "typesys"
    try:
        return tuple(
            (str(f.relative_to(root)), st.st_size, st.st_mtime_ns)
            for f in sorted(root.rglob("*.py"))
            for st in (f.stat(),)
        )
    except OSError:
        return ()


def generic_encoder(msgtype: str):
    """A function message dict -> CDR bytes: mcap-ros2-support's encoder for ``msgtype``."""
    if msgtype not in _encoders:
        from mcap_ros2._dynamic import serialize_dynamic

        _encoders[msgtype] = serialize_dynamic(msgtype, msgdef(msgtype))[msgtype]
    return _encoders[msgtype]


def encoder(msgtype: str):
    """A function message dict -> CDR bytes: :mod:`mps_ros.wire.cdr`'s for the per-step types (the
    same bytes, faster), mcap-ros2-support's for the others."""
    return ENCODERS.get(msgtype) or generic_encoder(msgtype)
