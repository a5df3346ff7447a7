"""The node is a managed (lifecycle) node: with ``autostart:=false`` it waits unconfigured;
driven through its lifecycle services it configures, runs when activated, pauses when
deactivated (nothing but diagnostics go out, saying STALE; simulated time holds), goes on when
activated again (the run the same, bit for bit, as one never paused), and ends with a finished
recording on shutdown."""

from __future__ import annotations

import time

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("mcap")
pytest.importorskip("rosbags")

from test_recording import read_all
from twin_probe import Listener, NodeProcess, ns, wait_until


def _uninterrupted(tmp_path, t_end: float) -> dict:
    """The same run never paused or reset: a node of its own, realtime at ten times real time
    (the same steps: the pacing changes no value), read back. Made the same way as the run it
    is compared with, so that the kernels its stepping process traces are the same (a
    long-lived process, or one that warms up otherwise, may differ in the last bits)."""
    ref = tmp_path / "uninterrupted.mcap"
    with NodeProcess(
        tmp_path,
        dict(pacing="realtime", real_time_factor=10.0, dt=0.001, t_end=t_end, recording=str(ref)),
        name="ref",
    ) as node:
        assert node.wait(120) == 0, node.log()
    return read_all(ref)


def _answered(client, timeout: float = 60.0) -> None:
    """Until the node's ``~/change_state`` has answered this client once: a request no
    transition has (an unknown label: refused, nothing changes, nothing logged), sent again each
    second until an answer to one of them comes back. The first answers of a service can be
    lost where the node has not yet matched the client's reader (Fast DDS: "failed to send
    response (timeout)", seen on a busy machine), and a transition itself must not be sent
    twice."""
    from lifecycle_msgs.srv import ChangeState

    if getattr(client, "answered", False):
        return
    req = ChangeState.Request()
    req.transition.label = "no-such-transition"
    sent: list = []  # (when, the future of its answer)

    def answered() -> bool:
        if not sent or time.monotonic() >= sent[-1][0] + 1.0:
            sent.append((time.monotonic(), client.call_async(req)))
        return any(f.done() for _, f in sent)

    wait_until(answered, timeout, "~/change_state to answer a request")
    assert not next(f for _, f in sent if f.done()).result().success
    client.answered = True


def _change(node, client, transition_id: int, timeout: float = 60.0) -> bool:
    from lifecycle_msgs.srv import ChangeState

    assert client.wait_for_service(timeout_sec=timeout), "no ~/change_state service"
    _answered(client, timeout)
    req = ChangeState.Request()
    req.transition.id = transition_id
    fut = client.call_async(req)
    wait_until(fut.done, timeout, f"an answer to transition {transition_id}")
    return fut.result().success


def _state(client) -> str:
    from lifecycle_msgs.srv import GetState

    fut = client.call_async(GetState.Request())
    wait_until(fut.done, 30, "the lifecycle state")
    return fut.result().current_state.label


