"""The commands and readers that other packages add, found through their entry points.

A distribution names them in its ``[project.entry-points]``: group ``mps.commands`` (a
``register(subparsers)`` each, whose parser sets ``func``), group ``mps.recordings`` (a reader
of a recording format into columns, by the format's name: ``mcap``), group ``mps.track_writers``
(a writer of a tracked run's record, :class:`~mps_core.track.recording.TrackRecording`, into a
recording of that format: ``write(path, recording)``, returning the messages written, by the
format's name), group ``mps.track_readers`` (a reader of a press's measurements and mode signals
out of a recording of that format, for ``mps track``: ``read(path, topics, variances)``,
:mod:`mps_core.track.recording_input`). ``mps_core`` names none of them itself.
"""

from __future__ import annotations

from collections.abc import Callable
from importlib.metadata import EntryPoint, entry_points
from typing import Any

#: the group of the commands that other packages add to ``mps``
COMMANDS = "mps.commands"
#: the group of the recording readers: name (the format) -> ``load_columns(path)``
RECORDINGS = "mps.recordings"
#: the group of the tracked runs' recording writers: name (the format) -> ``write(path, recording)``
TRACK_WRITERS = "mps.track_writers"
#: the group of the readers of a press's measurements out of a recording: name (the format) ->
#: ``read(path, topics, variances)``
TRACK_READERS = "mps.track_readers"


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


def track_plugin(
    group: str, fmt: str, field: str, doing: str, error: type[Exception], otherwise: str
) -> Callable[..., Any]:
    """Return the loaded entry point ``fmt`` of ``group`` (:data:`TRACK_WRITERS`, :data:`TRACK_READERS`).

    Where there is none, or its package is missing, raise ``error``: ``field`` (the option and
    the path) names what asked, ``doing`` what the plugin does (``writes``, ``reads``),
    ``otherwise`` what the user can do instead.
    """
    ep = next((e for e in found(group) if e.name == fmt), None)
    install = "install the ros extra (pip install -e '.[ros]')"
    if ep is not None:
        try:
            return ep.load()
        except ModuleNotFoundError as exc:
            gerund = doing[:-1] + "ing"
            raise error(
                f"{field}: {gerund} a {fmt} recording needs the package {exc.name!r}, which is not "
                f"installed: {install}"
            ) from None
    raise error(
        f"{field}: no installed package {doing} {fmt} recordings (entry-point group {group!r}): "
        f"{install}, or {otherwise}"
    )
