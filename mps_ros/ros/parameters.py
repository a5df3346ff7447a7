"""The node's parameters, in one table: each one's name, default (and so its type), range and
description. The node declares them from it (read-only, typed, with the range that rclpy
enforces and the description that ``describe_parameters`` gives); docs/ros.md's table is
:func:`markdown_table` (a test compares them), and ``config/press_twin.yaml`` sets each one.

A number outside its range, or of the wrong type, ends the node at once with one line that
names the parameter, the value and what was expected; an integer is taken where a real number
is expected (``-p t_end:=20``)."""

from __future__ import annotations

from dataclasses import dataclass, replace

from mps_core.derivatives import SCHEMES
from mps_core.track.settings import SIGNAL_LATENCY

from ..run.runner import PACINGS
from ..run.twin import check_outputs
from ..wire.topics import OUTPUTS


class ParameterError(ValueError):
    """A parameter the node was given that it cannot take (its name, value, what it expects)."""


@dataclass(frozen=True)
class Parameter:
    """One parameter. ``default``: its value where none is given (its type too: str, bool,
    int, float, or a list of str); ``lo``/``hi``: its range, bounds included (numbers only);
    ``choices``: the strings it may be; ``shown``: the default as the docs say it, where that
    is not the value itself; ``description``: Markdown, one paragraph."""

    name: str
    default: object
    description: str
    lo: float | None = None
    hi: float | None = None
    choices: tuple[str, ...] = ()
    shown: str | None = None

    @property
    def kind(self) -> str:
        d = self.default
        if isinstance(d, bool):
            return "bool"
        if isinstance(d, int):
            return "integer"
        if isinstance(d, float):
            return "double"
        if isinstance(d, list):
            return "string_array"
        return "string"

    def expected(self) -> str:
        """What a value must be, in words (for a refusal)."""
        if self.choices:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        what = {
            "bool": "true or false",
            "integer": "an integer",
            "double": "a number",
            "string_array": "a list of words such as [joint_states, clock]",
            "string": "a string",
        }[self.kind]
        if self.lo is not None and self.hi is not None:
            what += f" from {_number(self.lo)} to {_number(self.hi)}"
        return what


