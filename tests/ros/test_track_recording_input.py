"""``mps track --recording``: a node's recording of the press it followed, tracked again offline,
gives the node's live estimates bit for bit; a recording it cannot read is named.

The node is driven in this process, without ROS processes: an emulated press's messages (the
emulator's grouping, its glitches) handed to the node's own source
(:class:`~mps_ros.ros.tracking_source.TrackingSource`: rclpy's deserialization, the shared
reading of :mod:`mps_ros.wire.measured`) and its tracking run, recorded by a recording sink as
the node records. The end-to-end test with the node's process (``test_tracking_node.py``)
compares the same over DDS.
"""

from __future__ import annotations

import csv
import inspect
import math
from pathlib import Path

import pytest
from sqlite_bags import as_sqlite3_bag
from track_estimates import differences, node_estimates, tracked

from mps_core import load_scene
from mps_core.cli import main
from mps_core.track import Sensors, run_truth, truth_scene
from mps_core.track.measurements import MeasurementError
from mps_core.track.recording_input import SLIDER_VARIANCE, Tuning
from mps_core.track.truth import nominal_scene
from mps_ros.recording.recorder import Recorder
from mps_ros.run.sinks import Fanout, RecordingSink
from mps_ros.run.tracking import TrackingRun
from mps_ros.wire.cdr import joint_state, string
from mps_ros.wire.track_topics import RECEIVED_JOINTS, RECEIVED_MODE

SCENE = "press-cycle"  # idle, engaged by its signal at 8 ms, the stop released, the latch closing
T_END = 0.2
GLITCHES = {40: "jump", 60: "duplicate", 80: "out-of-order"}  # at these messages, as mps emulator --glitch


def _ns(t: float) -> int:
    return int(round(t * 1e9))


