"""What the node asks of the system for its threads: a name, and a short scheduler slice with
the thread's nice value kept; granted where the system offers it, and then read back."""

from __future__ import annotations

import os
import sys
import threading

import pytest

from mps_ros.os_threads import name_thread, short_slice, thread_slice

linux = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux's prctl, /proc")


def _in_thread(fn):
    out = {}

    def run():
        out["tid"] = threading.get_native_id()
        out["value"] = fn()

    t = threading.Thread(target=run)
    t.start()
    t.join()
    return out


@linux
def test_a_thread_is_named_in_proc():
    def named():
        ok = name_thread("mps-test-name")
        with open(f"/proc/self/task/{threading.get_native_id()}/comm") as f:
            return ok, f.read().strip()

    assert _in_thread(named)["value"] == (True, "mps-test-name")


@linux
def test_a_short_slice_is_granted_and_read_back_or_not_claimed():
    main_slice = thread_slice()

    def ask():
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, 3)  # lowering is never refused
        granted = short_slice(1e-4)
        return granted, thread_slice(), os.getpriority(os.PRIO_PROCESS, tid)

    granted, got, nice = _in_thread(ask)["value"]
    assert nice == 3  # kept
    if granted:
        assert got == pytest.approx(1e-4)
    else:  # an older kernel: nothing claimed
        assert got is None or got != pytest.approx(1e-4)
    assert thread_slice() == main_slice  # the calling thread's only
