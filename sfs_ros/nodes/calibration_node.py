"""Calibration node: calibrates the running cell from a ChArUco board on the plate.

| kind | name | type | notes |
|---|---|---|---|
| act | ``calibrate`` | sfs_ros_interfaces/Calibrate | a calibration: feedback, cancel, result |
| sub | ``calibration/image``, ``calibration/joint_state`` | Image, JointState | a board scan's captures |
| pub | ``capture/stored`` | std_msgs/Header | a receipt for each capture received |
| cli | ``scan`` | sfs_ros_interfaces/Scan | the scan node's action (object "board") |
| cli | ``carving/get_parameters`` | rcl_interfaces | the cell's rig now (the fit's start) |
| cli | each rig holder's parameter services | rcl_interfaces | ``apply``: the new rig |

A ``calibrate`` goal: a ``Scan`` goal of object ``board`` with the calibration plan
(the goal's ``plan_file``, else the parameter ``plan_file``); the board's captures, paired
by stamp, are stored in ``OUTPUT_DIR/calibration_<UTC time>/session/`` and receipted on
``capture/stored`` (the scan node's delivery: a capture not receipted is sent again), and
the board looked for in each (feedback ``boards_detected``); then, in a worker thread, the
fit of ``sfs-calibrate`` (:func:`sfs_ros.cell_logic.calibration_run.fit_and_write`) from the
carving node's rig, which writes ``rig.yaml``, ``camera_info.yaml`` and
``calibration_report.yaml`` beside the session; with ``apply``, the rig is set on every
node that holds it and kept in ``OUTPUT_DIR/calibration/rig.yaml``
(:func:`sfs_ros.ros.rig_apply.apply_rig`). Feedback: the phase (scanning, fitting,
applying), views captured of the plan's, boards detected. A cancel cancels the board scan
(the fit is not started). One goal at a time; a bad goal (board, plan) is accepted, then
aborted with the reason. Board captures that come outside a goal (a board scan started
another way, recorded for ``sfs-calibrate BAG``) are receipted, not stored.

Capture topics and receipts: reliable, volatile, depth ``queue_depth``
(:func:`sfs_ros.ros.capture_qos`), as the scan node's. Parameters: :data:`PARAMS`;
``output_dir`` is required, nothing is written outside it.
"""

from __future__ import annotations

import threading
from functools import partial
from pathlib import Path

import numpy as np
from builtin_interfaces.msg import Time
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import Image, JointState
from std_msgs.msg import Header

from sfs_ros.cell_logic.calibration_run import BoardCaptures, calibration_folder, fit_and_write
from sfs_ros.cell_logic.message_fields import angles_from_joint_state, msg_to_image
from sfs_ros.cell_logic.scan_plan import load_plan
from sfs_ros.core.calibration import BoardSpec
from sfs_ros.nodes.entry import run_node
from sfs_ros.process import configure_process
from sfs_ros.ros import capture_qos
from sfs_ros.ros.action_client import RaceFreeActionClient
from sfs_ros.ros.calibration_params import PARAMS
from sfs_ros.ros.names import CALIBRATE_ACTION, SCAN_ACTION
from sfs_ros.ros.paired_input import PairedInput, Stream
from sfs_ros.ros.pairing import format_stamp
from sfs_ros.ros.params import ParameterError, declare, output_folder
from sfs_ros.ros.rig_apply import apply_rig, cell_rig
from sfs_ros.ros.worker import Worker
from sfs_ros_interfaces.action import Calibrate, Scan

__all__ = ["CalibrationNode", "PARAMS", "main"]

NODE_NAME = "calibration"
#: The goal states a result comes with (action_msgs/GoalStatus).
_SUCCEEDED = 4
#: How often a goal waiting on the scan, the fit or the apply looks for a cancel, s.
_POLL_S = 0.1