def _joints(t: float, angle: float, slider: float | None, torque: float | None = None) -> bytes:
    """Return a press's JointState bytes, as the emulator publishes them (the motor's torque the
    crank's effort, where measured)."""
    ns = _ns(t)
    effort = [] if torque is None else [torque] + ([math.nan] if slider is not None else [])
    return joint_state(
        {
            "header": {"stamp": {"sec": ns // 10**9, "nanosec": ns % 10**9}, "frame_id": "press"},
            "name": ["crank"] + (["slider"] if slider is not None else []),
            "position": [angle] + ([slider] if slider is not None else []),
            "velocity": [],
            "effort": effort,
        }
    )


def follow(
    tmp: Path, clock_ns: int = 0, torque: bool = False, late_ns: int = 12_345, tuning: Tuning | None = None
) -> tuple[TrackingRun, list[Path]]:
    """Follow the emulated press with the node's source and run; record it as a file and a bag.

    Each message goes to the node ``clock_ns`` after its stamp on the middleware's clock (its
    source timestamp); a mode signal before the first measurement at or after its time, as
    the emulator sends them, ``late_ns`` after its command; ``torque``: the motor's torque
    measured too; ``tuning``: the node's parameters other than its defaults, recorded as the
    node records them. Return the run and the recordings.
    """
    from mps_ros.ros.emulator import samples
    from mps_ros.ros.tracking_source import TrackingSource

    nominal = nominal_scene(load_scene(SCENE))
    sensors = Sensors(slider=True, motor_torque=torque)
    truth = run_truth(truth_scene(nominal), T_END, sensors=sensors, seed=0)
    paths = [tmp / "node.mcap", tmp / "node-bag"]
    meta = None if tuning is None else tuning.metadata()
    recorders = [Recorder(p, scene_name=nominal.name, scene_text=nominal.text, metadata=meta) for p in paths]
    tuning = tuning or Tuning(signal_latency=0.01)  # the node's, its mode topic given
    names = {RECEIVED_JOINTS.key: "/press/joint_states", RECEIVED_MODE.key: "/press/mode"}
    sinks = Fanout([RecordingSink(r, names=names) for r in recorders])
    said: list[tuple[str, str]] = []
    run = TrackingRun(
        load_scene(SCENE),
        sinks,
        late_after=math.inf,
        settings=tuning.settings(),
        encoder=tuning.encoder,
        torque_sensor=tuning.torque,
        log=lambda level, line: said.append((level, line)),
    )
    run.said = said
    source = TrackingSource(None, run)  # its callbacks use the run only
    todo = sorted(truth.modes, key=lambda s: s.t)
    prev = None
    for i, s in enumerate(samples(truth.measurements)):
        info = {"source_timestamp": clock_ns + _ns(s.t), "received_timestamp": clock_ns + _ns(s.t) + 90_000}
        while todo and todo[0].t + late_ns * 1e-9 <= s.t:
            m = todo.pop(0)
            source.on_mode(string({"data": m.command}), {"source_timestamp": clock_ns + _ns(m.t) + late_ns})
        glitch = GLITCHES.get(i)
        angle = s.angle + math.radians(20.0) if glitch == "jump" else s.angle
        source.on_measurement(_joints(s.t, angle, s.slider, s.torque), info)
        if glitch == "duplicate":
            source.on_measurement(_joints(s.t, angle, s.slider, s.torque), info)
        if glitch == "out-of-order" and prev is not None:
            source.on_measurement(_joints(0.5 * (prev.t + s.t), prev.angle, prev.slider), info)
        prev = s
    for r in recorders:
        r.finish()
    return run, paths


@pytest.fixture(scope="module")
def followed(tmp_path_factory):
    """The node's run over 0.2 s of press-cycle's truth (slider scale, engage signal, glitches)."""
    return follow(tmp_path_factory.mktemp("followed"))


def test_mps_track_over_the_node_s_recording_gives_its_live_estimates(followed, tmp_path, capsys):
    run, (mcap, bag) = followed
    assert run.rejected() == {"jump": 1, "duplicate": 2, "out-of-order": 2}  # crank and slider each
    node = node_estimates(mcap)
    assert len(node) == run.estimates == 199
    # the loads computed (as --out FILE.mcap does) change no estimate
    offline = tracked(SCENE, mcap, tmp_path / "est.csv", "--loads")
    said = capsys.readouterr().out
    assert "397 taken; rejected or reported: duplicate 2, jump 1, out-of-order 2" in said
    # the engage signal searched for (on time: kept where it came), said once
    found = [line for _level, line in run.said if "its command found" in line]
    assert len(found) == 1 and "mode signal engage at t = 0.008012" in found[0], found
    assert "found 0.00 ms before it (searched over 10 ms: " in found[0]
    assert differences(node, offline) == dict.fromkeys(differences(node, offline), 0.0)
    assert all(offline[t] == est for t, est in node.items())  # bit for bit, every stamp
    # a bag directory of the same run reads the same
    assert tracked(SCENE, bag, tmp_path / "bag.csv") == offline


def test_a_bag_of_rosbag2_s_sqlite3_storage_reads_as_its_mcap(followed, tmp_path):
    """The node's recording copied into a sqlite3 bag (rosbag2's storage before Iron) is tracked
    again as the MCAP file is: the same estimates, bit for bit (its tuning the defaults, as the
    node's was)."""
    _run, (mcap, _bag) = followed
    bag = as_sqlite3_bag(mcap, tmp_path / "sqlite-bag")
    assert sorted(p.suffix for p in bag.iterdir()) == [".db3", ".yaml"]
    assert tracked(SCENE, bag, tmp_path / "db3.csv") == tracked(SCENE, mcap, tmp_path / "mcap.csv")


def test_a_sqlite_file_that_is_not_a_bag_is_named(tmp_path, capsys):
    import sqlite3

    bag = tmp_path / "not-a-bag"
    bag.mkdir()
    con = sqlite3.connect(bag / "x_0.db3")
    con.execute("CREATE TABLE t (a INTEGER)")
    con.commit()
    con.close()
    assert main(["track", SCENE, "--recording", str(bag)]) == 2
    err = capsys.readouterr().err
    assert "x_0.db3: an SQLite file that is not a rosbag2 bag file (no such table: topics)" in err
    assert "expected the tables topics (id, name, type, serialization_format) and messages" in err


def test_a_late_engage_is_found_where_it_was_and_tracked_again_alike(tmp_path, capsys):
    """The engage signal sent 4 ms after its command: the node's run finds the command there,
    rejects nothing but the glitches, and says so; mps track over its recording gives its
    estimates bit for bit (the same search)."""
    run, (mcap, _bag) = follow(tmp_path, late_ns=4_000_000)
    assert run.rejected() == {"jump": 1, "duplicate": 2, "out-of-order": 2}
    found = [line for _level, line in run.said if "its command found" in line]
    assert len(found) == 1 and "mode signal engage at t = 0.012" in found[0], found
    shift = float(found[0].split("found ")[1].split(" ms")[0])
    assert 3.0 < shift < 5.0, found
    assert "hypotheses, " in found[0] and " ms of CPU holding the measurements up)" in found[0], found
    node = node_estimates(mcap)
    offline = tracked(SCENE, mcap, tmp_path / "est.csv")
    assert "mode signals: 1, their commands found" in capsys.readouterr().out
    assert all(offline[t] == est for t, est in node.items())


def test_the_node_s_own_tuning_is_recorded_and_tracked_again_alike(tmp_path, capsys):
    """A node run with its own encoder, torque sensor, timeout, jump and signals' latency
    records them; mps track over its recording follows with them: the live estimates, bit for
    bit. Tracked with the defaults instead (the tuning left out of the file), they part."""
    from mps_core.track import Encoder, TorqueSensor

    tuning = Tuning(
        Encoder(16, 0.5), TorqueSensor(0.03), timeout=0.08, max_jump_deg=7.0, signal_latency=0.004
    )
    run, (mcap, _bag) = follow(tmp_path, torque=True, late_ns=3_000_000, tuning=tuning)
    node = node_estimates(mcap)
    offline = tracked(SCENE, mcap, tmp_path / "est.csv")
    capsys.readouterr()
    assert all(offline[t] == est for t, est in node.items())
    (tmp_path / "bare").mkdir()
    _, (bare, _bag) = follow(tmp_path / "bare", torque=True, late_ns=3_000_000)  # the defaults
    assert node_estimates(bare) != node  # the tuning moves the estimates: the equality is not given


def test_a_recording_s_tuning_out_of_range_is_named():
    with pytest.raises(MeasurementError, match=r"r.mcap: metadata mps.track_encoder_bits = '40': expected a"):
        Tuning.of({"track_encoder_bits": "40"}, "r.mcap")
    assert Tuning.of({}, "r.mcap") == Tuning()
    t = Tuning(signal_latency=0.004, max_jump_deg=7.0)
    assert Tuning.of(t.metadata(), "r.mcap") == t


def test_without_its_mode_signals_the_engage_is_found_later(followed, tmp_path, capsys):
    _run, (mcap, _bag) = followed
    engaged = {}  # the first estimate out of the idle structure (held)
    for name, extra in (("signalled", []), ("inferred", ["--mode-topic", ""])):
        est = tmp_path / f"{name}.csv"
        assert main(["track", SCENE, "--recording", str(mcap), "--out", str(est), *extra]) == 0
        with est.open() as fh:
            engaged[name] = next(float(r["t"]) for r in csv.DictReader(fh) if r["structure"] != "held")
    capsys.readouterr()
    # the signal at 8 ms; without it, from the slider scale (docs/tracking.md: a few ms later)
    assert 0.008 < engaged["signalled"] < 0.0095 < engaged["inferred"]


def test_the_motor_s_torque_is_taken_live_and_offline_alike(tmp_path, capsys):
    """The crank's effort, the motor's torque: the node takes it as a third measurement, and
    ``mps track`` over the node's recording gives its live estimates bit for bit."""
    run, (mcap, _bag) = follow(tmp_path / "torque", torque=True)
    assert run.tracker.motor_measured
    node = node_estimates(mcap)
    offline = tracked(SCENE, mcap, tmp_path / "est.csv")
    said = capsys.readouterr().out
    assert "595 taken" in said and "the motor's torque: " in said, said
    assert all(offline[t] == est for t, est in node.items())


def test_the_slider_s_variance_is_the_node_s():
    default = inspect.signature(TrackingRun.__init__).parameters["slider_variance"].default
    assert SLIDER_VARIANCE == default


#: the middleware's clock of a real node: the system clock, about 1.79e9 s (its float's step 0.24 µs)
WALL_CLOCK_NS = 1_790_000_000_123_456_789


@pytest.fixture(scope="module")
def followed_on_the_wall_clock(tmp_path_factory):
    """The same run, each message sent on the system clock (the press's clock offset from it)."""
    run, (mcap, _bag) = follow(tmp_path_factory.mktemp("wall"), clock_ns=WALL_CLOCK_NS)
    return node_estimates(mcap), mcap


def test_a_mode_signal_sent_on_the_wall_clock_gives_the_node_s_estimates_bit_for_bit(
    followed_on_the_wall_clock, tmp_path, capsys
):
    """The node applies a mode signal at the time it records it at, to the nanosecond: offline
    it applies at the same time, and every estimate after it is the same."""
    node, mcap = followed_on_the_wall_clock
    offline = tracked(SCENE, mcap, tmp_path / "est.csv")
    capsys.readouterr()
    assert all(offline[t] == est for t, est in node.items())


# -- bad input -------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("args", "said"),
    [
        (
            ["--joints-topic", "/press/encoder"],
            "--joints-topic = '/press/encoder': expected a topic of the recording with "
            "sensor_msgs/msg/JointState messages (it has: ",
        ),
        (
            ["--joints-topic", "/press/mode"],
            "/press/mode: type = 'std_msgs/msg/String': expected sensor_msgs/msg/JointState",
        ),
        (["--mode-topic", "/press/signals"], "--mode-topic = '/press/signals': expected a topic"),
    ],
)
def test_a_topic_missing_or_of_another_type_is_named(followed, capsys, args, said):
    _run, (mcap, _bag) = followed
    assert main(["track", SCENE, "--recording", str(mcap), *args]) == 2
    assert said in capsys.readouterr().err


def _recording(path: Path, joints: list[bytes], modes: list[tuple[int, str]] = ()) -> Path:
    """Write a small recording of the press's topics."""
    with Recorder(path) as rec:
        for k, data in enumerate(joints):
            rec.write("/press/joint_states", "sensor_msgs/msg/JointState", data, (k + 1) * 1_000_000)
        for t_ns, word in modes:
            rec.write("/press/mode", "std_msgs/msg/String", string({"data": word}), t_ns)
    return path


def test_a_message_without_a_crank_angle_is_named(tmp_path, capsys):
    rocker = joint_state(
        {
            "header": {"stamp": {"sec": 0, "nanosec": 2_000_000}, "frame_id": "press"},
            "name": ["rocker"],
            "position": [0.25],
            "velocity": [],
            "effort": [],
        }
    )
    rec = _recording(tmp_path / "r.mcap", [_joints(0.001, 0.5, None), rocker])
    assert main(["track", SCENE, "--recording", str(rec)]) == 2
    err = capsys.readouterr().err
    assert (
        "/press/joint_states: message 1 (log time 2000000 ns): name, position = (['rocker'], [0.25])" in err
    )
    assert "expected a crank angle: the position of a joint named 'crank'" in err


def test_a_bad_mode_signal_and_a_bad_path_are_named(tmp_path, capsys):
    rec = _recording(tmp_path / "r.mcap", [_joints(0.001, 0.5, None)], [(1_500_000, "stop")])
    assert main(["track", SCENE, "--recording", str(rec)]) == 2
    assert (
        "/press/mode: message at log time 1500000 ns: data = 'stop': expected one of engage, disengage"
        in (capsys.readouterr().err)
    )
    csv_file = tmp_path / "m.csv"
    csv_file.write_text("t,crank_angle_rad\n")
    assert main(["track", SCENE, "--recording", str(csv_file)]) == 2
    assert f"--recording = '{csv_file}': expected an .mcap file or a bag directory" in capsys.readouterr().err
    assert main(["track", SCENE, "--csv", str(csv_file), "--joints-topic", "/x"]) == 2
    assert "--joints-topic = '/x': expected --recording FILE with it" in capsys.readouterr().err


@pytest.mark.parametrize("slider", [None, 0.0123])
def test_the_emulator_s_joint_state_carries_the_torque_as_the_node_reads_it(slider):
    """The emulator's message (rclpy's, serialized as the middleware sends it) read by the node's
    reader: the crank's effort is the motor's torque, the slider's NaN effort none of it."""
    from rclpy.serialization import serialize_message

    from mps_ros.recording.replay import joint_state_readings
    from mps_ros.ros.emulator import Samples, _joint_state
    from mps_ros.wire.measured import crank_and_slider, crank_torque

    raw = serialize_message(_joint_state(Samples(0.25, 1.5, slider, 31.25)))
    sec, nanosec, names, positions, efforts = joint_state_readings(raw)
    assert (sec, nanosec) == (0, 250_000_000)
    assert crank_and_slider(names, positions) == (1.5, slider)
    assert crank_torque(names, efforts) == 31.25
    plain = serialize_message(_joint_state(Samples(0.25, 1.5, slider)))
    assert crank_torque(*joint_state_readings(plain)[2::2]) is None
