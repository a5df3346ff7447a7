"""The disk cache of generated code (mps_core.codegen.disk_cache): a fresh process whose cache
holds a run's code generates nothing and gives the same numbers; an entry that is corrupt, of
another generator version or another key's is made again, never used; two processes filling
one cache at once both finish and leave it valid; a folder that cannot be written leaves the
run generating in memory; ``mps cache info`` and ``clear``.

Every process here has its cache in the test's own folder; what a process did is read from
its counts (``disk_cache.COUNTS``), never from its time."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mps_core.cli import main
from mps_core.codegen import disk_cache
from mps_core.codegen.disk_cache import KernelStore

#: one process: two runs through the command line (exact derivatives on press-cycle's
#: effects, central differences on paper's, both with their reactions: every kind of kernel a
#: scalar run makes), their CSVs written to argv[1], argv[2]; its counts printed last
RUNS = """
import json, sys
from mps_core.cli import main
from mps_core.codegen import disk_cache
if len(sys.argv) > 3:  # another generator version
    disk_cache._VERSION[0] = sys.argv[3]
common = ["--reactions", "-q", "--force", "--csv"]
assert main(["run", "press-cycle", "--t-end", "0.03", "--dt", "0.001", *common, sys.argv[1]]) == 0
assert main(["run", "paper", "--derivatives", "central", "--t-end", "0.02", *common, sys.argv[2]]) == 0
print(json.dumps(disk_cache.COUNTS))
"""


def _start(cache, out: Path, version: str | None = None) -> subprocess.Popen:
    env = dict(os.environ, MPS_CACHE_DIR=str(cache))
    out.mkdir(parents=True, exist_ok=True)
    args = [sys.executable, "-c", RUNS, str(out / "a.csv"), str(out / "b.csv")]
    return subprocess.Popen(
        args + ([version] if version else []),
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _finish(p: subprocess.Popen) -> dict:
    out, err = p.communicate(timeout=300)
    assert p.returncode == 0, err
    return json.loads(out.strip().splitlines()[-1])


def _run(cache, out: Path, version: str | None = None) -> dict:
    """The counts of a fresh process running :data:`RUNS` with its cache in ``cache``."""
    return _finish(_start(cache, out, version))


def _csvs(out: Path) -> tuple[bytes, bytes]:
    return (out / "a.csv").read_bytes(), (out / "b.csv").read_bytes()


def _entries(cache) -> list[Path]:
    return sorted(p for p in (Path(cache) / "kernels").glob("*/*") if not p.name.startswith(".tmp-"))


def _all_valid(cache) -> None:
    """Every entry under ``cache`` is whole, of this generator version and named by its key."""
    version = disk_cache.generator_version()
    files = _entries(cache)
    assert files
    for f in files:
        assert disk_cache._parse(f.read_bytes(), f.name, version) is not None, f
    assert not list((Path(cache) / "kernels").glob("*/.tmp-*"))


@pytest.fixture(scope="module")
def filled(tmp_path_factory):
    """(a cache filled by a fresh process, that process's counts, its CSVs), and the CSVs of
    the same runs without a cache."""
    root = tmp_path_factory.mktemp("filled")
    counts = _run(root / "cache", root / "first")
    _run("off", root / "off")
    return root / "cache", counts, _csvs(root / "first"), _csvs(root / "off")


def _copy(filled, tmp_path) -> Path:
    cache = tmp_path / "cache"
    shutil.copytree(filled[0], cache)
    return cache


def test_a_cold_process_fills_the_cache_and_gives_what_it_gives_without_one(filled):
    cache, counts, first, off = filled
    assert counts["generated"] > 10 and counts["read"] == 0 and counts["rejected"] == 0
    assert counts["written"] == counts["generated"] == len(_entries(cache))
    assert first == off  # the cache changes no number
    _all_valid(cache)


def test_a_warm_start_generates_nothing(filled, tmp_path):
    cache = _copy(filled, tmp_path)
    counts = _run(cache, tmp_path / "out")
    assert counts["generated"] == 0 and counts["written"] == 0 and counts["rejected"] == 0
    assert counts["read"] == filled[1]["written"]
    assert _csvs(tmp_path / "out") == filled[2]


def _rewrite(path: Path, edit) -> None:
    """Rewrite an entry with ``edit(head, body) -> (head, body)``, its hash made right again."""
    data = path.read_bytes()
    end = data.index(b"\n", len(disk_cache.MAGIC))
    head, body = json.loads(data[len(disk_cache.MAGIC) : end]), data[end + 1 :]
    head, body = edit(head, body)
    head["sha256"] = hashlib.sha256(body).hexdigest()
    head["sizes"] = [len(body) - sum(head["sizes"][1:]), *head["sizes"][1:]]
    path.write_bytes(disk_cache.MAGIC + json.dumps(head).encode() + b"\n" + body)


def test_a_corrupt_or_stale_entry_is_made_again_never_used(filled, tmp_path):
    """Truncated, garbled (its hash no longer holds), another key's content under this key's
    name, another generator version's header, garbage: each found invalid, the code made again
    and written anew; the numbers are the same."""
    cache = _copy(filled, tmp_path)
    files = _entries(cache)
    codes = [
        f
        for f in files
        if disk_cache.code_from(disk_cache._parse(f.read_bytes(), f.name, disk_cache.generator_version()))
        is not None
    ]
    truncated, garbled, swapped, stale, garbage = codes[:5]
    truncated.write_bytes(truncated.read_bytes()[: len(truncated.read_bytes()) // 2])
    data = bytearray(garbled.read_bytes())
    data[-40] ^= 0x55  # in the compiled code: the header's hash no longer matches
    garbled.write_bytes(bytes(data))
    swapped.write_bytes(codes[5].read_bytes())  # a whole, valid entry of another key
    _rewrite(stale, lambda head, body: ({**head, "version": "0" * 64}, body))
    garbage.write_bytes(b"def kernel(*a):\n    return 0\n")
    counts = _run(cache, tmp_path / "out")
    assert counts["rejected"] == 5
    assert counts["generated"] == counts["written"] == 5
    assert _csvs(tmp_path / "out") == filled[2]
    _all_valid(cache)
    # and the next process reads them all
    again = _run(cache, tmp_path / "again")
    assert again["generated"] == 0 and again["rejected"] == 0


def test_an_entry_whose_hash_holds_but_whose_code_was_changed_is_not_used(filled, tmp_path):
    """An entry edited with its header's hash made right again but its digest another key's:
    the header records the key it was written for, and this one is not its file's."""
    cache = _copy(filled, tmp_path)
    files = _entries(cache)
    _rewrite(files[0], lambda head, body: ({**head, "digest": files[1].name}, body))
    counts = _run(cache, tmp_path / "out")
    assert counts["rejected"] == 1 and counts["generated"] == 1
    assert _csvs(tmp_path / "out") == filled[2]


def test_another_generator_version_reads_nothing_of_this_ones(filled, tmp_path):
    cache = _copy(filled, tmp_path)
    other = _run(cache, tmp_path / "other", version="f" * 64)
    assert other["read"] == 0 and other["generated"] == filled[1]["generated"]
    assert _csvs(tmp_path / "other") == filled[2]
    assert len({p.parent.name for p in _entries(cache)}) == 2  # one folder a version
    mine = _run(cache, tmp_path / "mine")
    assert mine["generated"] == 0 and mine["rejected"] == 0


def test_two_processes_filling_an_empty_cache_at_once(filled, tmp_path):
    cache = tmp_path / "cache"
    a, b = _start(cache, tmp_path / "a"), _start(cache, tmp_path / "b")
    ca, cb = _finish(a), _finish(b)
    assert ca["rejected"] == cb["rejected"] == 0
    assert _csvs(tmp_path / "a") == _csvs(tmp_path / "b") == filled[2]
    _all_valid(cache)
    assert len(_entries(cache)) == filled[1]["written"]
    warm = _run(cache, tmp_path / "warm")
    assert warm["generated"] == 0 and warm["rejected"] == 0


#: two of these write one entry over and over and read it back between writes
RACE = """
import sys
from pathlib import Path
from mps_core.codegen import disk_cache
store = disk_cache.KernelStore(Path(sys.argv[1]))
entry = store.entry("race", ("one key",))
items = [b"x" * 100000, sys.argv[2].encode() * 1000]
seen = set()
for _ in range(300):
    entry.write(items)
    got = entry.read()
    assert got is not None and len(got) == 2 and got[0] == items[0], "a partial entry was read"
    seen.add(got[1][:1])
assert disk_cache.COUNTS["rejected"] == 0 and disk_cache.COUNTS["unwritten"] == 0
print("".join(sorted(x.decode() for x in seen)))
"""


def test_two_writers_of_one_entry_never_leave_a_partial_one(tmp_path):
    ps = [
        subprocess.Popen(
            [sys.executable, "-c", RACE, str(tmp_path), tag],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for tag in "ab"
    ]
    for p in ps:
        out, err = p.communicate(timeout=120)
        assert p.returncode == 0, err
    entry = KernelStore(tmp_path).entry("race", ("one key",))
    assert entry is not None and entry.read() is not None
    assert not list(tmp_path.glob("*/.tmp-*"))


def test_a_folder_that_cannot_be_written_leaves_the_run_generating_in_memory(tmp_path):
    blocked = tmp_path / "a file"
    blocked.write_text("not a folder")
    store = KernelStore(blocked / "kernels")
    entry = store.entry("code", ("k",))
    before = dict(disk_cache.COUNTS)
    entry.write([b"text"])  # no error
    assert entry.read() is None
    assert disk_cache.COUNTS["unwritten"] == before["unwritten"] + 1
    counts = _run(blocked, tmp_path / "out")
    assert counts["generated"] > 0 and counts["written"] == 0 and counts["unwritten"] == 1


def test_keys_are_written_out_exactly_or_not_stored(tmp_path):
    store = KernelStore(tmp_path)
    digests = set()
    for key in (1, 1.0, True, "1", b"1", (1,), [1], 0.0, -0.0, None, (None,), ("a", "b"), ("ab",)):
        e = store.entry("k", key)
        assert e is not None
        digests.add(e.digest)
    assert len(digests) == 13
    assert store.entry("k", (1, object())) is None  # a process's own value: not stored
    assert store.entry("k", (1, 2)).digest == store.entry("k", (1, 2)).digest
    assert store.entry("k", 1).digest != store.entry("j", 1).digest
    # numpy's scalars are their values; an array, a dict, a set are not written (marshal would
    # write an array as its raw bytes, a set in the process's own order)
    plain = store.entry("k", (1, 2.5, True, ("x",))).digest
    assert store.entry("k", (np.int64(1), np.float64(2.5), np.bool_(True), ("x",))).digest == plain
    for refused in (np.array([1.0]), {1: 2}, {1, 2}, 1 + 2j, bytearray(b"1")):
        assert store.entry("k", (1, refused)) is None, refused


def test_a_key_has_one_digest_in_every_process(tmp_path):
    """The digest is the key's, not the process's: strings interned or not, another hash seed."""
    key = ("view", ("phi", "psi"), 1.5, -0.0, None, [True, 3], "é" * 3)
    here = KernelStore(tmp_path).entry("k", key).digest
    script = (
        "import sys; from mps_core.codegen.disk_cache import KernelStore; "
        "key = ('view', ('ph' + 'i', sys.intern('psi')), 1.5, -0.0, None, [True, 3], 'é' * 3); "
        "print(KernelStore(sys.argv[1]).entry('k', key).digest)"
    )
    for seed in ("0", "1"):
        out = subprocess.run(
            [sys.executable, "-c", script, str(tmp_path)],
            env={**os.environ, "PYTHONHASHSEED": seed},
            capture_output=True,
            text=True,
            check=True,
        )
        assert out.stdout.strip() == here


def test_the_folder_is_kept_under_its_bound(tmp_path):
    store = KernelStore(tmp_path, bound=40_000)
    for k in range(60):
        e = store.entry("k", k)
        e.write([bytes(1000)])
        os.utime(e.path, (1_000_000 + k, 1_000_000 + k))
    store.prune()
    left = sorted(int(p.stat().st_mtime) - 1_000_000 for p in tmp_path.glob("*/*"))
    assert sum(p.stat().st_size for p in tmp_path.glob("*/*")) <= 30_000
    assert left == list(range(60 - len(left), 60))  # the newest kept


def test_where_the_cache_is(monkeypatch, tmp_path):
    monkeypatch.delenv("MPS_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert disk_cache.store().folder == tmp_path / "xdg" / "mps" / "kernels"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert disk_cache.store().folder == tmp_path / "home" / ".cache" / "mps" / "kernels"
    monkeypatch.setenv("MPS_CACHE_DIR", str(tmp_path / "mine"))
    assert disk_cache.store().folder == tmp_path / "mine" / "kernels"
    monkeypatch.setenv("MPS_CACHE_DIR", "off")
    assert disk_cache.store() is None and disk_cache.entry("code", 1) is None


def test_mps_cache_info_and_clear(monkeypatch, tmp_path, capsys):
    monkeypatch.setenv("MPS_CACHE_DIR", str(tmp_path))
    for k in range(3):
        disk_cache.entry("k", k).write([b"x" * 100])
    assert main(["cache", "info"]) == 0
    out = capsys.readouterr().out
    assert str(tmp_path / "kernels") in out and ": 3 entries" in out
    assert main(["cache", "clear"]) == 0
    assert "removed 3 file(s)" in capsys.readouterr().out
    assert not (tmp_path / "kernels").exists()
    assert main(["cache", "info"]) == 0
    assert ": 0 entries" in capsys.readouterr().out
    monkeypatch.setenv("MPS_CACHE_DIR", "off")
    assert main(["cache", "clear"]) == 0
    assert "off" in capsys.readouterr().out