def _decode_image(msg: Image) -> np.ndarray:
    """(H, W, 3) uint8 RGB of a capture; ValueError for another depth or a bad layout."""
    image = msg_to_image(msg)
    if image.dtype != np.uint8:
        raise ValueError(f"image encoding {msg.encoding!r} is not 8-bit")
    return image if image.ndim == 3 else np.repeat(image[:, :, None], 3, axis=2)


def _wait(future, until: float | None, cancelled) -> bool:
    """Wait for an rclpy or concurrent future, looking for ``cancelled()`` every
    :data:`_POLL_S`; whether it is done (False: cancelled, or ``until`` s elapsed)."""
    done = threading.Event()
    future.add_done_callback(lambda _f: done.set())
    waited = 0.0
    while not done.wait(_POLL_S):
        waited += _POLL_S
        if cancelled() or (until is not None and waited >= until):
            return done.is_set()
    return True


class CalibrationNode(Node):
    """Serves ``calibrate``; see the module's description.

    Raises :class:`ParameterError` at construction for invalid parameters.
    """

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        p = self._p = declare(self, PARAMS)
        try:
            self._output = output_folder(p["output_dir"], "the calibrations").resolve()
        except ParameterError:
            super().destroy_node()
            raise
        self._lock = threading.Lock()
        self._busy = False
        self._captures: BoardCaptures | None = None   # the goal's, while it scans
        self._rejected: list[tuple[str, str]] = []     # captures the goal could not use
        self._outside_said = False
        self._worker = Worker("calibration", on_error=lambda _name, _exc: None)
        qos = capture_qos(p["queue_depth"])
        self._receipts = self.create_publisher(Header, "capture/stored", qos)
        PairedInput(self, Stream(Image, "calibration/image", "image", _decode_image),
                    Stream(JointState, "calibration/joint_state", "joint state",
                           angles_from_joint_state),
                    p["queue_depth"], qos, unit="capture", on_pair=self._on_capture,
                    on_problem=lambda _kind, text: self.get_logger().warning(text),
                    callback_group=MutuallyExclusiveCallbackGroup())
        actions = ReentrantCallbackGroup()
        self._scan = RaceFreeActionClient(self, Scan, SCAN_ACTION, callback_group=actions)
        self._action = ActionServer(self, Calibrate, CALIBRATE_ACTION, self._execute,
                                    goal_callback=self._on_goal,
                                    cancel_callback=lambda _h: CancelResponse.ACCEPT,
                                    callback_group=actions)
        self.get_logger().info(f"calibrations go to {self._output}; board "
                               f"{p['columns']}x{p['rows']} squares of {p['square_m']} m; "
                               "send a calibrate goal")

    def destroy_node(self) -> None:
        self._worker.stop(cancel_reason="the node is shutting down")
        self._worker.join(timeout_s=10.0)
        self._action.destroy()
        self._scan.destroy()
        super().destroy_node()

    # -- captures (executor) -----------------------------------------------------------------

    def _on_capture(self, stamp, rgb: np.ndarray, angles: tuple[float, float]) -> None:
        """Store the capture in the goal's session (if a goal scans), then receipt it; one
        that cannot be written is not receipted (the scan node sends it again)."""
        with self._lock:
            captures = self._captures
        if captures is None:
            if not self._outside_said:
                self._outside_said = True
                self.get_logger().info("board captures outside a calibrate goal: receipted, "
                                       "not stored (said once)")
        else:
            try:
                captures.add(stamp, rgb, *angles)
            except ValueError as exc:
                with self._lock:
                    self._rejected.append((f"view at stamp {format_stamp(stamp)}", str(exc)))
            except OSError as exc:
                self.get_logger().error(f"board capture at stamp {format_stamp(stamp)} not "
                                        f"stored in {captures.session}: {exc}; not receipted, "
                                        "it comes again")
                return
        self._receipts.publish(Header(stamp=Time(sec=stamp[0], nanosec=stamp[1])))

    # -- the calibrate action ----------------------------------------------------------------

    def _on_goal(self, _goal) -> GoalResponse:
        with self._lock:
            if self._busy:
                self.get_logger().info("calibrate goal rejected: a calibration is running")
                return GoalResponse.REJECT
            self._busy = True
        return GoalResponse.ACCEPT

    def _execute(self, goal_handle) -> Calibrate.Result:
        try:
            return self._calibrate(goal_handle)
        finally:
            with self._lock:
                self._busy, self._captures = False, None

    def _goal_settings(self, goal) -> tuple[str, int, BoardSpec]:
        """The goal's plan file, its number of views and the board, each empty field the
        parameter's; ValueError naming what was wrong."""
        p = self._p
        plan = goal.plan_file.strip() or p["plan_file"].strip()
        if not plan:
            raise ValueError("no plan: the goal's plan_file is empty and so is the node's "
                             "plan_file parameter; expected a calibration plan file")
        views = len(load_plan(plan))
        board = BoardSpec(goal.columns or p["columns"], goal.rows or p["rows"],
                          square_m=goal.square_m or p["square_m"],
                          marker_m=goal.marker_m or p["marker_m"],
                          dictionary=goal.dictionary.strip() or p["dictionary"])
        return str(Path(plan).resolve()), views, board

    def _calibrate(self, goal_handle) -> Calibrate.Result:
        """Scan the board, fit, write, apply: the goal's result."""
        goal, result = goal_handle.request, Calibrate.Result()
        try:
            plan, views, board = self._goal_settings(goal)
            rig = cell_rig(self, timeout_s=self._p["apply_timeout_s"])
            captures = BoardCaptures(calibration_folder(self._output), rig, board)
            captures.planned = views
        except (ValueError, OSError, TimeoutError) as exc:
            return self._end(goal_handle, result, f"calibration refused: {exc}")
        with self._lock:
            self._captures, self._rejected = captures, []
        self.get_logger().info(f"calibrate goal: board {board.squares_x}x{board.squares_y}, "
                               f"plan {plan}, captures to {captures.session}")
        failure = self._scan_board(goal_handle, plan, captures)
        with self._lock:
            self._captures = None
        if failure:
            return self._end(goal_handle, result, failure)
        self._feedback(goal_handle, Calibrate.Feedback.PHASE_FITTING, captures,
                       f"fitting the rig to {captures.detected} board views")
        job = partial(fit_and_write, captures, within=self._output,
                      radial_terms=self._p["radial_terms"],
                      max_view_rms_px=self._p["max_view_rms_px"],
                      camera_name=self._p["camera_name"])
        files, failure = self._run(job, "fit")
        if failure:
            return self._end(goal_handle, result, f"calibration failed: {failure}")
        self._fill(result, files)
        if goal.apply and not goal_handle.is_cancel_requested:
            self._feedback(goal_handle, Calibrate.Feedback.PHASE_APPLYING, captures,
                           f"applying {files.rig_file} to the cell")
            applied, failure = self._run(partial(apply_rig, self, files.rig_file,
                                                 timeout_s=self._p["apply_timeout_s"]),
                                         "apply")
            if failure:
                return self._end(goal_handle, result, f"calibrated ({result.rig_file}), "
                                 f"not applied: {failure}")
            result.applied, result.applied_nodes = True, list(applied.nodes)
            result.message += f"; applied to {', '.join(applied.nodes)}, kept in " \
                              f"{applied.persisted}"
        return self._end(goal_handle, result, "", success=not goal_handle.is_cancel_requested)

    def _scan_board(self, goal_handle, plan: str, captures: BoardCaptures) -> str:
        """Run the board scan to its end; "" when it succeeded, else why not."""
        if not self._scan.wait_for_server(timeout_sec=self._p["apply_timeout_s"]):
            return f"the {SCAN_ACTION} action is not available: is the scan node running?"

        def on_feedback(msg) -> None:
            f = msg.feedback
            self._feedback(goal_handle, Calibrate.Feedback.PHASE_SCANNING, captures,
                           f.message, captured=f.views_captured, total=f.views_total)

        sent = self._scan.send_goal_async(Scan.Goal(plan_file=plan, object=Scan.Goal.BOARD),
                                          feedback_callback=on_feedback)
        if not _wait(sent, self._p["apply_timeout_s"], lambda: False):
            return "the scan node did not answer the board scan goal"
        handle = sent.result()
        if not handle.accepted:
            return "the scan node rejected the board scan: a scan is running (cancel it first)"
        answer = handle.get_result_async()
        cancelling = False
        while not _wait(answer, self._p["scan_timeout_s"],
                        lambda: goal_handle.is_cancel_requested and not cancelling):
            if not goal_handle.is_cancel_requested:
                handle.cancel_goal_async()
                return f"the board scan took longer than {self._p['scan_timeout_s']:g} s"
            cancelling = True
            handle.cancel_goal_async()
        scan = answer.result()
        if scan.status != _SUCCEEDED:
            return f"board scan {'cancelled' if cancelling else 'failed'}: {scan.result.message}"
        return ""

    def _run(self, job, name: str):
        """``(answer, "")`` of ``job`` run in the worker thread, or ``(None, why not)``."""
        future = self._worker.submit(job, name=name)
        _wait(future, None, lambda: False)
        try:
            return future.result(), ""
        except (ValueError, OSError, TimeoutError) as exc:
            return None, str(exc)
        except Exception as exc:  # noqa: BLE001 -- a bug must end the goal, not the node
            return None, f"internal error in the {name}: {type(exc).__name__}: {exc}"

    def _feedback(self, goal_handle, phase: str, captures: BoardCaptures, message: str, *,
                  captured: int | None = None, total: int | None = None) -> None:
        feedback = Calibrate.Feedback(phase=phase, views_captured=captures.stored,
                                      views_total=captures.planned,
                                      boards_detected=captures.detected, message=message)
        if captured is not None:
            feedback.views_captured, feedback.views_total = captured, total
        goal_handle.publish_feedback(feedback)

    @staticmethod
    def _fill(result: Calibrate.Result, files) -> None:
        fit = files.fit
        result.rig_file, result.report_file = str(files.rig_file), str(files.report_file)
        result.rms_px, result.views_used = fit.rms_px, len(fit.view_rms_px)
        result.views_rejected = [f"{name}: {reason}" for name, reason in fit.rejected]
        result.message = (f"calibrated from {len(fit.view_rms_px)} views ({fit.corners} "
                          f"corners, {len(fit.rejected)} rejected): RMS {fit.rms_px:.3f} px; "
                          f"{files.rig_file}")

    def _end(self, goal_handle, result: Calibrate.Result, failure: str, *,
             success: bool = False) -> Calibrate.Result:
        """End the goal: succeeded, else canceled when asked, else aborted with
        ``failure`` as the message (a WARN: the caller's to act on)."""
        with self._lock:
            result.views_rejected = [f"{n}: {r}" for n, r in self._rejected] \
                + list(result.views_rejected)
        if success:
            result.success = True
            goal_handle.succeed()
            self.get_logger().info(f"calibrate goal: {result.message}")
            return result
        result.success, result.message = False, failure or "cancelled"
        if goal_handle.is_cancel_requested:
            goal_handle.canceled()
        else:
            goal_handle.abort()
        self.get_logger().warning(f"calibrate goal ended: {result.message}")
        return result


def main(args=None) -> None:
    """Entry point ``sfs-calibration`` (``--ros-args --params-file config/calibration.yaml
    -p output_dir:=OUT``)."""
    configure_process()
    run_node("sfs-calibration", CalibrationNode, args, threads=4)


if __name__ == "__main__":
    main()
