"""Scan node: the operator console. Visits a plan of viewpoints and publishes tagged captures.

| kind | name | type | notes |
|---|---|---|---|
| pub | ``joint_command`` | sensor_msgs/JointState | the next viewpoint, rad (to the motor node) |
| sub | ``joint_states`` | sensor_msgs/JointState | encoder read-back (from the motor node) |
| sub | ``image_raw`` | sensor_msgs/Image | the camera's frames (any driver); QoS: see below |
| sub | ``image_raw/compressed`` | sensor_msgs/CompressedImage | instead (``image_transport``) |
| sub | ``<image ns>/camera_info`` | sensor_msgs/CameraInfo | the driver's intrinsics |
| pub | ``capture/image`` | sensor_msgs/Image | each view's frame, its shutter stamp |
| pub | ``capture/joint_state`` | sensor_msgs/JointState | encoder angles at the shutter, same stamp |
| pub | ``calibration/image``, ``calibration/joint_state`` | as ``capture/*`` | a board scan's |
| sub | ``capture/stored`` | std_msgs/Header | receipts (reconstruction, calibration node) |
| pub | ``/diagnostics`` | diagnostic_msgs/DiagnosticArray | progress, at 1 Hz and on every event |
| pub | ``status`` | sfs_ros_interfaces/CellStatus | the same, typed; 1 Hz and on every change |
| act | ``scan`` | sfs_ros_interfaces/Scan | a scan: feedback, cancel, result |
| srv | ``~/start`` | std_srvs/Trigger | alias: a default ``scan`` goal, not followed |
| srv | ``~/cancel`` | std_srvs/Trigger | stop the axes, keep what was captured |
| srv | ``~/resume`` | std_srvs/Trigger | go on with the views not yet captured |
| sub | ``carving/status`` | sfs_ros_interfaces/ReconstructionStatus | for the result |
| cli | ``motor/home``, ``motor/stop`` | std_srvs/Trigger | the motor node's |
| cli | ``camera/capture`` | std_srvs/Trigger | our camera's shutter (trigger ``shutter``) |
| cli | ``carving/new_scan`` | sfs_ros_interfaces/NewScan | the carving node's reset |

Names: :mod:`sfs_ros.ros.names` (the node is ``scan``, so ``~/start`` is
``scan/start`` in the cell's namespace; the action is ``<namespace>/scan`` and the status
``<namespace>/status``). A camera driver publishing elsewhere is connected by a remap
(``-r image_raw:=/my_camera/image_raw``).

The ``scan`` action: a goal scans the configured plan, or the goal's own (``plan_file``,
or ``theta_rad`` / ``phi_rad`` lists visited in the order given: this scan only; a
restarted node does not take such a scan up), and names the scan's folder in the
reconstruction (``scan_name``, passed with its reset, ``reconstruction/new_scan``). One
goal at a time: a goal while a scan runs is rejected. A goal that cannot be scanned (lists
of different lengths, angles not finite or outside the carriage's range, a plan file that
does not load, too many views, a bad name) is accepted, then aborted at once with the
reason in the result's ``message`` (a rejection carries no reason). Feedback follows every
change of ``status``. A cancel request stops the axes; the goal ends canceled with what
was captured (``scan/resume`` goes on with it). The result comes once every view is
captured and receipted: success, the scan's number, and from the reconstruction's
``status`` its session folder and the views it stored and rejected; a scan that pauses on
a fault aborts the goal with the reason (``scan/resume`` goes on outside the action).
A goal's ``object`` "board" is a calibration scan: its captures go to
``calibration/image`` + ``calibration/joint_state`` instead (segmentation and
reconstruction never see them; the calibration node stores and receipts them), the
reconstruction is not reset, and the result's ``views_stored`` counts the receipts.
``status`` (sfs_ros_interfaces/CellStatus; reliable, transient local, depth 1) carries
what the diagnostics carry, the scan's ``object`` and the last encoder angles, ``axes_connected`` meaning that
readings came within :data:`AXES_SILENT_S`.

Capture topics and receipts: reliable, volatile, depth ``queue_depth``
(:func:`sfs_ros.ros.capture_qos`): no view may be dropped. The camera's frames
(``image_raw``, or ``image_raw/compressed`` with ``image_transport`` compressed), their
QoS following the publisher's (``image_reliability`` auto) and the driver's
``camera_info``: :class:`sfs_ros.ros.driver_camera.DriverCamera`, which at each start of
a streamed scan compares the driver's intrinsics with the rig or sets them on the
reconstruction (``intrinsics_source``).

A scan, view by view, in plan order (:class:`sfs_ros.cell.scan_plan.ScanPlan`,
from ``plan_file`` or the ring parameters): command the viewpoint, wait until
the encoders have settled on it (:class:`sfs_ros.cell.settle.SettleDetector`),
take the view's frame, and tag it with the encoder reading nearest to its
stamp: ``capture/image`` (the frame) and ``capture/joint_state`` (that
reading) share the frame's stamp.
``scan/start`` first resets the reconstruction and homes the axes (each can
be switched off).

Before the first capture of a scan the node waits (at most ``listen_timeout_s``;
one INFO line naming what it waits for) until the captures will be seen, as far as
its view of the graph tells: every node of :data:`LISTENERS` that runs in its
namespace (segmentation, reconstruction, recorder; a board scan's calibration node
and recorder) has its subscriptions on the topics it must get, and every
subscription to the scan's own capture topics is matched to its publishers. The
reconstruction's mask subscriptions are matched to the segmentation's publishers,
not to this node's: that they exist is what it can see. A node not running is not
waited for (a scan node alone scans). When the time is up the scan pauses naming
what is missing (``scan/resume`` goes on).

The view's frame (``camera_trigger``): ``shutter`` calls our camera node's
``capture`` and waits for the frame it announces; ``stream`` takes the frame
from any driver that streams ``image_raw`` (``usb_cam``, ``v4l2_camera``, a
GenICam driver): the first frame stamped at or after the moment the axes
settled plus ``exposure_delay_s``. Both can change between scans (they take
effect at the next ``scan/start``).

Joint states without the cell's joints (a robot arm's broadcaster on the
same topic) are ignored: one INFO line the first time, nothing counted.

The sequencing is :class:`sfs_ros.cell.scan_sequence.ScanSequence` (tested
without processes); this node connects its ports to topics and services.

Faults: a move that does not settle (timeout, stall, no encoder readings) is
commanded again up to ``move_retries`` times, a missing frame retaken up to
``capture_retries`` times; each retry is a WARN. When the retries are used
up the scan **pauses** with an ERROR naming the view and the reason;
``scan/resume`` goes on from that view once the fault is mended (the views
captured stay captured). ``scan/cancel`` stops the axes and pauses likewise.

Delivery: every capture of the scan is kept until the next ``scan/start``.
One that the reconstruction has not receipted on ``capture/stored`` within
``receipt_timeout_s`` is sent again (at most ``max_sends`` times in all, then
reported as lost in transport); when a publisher of receipts appears that
was not there before (the carving node restarted, or started late),
every capture is sent again. The reconstruction stores
each view once, so a view is never lost to a restarted node and never carved twice.

Restarts of this node: with ``progress_dir`` (the bring-up sets
``OUTPUT_DIR/scan_progress``), every capture is written there before it is sent, with the
scan's number, state and receipts (:mod:`sfs_ros.cell.scan_progress`, atomic writes). A node
started again (after SIGKILL, a crash) takes that scan up: a scan that was under way goes on
from the first view not captured, and its captures are sent again. A capture that cannot be
written (disk full) puts the scan in state ``waiting`` with an ERROR naming the folder and the
space needed; it goes on by itself once the write succeeds. ``home_before_retry`` homes the
axes before a failed move is commanded again (a restarted controller refuses moves until
homed).

Diagnostics values: ``scan`` (1 for the first ``scan/start``, then 2, ...),
``state`` (idle, starting, running, waiting, paused, cancelled, done), ``view`` (the
view being taken, 1-based), ``total``, ``captured``, ``receipted``,
``resends``, ``move_retries``, ``capture_retries``, ``lost_in_transport``,
``malformed``, this scan's seconds of ``motion_s`` (command to settled)
and ``shutter_s`` (shutter call, or settling, to frame in hand), and its
``trigger``. Parameters: :data:`PARAMS`.
"""