P = Parameter
#: every parameter of the node, in the order the docs list them
PARAMETERS: tuple[Parameter, ...] = (
    P(
        "scene",
        "press-cycle",
        "preset name or scene file",
        shown="the command line's SCENE, else `press-cycle`",
    ),
    P(
        "autostart",
        True,
        "configure and activate at start, and run; false: wait unconfigured "
        "for a lifecycle manager (`~/change_state`: configure, activate; deactivate pauses, "
        "activate goes on; cleanup or shutdown ends the run)",
    ),
    P(
        "pacing",
        "realtime",
        "how the steps are paced: at their simulated times on the wall "
        "clock (scaled by `real_time_factor`), or as fast as the machine goes",
        choices=PACINGS,
    ),
    P("real_time_factor", 1.0, "simulated seconds per wall second, in realtime pacing", lo=1e-3, hi=1e3),
    P(
        "dt",
        0.0,
        "the step (s); 0: the scene's. press-cycle's own step is 1e-4 s: use `dt:=0.001` for real time",
        lo=0.0,
        hi=1.0,
    ),
    P("t_end", 0.0, "the end time (s); 0: the scene's", lo=0.0, hi=1e9),
    P(
        "derivatives",
        "",
        "the Lagrange equations' derivatives: `central` (the seed's finite "
        "differences, the `paper` scene's) or `autodiff` (exact, press-cycle's); empty: the "
        "scene's. Exact derivatives cost the node less and let the reactions read the step's "
        "own motion (measured under Performance)",
        choices=("", *SCHEMES),
    ),
    P(
        "publish_every",
        1,
        "publish (and record) every N-th step; commands and events are taken at every step",
        lo=1,
        hi=1_000_000,
    ),
    P(
        "outputs",
        list(OUTPUTS),
        "what to compute and publish, a list of "
        + ", ".join(f"`{o}`" for o in OUTPUTS)
        + "; the reactions are solved only if "
        "`reactions` or `foundation` is asked for",
        shown="all",
    ),
    P(
        "recording",
        "auto",
        "an MCAP path (`….mcap`), never an existing file (one line and "
        "exit status 2), or a new directory: a bag as rosbag2 writes one "
        "(`metadata.yaml`, its files split by `recording_max_mb`, `recording_max_s`); `auto`: "
        "`recordings/SCENE-DATE-TIME-MS.mcap`, created exclusively; `none` or empty: no "
        "recording. Written by a process of its own, off the steps' time",
    ),
    P("recording_max_mb", 0.0, "a bag: a new file once one holds this many MB (0: never)", lo=0.0, hi=1e6),
    P(
        "recording_max_s",
        0.0,
        "a bag: a new file once one spans this many simulated seconds (0: never)",
        lo=0.0,
        hi=1e9,
    ),
    P(
        "recording_compression",
        "zstd",
        "the recording's chunks compressed with `zstd`, "
        "`lz4` (faster, larger) or not at all (`none`); readers take all three",
        choices=("zstd", "lz4", "none"),
    ),
    P(
        "recording_flush_period",
        1.0,
        "wall seconds after which a chunk is written even if not full",
        lo=0.01,
        hi=3600.0,
    ),
    P(
        "scene_commands",
        True,
        "apply the scene's own `[[commands]]`; false: an operator sends them on `~/mode`",
    ),
    P(
        "qos_depth",
        1000,
        "history depth of every publisher (keep last, reliable) but "
        "`~/structure`, which is latched (see QoS)",
        lo=1,
        hi=1_000_000,
    ),
    P(
        "wait_for_subscribers",
        0,
        "start stepping once every published topic has this many subscribers ...",
        lo=0,
        hi=10_000,
    ),
    P("wait_for_commanders", 0, "... and `~/mode` this many publishers ...", lo=0, hi=10_000),
    P(
        "wait_for_foxglove",
        0,
        "... and the Foxglove endpoint this many clients subscribed to every channel ...",
        lo=0,
        hi=10_000,
    ),
    P("wait_timeout", 10.0, "... or after this many seconds", lo=0.0, hi=86400.0),
    P(
        "start_delay",
        0.0,
        "then wait this many wall seconds more, e.g. for discovery to settle both ways",
        lo=0.0,
        hi=3600.0,
    ),
    P("command_burst", 10, "the flood limit: at most this many commands at once ...", lo=1, hi=1_000_000),
    P(
        "command_rate",
        20.0,
        "... then this many a second; the rest are refused (see Commands)",
        lo=1e-3,
        hi=1e6,
    ),
    P("diagnostics_period", 1.0, "wall seconds between `/diagnostics` messages", lo=0.01, hi=3600.0),
    P(
        "realtime_priority",
        40,
        "realtime pacing: SCHED_FIFO priority of the stepping process and the "
        "publishing thread (below the kernel's threaded interrupt handlers at 50); where the "
        "system refuses it, one warning that says how to allow it, and the run goes on at "
        "normal priority (see Real-time scheduling). 0: normal scheduling",
        lo=0,
        hi=99,
    ),
    P(
        "stepping_process",
        True,
        "the twin steps in a process of its own "
        "(`mps_ros/run/stepping.py`; as fast as possible, where the twin can come back to a step); "
        "false: in the node's process, a thread beside the publishing one in realtime pacing "
        "(both measured under Performance)",
    ),
    P(
        "markers_hz",
        30.0,
        "`~/markers` (the press drawn for RViz2 and Foxglove) this many "
        "times a simulated second at most, never more often than the steps",
        lo=1e-3,
        hi=1e6,
    ),
    P("markers_scale", 2e6, "the markers' arrows: newtons a metre of arrow", lo=1e-3, hi=1e15),
    P(
        "lead",
        0.1,
        "realtime pacing: steps are computed up to this many wall seconds ahead "
        "of their deadlines and released at them (0: one step's period, nothing banked); see "
        "Steps and pacing",
        lo=0.0,
        hi=1.0,
    ),
    P(
        "command_delay",
        0.05,
        "realtime pacing with steps banked: a command takes effect at the "
        "first step boundary at least this many wall seconds after it arrives (a fixed, stated "
        "delay; 0: the first boundary after it arrives, at the cost of deadlines), time for the "
        "stepping process to redo the steps after it with steps still banked; see Steps and pacing",
        lo=0.0,
        hi=1.0,
    ),
    P(
        "release_slice",
        1e-4,
        "realtime pacing: the scheduler slice (s) the publishing thread "
        "asks for, 0.0001 at least, where the system grants one (Linux 6.12 on, no privilege "
        "needed; its nice value is kept): the subscribers' threads that its messages wake then "
        "preempt it less often. 0: none asked (the system's). The node's last log line says "
        "what was granted",
        lo=0.0,
        hi=0.1,
    ),
    P(
        "release_period",
        0.0,
        "realtime pacing: the publishing thread wakes about once per "
        "this many wall seconds and sends every step whose deadline has passed, each at most "
        "this less one step's period after its deadline. 0, or anything up to one step's "
        "period: each step at its deadline, one wake-up a step. 0.002 at 1 kHz: the steps go "
        "out in pairs, the first of each 1 ms late, for less CPU (both measured under "
        "Performance)",
        lo=0.0,
        hi=0.1,
    ),
    P(
        "foxglove_port",
        0,
        "serve a Foxglove WebSocket endpoint on this port (0: none): every topic as published and "
        "recorded, the mode commands and the lifecycle's pause, resume and step as services, the "
        "parameters; served by the recording process (see Foxglove, live), so it needs a recording",
        lo=0,
        hi=65535,
    ),
    P(
        "foxglove_address",
        "127.0.0.1",
        "the address the Foxglove endpoint listens on: this machine only by default; another "
        "(`0.0.0.0`: every interface) only when given",
    ),
    P(
        "track",
        "",
        "follow a press: the `sensor_msgs/JointState` topic of its crank encoder (joint `crank`, rad, "
        "stamped with the measurement's time; optionally joint `slider`, m), e.g. `/press/joint_states`; "
        "each measurement updates the tracker at its stamp and the estimate is published as the "
        "simulator's steps are, with the 1-σ of each wrench (`…/sigma`) and the process force; the run "
        "goes on until the node is stopped. Empty: simulate (see Following a press)",
    ),
    P(
        "track_mode",
        "",
        "following a press: the `std_msgs/String` topic of its mode signals (`engage`, "
        "`disengage`); empty: none",
    ),
    P(
        "track_signal_latency",
        SIGNAL_LATENCY,
        "following a press: how late a mode signal may come after its command took effect (s; a "
        "String has no stamp): the command is searched for over that window before the signal, the "
        "measurements since taken again (docs/tracking.md, Late mode signals); 0: applied when it comes",
        lo=0.0,
        hi=0.1,
    ),
    P(
        "track_encoder_bits",
        17,
        "following a press: the crank encoder's bits a turn (the angle's variance LSB²/12 + noise)",
        lo=8,
        hi=32,
    ),
    P(
        "track_encoder_noise",
        0.3,
        "following a press: the crank encoder's electrical noise (counts, 1-σ)",
        lo=0.0,
        hi=1e3,
    ),
    P(
        "track_torque_noise",
        0.02,
        "following a press: the motor torque's noise as a share of its reading (1-σ; of 1 N·m's "
        "below 1 N·m), where the crank's effort carries it",
        lo=1e-6,
        hi=1.0,
    ),
    P(
        "track_timeout",
        0.05,
        "following a press: a measurement later than this many seconds after the last one taken "
        "(its stamp: counted as `gap`, not screened for a jump, the crank acquired again where the "
        "model drifted off it; wall time: as `timeout`, WARN in /diagnostics while it lasts)",
        lo=1e-3,
        hi=3600.0,
    ),
    P(
        "track_max_jump",
        10.0,
        "following a press: a crank angle this many degrees or more from where its rate takes it "
        "is rejected (`jump`)",
        lo=0.1,
        hi=180.0,
    ),
    P(
        "track_max_behind",
        0.25,
        "following a press: a measurement taken this many seconds after it arrived updates the "
        "estimate, which is not published (counted, said, WARN in /diagnostics: the node catches "
        "up with its press); 0: every estimate published however late",
        lo=0.0,
        hi=3600.0,
    ),
    P(
        "track_sigma_every",
        10,
        "following a press: the wrenches' 1-σ (`…/sigma`) computed and published every this many estimates "
        "(each costs 2n more evaluations and 2n + 3 reaction solves: at every one the node keeps "
        "1 kHz on two cores only where little else runs, see Following a press)",
        lo=1,
        hi=1e6,
    ),
)
del P

