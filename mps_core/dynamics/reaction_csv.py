"""A trajectory's CSV with the reaction columns: written (:func:`write_csv`) and read back
(:func:`read_csv`, the ``# partial`` comment of a run that stopped skipped)."""

from __future__ import annotations

import csv
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from .reactions import REACTION_COLUMNS


def write_csv(trajectory, path, extra: Mapping[str, str] = REACTION_COLUMNS) -> Path:
    """The trajectory's CSV (:data:`~mps_core.names.COLUMNS`) followed by the ``extra`` columns
    it holds (by default the reactions)."""
    return trajectory.to_csv(path, extra=[k for k in extra if k in trajectory.columns])


def read_csv(path) -> dict[str, np.ndarray]:
    """Columns of a CSV written by :func:`write_csv` (or ``Trajectory.to_csv``) as arrays."""
    path = Path(path)
    with path.open(newline="") as fh:
        # a partial run's last line is a comment (# partial: ...)
        rows = [r for r in csv.reader(fh) if r and not r[0].startswith("#")]
    if not rows:
        raise ValueError(f"{path}: an empty file, expected a header and rows")
    head, body = rows[0], rows[1:]
    out = {}
    for i, name in enumerate(head):
        vals = [r[i] for r in body]
        if name in ("structure", "chart"):
            out[name] = np.array(vals)
        else:
            try:
                out[name] = np.array([float(v) for v in vals])
            except ValueError:
                raise ValueError(f"{path}: column {name!r} has a non-numeric value") from None
    return out


__all__ = ["write_csv", "read_csv"]
