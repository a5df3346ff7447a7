"""Writing the files a user names (CSV, event logs, recordings, figures): every output path is
checked before a command does its work, never resolves to one of the command's inputs, never
replaces an existing file unless the user says so (``--force``), and is written whole or not at
all (under a temporary name beside it, renamed over it once complete).

A *stream* is written into, never renamed over: an existing FIFO or device (``/dev/null``, a
terminal), or ``-`` for standard output, where the command names that output as one that may be
a stream (a table, an event log). What goes to it is written whole first to a temporary file,
then copied: a reader gets all of it or, where the command fails first, nothing. ``--force``
replaces regular files only."""

from __future__ import annotations

import contextlib
import os
import shutil
import stat
import sys
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from ..errors import MpsError


class OutputFileError(MpsError, ValueError):
    """A path named for an output cannot be used: its folder is missing or not writable, it is a
    folder, it is one of the command's inputs, another output's, or an existing file."""

    def __init__(self, path, what: str, problem: str):
        self.path = Path(path)
        self.what = what
        self.problem = problem
        super().__init__(f"{what} {str(path)!r}: {problem}")


#: the name that means standard output, for an output that may be a stream
STDOUT = "-"


def stream_kind(path) -> str | None:
    """Return what ``path`` is where it is a stream ("standard output", "a FIFO", "a character
    device", "a block device", "a socket"), else None (a regular file, a folder, nothing)."""
    if str(path) == STDOUT:
        return "standard output"
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return None
    for test, kind in (
        (stat.S_ISFIFO, "a FIFO"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISSOCK, "a socket"),
    ):
        if test(mode):
            return kind
    return None


def check_outputs(
    outputs: dict[str, object],
    inputs: Iterable[object] = (),
    force: bool = False,
    folders: Iterable[str] = (),
    streams: Iterable[str] = (),
) -> dict[str, Path]:
    """The outputs a command was given (``{what: path or None}``), checked before anything runs;
    their paths, or :class:`OutputFileError` for the first that cannot be used. ``inputs``: the
    files the command reads (a path that is not a file, such as a preset's name, is ignored);
    ``force``: an existing file may be replaced; ``folders``: the outputs that are a new
    directory (a bag of files): one that exists is refused, whatever ``force`` says (a
    directory is never written into); ``streams``: the outputs that may be a stream (``-``, a
    FIFO, a device: written into, see the module's notes); any other that is one is refused."""
    folders, streams = set(folders), set(streams)
    ins = {}
    for i in inputs:
        if i is not None and Path(str(i)).is_file():
            ins[Path(str(i)).resolve()] = str(i)
    seen: dict[Path, str] = {}
    out = {}
    for what, path in outputs.items():
        if path is None:
            continue
        p = Path(str(path))
        kind = stream_kind(path)
        if kind is not None:
            if what not in streams or kind == "a socket":
                raise OutputFileError(
                    p,
                    what,
                    f"{kind}; expected a file path (this output is written as a file)"
                    if what not in streams
                    else f"{kind}; expected a file path, a FIFO, a device or - (standard output)",
                )
            key = Path(STDOUT) if kind == "standard output" else p.resolve()
            if key in seen:
                raise OutputFileError(p, what, f"also the {seen[key]}: expected another path")
            seen[key] = what
            out[what] = p
            continue
        if str(path) == "" or p.name in ("", ".", ".."):
            raise OutputFileError(p, what, "not a file name")
        real = p.resolve()
        if real in ins:
            raise OutputFileError(
                p,
                what,
                f"the command's input ({ins[real]!r}); writing it would destroy it: expected another path",
            )
        if what in folders:
            if p.exists():
                raise OutputFileError(
                    p,
                    what,
                    "exists; expected a new directory (a bag is never written into one that is there)",
                )
        elif p.is_dir():
            raise OutputFileError(p, what, "a directory, expected a file path")
        parent = p.parent
        if not parent.is_dir():
            raise OutputFileError(p, what, f"no directory {str(parent)!r} to write it in")
        if not os.access(parent, os.W_OK | os.X_OK):
            raise OutputFileError(p, what, f"the directory {str(parent)!r} is not writable")
        if real in seen:
            raise OutputFileError(p, what, f"also the {seen[real]}: expected another path")
        if p.exists() and not force and what not in folders:
            raise OutputFileError(p, what, "exists; expected a new path, or --force to replace it")
        seen[real] = what
        out[what] = p
    return out


def partial_name(path) -> Path:
    """The temporary name an output is written under, beside it (same folder, so that the
    rename is atomic): hidden, with this process's id."""
    p = Path(path)
    return p.with_name(f".{p.name}.{os.getpid()}.partial")


@contextlib.contextmanager
def written_whole(path, stdout=None) -> Iterator[Path]:
    """Write ``path`` whole or not at all: ``with written_whole(path) as tmp:`` write ``tmp``.

    ``tmp`` replaces ``path`` only once the block ends without an error (an error, Ctrl-C
    included, removes it and leaves ``path`` as it was). A stream (``-``, an existing FIFO or
    device) is not replaced: ``tmp`` is copied into it once complete; ``stdout``: the text
    stream ``-`` means (default: ``sys.stdout`` as it is then)."""
    p = Path(path)
    streamed = stream_kind(path) is not None
    if streamed:
        fd, name = tempfile.mkstemp(prefix="mps-", suffix=".partial")
        os.close(fd)
        tmp = Path(name)
    else:
        tmp = partial_name(p)
    try:
        yield tmp
        if streamed:
            _copy_into(tmp, path, sys.stdout if stdout is None else stdout)
        else:
            os.replace(tmp, p)
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink()


def _copy_into(src: Path, stream, stdout) -> None:
    """Copy the file ``src`` into the stream ``stream`` (``-``: the text stream ``stdout``)."""
    with src.open("rb") as fin:
        try:
            if str(stream) == STDOUT:
                stdout.flush()
                out = stdout.buffer
                shutil.copyfileobj(fin, out)
                out.flush()
            else:
                with open(stream, "wb") as fout:
                    shutil.copyfileobj(fin, fout)
        except OSError as exc:  # the stream's error, named by the stream
            raise OSError(exc.errno, exc.strerror, str(stream)) from None


__all__ = ["OutputFileError", "STDOUT", "check_outputs", "partial_name", "stream_kind", "written_whole"]
