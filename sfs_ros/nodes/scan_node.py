"""Scan node: the operator console. Visits a plan of viewpoints and publishes tagged captures.

The sequencing is :class:`sfs_ros.cell_logic.scan_sequence.ScanSequence` (tested without
processes); this node connects its ports (:class:`sfs_ros.ros.scan_ports.RosPorts`) to
topics and services, and serves the ``scan`` action. What it does, in full:
``doc/nodes.md``; its parameters: ``doc/reference.md`` (generated from :data:`PARAMS`);
its topics and services: ``doc/cell.md``.
"""

from __future__ import annotations

import math
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import Image, JointState
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from sfs_ros.cell_logic.message_fields import ForeignJointState
from sfs_ros.cell_logic.scan_goal import OBJECTS, goal_object, goal_plan
from sfs_ros.cell_logic.scan_sequence import TRIGGERS, ScanSequence
from sfs_ros.nodes.entry import run_node
from sfs_ros.process import configure_process
from sfs_ros.ros import capture_qos
from sfs_ros.ros.convert import angles_from_joint_state, diagnostic_array, health
from sfs_ros.ros.driver_camera import DRIVER_PARAMS, DriverCamera
from sfs_ros.ros.names import (
    DIAGNOSTICS,
    RECORDER_NODE,
    SERVICES,
    TYPED_SERVICES,
    private,
    status_name,
)
from sfs_ros.ros.pairing import stamp_key
from sfs_ros.ros.params import Param, ParameterError, declare, read, validating_callback
from sfs_ros.ros.scan_action import ScanGoals, ScanStatusBoard
from sfs_ros.ros.scan_params import scan_plan, scan_progress, scan_settings
from sfs_ros.ros.scan_ports import RosPorts
from sfs_ros.ros.typed import cell_status
from sfs_ros_interfaces.srv import NewScan

__all__ = ["ScanNode", "PARAMS", "main"]

NODE_NAME = "scan"
#: The axes count as disconnected when no encoder reading came for this long, s.
AXES_SILENT_S = 2.0

PARAMS: list[Param] = [
    Param("plan_file", "", "YAML scan plan (format: sfs_ros/cell_logic/scan_plan.py); empty = the "
          "ring parameters below.", read_only=True),
    Param("rings_phi_deg", [15.0, 40.0, 65.0], "Carriage elevations of the view rings, deg.",
          bounds=(-90.0, 90.0), read_only=True),
    Param("per_ring", 16, "Turntable stops per ring.", bounds=(1, 3600), read_only=True),
    Param("top_view", True, "One more view from straight above.", read_only=True),
    Param("stagger", True, "Offset every other ring by half a turntable step.", read_only=True),
    Param("reorder", True, "Order the views to shorten the motion.", read_only=True),
    Param("settle_tolerance_deg", 0.1, "Largest distance from the target, and spread of the "
          "last readings, of a settled axis, deg.", bounds=(0.0001, 10.0), read_only=True),
    Param("settle_samples", 3, "Consecutive encoder readings that must be on the target.",
          bounds=(1, 100), read_only=True),
    Param("move_timeout_s", 60.0, "Longest wait for one move to settle, s.",
          bounds=(0.1, 3600.0), read_only=True),
    Param("stall_s", 3.0, "Readings that stay still this long away from the target are a "
          "stall, s.", bounds=(0.1, 3600.0), read_only=True),
    Param("move_retries", 2, "Moves commanded again before the scan pauses.",
          bounds=(0, 100), read_only=True),
    Param("capture_timeout_s", 10.0, "Longest wait for the shutter's answer and its frame, s.",
          bounds=(0.1, 600.0), read_only=True),
    Param("capture_retries", 2, "Shots retaken before the scan pauses.", bounds=(0, 100),
          read_only=True),
    Param("encoder_max_gap_s", 0.5, "Largest time between the shutter and the encoder reading "
          "that tags it, s.", bounds=(0.001, 60.0), read_only=True),
    Param("receipt_timeout_s", 10.0, "A capture not receipted by the reconstruction this long "
          "after it was sent is sent again, s.", bounds=(0.1, 3600.0), read_only=True),
    Param("max_sends", 5, "Most sends of one capture.", bounds=(1, 1000), read_only=True),
    Param("reset_reconstruction", True, "scan/start resets the carving node first.",
          read_only=True),
    Param("home_before_scan", True, "scan/start homes the axes first.", read_only=True),
    Param("service_timeout_s", 10.0, "Deadline of the reset and stop calls, s.",
          bounds=(0.1, 600.0), read_only=True),
    Param("home_timeout_s", 120.0, "Deadline of the homing call, s.", bounds=(0.1, 3600.0),
          read_only=True),
    Param("queue_depth", 100, "Depth of the reliable capture topics; at least the number of "
          "views of a scan.", bounds=(1, 100000), read_only=True),
    Param("camera_trigger", TRIGGERS[0], "How a view's frame is taken: shutter (our camera "
          "node's capture service) or stream (the first frame of image_raw stamped after the "
          "axes settled plus exposure_delay_s: any camera driver).", choices=TRIGGERS,
          constraints="takes effect at the next scan/start"),
    Param("exposure_delay_s", 0.0, "stream: the view's frame is stamped at least this long "
          "after the axes settled, s.", bounds=(0.0, 60.0),
          constraints="takes effect at the next scan/start"),
    Param("progress_dir", "", "Folder where the scan's progress and captures are kept, so "
          "that a restarted node takes the scan up; empty = not kept.", read_only=True),
    Param("home_before_retry", False, "Home the axes before a failed move is commanded "
          "again.", read_only=True),
    Param("listen_timeout_s", 30.0, "Longest wait before a scan's first capture for the "
          "subscriptions that must see it, s.", bounds=(0.1, 3600.0), read_only=True),
    *DRIVER_PARAMS,
]