BY_NAME = {p.name: p for p in PARAMETERS}


def descriptor(p: Parameter, scene: str | None = None):
    """The rclpy ``(name, default, ParameterDescriptor)`` to declare ``p`` with (``scene``:
    the default scene, the command line's)."""
    from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType

    kind = {
        "bool": ParameterType.PARAMETER_BOOL,
        "integer": ParameterType.PARAMETER_INTEGER,
        "double": ParameterType.PARAMETER_DOUBLE,
        "string_array": ParameterType.PARAMETER_STRING_ARRAY,
        "string": ParameterType.PARAMETER_STRING,
    }[p.kind]
    d = ParameterDescriptor(name=p.name, type=kind, description=p.description, read_only=True)
    if p.choices:
        d.additional_constraints = "one of " + ", ".join(repr(c) for c in p.choices)
    if p.lo is None or p.hi is None:
        pass
    elif p.kind == "double":
        d.floating_point_range = [FloatingPointRange(from_value=float(p.lo), to_value=float(p.hi), step=0.0)]
    elif p.kind == "integer":
        d.integer_range = [IntegerRange(from_value=int(p.lo), to_value=int(p.hi), step=0)]
    default = scene if (p.name == "scene" and scene) else p.default
    return p.name, default, d


def _number(x: object) -> str:
    return f"{x:g}".replace("e+0", "e").replace("e+", "e").replace("e-0", "e-")


