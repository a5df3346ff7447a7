"""A simulated run: numpy arrays by name, the run's events and its work counts."""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..names import COLUMNS, NUMERIC_COLUMNS


@dataclass
class Trajectory:
    """Arrays by name (see :data:`mps_core.names.COLUMNS`), one row per output step and the
    initial state; ``events`` (chart switches and, later, structure events) and ``counts``
    (right-hand-side evaluations, position calls and points, steps)."""

    columns: dict
    events: list = field(default_factory=list)
    counts: dict = field(default_factory=dict)
    settings: dict = field(default_factory=dict)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]

    def __getattr__(self, name):
        cols = self.__dict__.get("columns")
        if cols is not None and name in cols:
            return cols[name]
        raise AttributeError(name)

    def __len__(self) -> int:
        return len(self.columns["t"])

    @property
    def energy(self) -> np.ndarray:
        return self.columns["T"] + self.columns["V"]

    def to_csv(self, path, extra=()) -> Path:
        """One row per step: the columns of :data:`mps_core.names.COLUMNS`, then ``extra``
        numeric columns the trajectory holds (e.g. the reactions)."""
        path = Path(path)
        names = list(COLUMNS) + [k for k in extra if k not in COLUMNS]
        numeric = set(NUMERIC_COLUMNS) | set(extra)
        with path.open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(names)
            cols = [self.columns[k] for k in names]
            for row in zip(*cols):
                w.writerow([repr(float(v)) if k in numeric else v for k, v in zip(names, row)])
        return path

    def events_to_jsonl(self, path) -> Path:
        path = Path(path)
        with path.open("w") as fh:
            for ev in self.events:
                fh.write(json.dumps(ev) + "\n")
        return path


#: a fixed step beyond which a run's trajectory depends on the step: the crank or the rocker
#: turning more than this (rad) in one step. press-cycle at 1 s (docs/model.md's table): dt =
#: 2 ms (8.1 deg a step at most) lands 5 deg of crank angle from dt = 0.5 ms; 5 ms (14.5 deg)
#: 311 deg away, with another chart sequence; 20 ms cannot go on (no chart holds).
COARSE_TURN = np.radians(10.0)


def coarse_step(traj: Trajectory, step: float) -> str | None:
    """Where a fixed ``step`` (s) is coarse for the run's fastest motion (the crank's or the
    rocker's rate times the step above :data:`COARSE_TURN`), a sentence saying so with the
    largest step that keeps the turn a step within it; else None."""
    rates = [np.abs(traj.columns[c]) for c in ("phi_dot", "psi_dot") if c in traj.columns]
    return coarse_for_rate(max((float(np.nanmax(r)) for r in rates if len(r)), default=0.0), step)


def coarse_for_rate(fast: float, step: float) -> str | None:
    """Say where a fixed ``step`` (s) is coarse for a run whose fastest rate (crank or
    rocker) was ``fast`` rad/s, as :func:`coarse_step` does; else None."""
    if not (fast > 0.0 and np.isfinite(fast)) or fast * step <= COARSE_TURN:
        return None
    largest = COARSE_TURN / fast
    scale = 10.0 ** (np.floor(np.log10(largest)) - 1)
    largest = np.floor(largest / scale) * scale  # two figures, rounded down
    return (
        f"the step {step:.6g} s is coarse for this run: the crank or rocker turns up to "
        f"{np.degrees(fast * step):.3g} deg in one ({fast:.4g} rad/s); beyond "
        f"{np.degrees(COARSE_TURN):.0f} deg a step the trajectory depends on the step "
        f"(impacts and chart changes move or vanish). Largest step within it: "
        f"{largest:.2g} s"
    )
