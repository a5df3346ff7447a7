"""An executor's thread ends before what it spins is destroyed (mps_ros.ros.spinning)."""

from __future__ import annotations

import os

from twin_probe import wait_until


def _node_with_a_topic(suffix: str, callback):
    from rclpy.node import Node
    from std_msgs.msg import String

    node = Node(f"spin_{suffix}_{os.getpid()}")
    topic = f"/spin_test_{suffix}_{os.getpid()}"
    node.create_subscription(String, topic, callback, 10)
    pub = node.create_publisher(String, topic, 10)
    return node, pub, String


def test_the_thread_takes_messages_until_stopped_and_has_ended_before_the_node_goes(ros):
    from rclpy.executors import SingleThreadedExecutor

    from mps_ros.ros.spinning import SpinThread, close

    got: list[str] = []
    node, pub, String = _node_with_a_topic("ok", lambda m: got.append(m.data))
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    spin = SpinThread(executor, "spin-test")
    wait_until(lambda: pub.get_subscription_count() > 0, 30, "the subscription matched")
    pub.publish(String(data="one"))
    wait_until(lambda: got, 30, "the message taken by the spinning thread")
    assert spin.alive()
    assert close(spin, [node])
    assert not spin.alive() and spin.error is None
    assert got == ["one"]


def test_a_callback_that_fails_ends_the_spinning_and_is_handed_over(ros):
    from rclpy.executors import SingleThreadedExecutor

    from mps_ros.ros.spinning import SpinThread, close

    def fail(msg):
        raise ValueError(f"cannot take {msg.data}")

    errors: list[Exception] = []
    node, pub, String = _node_with_a_topic("fail", fail)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    spin = SpinThread(executor, "spin-test-fail", errors.append)
    wait_until(lambda: pub.get_subscription_count() > 0, 30, "the subscription matched")
    pub.publish(String(data="two"))
    wait_until(lambda: not spin.alive(), 30, "the thread's end")
    assert [str(e) for e in errors] == ["cannot take two"]
    assert isinstance(spin.error, ValueError)
    assert close(spin, [node])


def test_a_thread_that_does_not_end_leaves_the_nodes_undestroyed(ros):
    import threading

    from rclpy.executors import SingleThreadedExecutor

    from mps_ros.ros.spinning import SpinThread, close

    release = threading.Event()
    entered = threading.Event()

    def hold(msg):  # a callback that has not returned when the thread is told to stop
        entered.set()
        release.wait(60)

    node, pub, String = _node_with_a_topic("held", hold)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    spin = SpinThread(executor, "spin-test-held")
    wait_until(lambda: pub.get_subscription_count() > 0, 30, "the subscription matched")
    pub.publish(String(data="three"))
    assert entered.wait(30)
    assert not close(spin, [node], timeout=0.2)
    assert spin.alive()
    node.get_name()  # not destroyed: a destroyed node raises InvalidHandle here
    release.set()
    assert close(spin, [node])
    assert not spin.alive()
