"""Recordings for the replay and viewer tests that the twin does not make itself: a long
synthetic one (10 s at 1 kHz in a fraction of a second) and MCAP files of other programs.

The synthetic recording has the twin's layout (profile ros2, ros2msg schemas, cdr, the ``mps``
and ``scene`` metadata records, the topics of :mod:`mps_ros.wire.topics`). Its messages are encoded
by mcap-ros2-support's encoder once a topic, then copied with their stamps and numbers written
in place (positions from an independent CDR reading of that first message), so writing 120 000
messages takes well under a second. Its motion is a locked crank-slider turning at a constant
speed (exact positions); its forces are smooth functions of the crank angle.
"""

from __future__ import annotations

import json
import math
import struct
from pathlib import Path

import numpy as np

from mps_ros.wire.topics import BY_KEY, FOUNDATION, FRAME_ID, JOINT_NAMES, WRENCHES, resolve


def _msgdef(msgtype: str) -> str:
    from rosbags.typesys import Stores, get_typestore

    text, _ = get_typestore(Stores.ROS2_JAZZY).generate_msgdef(msgtype, ros_version=2)
    return text


def _encode(msgtype: str, msg: dict) -> bytes:
    from mcap_ros2._dynamic import serialize_dynamic

    return bytes(serialize_dynamic(msgtype, _msgdef(msgtype))[msgtype](msg))


def _offsets_of_doubles(data: bytes, values: list[float]) -> list[int]:
    """Offsets of distinct marker doubles in a CDR message (found by their bytes)."""
    out = []
    for v in values:
        b = struct.pack("<d", v)
        i = data.find(b)
        assert i > 0 and data.find(b, i + 1) < 0, f"marker {v} not unique"
        out.append(i)
    return out


def _patch(
    template: bytes, n: int, t_ns: np.ndarray, stamp_at: int | None, doubles: dict[int, np.ndarray]
) -> np.ndarray:
    M = np.tile(np.frombuffer(template, dtype=np.uint8), (n, 1))
    if stamp_at is not None:
        M[:, stamp_at : stamp_at + 4] = (t_ns // 1_000_000_000).astype("<i4").view(np.uint8).reshape(n, 4)
        M[:, stamp_at + 4 : stamp_at + 8] = (t_ns % 1_000_000_000).astype("<u4").view(np.uint8).reshape(n, 4)
    for off, v in doubles.items():
        M[:, off : off + 8] = np.asarray(v, dtype="<f8").view(np.uint8).reshape(n, 8)
    return M


def synthetic_recording(
    path, *, t_end: float = 10.0, dt: float = 1e-3, scene: str = "working", omega: float = 46.0
) -> dict:
    """Write a synthetic twin recording; returns its columns (what a reader must find)."""
    from mcap.writer import CompressionType, Writer

    from mps_core.scene import load_scene

    sc = load_scene(scene)
    g = sc.geometry
    n = int(round(t_end / dt)) + 1
    t_ns = np.arange(n, dtype=np.int64) * int(round(dt * 1e9))
    t = t_ns / 1e9
    phi = omega * t - 1.0
    xc = g.l1 * np.cos(phi) + np.sqrt(g.l2**2 - (g.l1 * np.sin(phi)) ** 2) - g.l3
    rod = np.arctan2(-g.l1 * np.sin(phi), xc + g.l3 - g.l1 * np.cos(phi))
    cols = {
        "t": t,
        "phi": phi,
        "phi_dot": np.full(n, omega),
        "psi": np.zeros(n),
        "psi_dot": np.zeros(n),
        "x_C": xc,
        "x_C_dot": np.gradient(xc, t),
        "rod": rod,
        "rod_dot": np.gradient(rod, t),
        "M_motor": 20.0 + np.sin(phi),
        "M_latch": 3.0 * np.cos(2 * phi),
        "F_stop": np.zeros(n),
        "structure": np.full(n, "locked"),
    }
    wrench_cols = {}
    for k, w in enumerate((*WRENCHES, FOUNDATION)):
        for j, c in enumerate((*w.force, w.torque)):
            if c is not None and c not in cols:
                cols[c] = 1000.0 * (k + 1) * np.cos(phi + 0.3 * j) if j < 2 else 10.0 * (k + 1) * np.sin(phi)
            wrench_cols[(w.name, j)] = c

    path = Path(path)
    with open(path, "wb") as fh:
        wr = Writer(fh, compression=CompressionType.ZSTD, chunk_size=1 << 20)
        wr.start(profile="ros2", library="mps tests (synthetic)")
        wr.add_metadata("mps", {"software": "mps", "version": "synthetic", "scene": sc.name})
        wr.add_metadata("scene", {"name": sc.name, "toml": sc.text})
        schemas: dict[str, int] = {}
        rows: list[tuple[int, np.ndarray]] = []  # (channel, byte matrix)

        def channel(key):
            mt = BY_KEY[key].msgtype
            if mt not in schemas:
                schemas[mt] = wr.register_schema(mt, "ros2msg", _msgdef(mt).encode())
            return wr.register_channel(resolve(key), "cdr", schemas[mt])

        # joint states: markers at every number, then their offsets
        marks = [1.5 + 0.25 * i for i in range(12)]
        js = _encode(
            "sensor_msgs/msg/JointState",
            {
                "header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": FRAME_ID},
                "name": list(JOINT_NAMES),
                "position": marks[0:4],
                "velocity": marks[4:8],
                "effort": marks[8:12],
            },
        )
        off = _offsets_of_doubles(js, marks)
        vals = [
            phi,
            rod,
            cols["psi"],
            xc,
            cols["phi_dot"],
            cols["rod_dot"],
            cols["psi_dot"],
            cols["x_C_dot"],
            cols["M_motor"],
            np.full(n, math.nan),
            cols["M_latch"],
            cols["F_stop"],
        ]
        rows.append((channel("joint_states"), _patch(js, n, t_ns, 4, dict(zip(off, vals)))))
        for w in (*WRENCHES, FOUNDATION):
            m = _encode(
                "geometry_msgs/msg/WrenchStamped",
                {
                    "header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": w.frame_id},
                    "wrench": {
                        "force": {"x": 1.25, "y": 1.5, "z": 0.0},
                        "torque": {"x": 0.0, "y": 0.0, "z": 1.75},
                    },
                },
            )
            ox, oy, oz = _offsets_of_doubles(m, [1.25, 1.5, 1.75])
            d = {}
            for o, c in ((ox, w.force[0]), (oy, w.force[1]), (oz, w.torque)):
                d[o] = np.zeros(n) if c is None else cols[c]
            rows.append((channel(w.key), _patch(m, n, t_ns, 4, d)))
        clock = _encode("rosgraph_msgs/msg/Clock", {"clock": {"sec": 0, "nanosec": 0}})
        rows.append((channel("/clock"), _patch(clock, n, t_ns, 4, {})))
        st = _encode("std_msgs/msg/String", {"data": "locked"})
        rows.append((channel("~/structure"), _patch(st, n, t_ns, None, {})))
        ev = channel("~/events")
        wr.add_message(
            ev,
            log_time=0,
            publish_time=0,
            sequence=0,
            data=_encode(
                "std_msgs/msg/String",
                {
                    "data": json.dumps(
                        {"t": 0.0, "kind": "run-start", "scene": sc.name}, separators=(",", ":")
                    )
                },
            ),
        )
        for i in range(n):
            ti = int(t_ns[i])
            for cid, M in rows:
                wr.add_message(cid, log_time=ti, publish_time=ti, sequence=i, data=M[i].tobytes())
        wr.add_message(
            ev,
            log_time=int(t_ns[-1]),
            publish_time=int(t_ns[-1]),
            sequence=1,
            data=_encode(
                "std_msgs/msg/String",
                {
                    "data": json.dumps(
                        {"t": float(t[-1]), "kind": "run-end", "reason": "end"}, separators=(",", ":")
                    )
                },
            ),
        )
        wr.finish()
    return cols


