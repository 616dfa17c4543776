"""rclpy's executors, made safe against an entity destroyed while they wait, and a
multi-threaded one that can be shut down while callbacks are still queued."""

from __future__ import annotations

from rclpy.exceptions import InvalidHandle
from rclpy.executors import MultiThreadedExecutor
from rclpy.executors import SingleThreadedExecutor as _RclpySingleThreadedExecutor

__all__ = ["DrainingExecutor", "SingleThreadedExecutor"]

#: Wait sets built in a row for one wait, each after an entity was found destroyed.
_BUILDS = 4


class _RebuildsItsWaitSet:
    """An executor that builds its wait set again when an entity in it was destroyed
    meanwhile.

    rclpy 9.1.2 builds the wait set from the lists of each node's entities. A
    subscription destroyed from another thread (a callback, or a thread that created it
    on a node spun elsewhere) after the lists were taken cannot be entered; rclpy skips
    such an entity, but keeps its event handlers (waitables) on the list it adds to the
    set, and adding one raises ``InvalidHandle`` out of ``spin_once``: the thread that
    spins ends, and the node (or a :class:`~sfs_ros.ros.cell_client.CellClient`) answers
    nothing any more. The destroyed entity has left its node's lists by then, so the set
    is built again without it; an entity that stays destroyed on its node's lists is
    still an error, raised after :data:`_BUILDS` builds.
    """

    def wait_for_ready_callbacks(self, *args, **kwargs):
        for _ in range(_BUILDS - 1):
            try:
                return super().wait_for_ready_callbacks(*args, **kwargs)
            except InvalidHandle:
                pass          # its generator has ended: the next call builds the set anew
        return super().wait_for_ready_callbacks(*args, **kwargs)


class SingleThreadedExecutor(_RebuildsItsWaitSet, _RclpySingleThreadedExecutor):
    """rclpy's single-threaded executor, safe against an entity destroyed while it waits."""


class DrainingExecutor(_RebuildsItsWaitSet, MultiThreadedExecutor):
    """A :class:`MultiThreadedExecutor`, safe against an entity destroyed while it waits,
    whose shutdown first runs to their end the callbacks handed to its thread pool,
    while its guard condition exists. rclpy's destroys the guard condition first, then
    lets the pool run what is queued: each such callback then triggers the destroyed
    guard condition, an exception that no one retrieves ("The following exception was
    never retrieved: cannot use Destroyable because destruction was requested");
    dropping them instead leaves their coroutines never awaited.

    Shut it down once nothing spins it any more (the pool takes no new callbacks).
    """

    def shutdown(self, timeout_sec: float | None = None, *, wait_for_threads: bool = True) -> bool:
        self._executor.shutdown(wait=True)      # rclpy's thread pool: nothing new comes
        return super().shutdown(timeout_sec, wait_for_threads=wait_for_threads)