def markdown_table() -> str:
    """docs/ros.md's table of the parameters."""
    rows = ["| parameter | default | range | meaning |", "|---|---|---|---|"]
    for p in PARAMETERS:
        if p.shown is not None:
            shown = p.shown
        elif p.kind == "bool":
            shown = str(p.default).lower()
        elif p.kind == "string":
            shown = f"`{p.default}`" if p.default else '""'
        elif p.kind == "double":
            shown = _number(p.default)
            shown += "" if ("." in shown or "e" in shown) else ".0"
        else:
            shown = _number(p.default)
        rng = (
            f"{_number(p.lo)} to {_number(p.hi)}"
            if p.lo is not None
            else ", ".join(f"`{c}`" if c else '""' for c in p.choices)
        )
        rows.append(f"| `{p.name}` | {shown} | {rng} | {p.description} |")
    return "\n".join(rows) + "\n"


@dataclass(frozen=True)
class NodeSettings:
    """The node's parameters as read and checked (:func:`read`), a field each, in the order of
    :data:`PARAMETERS` (whose descriptions say what each one means)."""

    scene: str
    autostart: bool
    pacing: str
    real_time_factor: float
    dt: float
    t_end: float
    derivatives: str
    publish_every: int
    outputs: tuple[str, ...]
    recording: str
    recording_max_mb: float
    recording_max_s: float
    recording_compression: str
    recording_flush_period: float
    scene_commands: bool
    qos_depth: int
    wait_for_subscribers: int
    wait_for_commanders: int
    wait_for_foxglove: int
    wait_timeout: float
    start_delay: float
    command_burst: int
    command_rate: float
    diagnostics_period: float
    realtime_priority: int
    stepping_process: bool
    markers_hz: float
    markers_scale: float
    lead: float
    command_delay: float
    release_slice: float
    release_period: float
    foxglove_port: int
    foxglove_address: str
    track: str
    track_mode: str
    track_signal_latency: float
    track_encoder_bits: int
    track_encoder_noise: float
    track_torque_noise: float
    track_timeout: float
    track_max_jump: float
    track_max_behind: float
    track_sigma_every: int

    @classmethod
    def defaults(cls, **given: object) -> NodeSettings:
        """Return the settings of a node given nothing but ``given`` (checked as :func:`read`)."""
        values = {p.name: p.default for p in PARAMETERS}
        unknown = sorted(set(given) - set(values))
        if unknown:
            raise ParameterError(
                f"unknown parameter {unknown[0]}: expected one of {', '.join(sorted(BY_NAME))}"
            )
        values.update(given)
        return checked(values)


