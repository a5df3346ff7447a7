"""Names of the ROS face, defined once: the node, its topics and their types, frames, joints,
the wrenches and what each carries, the outputs a run can be asked for, the QoS it offers.

Pure Python (no rclpy): the node, the recorder, ``mps record`` and the tests all read these.

Topic keys are the names as the node creates them: ``~/x`` is private to the node
(``/press_twin/x`` by default), ``/x`` is absolute, ``x`` is relative to the node's namespace
(``/x`` by default). :func:`resolve` gives the full name without ROS, as ``rclpy`` would.
"""

from __future__ import annotations

from dataclasses import dataclass

NODE_NAME = "press_twin"

#: the press frame: origin at the crank bearing O, x along the slider guide (up), y across,
#: z out of the plane (contract §2); the frame every other frame id here is parallel to
FRAME_ID = "press"

#: joints of ``joint_states``, in order, with what their position, velocity and effort are
JOINTS: tuple[tuple[str, str, str, str], ...] = (
    (
        "crank",
        "phi: the crank angle from x (rad, continuous)",
        "phi_dot (rad/s)",
        "M_motor: the torque the crank receives from the motor (N*m)",
    ),
    ("rod", "the rod's angle from x, direction A->B (rad)", "its rate (rad/s)", "NaN: a passive joint"),
    (
        "rocker",
        "psi: the rocker angle from x, direction C->B (rad, continuous)",
        "psi_dot (rad/s)",
        "M_latch: the moment the slider receives from the rocker through the closed latch (N*m; "
        "0 while the latch is open)",
    ),
    (
        "slider",
        "x_C: the slider's position along the guide (m)",
        "x_C_dot (m/s)",
        "F_stop: the force along x the frame receives from the slider at the top stop (N, "
        "positive when compressed; 0 off the stop)",
    ),
)
JOINT_NAMES = tuple(j[0] for j in JOINTS)


@dataclass(frozen=True)
class Wrench:
    """One geometry_msgs/WrenchStamped topic: which reaction columns fill it, where it acts.

    ``force`` gives the reaction columns for force.x and force.y (None: zero); ``torque`` the
    column for torque.z. The frame ``frame_id`` is parallel to the press frame with its origin
    at ``point``, so the torque is about that point (ROS's convention for a wrench)."""

    name: str
    frame_id: str
    point: str
    force: tuple[str | None, str | None]
    torque: str | None
    meaning: str

    @property
    def key(self) -> str:
        return "~/foundation" if self.name == "foundation" else f"~/reactions/{self.name}"

    @property
    def columns(self) -> tuple[str, ...]:
        return tuple(c for c in (*self.force, self.torque) if c is not None)


#: one wrench a joint reaction (contract §7; signs as ``mps_core.dynamics.reactions``: what the
#: *receiving* body gets), then the foundation resultant
WRENCHES: tuple[Wrench, ...] = (
    Wrench("O", "press", "O", ("F_O_x", "F_O_y"), None, "the force the frame receives from the crank at O"),
    Wrench("A", "press_A", "A", ("F_A_x", "F_A_y"), None, "the force the crank receives from the rod at A"),
    Wrench("B", "press_B", "B", ("F_B_x", "F_B_y"), None, "the force the rod receives from the rocker at B"),
    Wrench(
        "C", "press_C", "C", ("F_C_x", "F_C_y"), None, "the force the slider receives from the rocker at C"
    ),
    Wrench(
        "guide",
        "press_C",
        "C",
        (None, "N_guide"),
        "M_guide",
        "the force (along y) and moment the frame receives from the slider through the guide",
    ),
    Wrench(
        "latch",
        "press_C",
        "C",
        (None, None),
        "M_latch",
        "the moment the slider receives from the rocker through the closed latch (0 open)",
    ),
    Wrench(
        "stop",
        "press_C",
        "C",
        ("F_stop", None),
        None,
        "the force along x the frame receives from the slider at the top stop (positive "
        "when compressed; 0 off the stop)",
    ),
    Wrench(
        "motor",
        "press",
        "O",
        (None, None),
        "M_motor",
        "the torque the crank receives from the motor (the frame receives its opposite through the stator)",
    ),
)
FOUNDATION = Wrench(
    "foundation",
    "press",
    "O",
    ("F_found_x", "F_found_y"),
    "M_found_O",
    "the resultant the frame receives from the moving links and the effects "
    "(the load on the foundation), moment about O",
)


@dataclass(frozen=True)
class Topic:
    key: str
    msgtype: str
    output: str  # the output that enables it ("" : always there)
    meaning: str


#: outputs a run can be asked for; reactions are solved only if "reactions" or "foundation" is
OUTPUTS = (
    "joint_states",
    "reactions",
    "foundation",
    "clock",
    "structure",
    "events",
    "diagnostics",
    "markers",
    "tf",
)

