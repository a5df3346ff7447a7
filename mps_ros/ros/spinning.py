"""An executor spun in a thread of its own, and ended before what it spins is destroyed.

rclpy does not support destroying a node while another thread spins it: the process can crash
in ``destroy_node`` (ros2/rclpy#663, and a test run here ended so). Jazzy's
``Executor.shutdown`` does not wait for the spinning thread either: it destroys the executor's
guard condition at once. So a thread spins until a future of its own is done, ``stop`` completes
that future (which wakes the executor) and waits for the thread to end, and only then are the
executor and its nodes taken down: :func:`close` does it in that order, or, when the thread does
not end, leaves them to the process's end rather than crash it.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable

from rclpy.executors import Executor, ExternalShutdownException
from rclpy.task import Future


class SpinThread:
    """``executor`` spun in a daemon thread named ``name`` from creation until :meth:`stop`.

    An exception a callback raises ends the spinning and is handed to ``on_error`` (kept in
    :attr:`error` when there is none)."""

    def __init__(self, executor: Executor, name: str, on_error: Callable[[Exception], None] | None = None):
        self.executor = executor
        self.error: Exception | None = None
        self._on_error = on_error
        self._stopped = Future()
        self.thread = threading.Thread(target=self._spin, name=name, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        try:
            self.executor.spin_until_future_complete(self._stopped)
        except ExternalShutdownException:
            pass
        except Exception as exc:  # a callback failed: said, not swallowed
            self.error = exc
            if self._on_error is not None:
                self._on_error(exc)

    def alive(self) -> bool:
        return self.thread.is_alive()

    def stop(self, timeout: float = 10.0) -> bool:
        """End the spinning; True once the thread has ended (within ``timeout`` s)."""
        if not self._stopped.done():
            self._stopped.set_result(True)  # its done callback wakes the executor
        self.executor.wake()
        self.thread.join(timeout)
        return not self.thread.is_alive()


def close(spin: SpinThread | None, nodes: Iterable, timeout: float = 10.0) -> bool:
    """Stop ``spin``, then shut its executor down and destroy ``nodes`` (None entries skipped).

    When the thread does not end within ``timeout`` s nothing is destroyed (False)."""
    if spin is not None:
        if not spin.stop(timeout):
            return False
        spin.executor.shutdown(timeout_sec=timeout)
    for node in nodes:
        if node is not None:
            node.destroy_node()
    return True
