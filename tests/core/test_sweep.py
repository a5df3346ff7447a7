"""mps sweep: the load report over many runs of a scene (mps_core.analysis.sweep)."""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys

import pytest

from mps_core import load_scene, scene_from_text, simulate
from mps_core.analysis import loads
from mps_core.analysis.sweep import (
    Axis,
    SweepError,
    figures,
    parse_axis,
    plan,
    set_field,
    sweep,
)

#: press-cycle at 1 kHz over its first second: three working strokes, a few tenths of a second
SHORT = dict(t_end=1.0, dt=1e-3)
THICKNESS = "effects.blanking.thickness_mm=0.5:2.0:3"


def _close(a: dict, b: dict, rtol: float = 1e-9) -> None:
    assert a.keys() == b.keys()
    for k in a:
        if isinstance(a[k], float):
            assert math.isclose(a[k], b[k], rel_tol=rtol, abs_tol=1e-9), (k, a[k], b[k])
        else:
            assert a[k] == b[k], k


def _figures_only(row: dict, varied: tuple = ("effects.blanking.thickness_mm",)) -> dict:
    return {k: v for k, v in row.items() if k not in ("run", "key", "status", "error") and k not in varied}


def test_axes_grid_list_range():
    assert parse_axis("effects.blanking.thickness_mm=0.5:2.0:4").values == (0.5, 1.0, 1.5, 2.0)
    assert parse_axis("solver.corrector_iterations=1:3:3").values == (1, 2, 3)
    assert parse_axis("solver.method=rk4,linear-acceleration").values == ("rk4", "linear-acceleration")
    assert parse_axis("outputs.reactions=true,false").values == (True, False)
    a = parse_axis("bodies.slider.mass_kg=80:120")
    assert a.sampled and (a.low, a.high) == (80.0, 120.0)
    for bad, words in (
        ("thickness", "KEY=SPEC"),
        ("k=1:x:3", "'x' is not a number"),
        ("k=1:2:0", "expected an integer >= 1"),
        ("k=2:1", "low < high"),
        ("k=1:2:3:4", "a:b:n"),
    ):
        with pytest.raises(SweepError, match=words):
            parse_axis(bad)


def test_keys_name_effects_and_commands_by_their_name_or_index():
    raw = {
        "effects": [{"type": "motor", "crank_speed_rad_s": 43.5}, {"type": "blanking"}],
        "commands": [{"t_s": 0.008, "command": "engage"}],
        "bodies": {},
    }
    set_field(raw, "effects.motor.crank_speed_rad_s", 40.0)
    set_field(raw, "effects.1.thickness_mm", 2.0)
    set_field(raw, "commands.engage.t_s", 0.01)
    set_field(raw, "bodies.slider.mass_kg", 90.0)
    assert raw["effects"][0]["crank_speed_rad_s"] == 40.0
    assert raw["effects"][1]["thickness_mm"] == 2.0
    assert raw["commands"][0]["t_s"] == 0.01 and raw["bodies"]["slider"]["mass_kg"] == 90.0
    with pytest.raises(SweepError, match=r"no type 'springs' \(it has: motor, blanking\)"):
        set_field(raw, "effects.springs.preload_n", 1.0)
    with pytest.raises(SweepError, match="the type names the entry"):
        set_field(raw, "effects.motor.type", "x")


def test_bad_specs_fail_before_any_run_naming_the_key():
    with pytest.raises(SweepError, match="no type 'blankin'"):
        plan("press-cycle", ["effects.blankin.thickness_mm=1:2:2"])
    # a value the scene refuses: the run, its values and the scene's own words
    with pytest.raises(
        SweepError,
        match=r"run 1 \(effects.blanking.thickness_mm=-1.0\).*"
        r"effects\[7\].thickness_mm",
    ):
        plan("press-cycle", ["effects.blanking.thickness_mm=1.0,-1.0"])
    with pytest.raises(SweepError, match="sampled: give --samples"):
        plan("press-cycle", ["bodies.slider.mass_kg=80:120"])
    with pytest.raises(SweepError, match="from ranges low:high only"):
        plan("press-cycle", ["bodies.slider.mass_kg=80,120"], samples=4)


