"""A multi-threaded executor that can be shut down while callbacks are still queued."""

from __future__ import annotations

from rclpy.executors import MultiThreadedExecutor

__all__ = ["DrainingExecutor"]


class DrainingExecutor(MultiThreadedExecutor):
    """A :class:`MultiThreadedExecutor` whose shutdown first runs to their end the callbacks
    handed to its thread pool, while its guard condition exists. rclpy's destroys the
    guard condition first, then lets the pool run what is queued: each such callback
    then triggers the destroyed guard condition, an exception that no one retrieves ("The
    following exception was never retrieved: cannot use Destroyable because destruction
    was requested"); dropping them instead leaves their coroutines never awaited.

    Shut it down once nothing spins it any more (the pool takes no new callbacks).
    """

    def shutdown(self, timeout_sec: float | None = None, *, wait_for_threads: bool = True) -> bool:
        self._executor.shutdown(wait=True)      # rclpy's thread pool: nothing new comes
        return super().shutdown(timeout_sec, wait_for_threads=wait_for_threads)
