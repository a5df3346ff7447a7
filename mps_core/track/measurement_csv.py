"""The measurements' CSV: one row a stamp, the measured columns, the mode signals.

    t,crank_angle_rad,slider_position_m,motor_torque_Nm,mode

``t`` (s) is the stamp; each measured column may be empty where that sensor has no sample then
(or missing where the press has no such sensor); ``mode`` is empty or a mode signal
(``engage``, ``disengage``) given at that stamp. ``crank_angle_rad`` is the encoder's count
times its LSB at the count's centre (any turn: the tracker unwraps it). The variances are not in
the file: the reader takes them from the encoder and the sensors given (``variances``).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TextIO

from .measurements import MODE_COMMANDS, Measurement, MeasurementError, ModeSignal

__all__ = ["COLUMNS", "read_measurements", "write_measurements"]

#: the file's columns: the stamp, each measured kind by its column, the mode signal
COLUMNS = {
    "t": "t",
    "crank_angle": "crank_angle_rad",
    "slider_position": "slider_position_m",
    "motor_torque": "motor_torque_Nm",
    "mode": "mode",
}


def write_measurements(
    fh: TextIO, measurements: Iterable[Measurement], modes: Iterable[ModeSignal] = ()
) -> int:
    """Write the measurements and mode signals, one row a stamp; return the rows written."""
    rows: dict[float, dict[str, str]] = {}
    for m in measurements:
        rows.setdefault(m.t, {})[COLUMNS[m.kind]] = repr(float(m.value))
    for s in modes:
        rows.setdefault(s.t, {})["mode"] = s.command
    w = csv.DictWriter(fh, fieldnames=list(COLUMNS.values()), lineterminator="\n")
    w.writeheader()
    for t in sorted(rows):
        w.writerow({"t": repr(float(t)), **rows[t]})
    return len(rows)


def read_measurements(
    path: str | Path, variances: dict[str, float | Callable[[float], float]]
) -> tuple[list[Measurement], list[ModeSignal]]:
    """Read a measurements CSV.

    ``variances``: kind → the variance of its measurements, a number or a function of the
    reading (a sensor whose noise is a share of what it reads)."""
    by_column = {v: k for k, v in COLUMNS.items() if k not in ("t", "mode")}
    out: list[Measurement] = []
    modes: list[ModeSignal] = []
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        names = reader.fieldnames or []
        if "t" not in names or COLUMNS["crank_angle"] not in names:
            raise MeasurementError(
                f"{path}: columns", ",".join(names), "at least t and crank_angle_rad (a header line)"
            )
        unknown = [c for c in names if c not in COLUMNS.values()]
        if unknown:
            raise MeasurementError(f"{path}: column", unknown[0], "one of " + ", ".join(COLUMNS.values()))
        for line, row in enumerate(reader, start=2):
            t = _number(row["t"], f"{path}:{line}: t")
            for column, kind in by_column.items():
                cell = (row.get(column) or "").strip()
                if cell:
                    value = _number(cell, f"{path}:{line}: {column}")
                    variance = variances[kind]
                    if callable(variance):
                        variance = variance(value)
                    out.append(Measurement(t, kind, value, variance))
            mode = (row.get("mode") or "").strip()
            if mode:
                if mode not in MODE_COMMANDS:
                    raise MeasurementError(f"{path}:{line}: mode", mode, "one of " + ", ".join(MODE_COMMANDS))
                modes.append(ModeSignal(t, mode))
    return out, modes


def _number(cell: str, field: str) -> float:
    """Return a cell's number (nan and inf are numbers here: the tracker counts them as not finite)."""
    try:
        v = float(cell)
    except ValueError:
        raise MeasurementError(field, cell, "a number") from None
    if math.isnan(v) and cell.strip().lower() not in ("nan", "+nan", "-nan"):
        raise MeasurementError(field, cell, "a number")
    return v
