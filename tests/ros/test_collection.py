"""The garbage collector's passes made by a run between its deadlines (mps_ros.run.collection)."""

import gc

from mps_ros.run import collection


def test_the_pass_due_is_made_as_the_interpreter_would():
    """None before the young generation's count passes its threshold; then the young
    generation's, and the older ones' once enough younger passes have counted in them."""
    was = collection.hold()
    old = gc.get_threshold()
    kept: list = []
    try:
        gc.set_threshold(100, 2, 2)
        gc.collect()
        assert not gc.isenabled()
        assert collection.collect_due() == -1
        kept += [[] for _ in range(150)]  # containers: the young generation's count
        assert gc.get_count()[0] > 100
        assert collection.collect_due() == 0
        assert gc.get_count()[0] < 100
        made = []
        for _ in range(12):
            kept += [[] for _ in range(150)]
            made.append(collection.collect_due())
        assert set(made) == {0, 1, 2}, made
    finally:
        gc.set_threshold(*old)
        collection.release(was)
    assert gc.isenabled() == was


def test_release_leaves_the_passes_off_where_they_were_off():
    gc.disable()
    try:
        was = collection.hold()
        assert was is False
        collection.release(was)
        assert not gc.isenabled()
    finally:
        gc.enable()