TOPICS: tuple[Topic, ...] = (
    Topic(
        "joint_states",
        "sensor_msgs/msg/JointState",
        "joint_states",
        "crank, rod, rocker angles and the slider position, rates, efforts; every step",
    ),
    *(Topic(w.key, "geometry_msgs/msg/WrenchStamped", "reactions", w.meaning) for w in WRENCHES),
    Topic(FOUNDATION.key, "geometry_msgs/msg/WrenchStamped", "foundation", FOUNDATION.meaning),
    Topic("/clock", "rosgraph_msgs/msg/Clock", "clock", "the simulated time, every step"),
    Topic(
        "~/structure", "std_msgs/msg/String", "structure", "the structure at this step: free, held or locked"
    ),
    Topic(
        "~/events",
        "std_msgs/msg/String",
        "events",
        "one JSON object an event (the core's event log: commands, impacts, chart changes; "
        "run-start and run-end)",
    ),
    Topic(
        "/diagnostics",
        "diagnostic_msgs/msg/DiagnosticArray",
        "diagnostics",
        "statuses pacing (real-time factor, step time and latency p50/p99, deadline "
        "misses), commands (accepted, refused, floods, lost) and the recording (bytes, "
        "messages; stopped)",
    ),
    Topic(
        "~/markers",
        "visualization_msgs/msg/MarkerArray",
        "markers",
        "the press drawn for RViz2 and Foxglove's 3D panel (frame press), its reaction forces "
        "as arrows; at a display rate (markers_hz)",
    ),
    Topic(
        "/tf",
        "tf2_msgs/msg/TFMessage",
        "tf",
        "the moving frames (press_A, press_B, press_C, press_slider) in press, every step; "
        "published where tf2_msgs can be imported, always recorded",
    ),
    Topic(
        "/tf_static",
        "tf2_msgs/msg/TFMessage",
        "tf",
        "the fixed frames: press in the z-up press_base, press_O in press; once, latched",
    ),
    Topic(
        "~/mode/status",
        "std_msgs/msg/String",
        "",
        "one JSON object a command received: accepted or refused, why, at which time",
    ),
)
#: commands in (the node subscribes; recordings hold what it received)
MODE = Topic("~/mode", "std_msgs/msg/String", "", "mode commands: engage, disengage, stop, start")
BY_KEY = {t.key: t for t in (*TOPICS, MODE)}

MSGTYPES = sorted({t.msgtype for t in (*TOPICS, MODE)})

#: each message type's type description hash (REP 2011) in Jazzy, which a recording's channel
#: carries as ``topic_type_hash`` as rosbag2 writes it (a test checks them against rclpy's
#: and rosbags')
TYPE_HASHES = {
    "diagnostic_msgs/msg/DiagnosticArray": (
        "RIHS01_5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e"
    ),
    "geometry_msgs/msg/WrenchStamped": (
        "RIHS01_8dc3deaf06b2ab281f9f9a742a8961c328ca7cec16e3fd6586d3a5c83fa78f77"
    ),
    "rosgraph_msgs/msg/Clock": "RIHS01_692f7a66e93a3c83e71765d033b60349ba68023a8c689a79e48078bcb5c58564",
    "sensor_msgs/msg/JointState": "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e",
    "std_msgs/msg/String": "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    "tf2_msgs/msg/TFMessage": "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    "visualization_msgs/msg/MarkerArray": (
        "RIHS01_86cb8800b6fb05b5eff1abd7a56f62a5641d3ae9a1c29e78e67e704f1d067dcf"
    ),
}


def resolve(key: str, node: str = NODE_NAME, namespace: str = "/") -> str:
    """The full topic name of ``key`` for a node called ``node`` in ``namespace``."""
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    if key.startswith("~/"):
        return f"{ns}/{node}/{key[2:]}"
    if key.startswith("/"):
        return key
    return f"{ns}/{key}"


# -- QoS offered, as rosbag2 (Jazzy) writes it into a recording's channels ----------------------
DEPTH = 1000
_INFINITE = "    sec: 9223372036\n    nsec: 854775807\n"


def qos_yaml(
    *, depth: int = DEPTH, reliable: bool = True, transient_local: bool = False, keep_all: bool = False
) -> str:
    """``offered_qos_profiles`` of a channel: the YAML rosbag2 writes (policies as words)."""
    return (
        f"- history: {'keep_all' if keep_all else 'keep_last'}\n"
        f"  depth: {0 if keep_all else int(depth)}\n"
        f"  reliability: {'reliable' if reliable else 'best_effort'}\n"
        f"  durability: {'transient_local' if transient_local else 'volatile'}\n"
        "  deadline:\n" + _INFINITE + "  lifespan:\n" + _INFINITE + "  liveliness: automatic\n"
        "  liveliness_lease_duration:\n" + _INFINITE + "  avoid_ros_namespace_conventions: false"
    )


#: the latched topics: offered transient-local, depth 1 (a subscriber that joins late still
#: gets the last message), published when their value changes
LATCHED = ("~/structure", "/tf_static")


def offered_qos(depth: int = DEPTH) -> dict[str, str]:
    """Every topic key's offered QoS as rosbag2's YAML: reliable, keep last ``depth``, volatile;
    the latched topics transient-local with depth 1; the mode commands' subscription keeps
    all (a flood is answered, never dropped unseen)."""
    out = {k: qos_yaml(depth=depth) for k in BY_KEY}
    for k in LATCHED:
        out[k] = qos_yaml(depth=1, transient_local=True)
    out[MODE.key] = qos_yaml(keep_all=True)
    return out


__all__ = [
    "NODE_NAME",
    "FRAME_ID",
    "JOINTS",
    "JOINT_NAMES",
    "Wrench",
    "WRENCHES",
    "FOUNDATION",
    "Topic",
    "TOPICS",
    "MODE",
    "BY_KEY",
    "MSGTYPES",
    "OUTPUTS",
    "DEPTH",
    "resolve",
    "qos_yaml",
    "LATCHED",
    "offered_qos",
]
