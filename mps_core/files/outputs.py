"""Writing the files a user names (CSV, event logs, recordings, figures): every output path is
checked before a command does its work, never resolves to one of the command's inputs, never
replaces an existing file unless the user says so (``--force``), and is written whole or not at
all (under a temporary name beside it, renamed over it once complete)."""

from __future__ import annotations

import contextlib
import os
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


def check_outputs(
    outputs: dict[str, object],
    inputs: Iterable[object] = (),
    force: bool = False,
    folders: Iterable[str] = (),
) -> dict[str, Path]:
    """The outputs a command was given (``{what: path or None}``), checked before anything runs;
    their paths, or :class:`OutputFileError` for the first that cannot be used. ``inputs``: the
    files the command reads (a path that is not a file, such as a preset's name, is ignored);
    ``force``: an existing file may be replaced; ``folders``: the outputs that are a new
    directory (a bag of files): one that exists is refused, whatever ``force`` says (a
    directory is never written into)."""
    folders = set(folders)
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
def written_whole(path) -> Iterator[Path]:
    """``with written_whole(path) as tmp:`` write ``tmp``; it replaces ``path`` only once the
    block ends without an error (an error, Ctrl-C included, removes it and leaves ``path`` as it
    was)."""
    p = Path(path)
    tmp = partial_name(p)
    try:
        yield tmp
        os.replace(tmp, p)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


__all__ = ["OutputFileError", "check_outputs", "partial_name", "written_whole"]