from __future__ import annotations

import json
import math
import struct
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import Image, JointState
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from sfs_ros.cell.capture_ledger import EncoderReading
from sfs_ros.cell.messages import ForeignJointState
from sfs_ros.cell.scan_goal import OBJECTS, goal_object, goal_plan
from sfs_ros.cell.scan_plan import ScanPlan, load_plan
from sfs_ros.cell.scan_progress import ScanProgress
from sfs_ros.cell.scan_sequence import (
    TRIGGERS,
    MonotonicClock,
    ScanSequence,
    ScanSettings,
    StepFailed,
)
from sfs_ros.nodes.entry import run_node
from sfs_ros.process import configure_process
from sfs_ros.ros import capture_qos, result_qos
from sfs_ros.ros.convert import (
    angles_from_joint_state,
    diagnostic_array,
    driver_frame,
    health,
    joint_state,
)
from sfs_ros.ros.driver_camera import DRIVER_PARAMS, DriverCamera
from sfs_ros.ros.names import (
    CARVING_NODE,
    CELL_STATUS,
    DIAGNOSTICS,
    RECONSTRUCTION_STATUS,
    RECORDER_NODE,
    SCAN_ACTION,
    SERVICES,
    TYPED_SERVICES,
    private,
    status_name,
)
from sfs_ros.ros.pairing import stamp_key
from sfs_ros.ros.params import Param, ParameterError, declare, read, validating_callback
from sfs_ros.ros.services import ServiceError, call
from sfs_ros.ros.typed import cell_status, scan_feedback
from sfs_ros_interfaces.action import Scan
from sfs_ros_interfaces.msg import CellStatus, ReconstructionStatus
from sfs_ros_interfaces.srv import NewScan

