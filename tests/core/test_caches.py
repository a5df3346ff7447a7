"""The process's memos (mps_core.caches): one kind, each bounded, all cleared at once; a run
after clearing them gives what it gave before."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from mps_core import caches, simulate
from mps_core.caches import Memo

ROOT = Path(__file__).resolve().parents[2]


def test_a_memo_is_emptied_when_full_before_it_keeps_the_next():
    m = Memo("test.bounded", 3)
    try:
        for k in range(3):
            assert m.keep(k, k * 10) == k * 10
        assert dict(m) == {0: 0, 1: 10, 2: 20}
        m.keep(3, 30)
        assert dict(m) == {3: 30} and len(m) <= m.bound
        assert caches.sizes()["test.bounded"] == (1, 3)
        with pytest.raises(ValueError, match="exists already"):
            Memo("test.bounded", 5)
    finally:
        del caches.MEMOS["test.bounded"]


def test_no_module_of_the_core_keeps_a_dict_of_its_own_at_module_level():
    """An empty dict made at a module's top level (to be filled as the process runs) is a memo
    of mps_core.caches; the excepted are registries that must never be cleared: the memos
    themselves, and two that number what they hold."""
    registries = {("caches.py", "MEMOS"), ("codegen/emitter.py", "_CODES"), ("codegen/emitter.py", "_TABLES")}
    found = []
    for f in (ROOT / "mps_core").rglob("*.py"):
        rel = str(f.relative_to(ROOT / "mps_core"))
        for node in ast.parse(f.read_text()).body:
            if isinstance(node, ast.AnnAssign):
                target, value = node.target, node.value
            elif isinstance(node, ast.Assign) and len(node.targets) == 1:
                target, value = node.targets[0], node.value
            else:
                continue
            if (
                isinstance(target, ast.Name)
                and isinstance(value, ast.Dict)
                and not value.keys
                and (rel, target.id) not in registries
            ):
                found.append(f"{rel}: {target.id}")
    assert not found, found


def test_a_run_after_every_memo_is_cleared_gives_the_same_trajectory():
    a = simulate("press-cycle", t_end=0.3, dt=1e-3)
    assert any(n for n, _bound in caches.sizes().values())
    caches.clear()
    assert all(n == 0 for n, _bound in caches.sizes().values())
    b = simulate("press-cycle", t_end=0.3, dt=1e-3)
    for c in ("phi", "psi", "phi_dot", "x_C"):
        np.testing.assert_allclose(b.columns[c], a.columns[c], rtol=1e-12, atol=1e-12)
    assert [e["kind"] for e in b.events] == [e["kind"] for e in a.events]
