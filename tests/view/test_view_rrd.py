"""``mps view REC.mcap --save FILE.rrd --no-spawn``: the .rrd read back with rerun's own reader
holds the expected entities, one sample a step, and the recording's values."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("rerun")

from test_view_replay import rosbags_read
from view_helpers import read_blueprint, read_rrd

from mps_core.cli import main
from mps_ros.recording.replay import read_recording
from mps_ros.view.offline import BEARING, FAMILIES, MARKERS, positions, to_view
from mps_ros.wire.topics import FOUNDATION, WRENCHES, resolve


@pytest.fixture(scope="module")
def rrd(cycle_mcap, tmp_path_factory):
    out = tmp_path_factory.mktemp("rrd") / "press-cycle.rrd"
    assert main(["view", str(cycle_mcap), "--save", str(out), "--no-spawn"]) == 0
    assert out.stat().st_size > 0
    return out, read_rrd(out)


def _col(ent, comp):
    return np.array([v[0] for v in ent[comp]])


def test_series_hold_the_recordings_values(rrd, cycle_mcap):
    _, d = rrd
    ref = rosbags_read(cycle_mcap)
    t_ns, js = ref[resolve("joint_states")]
    n = len(js)
    pos = np.array([m.position for m in js])
    vel = np.array([m.velocity for m in js])
    expect = {"phi": pos[:, 0], "psi": pos[:, 2], "x_C": pos[:, 3], "phi_dot": vel[:, 0]}
    for w in (*WRENCHES, FOUNDATION):
        _, msgs = ref[resolve(w.key)]
        for col, get in (
            (w.force[0], lambda m: m.wrench.force.x),
            (w.force[1], lambda m: m.wrench.force.y),
            (w.torque, lambda m: m.wrench.torque.z),
        ):
            if col is not None and col not in expect:
                expect[col] = np.array([get(m) for m in msgs])
    seen = set()
    for fam, _, series in FAMILIES:
        for col, name in series:
            ent = d[f"/plots/{fam}/{col}"]
            assert ent["static"]["SeriesLines:names"] == [name]
            assert np.array_equal(ent["time_ns"], t_ns), col  # one sample a step
            y = _col(ent, "Scalars:scalars")
            assert y.size == n
            if col in expect:
                assert np.array_equal(y, expect[col]), col
                seen.add(col)
            else:
                assert col == "phi_ddot"
                assert np.array_equal(y, np.gradient(vel[:, 0], t_ns / 1e9, edge_order=2))
    assert seen >= {
        "phi",
        "psi",
        "x_C",
        "phi_dot",
        "M_motor",
        "F_O_x",
        "F_found_x",
        "F_found_y",
        "M_found_O",
        "M_latch",
        "F_stop",
        "N_guide",
    }


def test_mechanism_drawn_from_joint_states_and_scene(rrd, cycle_mcap):
    _, d = rrd
    rep = read_recording(cycle_mcap)
    g = rep.scene.geometry
    n = len(rep)
    p = positions(rep.columns, g.l1, g.l3)
    joints = np.array(d["/mechanism/joints"]["Points2D:positions"], dtype=float)  # (n, 4, 2)
    assert joints.shape == (n, 4, 2)
    assert d["/mechanism/joints"]["static"]["Points2D:labels"] == ["O", "A", "B", "C"]
    for k, name in enumerate("OABC"):
        assert np.allclose(joints[:, k], to_view(p[name]), atol=1e-4), name  # float32, mm
    # press frame x up -> view (y, -x) in mm: C on the guide's axis, drawn at v = -x_C
    assert np.all(joints[:, 3, 0] == 0)
    assert np.allclose(joints[:, 3, 1], -1e3 * rep.columns["x_C"], atol=1e-4)
    assert joints[np.argmax(rep.columns["x_C"]), 3, 1] < 0  # top of the stroke: up
    # the drawing closes: |AB| = l2 (B from C and psi, A from phi) and matches the rod angle
    ab = np.hypot(*(joints[:, 2] - joints[:, 1]).T) / 1e3
    assert np.allclose(ab, g.l2, rtol=1e-5)
    rod = np.arctan2(p["B"][:, 1] - p["A"][:, 1], p["B"][:, 0] - p["A"][:, 0])
    assert np.allclose(np.angle(np.exp(1j * (rod - rep.columns["rod"]))), 0, atol=1e-9)
    links = d["/mechanism/links"]["LineStrips2D:strips"]
    assert len(links) == n and all(len(row) == 3 for row in links)
    assert d["/mechanism/links"]["static"]["LineStrips2D:labels"] == ["crank", "rod", "rocker"]
    assert len(d["/mechanism/slider"]["Boxes2D:centers"]) == n
    frame = d["/mechanism/frame"]["static"]["LineStrips2D:labels"]
    assert "top stop" in frame and "guide" in frame


def test_latch_state_visible(rrd, cycle_mcap):
    _, d = rrd
    rep = read_recording(cycle_mcap)
    st = rep.columns["structure"]
    t_ns = np.round(rep.columns["t"] * 1e9).astype(np.int64)
    ent = d["/mechanism/latch"]
    # labels only where the latch changes; latest-at gives the state at every step
    rows = [i for i, v in enumerate(ent["Points2D:labels"]) if v is not None]
    lt = ent["time_ns"][rows]
    labels = [ent["Points2D:labels"][i][0] for i in rows]
    idx = np.searchsorted(lt, t_ns, side="right") - 1
    shown = np.array(labels)[idx]
    assert np.array_equal(np.char.startswith(shown.astype(str), "latch closed"), st == "locked")
    assert set(labels) == {"latch open (held)", "latch open (free)", "latch closed (locked)"}
    assert 3 <= len(labels) < 10  # open, closed, open
    lanes = d["/state/structure"]["StateChange:state"]
    assert [v[0] for v in lanes][:3] == ["held", "free", "locked"]


def test_events_logged_and_marked(rrd, cycle_mcap):
    _, d = rrd
    rep = read_recording(cycle_mcap)
    log = d["/events"]
    text = [v[0] for v in log["TextLog:text"]]
    assert len(text) >= len(rep.events)
    latch = next(e for e in rep.events if e["kind"] == "latch-closes")
    i = next(k for k, s in enumerate(text) if s.startswith("latch closes"))
    assert log["time_ns"][i] == round(latch["t"] * 1e9)
    assert log["TextLog:level"][i] == ["WARN"]
    assert any(s.startswith("command engage") for s in text)
    for fam in ("latch", "stop", "command"):
        kinds = MARKERS[fam][0]
        te = [e["t"] for e in rep.events if e["kind"] in kinds]
        ent = d[f"/plots/crank_speed/events/{fam}"]
        assert np.array_equal(ent["time_ns"], np.round(np.array(sorted(te)) * 1e9)), fam
        assert ent["static"]["SeriesPoints:markers"]


def test_arrows_scaled_and_labelled(rrd, cycle_mcap):
    _, d = rrd
    rep = read_recording(cycle_mcap)
    c = rep.columns
    ent = d["/mechanism/reactions/foundation"]
    vec = np.array([v[0] for v in ent["Arrows2D:vectors"]])
    F = np.column_stack([c["F_found_x"], c["F_found_y"]])
    # the arrow is the force in the view's axes, to one scale: vec = (F_y, -F_x) / scale
    s = np.hypot(*F.T) / np.maximum(np.hypot(*vec.T), 1e-30)
    big = np.hypot(*F.T) > 1.0
    scale = np.median(s[big])
    assert np.allclose(vec[big], np.column_stack([F[big, 1], -F[big, 0]]) / scale, rtol=1e-5, atol=1e-4)
    k = int(np.argmax(np.hypot(*F.T)))
    assert ent["Arrows2D:labels"][k][0].startswith("foundation ")
    assert ent["Arrows2D:labels"][k][0].endswith("kN")
    origins = np.array([v[0] for v in ent["Arrows2D:origins"]])
    l1_mm = rep.scene.geometry.l1 * 1e3  # below O
    assert np.allclose(origins, [0.0, BEARING * l1_mm])
    a = np.array([v[0] for v in d["/mechanism/reactions/A"]["Arrows2D:origins"]])
    assert np.allclose(a, np.array(d["/mechanism/joints"]["Points2D:positions"])[:, 1])
    for w in ("O", "A", "B", "C", "guide", "stop"):
        assert len(d[f"/mechanism/reactions/{w}"]["Arrows2D:vectors"]) == len(rep)
    assert math.isfinite(scale)


def test_no_static_style_hides_data_in_time(rrd):
    """Rerun shows a static component instead of the same component in time: styles logged
    once must not carry what is sent at every step."""
    _, d = rrd
    for ent, v in d.items():
        temporal = {k for k in v if k not in ("static", "time_ns")}
        assert not (temporal & set(v["static"])), ent


def test_blueprint_lays_it_out(rrd):
    path, _ = rrd
    views = read_blueprint(path)
    assert views["2D"] == ["mechanism"]
    assert sorted(views["TimeSeries"]) == sorted(f"plots/{f}" for f, _, _ in FAMILIES)
    assert views["TextLog"] == ["events"]
    assert views["StateTimeline"] == ["state"]
