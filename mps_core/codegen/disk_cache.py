"""Generated code kept on disk: what a run generates is made once a machine, not once a process.

The generators (:mod:`mps_core.codegen`) write Python source for the chart views and effects a
run meets and compile it; the process's memos (:mod:`mps_core.caches`) keep it for the process.
This store keeps it for the next process: an entry holds the source text and its compiled code
(``marshal``'s form, as a ``.pyc`` holds it), the exact kernels' parts (JSON), or a text
another package's generator made (message definitions), never a pickle. Loading an entry gives
the code a generation would give: the same text, compiled the same.

**The key.** An entry's name is the SHA-256 digest of what its content depends on: the
generator's version (:func:`generator_version`: the source files of ``mps_core/codegen`` and
``mps_core/derivatives``, the package's version and Python's, with its bytecode's magic
number), the kind of entry and the key the generator keys its memo by, written out exactly
(:func:`key_bytes`: ``marshal``'s format 2, floats by their bits; a key holding anything else,
e.g. a process's own numbers, is not stored). The entries of one version share a folder of their own.

**Validity.** An entry starts with a header that records its digest, the generator's version
and the SHA-256 of the content; an entry whose header does not match what is asked for, or whose
content does not match its hash (truncated, garbled, from another version), is never used: the
code is generated again and the entry written anew. A writer writes a temporary file in the
same folder and renames it over the entry (:func:`os.replace`, atomic), so a reader sees a whole
entry or none, and two processes filling the cache at once both finish with valid entries.

**Where.** ``$MPS_CACHE_DIR/kernels``, else ``$XDG_CACHE_HOME/mps/kernels``, else
``~/.cache/mps/kernels``; ``MPS_CACHE_DIR=off`` turns the store off (the memos alone, as
before). A folder that cannot be written, or a full disk, leaves the run generating in memory
(one debug line of this module's logger), never failing it.

**Bound.** The folder is kept under :data:`BOUND_BYTES` (all versions together): a process's
first write and every 256th look at its size and remove the oldest entries, down to three
quarters of the bound. ``mps cache clear`` removes every entry; ``mps cache info`` says where
the store is and what it holds.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import logging
import marshal
import os
import shutil
import sys
import tempfile
import time
import types
from pathlib import Path

import numpy as np

from ..version import __version__

__all__ = [
    "BOUND_BYTES",
    "COUNTS",
    "Entry",
    "KernelStore",
    "generator_version",
    "key_bytes",
    "store",
]

_log = logging.getLogger(__name__)

#: the bound of the kernels' folder, every version's entries together
BOUND_BYTES = 256 * 2**20
#: the first line of every entry
MAGIC = b"mps kernel cache entry 1\n"
#: what the process did with the store: code generated (a miss, or no store), entries read,
#: written, found invalid (rejected), and writes that failed
COUNTS = {"generated": 0, "read": 0, "written": 0, "rejected": 0, "unwritten": 0}
#: the packages whose source the generated code is a function of (with the key)
_GENERATOR_PACKAGES = ("codegen", "derivatives")
_VERSION: list = [None]


def generator_version() -> str | None:
    """Return the generator's version: a digest of its source files, the package's version and
    Python's (None where a file cannot be read: then nothing is stored)."""
    if _VERSION[0] is None:
        h = hashlib.sha256()
        h.update(f"{__version__}\0{sys.version}\0".encode())
        h.update(importlib.util.MAGIC_NUMBER)
        root = Path(__file__).resolve().parents[1]
        try:
            for pkg in _GENERATOR_PACKAGES:
                for f in sorted((root / pkg).glob("*.py")):
                    h.update(f"\0{pkg}/{f.name}\0".encode())
                    h.update(f.read_bytes())
        except OSError:
            _VERSION[0] = ""
        else:
            _VERSION[0] = h.hexdigest()
    return _VERSION[0] or None


def key_bytes(x) -> bytes:
    """Return ``x`` written out exactly (None, bools, integers, floats, strings, bytes and tuples
    or lists of them; numpy's scalars as Python's): ``marshal``'s format 2, which writes every
    value whole (no references to values written before, no interning), so that the same key
    gives the same bytes in every process of one Python version; TypeError for anything else
    (``marshal`` alone would write a numpy value as its raw bytes). The 183 keys of press-cycle's
    first second take 5 ms so, against 28 ms fed to the hash value by value in Python."""
    if _plain_only(x):
        return marshal.dumps(x, 2)
    return marshal.dumps(_plain(x), 2)


