"""A simulated run: numpy arrays by name, the run's events and its work counts."""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .names import COLUMNS, NUMERIC_COLUMNS


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