def test_a_grid_is_the_product_and_a_sample_a_latin_hypercube():
    runs = plan("press-cycle", [THICKNESS, "effects.motor.crank_speed_rad_s=40,45"], **SHORT)
    assert [tuple(r.values.values()) for r in runs] == [(t, w) for t in (0.5, 1.25, 2.0) for w in (40, 45)]
    assert len({r.key for r in runs}) == 6
    assert runs[0].scene.reactions and runs[0].scene.t_end == 1.0 and runs[0].scene.dt == 1e-3
    sampled = plan("press-cycle", ["bodies.slider.mass_kg=80:120"], samples=8, seed=3, **SHORT)
    masses = sorted(r.values["bodies.slider.mass_kg"] for r in sampled)
    # one sample in each eighth of the range
    assert [int((m - 80) / 5) for m in masses] == list(range(8))
    assert [r.scene.bodies["slider"].mass for r in sampled] == [
        r.values["bodies.slider.mass_kg"] for r in sampled
    ]
    again = plan("press-cycle", ["bodies.slider.mass_kg=80:120"], samples=8, seed=3, **SHORT)
    assert [r.key for r in again] == [r.key for r in sampled]


def test_a_runs_key_is_its_whole_file_as_json():
    import tomllib

    from mps_core.analysis.sweep import run_key

    runs = plan("press-cycle", [THICKNESS, "bodies.slider.mass_kg=80,90"], **SHORT)
    for r in runs:
        raw = tomllib.loads(load_scene("press-cycle").text)
        raw["solver"].pop("steps", None)
        raw["solver"].update(t_end_s=1.0, dt_s=1e-3)
        raw.setdefault("outputs", {})["reactions"] = True
        for k, v in r.values.items():
            set_field(raw, k, v)
        assert r.key == run_key(json.dumps(raw, sort_keys=True, default=str))
    assert len({r.key for r in runs}) == 6


def test_each_row_is_the_load_report_of_its_own_run():
    result = sweep("press-cycle", [THICKNESS], workers=1, **SHORT)
    assert result.computed == 3 and [r["status"] for r in result.rows] == ["ok"] * 3
    base = load_scene("press-cycle")
    for row, run in zip(result.rows, plan(base, [THICKNESS], **SHORT)):
        traj = simulate(run.scene)
        report = loads.load_report(traj.columns, events=traj.events, source=run.scene.name)
        _close(_figures_only(row), figures(report))
        assert row["effects.blanking.thickness_mm"] == run.values["effects.blanking.thickness_mm"]
    peaks = [r["|F_found|.peak"] for r in result.rows]
    assert peaks == sorted(peaks) and peaks[0] < peaks[-1]  # thicker sheet, larger load
    env = {e["figure"]: e for e in result.envelope()}
    assert env["|F_found|.peak"]["value"] == max(peaks) and env["|F_found|.peak"]["run"] == 2
    rec = result.records()
    assert list(rec["F_found_peak"]) == peaks and list(rec["status"]) == ["ok"] * 3


def test_a_run_that_fails_is_a_row_with_its_error():
    result = sweep("press-cycle", ["charts.switching=true,false"], workers=1, **SHORT)
    ok, failed = result.rows
    assert ok["status"] == "ok" and failed["status"] == "failed"
    assert "ChartBreakdown" in failed["error"] and "|F_found|.peak" not in failed
    assert [e["run"] for e in result.envelope()] == [0] * len(result.envelope())
    assert math.isnan(result.records()["F_found_peak"][1])


