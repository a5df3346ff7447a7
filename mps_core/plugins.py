"""The commands and readers that other packages add, found through their entry points.

A distribution names them in its ``[project.entry-points]``: group ``mps.commands`` (a
``register(subparsers)`` each, whose parser sets ``func``), group ``mps.recordings`` (a reader
of a recording format into columns, by the format's name: ``mcap``). ``mps_core`` names none of
them itself.
"""

from __future__ import annotations

from collections.abc import Callable
from importlib.metadata import EntryPoint, entry_points
from typing import Any

#: the group of the commands that other packages add to ``mps``
COMMANDS = "mps.commands"
#: the group of the recording readers: name (the format) -> ``load_columns(path)``
RECORDINGS = "mps.recordings"


def found(group: str) -> list[EntryPoint]:
    """Return the entry points of ``group``, by name (one each; the first on the path wins)."""
    by_name: dict[str, EntryPoint] = {}
    for ep in entry_points(group=group):
        by_name.setdefault(ep.name, ep)
    return [by_name[n] for n in sorted(by_name)]


def load(ep: EntryPoint) -> Callable[..., Any] | None:
    """Load ``ep``; None where its own package is not installed (a missing dependency of it
    is raised)."""
    try:
        return ep.load()
    except ModuleNotFoundError as exc:
        if exc.name is not None and ep.module.startswith(exc.name):
            return None
        raise


def reader(fmt: str) -> EntryPoint | None:
    """Return the entry point that reads recordings of format ``fmt``, or None."""
    for ep in found(RECORDINGS):
        if ep.name == fmt:
            return ep
    return None
