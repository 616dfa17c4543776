"""The scan node's ``scan`` action and ``status``: goals followed to their results.

:class:`ScanStatusBoard` publishes the scan node's ``status`` (``CellStatus``) and keeps
the carving node's (``ReconstructionStatus``), each waited for from any thread.
:class:`ScanGoals` serves the action: one goal at a time and none while a scan runs (a
bad goal is accepted, then aborted with the reason: a rejection carries none); feedback
follows every change of ``status``; a cancel request stops the axes; the result comes
once the scan's run ends and, done, every view is receipted.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node

from sfs_ros.cell_logic.scan_goal import scan_outcome
from sfs_ros.cell_logic.scan_sequence import ScanSequence
from sfs_ros.ros import result_qos
from sfs_ros.ros.names import CELL_STATUS, RECONSTRUCTION_STATUS, SCAN_ACTION
from sfs_ros.ros.typed import scan_feedback, scan_result
from sfs_ros_interfaces.action import Scan
from sfs_ros_interfaces.msg import CellStatus, ReconstructionStatus

__all__ = ["ScanGoals", "ScanStatusBoard"]

#: How often a running goal looks for a cancel request, s.
GOAL_POLL_S = 0.1


class ScanStatusBoard:
    """``node``'s ``status`` publisher and its subscription to the carving node's."""

    def __init__(self, node: Node, callback_group):
        self._changed = threading.Condition()  # notified with every status published or heard
        self._lock = threading.Lock()          # one status published at a time, newest last
        self.status: CellStatus | None = None
        self.reconstruction = ReconstructionStatus()
        self._publisher = node.create_publisher(CellStatus, CELL_STATUS, result_qos())
        node.create_subscription(ReconstructionStatus, RECONSTRUCTION_STATUS,
                                 self._on_reconstruction, result_qos(),
                                 callback_group=callback_group)

    def _on_reconstruction(self, msg: ReconstructionStatus) -> None:
        with self._changed:
            self.reconstruction = msg
            self._changed.notify_all()

    def publish(self, make: Callable[[], CellStatus]) -> None:
        """Publish ``make()`` (and wake the goal that follows it)."""
        with self._lock:
            msg = make()
            with self._changed:
                self.status = msg
                self._changed.notify_all()
            self._publisher.publish(msg)

    def next_status(self, sent: CellStatus | None, timeout_s: float) -> CellStatus | None:
        """The status once it is another than ``sent``, or after ``timeout_s``."""
        with self._changed:
            self._changed.wait_for(lambda: self.status is not sent, timeout_s)
            return self.status

    def reconstruction_of(self, views: int, timeout_s: float) -> ReconstructionStatus:
        """The carving node's status once it counts ``views`` views stored or rejected, or
        after ``timeout_s``."""
        with self._changed:
            self._changed.wait_for(
                lambda: self.reconstruction.views_stored
                + len(self.reconstruction.views_rejected) >= views, timeout_s)
            return self.reconstruction

    def latest_reconstruction(self) -> ReconstructionStatus:
        with self._changed:
            return self.reconstruction


class ScanGoals:
    """The ``scan`` action of ``node``. ``start(goal)`` starts a goal's scan and gives
    ``(why not, None)`` or ``("", the scan's number)``; ``board()`` tells whether the
    scan is of a calibration board. :attr:`lock` and :attr:`busy` tell a ``scan/start``
    that a goal runs."""

    def __init__(self, node: Node, sequence: ScanSequence, board: ScanStatusBoard, *,
                 start: Callable, of_board: Callable[[], bool], service_timeout_s: float):
        self._node = node
        self._sequence = sequence
        self._board = board
        self._start = start
        self._of_board = of_board
        self._service_timeout_s = service_timeout_s
        self.lock = threading.Lock()
        self.busy = False
        self._server = ActionServer(node, Scan, SCAN_ACTION, self._execute,
                                    goal_callback=self._on_goal,
                                    cancel_callback=lambda _goal_handle: CancelResponse.ACCEPT,
                                    callback_group=ReentrantCallbackGroup())

    def destroy(self) -> None:
        self._server.destroy()

    def _on_goal(self, _goal) -> GoalResponse:
        with self.lock:
            if self.busy or self._sequence.active:
                self._node.get_logger().info("scan goal rejected: a scan is running")
                return GoalResponse.REJECT
            self.busy = True
        return GoalResponse.ACCEPT

    def _execute(self, goal_handle) -> Scan.Result:
        try:
            refusal, scan = self._start(goal_handle.request)
            if refusal:
                return self._end(goal_handle, False, refusal)
            return self._follow(goal_handle, scan)
        finally:
            with self.lock:
                self.busy = False

    def _follow(self, goal_handle, scan: int) -> Scan.Result:
        """Feedback with every status until the scan's run ends and (done) every view is
        receipted; then the goal's end."""
        sent, cancelling = None, False
        while True:
            status = self._board.next_status(sent, GOAL_POLL_S)
            if goal_handle.is_cancel_requested and not cancelling:
                cancelling = True
                self._sequence.cancel()
            if status is not None and status is not sent and status.scan == scan:
                goal_handle.publish_feedback(scan_feedback(status))
            sent = status
            values = self._sequence.status().values
            success = scan_outcome(values, scan)
            if success is not None:
                return self._end(goal_handle, success, status.message, values)

    def _end(self, goal_handle, success: bool, message: str,
             values: dict | None = None) -> Scan.Result:
        """End the goal (succeeded; canceled when asked; else aborted) with its result; a
        scan that ended done waits (``service_timeout_s`` at most) for the reconstruction's
        status to count its views."""
        board = self._of_board()
        if values is not None and not board and success:
            reconstruction = self._board.reconstruction_of(values["total"],
                                                           self._service_timeout_s)
        else:
            reconstruction = self._board.latest_reconstruction()
        result = scan_result(success, message, values, reconstruction, board=board)
        if success:
            goal_handle.succeed()
        elif goal_handle.is_cancel_requested:
            goal_handle.canceled()
        else:
            goal_handle.abort()
        self._node.get_logger().info(f"scan goal ended: {'succeeded' if success else message}")
        return result