def test_an_interrupted_sweep_computes_only_what_is_missing(tmp_path):
    out = tmp_path / "s"
    seen = []

    def stop_after_two(row, done, total):
        seen.append(row["run"])
        if len(seen) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        sweep(
            "press-cycle",
            [THICKNESS, "effects.motor.crank_speed_rad_s=40,45"],
            out=out,
            workers=1,
            on_row=stop_after_two,
            **SHORT,
        )
    lines = (out / "runs.jsonl").read_text().splitlines()
    assert len(lines) == 2
    # a kill mid-line leaves a torn last line: it is not a row
    with (out / "runs.jsonl").open("a") as fh:
        fh.write('{"key": "torn", "run"')
    again = sweep(
        "press-cycle", [THICKNESS, "effects.motor.crank_speed_rad_s=40,45"], out=out, workers=1, **SHORT
    )
    assert again.computed == 4 and len(again.rows) == 6
    whole = sweep("press-cycle", [THICKNESS, "effects.motor.crank_speed_rad_s=40,45"], workers=1, **SHORT)
    for a, b in zip(again.rows, whole.rows):
        _close(a, b)
    third = sweep(
        "press-cycle", [THICKNESS, "effects.motor.crank_speed_rad_s=40,45"], out=out, workers=1, **SHORT
    )
    assert third.computed == 0 and [r["run"] for r in third.rows] == list(range(6))


def _local_cluster(distributed):
    """Two workers of one thread in this process, their HTTP servers (health, metrics) on the
    loopback only: with ``dashboard_address=None`` the scheduler's and the workers' listen on
    every interface (an in-process cluster's address is the machine's own)."""
    return distributed.LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=False,
        dashboard_address="127.0.0.1:0",
        worker_dashboard_address="127.0.0.1:0",
    )


def test_worker_processes_and_a_dask_cluster_give_the_same_rows():
    distributed = pytest.importorskip("dask.distributed")
    one = sweep("press-cycle", [THICKNESS], workers=1, **SHORT)
    two = sweep("press-cycle", [THICKNESS], workers=2, **SHORT)
    with (
        _local_cluster(distributed) as cluster,
        distributed.Client(cluster) as client,
    ):
        dask = sweep("press-cycle", [THICKNESS], client=client, **SHORT)
    for a, b, c in zip(one.rows, two.rows, dask.rows):
        _close(a, b)
        _close(a, c)


def test_a_worker_killed_mid_sweep_loses_no_row():
    import multiprocessing
    import os
    import signal

    killed = []

    def kill_a_worker(row, done, total):
        if not killed:
            pid = multiprocessing.active_children()[0].pid
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)

    vary = ["effects.blanking.thickness_mm=0.5:2.0:4"]
    hit = sweep("press-cycle", vary, workers=2, on_row=kill_a_worker, **SHORT)
    assert killed and len(hit.rows) == 4 and all(r["status"] == "ok" for r in hit.rows)
    whole = sweep("press-cycle", vary, workers=1, **SHORT)
    for a, b in zip(hit.rows, whole.rows):
        _close(a, b)


def _mps(*args):
    return subprocess.run(
        [sys.executable, "-m", "mps_core.cli", *args], capture_output=True, text=True, timeout=300
    )


