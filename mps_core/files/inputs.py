"""Reading the files a user names (scenes, CSV, event logs, recordings): every way a path can
be wrong becomes one :class:`InputFileError` that names the file, what it was meant to be and
what is wrong with it, instead of an exception from deep inside a reader."""

from __future__ import annotations

from pathlib import Path

from ..errors import MpsError

#: the first 8 bytes of an MCAP file (and its last 8): the specification's magic
MCAP_MAGIC = b"\x89MCAP0\r\n"


class InputFileError(MpsError, ValueError):
    """A named file cannot be used: missing, a directory, unreadable, empty, or not the kind of
    file expected."""

    def __init__(self, path, what: str, problem: str):
        self.path = Path(path)
        self.what = what
        self.problem = problem
        super().__init__(f"{what} {str(path)!r}: {problem}")


def _read(path, what: str, size: int = -1, allow_empty: bool = False) -> bytes:
    """Up to ``size`` bytes (all: -1) of a path that must be a readable, non-empty file (an
    empty one too, with ``allow_empty``)."""
    p = Path(path)
    if not p.exists():
        raise InputFileError(p, what, "no such file")
    if p.is_dir():
        raise InputFileError(p, what, "a directory, expected a file")
    try:
        with p.open("rb") as fh:
            data = fh.read(size)
    except PermissionError:
        raise InputFileError(p, what, "not readable (permission denied)") from None
    except OSError as exc:
        raise InputFileError(p, what, f"cannot be read ({exc.strerror or exc})") from None
    if not data and not allow_empty:
        raise InputFileError(p, what, "the file is empty")
    return data


def read_bytes(path, what: str) -> bytes:
    """The file's bytes, or :class:`InputFileError` for a path that is not a readable,
    non-empty file."""
    return _read(path, what)


def read_text(path, what: str, kind: str = "text", allow_empty: bool = False) -> str:
    """The file's text (UTF-8), or :class:`InputFileError`: also for a file of only blanks
    (unless ``allow_empty``: a log with nothing in it), a binary file and one that is not
    UTF-8. ``kind`` says what text was expected."""
    p = Path(path)
    data = _read(p, what, allow_empty=allow_empty)
    if not data.strip() and not allow_empty:
        raise InputFileError(p, what, "the file is empty (only blanks)")
    if b"\x00" in data:
        raise InputFileError(p, what, f"a binary file, expected {kind} (UTF-8)")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputFileError(
            p, what, f"not UTF-8 text: byte 0x{data[exc.start]:02x} at offset {exc.start}, expected {kind}"
        ) from None


def check_file(path, what: str, magic: bytes | None = None, kind: str = "") -> Path:
    """``path`` as a readable, non-empty file (that starts with ``magic``, where given), or
    :class:`InputFileError`. Reads at most the magic's length."""
    p = Path(path)
    head = _read(p, what, max(1, len(magic or b"")))
    if magic is not None and head != magic:
        raise InputFileError(
            p, what, f"not {kind or 'the expected kind of file'} (it starts with {head[:8]!r})"
        )
    return p


__all__ = ["InputFileError", "read_bytes", "read_text", "check_file"]