#: the types :func:`key_bytes` writes as they are
_PLAIN = frozenset((type(None), bool, int, float, str, bytes))


def _plain_only(x) -> bool:
    """Whether ``x`` holds only :data:`_PLAIN` values in tuples and lists (a walk without calls)."""
    stack = [x]
    pop, extend, plain = stack.pop, stack.extend, _PLAIN
    while stack:
        y = pop()
        t = type(y)
        if t is tuple or t is list:
            extend(y)
        elif t not in plain:
            return False
    return True


def _plain(x):
    """``x`` with numpy's scalars as Python's; TypeError where it holds anything else."""
    t = type(x)
    if t in _PLAIN:
        return x
    if t is tuple or t is list:
        return t(_plain(y) for y in x)
    if isinstance(x, np.bool_):
        return bool(x)
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.floating):
        return float(x)
    raise TypeError(f"not a key the disk cache can write: {t.__name__}")


def _folder_from_environment() -> Path | None:
    """Return the kernels' folder the environment names, or None (the store off)."""
    given = os.environ.get("MPS_CACHE_DIR", "").strip()
    if given.lower() in ("off", "none", "0", "no", "false"):
        return None
    if given:
        return Path(given).expanduser() / "kernels"
    xdg = os.environ.get("XDG_CACHE_HOME", "").strip()
    if xdg and Path(xdg).is_absolute():
        return Path(xdg) / "mps" / "kernels"
    try:
        return Path.home() / ".cache" / "mps" / "kernels"
    except (RuntimeError, KeyError):  # no home to find
        return None


class Entry:
    """One entry of a store: its digest and file; ``read()`` its items where it is valid,
    ``write(items)`` it anew."""

    __slots__ = ("store", "digest", "path")

    def __init__(self, store: KernelStore, digest: str, path: Path):
        self.store, self.digest, self.path = store, digest, path

    def read(self) -> list[bytes] | None:
        """Return the entry's items, or None where there is no valid entry (counted as
        rejected where a file is there but fails a check)."""
        try:
            data = self.path.read_bytes()
        except OSError:
            return None
        items = _parse(data, self.digest, self.store.version)
        if items is None:
            COUNTS["rejected"] += 1
            _log.debug("kernel cache: %s is not a valid entry; made again", self.path)
            return None
        COUNTS["read"] += 1
        return items

    def write(self, items: list[bytes]) -> None:
        """Write the entry (a temporary file renamed over it); a failure is one debug line."""
        self.store.write(self, items)


def _parse(data: bytes, digest: str, version: str) -> list[bytes] | None:
    """Return the items of an entry's bytes, where its header records ``digest`` and ``version`` and
    its content matches its hash; else None."""
    if not data.startswith(MAGIC):
        return None
    end = data.find(b"\n", len(MAGIC))
    if end < 0:
        return None
    try:
        head = json.loads(data[len(MAGIC) : end])
        sizes = [int(n) for n in head["sizes"]]
        ok = head["digest"] == digest and head["version"] == version
        sha = head["sha256"]
    except (ValueError, KeyError, TypeError, RecursionError):
        return None
    body = data[end + 1 :]
    if not ok or any(n < 0 for n in sizes) or sum(sizes) != len(body):
        return None
    if hashlib.sha256(body).hexdigest() != sha:
        return None
    out, at = [], 0
    for n in sizes:
        out.append(body[at : at + n])
        at += n
    return out


