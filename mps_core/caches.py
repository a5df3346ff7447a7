"""The process's memos, one kind of object: what a run makes once and later runs reuse
(generated code, traced parts, mechanisms), each bounded and all of them cleared at once.

A memo is a dict (lookups stay the dict's own, on the per-step path) that is emptied when it is
full, before the next entry is kept: what it held is made again where asked for, so a bound
costs time, never a result. Long sweeps of many different scenes in one process stay within
the bounds (``mps sweep``: every mechanism and every set of effect parameters makes code of its
own). :func:`clear` empties them all (between independent workloads, or to measure a run from
cold: with the disk cache off, ``MPS_CACHE_DIR=off``, :mod:`mps_core.codegen.disk_cache`, which
keeps generated code for the next process); :func:`sizes` says what they hold.
"""

from __future__ import annotations

from typing import Any

#: every memo of the process, by name
MEMOS: dict[str, Memo] = {}


class Memo(dict):
    """A named, bounded memo (see the module's notes)."""

    def __init__(self, name: str, bound: int):
        super().__init__()
        if name in MEMOS:
            raise ValueError(f"a memo named {name!r} exists already")
        self.name, self.bound = name, int(bound)
        MEMOS[name] = self

    def keep(self, key: Any, value: Any) -> Any:
        """``value`` kept under ``key`` (the memo emptied first where it is full); returned."""
        if len(self) >= self.bound:
            self.clear()
        self[key] = value
        return value

    def __repr__(self) -> str:
        return f"Memo({self.name!r}, {len(self)} of {self.bound})"


def clear() -> None:
    """Empty every memo of the process."""
    for m in MEMOS.values():
        m.clear()


def sizes() -> dict[str, tuple[int, int]]:
    """(entries, bound) of every memo, by name."""
    return {name: (len(m), m.bound) for name, m in MEMOS.items()}


__all__ = ["Memo", "MEMOS", "clear", "sizes"]