# -- the node's parameters declared and read -----------------------------------------------
def declare(node, scene: str) -> None:
    """Every parameter of :data:`~mps_ros.ros.parameters.PARAMETERS`, typed and read-only, its
    range enforced by rclpy: a value of the wrong type or out of range ends the node."""
    from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
    from rclpy.parameter import Parameter as Given

    given = getattr(node, "_parameter_overrides", None) or {}
    for p in PARAMETERS:
        v = given.get(p.name)
        if p.kind == "double" and v is not None and v.type_ == Given.Type.INTEGER:
            # an integer where a real number is expected: taken as one (-p t_end:=20)
            given[p.name] = v = Given(p.name, value=float(v.value))
        try:
            node.declare_parameter(*descriptor(p, scene))
        except (InvalidParameterTypeException, InvalidParameterValueException):
            shown = p.default if v is None else v.value
            raise ParameterError(f"parameter {p.name}: {shown!r}: expected {p.expected()}") from None


def read(node) -> NodeSettings:
    """The parameters' values as the node was given them, checked (the choices, the outputs,
    the release slice): :class:`ParameterError` names the first that is wrong."""
    # a parameter given (-p, a parameters file for this node) that the node does not have:
    # refused, not ignored (a typo would otherwise run with the default, without a word);
    # rclpy keeps what it was given in _parameter_overrides, and declares use_sim_time
    given = getattr(node, "_parameter_overrides", {}) or {}
    unknown = sorted(n for n in given if not node.has_parameter(n))
    if unknown:
        raise ParameterError(
            f"unknown parameter{'s' if len(unknown) > 1 else ''} "
            f"{', '.join(unknown)}: expected one of "
            f"{', '.join(sorted(BY_NAME))}"
        )
    return checked({p.name: node.get_parameter(p.name).value for p in PARAMETERS})


def checked(values: dict[str, object]) -> NodeSettings:
    """Return ``values`` (a value for every parameter) as :class:`NodeSettings`, each checked
    beyond what rclpy enforces (the choices, the outputs, the release slice):
    :class:`ParameterError` names the first that is wrong."""
    for p in PARAMETERS:
        v = values[p.name]
        if p.kind == "double" and isinstance(v, int) and not isinstance(v, bool):
            values[p.name] = v = float(v)
        if p.choices and v not in p.choices:
            raise ParameterError(f"parameter {p.name}: {v!r}, expected {p.expected()}")
    try:
        outputs = check_outputs(values["outputs"])  # type: ignore[arg-type]
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"parameter outputs: {exc}") from None
    settings = NodeSettings(**values)  # type: ignore[arg-type]
    settings = replace(settings, outputs=outputs, recording=settings.recording.strip())
    if 0.0 < settings.release_slice < 1e-4:
        raise ParameterError(
            f"parameter release_slice: {settings.release_slice!r} must be 0 "
            "(the system's) or from 0.0001 to 0.1 s"
        )
    return settings


__all__ = [
    "NodeSettings",
    "Parameter",
    "ParameterError",
    "PARAMETERS",
    "BY_NAME",
    "declare",
    "descriptor",
    "markdown_table",
    "checked",
    "read",
]