def foreign_mcap(path) -> Path:
    """An MCAP file of another program: JSON messages on topics of its own."""
    from mcap.writer import Writer

    path = Path(path)
    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start(profile="", library="some-other-logger 2.1")
        sid = w.register_schema("Pose", "jsonschema", b'{"type":"object"}')
        cid = w.register_channel("/robot/pose", "json", sid)
        cid2 = w.register_channel("/robot/battery", "json", sid)
        for i in range(10):
            w.add_message(cid, log_time=i, publish_time=i, data=b'{"x": 1}')
            w.add_message(cid2, log_time=i, publish_time=i, data=b'{"v": 12}')
        w.finish()
    return path


def cut_before_end(src, dst) -> Path:
    """A copy of a recording cut in the middle of its data (as a writer killed hard leaves it)."""
    data = Path(src).read_bytes()
    Path(dst).write_bytes(data[: len(data) // 2])
    return Path(dst)


def read_rrd(path) -> dict:
    """An .rrd read back with rerun's own reader: entity -> {"static": {component: value},
    "time_ns": (n,) sorted, component: [row values]} (temporal chunks concatenated in time;
    a row that lacks a component holds None)."""
    from rerun.chunk import RrdReader

    store = RrdReader(str(path)).stream().collect()
    parts: dict = {}
    out: dict = {}
    for ch in store.stream():
        b = ch.to_record_batch()
        ent = out.setdefault(ch.entity_path, {"static": {}})
        names = [n for n in b.schema.names if n not in ("rerun.controls.RowId", "sim_time")]
        if "sim_time" not in b.schema.names:
            for n in names:
                ent["static"][n] = b.column(n).to_pylist()[-1]
            continue
        t = b.column("sim_time").cast("int64").to_numpy()
        parts.setdefault(ch.entity_path, []).append((t, {n: b.column(n).to_pylist() for n in names}))
    for path_, chunks in parts.items():
        t = np.concatenate([c[0] for c in chunks])
        order = np.argsort(t, kind="stable")
        ent = out[path_]
        ent["time_ns"] = t[order]
        comps = sorted({k for _, c in chunks for k in c})
        for comp in comps:
            vals = []
            for tc, c in chunks:
                vals.extend(c.get(comp, [None] * len(tc)))
            ent[comp] = [vals[i] for i in order]
    return out


def read_blueprint(path) -> dict:
    """The blueprint of an .rrd: view class -> list of origins."""
    from rerun.chunk import RrdReader

    r = RrdReader(str(path))
    bps = r.blueprints()
    assert bps, "no blueprint in the .rrd"
    store = r.stream(store=bps[0]).collect()
    views: dict = {}
    for ch in store.stream():
        b = ch.to_record_batch()
        if "ViewBlueprint:class_identifier" not in b.schema.names:
            continue
        cls = b.column("ViewBlueprint:class_identifier").to_pylist()
        org = (
            b.column("ViewBlueprint:space_origin").to_pylist()
            if "ViewBlueprint:space_origin" in b.schema.names
            else [None] * len(cls)
        )
        for c, o in zip(cls, org):
            c = c[0] if isinstance(c, list) else c
            o = o[0] if isinstance(o, list) else o
            views.setdefault(c, []).append(o)
    return views