def test_the_lifecycle_configures_runs_pauses_goes_on_and_shuts_down(ros, tmp_path):
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState, GetState
    from std_srvs.srv import Trigger

    rec = tmp_path / "managed.mcap"
    params = dict(
        autostart=False, pacing="realtime", dt=0.001, t_end=3.0, recording=str(rec), diagnostics_period=0.2
    )
    lis = Listener(keys=("/clock", "/diagnostics", "joint_states"))
    change = lis.node.create_client(ChangeState, "/press_twin/change_state")
    get = lis.node.create_client(GetState, "/press_twin/get_state")
    step = lis.node.create_client(Trigger, "/press_twin/step")

    def one_step():
        assert step.wait_for_service(timeout_sec=30)
        fut = step.call_async(Trigger.Request())
        wait_until(fut.done, 30, "~/step's answer")
        return fut.result()

    try:
        with NodeProcess(tmp_path, params, name="managed") as node:
            assert get.wait_for_service(timeout_sec=60)
            assert _state(get) == "unconfigured"
            assert not lis.get("/clock")
            assert _change(lis.node, change, Transition.TRANSITION_CONFIGURE)
            assert _state(get) == "inactive" and not lis.get("/clock")
            assert _change(lis.node, change, Transition.TRANSITION_ACTIVATE)
            lis.wait_for(lambda: (lis.clock() or 0.0) >= 0.3, 60, "/clock >= 0.3")
            active = one_step()
            assert not active.success and "the node is active" in active.message
            assert _change(lis.node, change, Transition.TRANSITION_DEACTIVATE)

            def stale():
                return [
                    m
                    for m in lis.get("/diagnostics")
                    for s in m.status
                    if s.name == "press_twin: pacing" and s.level == b"\x03"
                ]

            # paused: two STALE reports (two diagnostics periods at least), and no step beyond
            # the one they say simulated time holds at
            lis.wait_for(lambda: len(stale()) >= 2, 30, "two STALE pacing statuses")
            held = ns(stale()[0].header.stamp)
            # the clock up to the held step may come in after the statuses: waited for
            lis.wait_for(lambda: ns(lis.get("/clock")[-1].clock) >= held, 30, "/clock at the held step")
            assert all(ns(m.clock) <= held for m in lis.get("/clock"))
            assert ns(lis.get("/clock")[-1].clock) == held
            # ~/step while paused: one step each, published, then held again
            for i in (1, 2, 3):
                answer = one_step()
                t = (held + i * 1_000_000) * 1e-9
                assert answer.success and answer.message == f"stepped to t = {t:.6f} s", answer
                lis.wait_for(
                    lambda i=i: ns(lis.get("/clock")[-1].clock) == held + i * 1_000_000,
                    30,
                    f"/clock at the step {i} taken",
                )
            n = len(stale())
            lis.wait_for(lambda: len(stale()) >= n + 1, 30, "STALE after the steps")
            assert ns(lis.get("/clock")[-1].clock) == held + 3_000_000
            assert _change(lis.node, change, Transition.TRANSITION_ACTIVATE)
            lis.wait_for(
                lambda: (lis.clock() or 0.0) >= held * 1e-9 + 0.3, 60, "/clock going on after the pause"
            )
            assert _change(lis.node, change, Transition.TRANSITION_ACTIVE_SHUTDOWN)
            assert node.wait(60) == 0, node.log()
            log = node.log()
    finally:
        lis.close()
    assert log.count("deactivated: paused") == 1 and "activated: the run goes on" in log
    assert "run stopped (shutdown)" in log and f"recording finished: {rec}" in log
    # the recording: finished (rosbags reads it), every step once, the same as a run never
    # paused up to where it stopped
    got = read_all(rec)
    stamps = [t for t, _m, _raw in got["/joint_states"]]
    assert stamps == [k * 1_000_000 for k in range(len(stamps))] and len(stamps) > 600
    want = _uninterrupted(tmp_path, 3.0)
    for topic in ("/joint_states", "/press_twin/foundation", "/tf"):
        n = len(got[topic])
        assert [(t, raw) for t, _m, raw in got[topic]] == [(t, raw) for t, _m, raw in want[topic][:n]], topic


def test_shut_down_before_it_is_configured(ros, tmp_path):
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState

    rec = tmp_path / "never.mcap"
    lis = Listener(keys=("/clock",))
    change = lis.node.create_client(ChangeState, "/press_twin/change_state")
    try:
        with NodeProcess(tmp_path, dict(autostart=False, recording=str(rec)), name="never") as node:
            assert _change(lis.node, change, Transition.TRANSITION_UNCONFIGURED_SHUTDOWN)
            assert node.wait(60) == 0, node.log()
            log = node.log()
    finally:
        lis.close()
    assert "ended before its run started" in log
    assert not rec.exists() and not lis.get("/clock")


def test_a_reset_begins_a_new_run_recorded_beside_the_first(ros, tmp_path):
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState
    from std_srvs.srv import Trigger

    rec = tmp_path / "first.mcap"
    params = dict(pacing="realtime", dt=0.001, t_end=5.0, recording=str(rec))
    lis = Listener(keys=("/clock",))
    change = lis.node.create_client(ChangeState, "/press_twin/change_state")
    reset = lis.node.create_client(Trigger, "/press_twin/reset")
    try:
        with NodeProcess(tmp_path, params, name="reset") as node:
            lis.wait_for(lambda: (lis.clock() or 0.0) >= 0.2, 60, "/clock >= 0.2")
            assert reset.wait_for_service(timeout_sec=30)
            fut = reset.call_async(Trigger.Request())
            wait_until(fut.done, 120, "~/reset's answer")
            answer = fut.result()
            second = tmp_path / "first-2.mcap"
            assert answer.success, answer.message
            assert answer.message == f"reset: a new run from t = 0 s, recording to {second}"

            def restarted():
                ts = [ns(m.clock) for m in lis.get("/clock")]
                back = next((i for i in range(1, len(ts)) if ts[i] < ts[i - 1]), None)
                return back is not None and ts[-1] >= 200_000_000 and ts[back] == 0

            lis.wait_for(restarted, 60, "/clock from 0 again, then to 0.2 s")
            assert _change(lis.node, change, Transition.TRANSITION_ACTIVE_SHUTDOWN)
            assert node.wait(60) == 0, node.log()
            log = node.log()
    finally:
        lis.close()
    assert "run stopped (reset)" in log and "run stopped (shutdown)" in log
    assert f"recording finished: {rec}" in log and f"recording finished: {second}" in log
    want = _uninterrupted(tmp_path, 5.0)
    for path in (rec, second):  # each a run from the start, as the same run unpaused
        got = read_all(path)
        n = len(got["/joint_states"])
        assert n > 150
        assert [(t, raw) for t, _m, raw in got["/joint_states"]] == [
            (t, raw) for t, _m, raw in want["/joint_states"][:n]
        ], path