class KernelStore:
    """The entries under ``folder`` (the kernels' folder; one sub-folder a generator version),
    the whole kept under ``bound`` bytes."""

    def __init__(self, folder: Path, bound: int = BOUND_BYTES):
        self.folder, self.bound = Path(folder), int(bound)
        self.version = generator_version() or ""
        self._writes = 0
        self._writable = True

    @property
    def here(self) -> Path:
        """Return this generator version's folder."""
        return self.folder / self.version[:16]

    def entry(self, kind: str, key) -> Entry | None:
        """Return the entry of ``kind`` under ``key``; None where the key cannot be written exactly
        or the generator's version is unknown."""
        if not self.version:
            return None
        h = hashlib.sha256()
        h.update(self.version.encode())
        try:
            h.update(key_bytes((kind, key)))
        except TypeError:
            return None
        digest = h.hexdigest()
        return Entry(self, digest, self.here / digest)

    def write(self, entry: Entry, items: list[bytes]) -> None:
        """Write ``entry`` with ``items`` (see :meth:`Entry.write`)."""
        if not self._writable:
            return
        body = b"".join(items)
        head = {
            "digest": entry.digest,
            "version": self.version,
            "sizes": [len(b) for b in items],
            "sha256": hashlib.sha256(body).hexdigest(),
        }
        data = MAGIC + json.dumps(head, sort_keys=True).encode() + b"\n" + body
        tmp = None
        try:
            self.here.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=self.here, prefix=".tmp-")
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
            os.replace(tmp, entry.path)
            tmp = None
        except OSError as exc:
            COUNTS["unwritten"] += 1
            self._writable = False  # the rest of this process generates in memory only
            _log.debug("kernel cache: %s cannot be written (%s); generating in memory", self.here, exc)
            return
        finally:
            if tmp is not None:
                try:
                    os.unlink(tmp)
                except OSError:
                    pass
        COUNTS["written"] += 1
        self._writes += 1
        if self._writes % 256 == 1:
            self.prune()

    def _files(self) -> list[tuple[float, int, Path]]:
        """List (mtime, size, path) of every file under the folder (every version's)."""
        out: list[tuple[float, int, Path]] = []
        try:
            versions = list(os.scandir(self.folder))
        except OSError:
            return out
        for v in versions:
            if not v.is_dir(follow_symlinks=False):
                continue
            try:
                with os.scandir(v.path) as it:
                    for f in it:
                        try:
                            st = f.stat(follow_symlinks=False)
                        except OSError:
                            continue
                        out.append((st.st_mtime, st.st_size, Path(f.path)))
            except OSError:
                continue
        return out

    def prune(self) -> None:
        """Remove the oldest entries while the folder holds more than its bound (down to three
        quarters of it), and temporary files an hour old (a writer that stopped)."""
        files = self._files()
        total = sum(size for _m, size, _p in files)
        over, target = total > self.bound, self.bound * 3 // 4
        old = time.time() - 3600.0
        for mtime, size, path in sorted(files, key=lambda f: f[0]):
            if path.name.startswith(".tmp-"):
                if mtime >= old:
                    continue  # a writer's, under way
            elif not (over and total > target):
                continue
            try:
                path.unlink()
                total -= size
            except OSError:
                pass

    def info(self) -> dict:
        """Say where the store is and what it holds: entries and bytes, this version's and all."""
        files = [f for f in self._files() if not f[2].name.startswith(".tmp-")]
        mine = [f for f in files if f[2].parent.name == self.version[:16]]
        return {
            "folder": str(self.folder),
            "version": self.version[:16],
            "entries": len(mine),
            "bytes": sum(f[1] for f in mine),
            "all_entries": len(files),
            "all_bytes": sum(f[1] for f in files),
            "bound": self.bound,
        }

    def clear(self) -> tuple[int, int]:
        """Remove every entry (every version's); (files, bytes) removed."""
        files = self._files()
        shutil.rmtree(self.folder, ignore_errors=True)
        return len(files), sum(size for _m, size, _p in files)


_STORE: list = [None]


def store() -> KernelStore | None:
    """Return the store the environment names now (see the module's notes), or None where it is off."""
    folder = _folder_from_environment()
    if folder is None:
        return None
    s = _STORE[0]
    if s is None or s.folder != folder:
        s = _STORE[0] = KernelStore(folder)
    return s


def entry(kind: str, key) -> Entry | None:
    """Return the entry of ``kind`` under ``key`` in the store (None: no store, or a key it
    cannot write)."""
    s = store()
    return None if s is None else s.entry(kind, key)


def code_items(source: str, code: types.CodeType) -> list[bytes]:
    """Return an entry's items for generated code: its source text and its compiled code."""
    return [source.encode("utf-8", "surrogatepass"), marshal.dumps(code)]


def code_from(items: list[bytes] | None):
    """Return (code, source) of an entry's items, or None where they are not generated code."""
    if items is None or len(items) != 2:
        return None
    try:
        source = items[0].decode("utf-8", "surrogatepass")
        code = marshal.loads(items[1])
    except (ValueError, EOFError, TypeError, UnicodeDecodeError):
        return None
    if not isinstance(code, types.CodeType):
        return None
    return code, source
