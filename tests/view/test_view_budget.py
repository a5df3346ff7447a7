"""The work of converting a 10 s recording at 1 kHz (10 001 steps, about 120 000 messages).

Budget (counted, not timed): reading decodes the messages of a channel in one numpy pass; the
conversion makes at most 40 ``send_columns`` calls and 40 static ``log`` calls whatever the
recording's length, sends one row a step to each time-varying entity (at most 40 rows a step in
all), and never logs a step by itself. Measured on the project's 2-core machine: about 0.4 s to
read and 0.4 s to convert (printed by ``mps view``)."""

from __future__ import annotations

import time

import numpy as np
import pytest

rr = pytest.importorskip("rerun")

from mps_ros.recording.replay import read_recording  # noqa: E402
from mps_ros.view import offline as view_mod  # noqa: E402

MAX_SEND_COLUMNS = 40
MAX_STATIC_LOGS = 40
MAX_ROWS_PER_STEP = 40


def test_ten_seconds_at_1khz_within_budget(synthetic_10s, tmp_path, monkeypatch):
    path, cols = synthetic_10s
    calls = {"send_columns": 0, "log": 0}
    send, log = rr.send_columns, rr.log

    def counting_send(entity, indexes, columns, **kw):
        calls["send_columns"] += 1
        return send(entity, indexes=indexes, columns=columns, **kw)

    def counting_log(*a, **kw):
        calls["log"] += 1
        return log(*a, **kw)

    monkeypatch.setattr(rr, "send_columns", counting_send)
    monkeypatch.setattr(rr, "log", counting_log)

    c0 = time.perf_counter()
    rep = read_recording(path)
    c1 = time.perf_counter()
    out = view_mod.save_rrd(rep, tmp_path / "ten.rrd")
    c2 = time.perf_counter()
    n = len(rep)
    assert n == 10001
    for k, v in cols.items():  # the synthetic values, all read back
        if k != "structure":
            assert np.array_equal(rep.columns[k], v, equal_nan=True), k
    # rerun's own entry points, counted from outside the converter
    assert calls["send_columns"] == out.calls["send_columns"] <= MAX_SEND_COLUMNS
    assert calls["log"] == out.calls["log"] <= MAX_STATIC_LOGS
    assert out.rows <= MAX_ROWS_PER_STEP * n
    per_step = [e for e, r in out.entities.items() if r == n]
    assert len(per_step) >= 30  # mechanism, arrows, every series
    assert all(r <= n + 20 for r in out.entities.values())  # a row a step, + state changes
    print(
        f"\n10 s at 1 kHz: read {c1 - c0:.2f} s, converted {c2 - c1:.2f} s, "
        f"{out.calls['send_columns']} send_columns, {out.calls['log']} static logs, "
        f"{out.rows} rows ({out.rows / n:.1f} a step)"
    )


def test_a_view_behind_the_run_thins_the_drawing_not_the_plots(synthetic_10s):
    """draw_every = 10 (what the live view does when a frame holds ten times its drawing's
    steps): the mechanism and the arrows get every tenth step and the last, each plot every
    step."""
    path, _cols = synthetic_10s
    rep = read_recording(path)
    n = len(rep)
    full = view_mod.convert(rep, recording=rr.RecordingStream("full"))
    thin = view_mod.convert(rep, recording=rr.RecordingStream("thin"), draw_every=10)
    drawn = len(range(0, n, 10)) + (0 if (n - 1) % 10 == 0 else 1)
    assert full.drawn_steps == n and thin.drawn_steps == drawn
    drawing = [
        e
        for e in thin.entities
        if e in ("mechanism/links", "mechanism/joints", "mechanism/slider")
        or e.startswith("mechanism/reactions/")
    ]
    plots = [e for e in thin.entities if e.startswith("plots/")]
    assert len(drawing) >= 8 and len(plots) >= 15, sorted(thin.entities)
    for entity in drawing:
        assert full.entities[entity] == n and thin.entities[entity] == drawn, entity
    for entity in plots:
        assert thin.entities[entity] == full.entities[entity], entity
    assert sum(thin.entities[e] == n for e in plots) >= 15
