"""An action client whose goal answer cannot be lost to the thread that spins it.

rclpy's ``ActionClient.send_goal_async`` (rclpy 9.1.2, the kilted wheels) registers the
goal's future under its lock, then, after releasing the lock, registers a second future for
the same request and returns that one. When the answer comes before the second
registration (another thread spins the node, and the sending thread is held up in
between, as on a loaded machine), it completes the first future and the returned one
never completes: the goal was accepted, its sender waits in vain.
"""

from __future__ import annotations

from rclpy.action import ActionClient
from rclpy.task import Future

__all__ = ["RaceFreeActionClient"]


class RaceFreeActionClient(ActionClient):
    """:class:`rclpy.action.ActionClient` with :meth:`send_goal_async` sending the goal and
    registering its one future and its feedback callback under the client's lock, which
    the executor takes to read an answer or a feedback message."""

    def send_goal_async(self, goal, feedback_callback=None, goal_uuid=None) -> Future:
        """Send ``goal``; a future of its ClientGoalHandle, done when the server accepts or
        rejects it. ``feedback_callback`` sees each of its feedback messages from the
        first; ``goal_uuid``: its ID (None: a random one)."""
        if not isinstance(goal, self._action_type.Goal):
            raise TypeError(f"expected a goal of {self._action_type.Goal.__name__}, "
                            f"got {type(goal).__name__}")
        request = self._action_type.Impl.SendGoalService.Request()
        request.goal_id = self._generate_random_uuid() if goal_uuid is None else goal_uuid
        request.goal = goal
        future = Future()
        with self._lock:
            sequence_number = self._client_handle.send_goal_request(request)
            if sequence_number in self._pending_goal_requests:
                raise RuntimeError(f"goal request {sequence_number} is already pending")
            if feedback_callback is not None:
                self._feedback_callbacks[bytes(request.goal_id.uuid)] = feedback_callback
            self._pending_goal_requests[sequence_number] = future
            self._goal_sequence_number_to_goal_id[sequence_number] = request.goal_id
            future.add_done_callback(self._remove_pending_goal_request)
            self.add_future(future)
        return future