class ScanNode(Node):
    """Runs the plan in a worker thread; the executor only feeds it and answers services.

    Raises :class:`ParameterError` at construction for invalid parameters.
    """

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        self._worker: threading.Thread | None = None
        try:
            self._p = declare(self, PARAMS)
            self.plan = scan_plan(self._p)
            progress = scan_progress(self._p, self.plan)
        except ParameterError:
            super().destroy_node()
            raise
        self._sequence = ScanSequence(self.plan.views,
                                      RosPorts(self, self._p["service_timeout_s"]),
                                      scan_settings(self._p), progress)
        self.scan_name = ""                   # the reconstruction's name of the next scan
        self.scan_object = OBJECTS[0]         # what this scan is of (its captures' topics)
        self._reading = (math.nan, math.nan)  # the last encoder reading, rad
        self._reading_at = -math.inf          # when it came, time.monotonic()
        self._foreign_seen = False            # a joint state of another machine was logged
        self.add_on_set_parameters_callback(validating_callback(self, PARAMS, lambda _: None))

        inputs = MutuallyExclusiveCallbackGroup()
        services = MutuallyExclusiveCallbackGroup()
        clients = ReentrantCallbackGroup()
        qos = capture_qos(self._p["queue_depth"])
        self.command_pub = self.create_publisher(JointState, "joint_command", 10)
        self.image_pub = self.create_publisher(Image, "capture/image", qos)
        self.joints_pub = self.create_publisher(JointState, "capture/joint_state", qos)
        self.outputs = {"object": (self.image_pub, self.joints_pub),
                        "board": (self.create_publisher(Image, "calibration/image", qos),
                                  self.create_publisher(JointState, "calibration/joint_state",
                                                        qos))}
        self._diag_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS, 10)
        self.create_subscription(JointState, "joint_states", self._on_joint_state, 10,
                                 callback_group=inputs)
        self.camera = DriverCamera(self, self._on_frame, inputs=inputs, clients=clients)
        self._receipt_sub = self.create_subscription(Header, "capture/stored", self._on_receipt,
                                                     qos, callback_group=inputs)
        self.peers = {name: self.create_client(Trigger, SERVICES[name], callback_group=clients)
                      for name in ("home", "stop", "capture")}
        self.new_scan = self.create_client(NewScan, TYPED_SERVICES["new_scan"],
                                           callback_group=clients)
        self._board = ScanStatusBoard(self, inputs)
        self._goals = ScanGoals(self, self._sequence, self._board, start=self._start_goal,
                                of_board=lambda: self.scan_object == "board",
                                service_timeout_s=self._p["service_timeout_s"])
        for name, handler in (("start", self._on_start), ("cancel", self._on_cancel),
                              ("resume", self._on_resume)):
            self.create_service(Trigger, private(f"scan/{name}"), handler, callback_group=services)
        self.create_timer(1.0, self._tick, callback_group=inputs)
        turntable, carriage = self.plan.travel_deg()
        self.get_logger().info(f"scan plan of {len(self.plan)} views ({turntable:.0f} deg of "
                               f"turntable and {carriage:.0f} deg of carriage travel); "
                               "call scan/start")
        if progress is not None:
            go_on, message = self._sequence.restore()
            self.get_logger().info(f"progress in {progress.folder}: {message}")
            if go_on:
                self._launch()

    def destroy_node(self) -> None:
        if self._worker is not None:
            self._sequence.cancel(stop_axes=False)
            self._worker.join(timeout=10.0)
        self._goals.destroy()
        super().destroy_node()

    # -- inputs (executor) -------------------------------------------------------------------

    def _on_joint_state(self, msg: JointState) -> None:
        try:
            theta, phi = angles_from_joint_state(msg)
            self._sequence.encoder_reading(stamp_key(msg.header.stamp), theta, phi)
            self._reading, self._reading_at = (theta, phi), time.monotonic()
        except ForeignJointState as exc:
            if not self._foreign_seen:
                self._foreign_seen = True
                self.get_logger().info(f"{exc}: such joint states are ignored (another "
                                       "machine's on the same topic); said once")
        except ValueError as exc:
            self._malformed(f"joint state ignored: {exc}")

    def _on_frame(self, msg) -> None:
        """A camera frame (``Image`` or ``CompressedImage``; converted once it is a view's)."""
        try:
            stamp = stamp_key(msg.header.stamp)
        except ValueError as exc:
            self._malformed(f"camera frame ignored: {exc}")
            return
        self._sequence.frame(stamp, msg)

    def _on_receipt(self, msg: Header) -> None:
        try:
            stamp = stamp_key(msg.stamp)
        except ValueError as exc:
            self._malformed(f"receipt ignored: {exc}")
            return
        if self._sequence.receipt(stamp):
            self.publish_status()

    def _malformed(self, text: str) -> None:
        self._sequence.count_malformed()
        self.get_logger().error(text)

    def _tick(self) -> None:
        """Delivery (resends; a receiver not seen before, a publisher of receipts or the
        recorder's subscription to the captures, is a restarted carving node or
        recorder: everything is sent again), then diagnostics."""
        receipts = self.get_publishers_info_by_topic(self._receipt_sub.topic_name)
        recorders = [info for info in
                     self.get_subscriptions_info_by_topic(self.joints_pub.topic_name)
                     if info.node_name == RECORDER_NODE
                     and info.node_namespace == self.get_namespace()]
        self._sequence.tick({bytes(info.endpoint_gid) for info in receipts + recorders})
        self.camera.update()
        self.publish_diagnostics()
        self.publish_status()

    # -- services and the scan action (executor) ---------------------------------------------

    def _on_start(self, _request, response):
        with self._goals.lock:
            if self._goals.busy:
                response.success, response.message = False, "a scan goal is running"
                return response
            values = read(self, PARAMS)
            refusal = self._check_camera(values)
            if refusal:
                response.success, response.message = False, refusal
                return response
            self.scan_name, self.scan_object = "", OBJECTS[0]
            response.success, response.message = self._sequence.start(scan_settings(values))
        if response.success:
            self._launch()
        return response

    def _on_resume(self, _request, response):
        response.success, response.message = self._sequence.resume()
        if response.success:
            self._launch()
        return response

    def _on_cancel(self, _request, response):
        response.success, response.message = self._sequence.cancel()
        if response.success:
            self._worker.join(timeout=self._p["service_timeout_s"])
        return response

    def _check_camera(self, values: dict) -> str:
        """Before a streamed scan starts: the driver's intrinsics against the rig
        (:meth:`DriverCamera.check_intrinsics`); the reason it may not start, or ""."""
        if values["camera_trigger"] != "stream" or self._sequence.active:
            return ""
        refusal = self.camera.check_intrinsics(values["service_timeout_s"])
        if refusal:
            self.get_logger().error(refusal)
        if self.camera.warning:
            self.get_logger().warning(self.camera.warning)
        self.publish_diagnostics()
        return refusal

    def _launch(self) -> None:
        self._worker = threading.Thread(target=self._sequence.run, name="scan", daemon=True)
        self._worker.start()

    def _start_goal(self, goal) -> tuple[str, int | None]:
        """Start a goal's scan: ``(why not, None)`` or ``("", the scan's number)``."""
        try:
            plan = goal_plan(goal.plan_file, goal.theta_rad, goal.phi_rad, goal.scan_name,
                             max_views=self._p["queue_depth"])
            scan_object = goal_object(goal.object)
        except ValueError as exc:
            return f"goal refused: {exc}", None
        values = read(self, PARAMS)
        refusal = self._check_camera(values)
        if refusal:
            return f"goal refused: {refusal}", None
        with self._goals.lock:
            self.scan_name, self.scan_object = goal.scan_name, scan_object
            ok, message = self._sequence.start(
                scan_settings(values, board=scan_object == "board"),
                None if plan is None else plan.views)
        if not ok:
            return f"goal refused: {message}", None
        self.get_logger().info(f"scan goal ({scan_object}): {message}")
        self._launch()
        return "", self._sequence.status().values["scan"]

    # -- diagnostics (any thread) ------------------------------------------------------------

    def publish_diagnostics(self) -> None:
        status = self._sequence.status()
        stream = self.get_parameter("camera_trigger").value == "stream"
        level, message = health(status.problem, status.warning
                                or (self.camera.warning if stream else ""), status.summary)
        self._diag_pub.publish(diagnostic_array(status_name(self, "scan"), level, message,
                                                {**status.values, **self.camera.values},
                                                stamp=self.get_clock().now().to_msg()))

    def publish_status(self) -> None:
        """``status`` now (and wake the goal that follows it)."""
        self._board.publish(lambda: cell_status(
            self._sequence.status(), self._reading,
            time.monotonic() - self._reading_at <= AXES_SILENT_S,
            stamp=self.get_clock().now().to_msg(), scan_object=self.scan_object))


def main(args=None) -> None:
    """Entry point ``sfs-scan`` (``--ros-args --params-file config/scan.yaml``)."""
    configure_process()
    run_node("sfs-scan", ScanNode, args, threads=4)


if __name__ == "__main__":
    main()