__all__ = ["ScanNode", "PARAMS", "main"]

NODE_NAME = "scan"
#: A shutter call unanswered this long is sent again (a response lost in the middleware;
#: a second frame is harmless: the first answer's frame is the one used).
_RESEND_AFTER_S = 2.0
#: The axes count as disconnected when no encoder reading came for this long, s.
AXES_SILENT_S = 2.0
#: How often a running goal looks for a cancel request, s.
_GOAL_POLL_S = 0.1
#: States in which a scan's run has ended.
_ENDED = ("done", "paused", "cancelled")
#: How often the graph is looked at while waiting for the capture subscriptions, s.
_LISTEN_POLL_S = 0.1
_CAPTURES = ("capture/image", "capture/joint_state")
_MASKS = ("capture/mask", "capture/mask_joint_state")
_BOARD = ("calibration/image", "calibration/joint_state")
#: By the scan's object: the nodes whose subscriptions must be there before its first
#: capture, and the topics of each.
LISTENERS = {
    "object": {"segmentation": _CAPTURES, CARVING_NODE: _MASKS,
               RECORDER_NODE: _CAPTURES + _MASKS},
    "board": {"calibration": _BOARD, RECORDER_NODE: _BOARD},
}

PARAMS: list[Param] = [
    Param("plan_file", "", "YAML scan plan (format: sfs_ros/cell/scan_plan.py); empty = the "
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
#: Bytes of the length of the first message in a capture's bytes (big-endian).
_LENGTH = struct.Struct(">Q")


def scan_plan(values: dict) -> ScanPlan:
    """The plan from the node's parameter values; :class:`ParameterError` naming the cause."""
    if values["plan_file"].strip():
        try:
            return load_plan(values["plan_file"])
        except ValueError as exc:
            raise ParameterError("plan_file", str(exc)) from None
    try:
        return ScanPlan.from_rings(values["rings_phi_deg"], values["per_ring"],
                                   values["top_view"], stagger=values["stagger"],
                                   reorder=values["reorder"])
    except ValueError as exc:
        raise ParameterError("rings_phi_deg", str(exc)) from None


def scan_settings(values: dict, *, board: bool = False) -> ScanSettings:
    """The sequence's settings from the node's parameter values (``board``: a calibration
    scan, which leaves the reconstruction as it is)."""
    steps = [("reset", values["reset_reconstruction"] and not board,
              values["service_timeout_s"]),
             ("home", values["home_before_scan"], values["home_timeout_s"]),
             ("listeners", True, values["listen_timeout_s"])]
    return ScanSettings(
        settle_tolerance_rad=math.radians(values["settle_tolerance_deg"]),
        settle_samples=values["settle_samples"], move_timeout_s=values["move_timeout_s"],
        stall_s=values["stall_s"], move_retries=values["move_retries"],
        capture_timeout_s=values["capture_timeout_s"],
        capture_retries=values["capture_retries"],
        encoder_max_gap_s=values["encoder_max_gap_s"],
        receipt_timeout_s=values["receipt_timeout_s"], max_sends=values["max_sends"],
        prepare=tuple((name, timeout_s) for name, wanted, timeout_s in steps if wanted),
        trigger=values["camera_trigger"], exposure_delay_s=values["exposure_delay_s"],
        rehome_before_retry=values["home_before_retry"])


class _RosPorts(MonotonicClock):
    """The sequence's ports on the node's topics and services (called from its threads)."""

    def __init__(self, node: "ScanNode"):
        self._node = node

    def command_move(self, theta_rad: float, phi_rad: float) -> None:
        node = self._node
        node.command_pub.publish(joint_state(theta_rad, phi_rad,
                                             stamp=node.get_clock().now().to_msg()))

    def stop_axes(self) -> None:
        # Waited for: a stop still on its way when the next goal starts would halt its homing.
        try:
            answer = call(self._node.peers["stop"], Trigger.Request(),
                          timeout_s=self._node._p["service_timeout_s"])
        except ServiceError as exc:
            self.log("warning", f"the axes' stop was not confirmed: {exc}")
            return
        if not answer.success:
            self.log("warning", f"the axes' stop failed: {answer.message}")

    def prepare(self, step: str, *, timeout_s: float, cancelled: threading.Event) -> None:
        if step == "listeners":
            self._node.wait_listeners(timeout_s, cancelled)
            return
        try:
            # Both steps may be asked twice (a reset before the scan's first view; a home
            # that comes while homing joins it): sent again when the answer is late, as the
            # shutter is (services.call: a lost answer).
            client, request = ((self._node.new_scan, NewScan.Request(
                scan_name=self._node.scan_name)) if step == "reset"
                else (self._node.peers[step], Trigger.Request()))
            answer = call(client, request, timeout_s=timeout_s,
                          cancelled=cancelled, resend_after_s=_RESEND_AFTER_S)
        except ServiceError as exc:
            raise StepFailed(str(exc)) from None
        if not answer.success:
            raise StepFailed(f"{step} failed: {answer.message}")

    def stamp_now(self):
        return stamp_key(self._node.get_clock().now().to_msg())

    def shutter(self, *, timeout_s: float, cancelled: threading.Event):
        try:
            answer = call(self._node.peers["capture"], Trigger.Request(), timeout_s=timeout_s,
                          cancelled=cancelled, resend_after_s=_RESEND_AFTER_S)
        except ServiceError as exc:
            raise StepFailed(str(exc)) from None
        if not answer.success:
            raise StepFailed(f"the camera took no frame: {answer.message}")
        try:
            return stamp_key(tuple(json.loads(answer.message)["stamp"]))
        except (ValueError, KeyError, TypeError):
            raise StepFailed(f"the camera's answer {answer.message!r} has no stamp; expected "
                             "JSON with \"stamp\": [sec, nanosec]") from None

    def make_capture(self, frame, stamp, reading: EncoderReading):
        try:
            image = driver_frame(frame)
        except ValueError as exc:
            raise StepFailed(f"the camera's frame cannot be read: {exc}") from None
        return image, joint_state(reading.theta_rad, reading.phi_rad, stamp=stamp)

    def send(self, capture) -> None:
        frame, joints = capture
        image_pub, joints_pub = self._node.outputs[self._node.scan_object]
        image_pub.publish(frame)
        joints_pub.publish(joints)

    def encode_capture(self, capture) -> bytes:
        frame, joints = (serialize_message(m) for m in capture)
        return _LENGTH.pack(len(frame)) + frame + joints

    def decode_capture(self, data: bytes):
        if len(data) < _LENGTH.size:
            raise ValueError(f"{len(data)} bytes is too short for a capture")
        (length,) = _LENGTH.unpack_from(data)
        if length > len(data) - _LENGTH.size:
            raise ValueError(f"a capture of {len(data)} bytes cannot hold a frame of {length}")
        start = _LENGTH.size
        try:
            return (deserialize_message(data[start:start + length], Image),
                    deserialize_message(data[start + length:], JointState))
        except Exception as exc:  # noqa: BLE001 -- rclpy raises several kinds for bad bytes
            raise ValueError(f"not a capture: {exc}") from None

    def log(self, level: str, text: str) -> None:
        logger = self._node.get_logger()
        # One call site per severity: rclpy refuses a site whose severity changes.
        if level == "error":
            logger.error(text)
        elif level == "warning":
            logger.warning(text)
        else:
            logger.info(text)

    def changed(self) -> None:
        self._node.publish_diagnostics()
        self._node.publish_status()


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
        except ParameterError:
            super().destroy_node()
            raise
        if len(self.plan) > self._p["queue_depth"]:
            super().destroy_node()
            raise ParameterError("queue_depth", f"got {self._p['queue_depth']}, expected at "
                                 f"least the {len(self.plan)} views of the plan")
        progress = None
        if self._p["progress_dir"].strip():
            try:
                progress = ScanProgress(self._p["progress_dir"], self.plan.views)
            except OSError as exc:
                super().destroy_node()
                raise ParameterError("progress_dir", f"cannot use {self._p['progress_dir']}: "
                                     f"{exc}") from None
        self._sequence = ScanSequence(self.plan.views, _RosPorts(self), scan_settings(self._p),
                                      progress)
        self._receivers: set[bytes] = set()   # every publisher of receipts seen (by GID)
        self.scan_name = ""                   # the reconstruction's name of the next scan
        self.scan_object = OBJECTS[0]         # what this scan is of (its captures' topics)
        self._reading = (math.nan, math.nan)  # the last encoder reading, rad
        self._reading_at = -math.inf          # when it came, time.monotonic()
        self._changed = threading.Condition() # notified with every status published
        self._status_lock = threading.Lock()  # one status published at a time, newest last
        self._status: CellStatus | None = None
        self._reconstruction = ReconstructionStatus()
        self._goal_lock = threading.Lock()
        self._goal_busy = False
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
        self._status_pub = self.create_publisher(CellStatus, CELL_STATUS, result_qos())
        self.create_subscription(ReconstructionStatus, RECONSTRUCTION_STATUS,
                                 self._on_reconstruction_status, result_qos(),
                                 callback_group=inputs)
        self._action = ActionServer(self, Scan, SCAN_ACTION, self._execute,
                                    goal_callback=self._on_goal,
                                    cancel_callback=self._on_cancel_goal,
                                    callback_group=ReentrantCallbackGroup())
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
        self._action.destroy()
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

    def _on_reconstruction_status(self, msg: ReconstructionStatus) -> None:
        with self._changed:
            self._reconstruction = msg
            self._changed.notify_all()

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

    # -- services (executor) -----------------------------------------------------------------

    def _on_start(self, _request, response):
        with self._goal_lock:
            if self._goal_busy:
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

    # -- the scan action (executor) ----------------------------------------------------------

    def _on_goal(self, _goal) -> GoalResponse:
        """One goal at a time, and none while a scan runs (a bad goal is accepted, then
        aborted with the reason: a rejection carries none)."""
        with self._goal_lock:
            if self._goal_busy or self._sequence.active:
                self.get_logger().info("scan goal rejected: a scan is running")
                return GoalResponse.REJECT
            self._goal_busy = True
        return GoalResponse.ACCEPT

    @staticmethod
    def _on_cancel_goal(_goal_handle) -> CancelResponse:
        return CancelResponse.ACCEPT

    def _execute(self, goal_handle) -> Scan.Result:
        try:
            return self._run_goal(goal_handle)
        finally:
            with self._goal_lock:
                self._goal_busy = False

    def _run_goal(self, goal_handle) -> Scan.Result:
        """Start the goal's scan and follow it to its result."""
        goal = goal_handle.request
        try:
            plan = goal_plan(goal.plan_file, goal.theta_rad, goal.phi_rad, goal.scan_name,
                             max_views=self._p["queue_depth"])
            scan_object = goal_object(goal.object)
        except ValueError as exc:
            return self._end_goal(goal_handle, False, f"goal refused: {exc}")
        values = read(self, PARAMS)
        refusal = self._check_camera(values)
        if refusal:
            return self._end_goal(goal_handle, False, f"goal refused: {refusal}")
        with self._goal_lock:
            self.scan_name, self.scan_object = goal.scan_name, scan_object
            ok, message = self._sequence.start(
                scan_settings(values, board=scan_object == "board"),
                None if plan is None else plan.views)
        if not ok:
            return self._end_goal(goal_handle, False, f"goal refused: {message}")
        self.get_logger().info(f"scan goal ({scan_object}): {message}")
        self._launch()
        return self._follow(goal_handle, self._sequence.status().values["scan"])

    def _follow(self, goal_handle, scan: int) -> Scan.Result:
        """Feedback with every status until the scan's run ends and (done) every view is
        receipted; then the goal's end."""
        sent, cancelling = None, False
        while True:
            with self._changed:
                self._changed.wait_for(lambda: self._status is not sent, _GOAL_POLL_S)
                status = self._status
            if goal_handle.is_cancel_requested and not cancelling:
                cancelling = True
                self._sequence.cancel()
            if status is not None and status is not sent and status.scan == scan:
                goal_handle.publish_feedback(scan_feedback(status))
            sent = status
            values = self._sequence.status().values
            if values["scan"] != scan or values["state"] not in _ENDED:
                continue
            if values["state"] == "done" and values["receipted"] + \
                    values["lost_in_transport"] < values["total"]:
                continue                                 # receipts still to come
            success = values["state"] == "done" and values["lost_in_transport"] == 0
            return self._end_goal(goal_handle, success, status.message, values)

    def _end_goal(self, goal_handle, success: bool, message: str,
                  values: dict | None = None) -> Scan.Result:
        """End the goal (succeeded; canceled when asked; else aborted) with its result; a
        scan that ended done waits (``service_timeout_s`` at most) for the reconstruction's
        status to count its views."""
        result = Scan.Result(success=success, message=message)
        if values is not None and self.scan_object == "board":
            result.scan, result.views_total = values["scan"], values["total"]
            result.views_captured = values["captured"]
            result.views_stored = values["receipted"]      # by the calibration node
        elif values is not None:
            if success:
                with self._changed:
                    self._changed.wait_for(
                        lambda: self._reconstruction.views_stored
                        + len(self._reconstruction.views_rejected) >= values["total"],
                        self._p["service_timeout_s"])
            with self._changed:
                reconstruction = self._reconstruction
            result.scan, result.views_total = values["scan"], values["total"]
            result.views_captured = values["captured"]
            result.session_dir = reconstruction.session_dir
            result.views_stored = reconstruction.views_stored
            result.views_rejected = list(reconstruction.views_rejected)
        if success:
            goal_handle.succeed()
        elif goal_handle.is_cancel_requested:
            goal_handle.canceled()
        else:
            goal_handle.abort()
        self.get_logger().info(f"scan goal ended: {'succeeded' if success else message}")
        return result

    # -- the graph (the scan's worker thread) ------------------------------------------------

    def missing_listeners(self) -> list[str]:
        """What keeps this scan's captures from being seen now: the subscriptions of
        :data:`LISTENERS`' running nodes not in the graph, and subscriptions to the capture
        topics not yet matched (empty: none)."""
        namespace = self.get_namespace()
        running = {name for name, space in self.get_node_names_and_namespaces()
                   if space == namespace}
        missing = []
        for node, topics in LISTENERS[self.scan_object].items():
            if node not in running:
                continue
            for topic in topics:
                infos = self.get_subscriptions_info_by_topic(self.resolve_topic_name(topic))
                if not any(i.node_name == node and i.node_namespace == namespace
                           for i in infos):
                    missing.append(f"{node}'s subscription to {topic}")
        for publisher in self.outputs[self.scan_object]:
            known = len(self.get_subscriptions_info_by_topic(publisher.topic_name))
            if publisher.get_subscription_count() < known:
                missing.append(f"a subscription to {publisher.topic_name} still matching")
        return missing

    def wait_listeners(self, timeout_s: float, cancelled: threading.Event) -> None:
        """Until :meth:`missing_listeners` is empty (INFO once while waiting); StepFailed
        naming what is missing after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        said = False
        while missing := self.missing_listeners():
            if cancelled.is_set():
                return
            if time.monotonic() > deadline:
                raise StepFailed(f"after {timeout_s:g} s the captures would still not be seen: "
                                 f"no {', '.join(missing)}")
            if not said:
                said = True
                self.get_logger().info(f"first capture waits for {', '.join(missing)}")
            cancelled.wait(_LISTEN_POLL_S)

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
        with self._status_lock:
            connected = time.monotonic() - self._reading_at <= AXES_SILENT_S
            msg = cell_status(self._sequence.status(), self._reading, connected,
                              stamp=self.get_clock().now().to_msg(),
                              scan_object=self.scan_object)
            with self._changed:
                self._status = msg
                self._changed.notify_all()
            self._status_pub.publish(msg)


def main(args=None) -> None:
    """Entry point ``sfs-scan`` (``--ros-args --params-file config/scan.yaml``)."""
    configure_process()
    run_node("sfs-scan", ScanNode, args, threads=4)


if __name__ == "__main__":
    main()