def test_the_command_writes_the_table_the_envelope_and_resumes(tmp_path):
    out = tmp_path / "sweep"
    args = [
        "sweep",
        "press-cycle",
        "--vary",
        "effects.blanking.thickness_mm=0.5,2.0",
        "--t-end",
        "1",
        "--dt",
        "0.001",
        "--workers",
        "2",
        "--out",
        str(out),
    ]
    res = _mps(*args)
    assert res.returncode == 0, res.stderr
    assert "2 runs (2 computed now, 0 kept from before), 0 failed" in res.stdout
    with (out / "sweep.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert [r["effects.blanking.thickness_mm"] for r in rows] == ["0.5", "2.0"]
    assert all(r["status"] == "ok" for r in rows)
    with (out / "envelope.csv").open() as fh:
        env = {r["figure"]: r for r in csv.DictReader(fh)}
    assert env["|F_found|.peak"]["run"] == "1"
    assert float(env["|F_found|.peak"]["value"]) == float(rows[1]["|F_found|.peak"])
    spec = json.loads((out / "sweep.json").read_text())
    assert (
        spec["scene"] == "press-cycle"
        and spec["vary"] == ["effects.blanking.thickness_mm=0.5,2.0"]
        and spec["version"]
    )
    assert (out / "sweep.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    again = _mps(*args)
    assert again.returncode == 0 and "(0 computed now, 2 kept from before)" in again.stdout
    # another sweep into the same folder is refused; a bad key fails before any run
    other = _mps("sweep", "press-cycle", "--vary", "effects.blanking.thickness_mm=1.0,3.0", "--out", str(out))
    assert other.returncode == 2 and "holds another sweep" in other.stderr
    bad = _mps(
        "sweep", "press-cycle", "--vary", "effects.blanking.thicknes_mm=1,2", "--out", str(tmp_path / "bad")
    )
    lines = bad.stderr.strip().splitlines()
    assert bad.returncode == 2 and len(lines) == 1 and "thicknes_mm" in lines[0], bad.stderr
    assert not (tmp_path / "bad").exists()


def test_axis_values_are_what_the_scene_receives():
    runs = plan("press-cycle", [Axis("solver.corrector_iterations", (1, 2))], **SHORT)
    assert [r.scene.solver.iterations for r in runs] == [1, 2]
    # two keys of one table, two of the effects, a command: each run's own, none another's
    # (the runs' files are one, changed run by run: a scene keeps none of its tables)
    runs = plan(
        "press-cycle",
        [
            "bodies.slider.mass_kg=80,90",
            "bodies.crank.mass_kg=4,5",
            "effects.motor.crank_speed_rad_s=40,45",
            "effects.blanking.thickness_mm=1,2",
            "commands.engage.t_s=0.1,0.2",
        ],
        **SHORT,
    )
    got = []
    for r in runs:
        params = {e.kind: e.params for e in r.scene.effects}
        got.append(
            (
                r.scene.bodies["slider"].mass,
                r.scene.bodies["crank"].mass,
                params["motor"]["crank_speed"],
                params["blanking"]["thickness"] * 1e3,
                dict((w, t) for t, w in r.scene.commands)["engage"],
            )
        )
    assert got == [tuple(r.values.values()) for r in runs] and len(set(got)) == 32
    assert plan("press-cycle", ["bodies.slider.mass_kg=85"], **SHORT)[0].scene.bodies["crank"].mass == 4.6


#: working (locked, no events) with exact derivatives: its runs share vectorised batches from two
#: runs on (with central differences from MIN_BATCH's 10); 2.4 crank revolutions
WORKING = dict(t_end=0.35, dt=5e-4)
EXACT_TEXT = load_scene("working").text.replace('derivatives = "central"', 'derivatives = "autodiff"')
EXACT = scene_from_text(EXACT_TEXT)
MASS_SPEED = ["bodies.slider.mass_kg=80:120:3", "effects.motor.crank_speed_rad_s=40,45"]


def _same_figures(a: dict, b: dict) -> None:
    """Equal rows, each figure to 1e-9 of itself or of its quantity's peak (a mean that
    cancels to nearly zero, e.g. F_found_y's, carries the round-off of the peak's size)."""
    assert a.keys() == b.keys()
    for k in a:
        if isinstance(a[k], float):
            scale = max(abs(b[k]), abs(b.get(k.rsplit(".", 1)[0] + ".peak", 0.0)))
            assert abs(a[k] - b[k]) <= 1e-9 * scale, (k, a[k], b[k])
        else:
            assert a[k] == b[k], k


def test_which_runs_go_in_batches():
    """Batches of at least MIN_BATCH runs of one group, one a worker where they are enough, as
    even as they can be; the rest one by one (nothing is run here)."""
    from mps_core.analysis.sweep import MIN_BATCH, tasks

    def shape(scene, n, workers, times=WORKING, **kw):
        runs = plan(scene, [f"bodies.slider.mass_kg=80:120:{n}"], **times)
        return [(batch, len(rs)) for batch, rs in tasks(runs, workers, **kw)]

    assert MIN_BATCH["central"] == 10
    assert shape("working", 6, 1) == [(False, 1)] * 6  # central differences: too few
    assert shape("working", 10, 1) == [(True, 10)]
    assert shape("working", 6, 1, min_batch=2) == [(True, 6)]  # unless asked
    assert shape("working", 45, 2) == [(True, 22), (True, 23)]
    assert shape("working", 45, 2, vectorise=False) == [(False, 1)] * 45
    assert shape(EXACT, 6, 2) == [(True, 3), (True, 3)]
    assert shape(EXACT, 7, 1, batch_size=3) == [(True, 2), (True, 2), (True, 3)]
    # more batches than workers: a multiple of them (each worker's last ends with the others')
    assert shape(EXACT, 9, 2, batch_size=3) == [(True, 2), (True, 2), (True, 2), (True, 3)]
    assert shape(EXACT, 13, 3, batch_size=3) == [(True, 2)] * 5 + [(True, 3)]
    assert shape(EXACT, 7, 2, batch_size=3) == [(True, 2), (True, 2), (True, 3)]  # not below 2
    # press-cycle has commands and events: never a batch
    assert shape("press-cycle", 3, 1, times=SHORT) == [(False, 1)] * 3


def test_a_vectorised_sweep_gives_the_rows_of_the_runs_one_by_one():
    vec = sweep(EXACT, MASS_SPEED, workers=1, **WORKING)
    one = sweep(EXACT, MASS_SPEED, workers=1, vectorise=False, **WORKING)
    assert vec.vectorised == 6 and one.vectorised == 0
    assert [r["status"] for r in vec.rows] == ["ok"] * 6
    for a, b in zip(vec.rows, one.rows):
        _same_figures(a, b)
    # the rows differ run by run (each scene's own masses and motor in the batch)
    assert len({r["|F_found|.peak"] for r in vec.rows}) == 6
    # two worker processes, a batch of three each
    two = sweep(EXACT, MASS_SPEED, workers=2, **WORKING)
    assert two.vectorised == 6
    for a, b in zip(two.rows, vec.rows):
        _same_figures(a, b)
    # runs that cannot share the pass (rk8: not a vectorised solver) go on their own beside
    # the batch, with the same rows as one by one
    vary = ["solver.method=linear-acceleration,rk8", "bodies.slider.mass_kg=80,120"]
    mixed = sweep(EXACT, vary, workers=1, **WORKING)
    alone = sweep(EXACT, vary, workers=1, vectorise=False, **WORKING)
    assert mixed.vectorised == 2 and [r["status"] for r in mixed.rows] == ["ok"] * 4
    for a, b in zip(mixed.rows, alone.rows):
        _same_figures(a, b)


def test_vectorised_batches_on_a_dask_cluster():
    distributed = pytest.importorskip("dask.distributed")
    local = sweep(EXACT, MASS_SPEED, workers=1, **WORKING)
    with (
        _local_cluster(distributed) as cluster,
        distributed.Client(cluster) as client,
    ):
        dask = sweep(EXACT, MASS_SPEED, client=client, **WORKING)
    assert dask.vectorised == 6  # two batches, one a worker
    for a, b in zip(dask.rows, local.rows):
        _same_figures(a, b)


def test_an_interrupted_vectorised_sweep_keeps_every_row_of_its_batches(tmp_path):
    out = tmp_path / "v"
    seen = []

    def stop_at_the_second_row(row, done, total):
        seen.append(row["run"])
        if len(seen) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        sweep(EXACT, MASS_SPEED, out=out, workers=1, batch_size=3, on_row=stop_at_the_second_row, **WORKING)
    # the batch of three was recorded whole before its rows were told
    assert len((out / "runs.jsonl").read_text().splitlines()) == 3
    again = sweep(EXACT, MASS_SPEED, out=out, workers=1, batch_size=3, **WORKING)
    assert again.computed == 3 and again.vectorised == 3 and len(again.rows) == 6
    whole = sweep(EXACT, MASS_SPEED, workers=1, **WORKING)
    for a, b in zip(again.rows, whole.rows):
        _same_figures(a, b)


def test_the_command_vectorises_unless_told_not_to(tmp_path):
    scene = tmp_path / "working-exact.toml"
    scene.write_text(EXACT_TEXT)
    base = [
        "sweep",
        str(scene),
        "--vary",
        "bodies.slider.mass_kg=80,120",
        "--t-end",
        "0.35",
        "--dt",
        "0.0005",
    ]
    vec = _mps(*base, "--workers", "1", "--out", str(tmp_path / "v"))
    assert vec.returncode == 0, vec.stderr
    assert "2 of the runs computed now in vectorised batches" in vec.stdout
    one = _mps(*base, "--workers", "1", "--no-vectorise", "--out", str(tmp_path / "o"))
    assert one.returncode == 0 and "vectorised" not in one.stdout, one.stderr
    tables = []
    for d in ("v", "o"):
        with (tmp_path / d / "sweep.csv").open() as fh:
            tables.append(list(csv.DictReader(fh)))
    for a, b in zip(*tables):
        assert a.keys() == b.keys() and a["status"] == b["status"] == "ok"
        assert math.isclose(float(a["|F_found|.peak"]), float(b["|F_found|.peak"]), rel_tol=1e-9)
    bad = _mps(*base, "--batch-size", "0", "--out", str(tmp_path / "b"))
    assert bad.returncode == 2 and "--batch-size 0: expected an integer >= 1" in bad.stderr


def test_the_vectorised_sweep_benchmark_counts_what_it_ran():
    from mps_core.bench.sweep import report_vectorised, vectorised

    # one worker process for the machine's row: the test takes no more than its own core
    # (the ROS tests beside it in `make test` keep real time on the other)
    rows = vectorised(
        sizes=(3,), alone=2, repeats=1, schemes=("autodiff",), workers=1, log=lambda *_: None, **WORKING
    )
    one, batch, machine = rows
    assert (one["way"], one["runs"], one["vectorised"]) == ("one by one", 2, 0)
    assert (batch["runs"], batch["vectorised"], batch["failed"]) == (3, 3, 0)
    assert batch["steps"] == 700 and batch["steps_per_s"] == 3 * 700 / batch["cpu_s"]
    assert batch["simulation_cpu_s"] + batch["reports_cpu_s"] <= batch["cpu_s"]
    assert 0.0 < batch["batch_reactions_cpu_s"] < batch["batch_cpu_s"]
    assert (machine["way"], machine["runs"], machine["vectorised"], machine["failed"]) == (
        "1 worker, batches of 3",
        3,
        3,
        0,
    )
    assert machine["steps_per_s"] == 3 * 700 / machine["wall_s"]
    report_vectorised(rows)


def test_the_envelope_takes_each_figures_largest_magnitude_over_the_runs_that_ended(tmp_path):
    """Each figure's value of largest magnitude over the runs that ended, the first run of a
    tie, finite numbers only (a NaN, an infinity, a word or a missing value passed over); the
    table and the envelope as CSV, a column where a row first has it."""
    from mps_core.analysis.sweep import Sweep, write_csv

    nan, inf = math.nan, math.inf
    rows = [
        {"run": 0, "key": "a", "k": 1, "status": "ok", "error": "", "F.peak": 2.0, "F.mean": -3.0, "n": 1},
        {"run": 1, "key": "b", "k": 2, "status": "ok", "error": "", "F.peak": nan, "F.mean": 3.0, "n": 4},
        {"run": 2, "key": "c", "k": 3, "status": "failed", "error": "E: x"},
        {"run": 3, "key": "d", "k": 4, "status": "ok", "error": "", "F.peak": inf, "F.mean": 1.0, "n": "?"},
        {"run": 4, "key": "e", "k": 5, "status": "ok", "error": "", "F.peak": -2.0, "F.mean": 0.5, "x": nan},
    ]
    rows[2]["F.peak"] = 99.0  # a failed run's figure is not the envelope's
    result = Sweep(["k"], rows)
    assert result.columns() == ["run", "key", "k", "status", "error", "F.peak", "F.mean", "n", "x"]
    env = {e["figure"]: (e["value"], e["run"], e["k"]) for e in result.envelope()}
    assert env == {"F.peak": (2.0, 0, 1), "F.mean": (-3.0, 0, 1), "n": (4, 1, 2)}
    write_csv(rows, result.columns(), tmp_path / "t.csv")
    with (tmp_path / "t.csv").open() as fh:
        table = list(csv.reader(fh))
    assert table[0] == result.columns() and table[3] == ["2", "c", "3", "failed", "E: x", "99.0", "", "", ""]
    assert table[2][5] == "nan" and len(table) == 6
