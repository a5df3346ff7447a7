"""The views that ship with the node (config/press_twin.rviz, config/press_twin.foxglove.json)
name what the node publishes: its topics with their types, fields that its messages have, frames
that its /tf gives. Neither RViz2 nor Foxglove is here to open them: this holds them to the
node's names, so that a renamed topic or field fails here first."""

from __future__ import annotations

import json
from pathlib import Path

import yaml

from mps_core.scene.settings import COMMANDS
from mps_ros.ros.foxglove_link import LIFECYCLE_WORDS
from mps_ros.run.twin import Twin
from mps_ros.wire.frames import BASE_FRAME, FIXED, MOVING
from mps_ros.wire.topics import BY_KEY, FOUNDATION, FRAME_ID, WRENCHES, resolve

CONFIG = Path(__file__).resolve().parents[2] / "config"
TOPICS = {resolve(k): t.msgtype for k, t in BY_KEY.items()}
FRAMES = {BASE_FRAME, FRAME_ID, *(f for f, _ in FIXED), *(f for f, _ in MOVING)}


def test_the_rviz_config_names_the_nodes_topics_and_frames():
    cfg = yaml.safe_load((CONFIG / "press_twin.rviz").read_text())
    vm = cfg["Visualization Manager"]
    assert vm["Global Options"]["Fixed Frame"] == BASE_FRAME
    types = {
        "rviz_default_plugins/Wrench": "geometry_msgs/msg/WrenchStamped",
        "rviz_default_plugins/MarkerArray": "visualization_msgs/msg/MarkerArray",
    }
    shown = set()
    for d in vm["Displays"]:
        if "Topic" in d:
            topic = d["Topic"]["Value"]
            assert TOPICS.get(topic) == types[d["Class"]], (d["Name"], topic)
            shown.add(topic)
        if "Reference Frame" in d:
            assert d["Reference Frame"] in FRAMES
    assert {resolve(w.key) for w in (*WRENCHES, FOUNDATION)} | {resolve("~/markers")} == shown


def _field(msg: dict, path: str):
    for part in path.split("."):
        msg = msg[part]
    return msg


def test_the_foxglove_layout_names_the_nodes_topics_fields_and_frames():
    layout = json.loads((CONFIG / "press_twin.foxglove.json").read_text())
    panels = layout["configById"]

    def leaves(node):
        if isinstance(node, str):
            return [node]
        return leaves(node["first"]) + leaves(node["second"])

    assert sorted(leaves(layout["layout"])) == sorted(panels)
    # a step's messages, to find each path's field in
    tw = Twin("press-cycle", dt=1e-3, t_end=0.01)
    msgs = {resolve(k): m for k, m in tw.state_messages()}
    msgs["/press_twin/events"] = {"data": ""}
    paths = []
    services = []
    for pid, cfg in panels.items():
        kind = pid.split("!")[0]
        if kind == "3D":
            assert cfg["followTfFrame"] in FRAMES
            assert all(layer.get("frameId", BASE_FRAME) in FRAMES for layer in cfg["layers"].values())
            assert set(cfg["topics"]) <= set(TOPICS)
        elif kind in ("Plot", "StateTransitions"):
            paths += [p["value"] for p in cfg["paths"]]
        elif kind == "RawMessages":
            assert cfg["topicPath"] in TOPICS
        elif kind == "DiagnosticSummary":
            assert TOPICS[cfg["topicToRender"]] == "diagnostic_msgs/msg/DiagnosticArray"
        elif kind == "CallService":  # a button a service of the node's Foxglove endpoint
            services.append(cfg["serviceName"])
            assert cfg["requestPayload"] == "{}", pid  # std_srvs/srv/Trigger: an empty request
    # every service the endpoint offers has its button (mps_ros.ros.foxglove_link)
    assert sorted(services) == sorted(f"/press_twin/{w}" for w in (*COMMANDS, *LIFECYCLE_WORDS))
    assert paths
    for p in paths:
        topic, field = p.split(".", 1)
        assert topic in TOPICS, p
        assert isinstance(_field(msgs[topic], field), (float, str)), p
