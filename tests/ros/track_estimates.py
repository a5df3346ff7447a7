"""A following node's live estimates read out of its recording (rosbags, an independent reader),
and ``mps track``'s over that recording, compared stamp by stamp."""

from __future__ import annotations

import csv
import math
from pathlib import Path

from mps_core.cli import main
from mps_ros.wire.topics import resolve

#: the estimates compared: (the estimates file's column, the recorded topic key, how it is read)
COMPARED = (
    ("phi", "joint_states", lambda m: m.position[0]),
    ("phi_dot", "joint_states", lambda m: m.velocity[0]),
    ("force", "~/process_force/now", lambda m: m.wrench.force.x),
    ("force_sigma", "~/process_force/now/sigma", lambda m: m.wrench.force.x),
    ("force_smoothed", "~/process_force", lambda m: m.wrench.force.x),
    ("force_smoothed_sigma", "~/process_force/sigma", lambda m: m.wrench.force.x),
)


def node_estimates(path: Path) -> dict[int, dict[str, float]]:
    """Return the node's estimates by their stamp (ns): each compared column, as it published them."""
    from rosbags.highlevel import AnyReader

    topics = {
        resolve(key): [(col, read) for col, k, read in COMPARED if k == key] for _c, key, _r in COMPARED
    }
    out: dict[int, dict[str, float]] = {}
    with AnyReader([path]) as reader:
        conns = [c for c in reader.connections if c.topic in topics]
        for conn, t_ns, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            for col, read in topics[conn.topic]:
                out.setdefault(t_ns, {})[col] = float(read(msg))
    return out


def tracked(scene: str, recording: Path, out: Path, *extra: str) -> dict[int, dict[str, float]]:
    """Run ``mps track SCENE --recording RECORDING`` and return its estimates by stamp (ns).

    The last row of a stamp: a message's crank angle and slider position are two measurements,
    the node publishes after both.
    """
    assert main(["track", scene, "--recording", str(recording), "--out", str(out), *extra]) == 0
    rows: dict[int, dict[str, float]] = {}
    with out.open() as fh:
        for r in csv.DictReader(fh):
            rows[int(round(float(r["t"]) * 1e9))] = {c: float(r[c]) for c, *_ in COMPARED}
    return rows


def differences(node: dict[int, dict[str, float]], offline: dict[int, dict[str, float]]) -> dict[str, float]:
    """Return the largest difference of each compared column over the node's stamps (inf: a stamp missing)."""
    worst = {c: 0.0 for c, *_ in COMPARED}
    for t, est in node.items():
        row = offline.get(t)
        for c in worst:
            d = math.inf if row is None else abs(row[c] - est[c])
            worst[c] = max(worst[c], d)
    return worst
