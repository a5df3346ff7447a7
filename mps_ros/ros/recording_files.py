"""The node's recording paths: claimed where a user named one, the next after a reset, and
discarded where the node did not run."""

from __future__ import annotations

from pathlib import Path


def claim_recording(path) -> tuple[Path, bool]:
    """The recording path a user named, made this run's own: created empty where it is new;
    an empty file (one reserved for it, e.g. by ``mps demo``) is taken; anything else is
    :class:`~mps_core.files.outputs.OutputFileError` (a recording never replaces a file).
    Returns (the path, whether it was an empty file reserved for it)."""
    from mps_core.files.outputs import OutputFileError
    from mps_core.files.outputs import check_outputs as check_paths

    from ..recording.bag import is_bag
    from ..recording.recorder import reserve

    p = Path(path)
    if is_bag(p):  # a new directory
        check_paths({"parameter recording": p}, folders={"parameter recording"})
        try:
            p.mkdir()
        except FileExistsError:
            raise OutputFileError(p, "parameter recording", "exists; expected a new directory") from None
        return p, False
    if p.is_file() and p.stat().st_size == 0:
        return p, True
    exists = OutputFileError(
        p, "parameter recording", "exists; a recording never replaces a file: expected a new path"
    )
    if p.exists() and not p.is_dir():
        raise exists
    check_paths({"parameter recording": p})
    try:
        return reserve(p), False
    except FileExistsError:
        raise exists from None


def next_recording(path) -> Path:
    """The recording of the run after a reset: beside ``path``, ``NAME-2.mcap``, ``-3``…
    (a bag: ``NAME-2``…), the first that is free, claimed at once."""
    from ..recording.recorder import reserve_free

    return reserve_free(Path(path), start=2)


def discard_recording(path: Path, reserved: bool) -> None:
    """A recording begun by a node that did not run: gone, but for what was there before it (an
    empty file or directory reserved for it stays, empty)."""
    if path.is_dir():  # a bag: its files
        for f in path.iterdir():
            f.unlink(missing_ok=True)
        if not reserved:
            path.rmdir()
    elif reserved:
        path.write_bytes(b"")
    else:
        path.unlink(missing_ok=True)
