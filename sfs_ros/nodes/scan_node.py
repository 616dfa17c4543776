"""Scan node: the operator console. Visits a plan of viewpoints and publishes tagged captures.

| kind | name | type | notes |
|---|---|---|---|
| pub | ``joint_command`` | sensor_msgs/JointState | the next viewpoint, rad (to the motor node) |
| sub | ``joint_states`` | sensor_msgs/JointState | encoder read-back (from the motor node) |
| sub | ``image_raw`` | sensor_msgs/Image | frames of the camera, reliable |
| pub | ``capture/image`` | sensor_msgs/Image | each view's frame, its shutter stamp |
| pub | ``capture/joint_state`` | sensor_msgs/JointState | encoder angles at the shutter, same stamp |
| sub | ``capture/stored`` | std_msgs/Header | receipts of the reconstruction node |
| pub | ``diagnostics`` | diagnostic_msgs/DiagnosticArray | progress, at 1 Hz and on every event |
| srv | ``scan/start`` | std_srvs/Trigger | a new scan from the first view |
| srv | ``scan/cancel`` | std_srvs/Trigger | stop the axes, keep what was captured |
| srv | ``scan/resume`` | std_srvs/Trigger | go on with the views not yet captured |
| cli | ``home``, ``stop`` | std_srvs/Trigger | the motor node's |
| cli | ``capture`` | std_srvs/Trigger | the camera's shutter |
| cli | ``reset`` | std_srvs/Trigger | the reconstruction node's: a new scan |

Capture topics and receipts: reliable, volatile, depth ``queue_depth``
(:func:`sfs_ros.ros.capture_qos`): no view may be dropped.

A scan, view by view, in plan order (:class:`sfs_ros.cell.scan_plan.ScanPlan`,
from ``plan_file`` or the ring parameters): command the viewpoint, wait until
the encoders have settled on it (:class:`sfs_ros.cell.settle.SettleDetector`),
release the shutter (the camera's ``capture``), wait for that frame, and tag
it with the encoder reading nearest to its stamp: ``capture/image`` (the
frame) and ``capture/joint_state`` (that reading) share the frame's stamp.
``scan/start`` first resets the reconstruction and homes the axes (each can
be switched off).

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
was not there before (the reconstruction node restarted, or started late),
every capture is sent again. The reconstruction stores each view once, so a view is never lost to
a restarted node and never carved twice.

Diagnostics values: ``scan`` (1 for the first ``scan/start``, then 2, ...),
``state`` (idle, starting, running, paused, cancelled, done), ``view`` (the
view being taken, 1-based), ``total``, ``captured``, ``receipted``,
``resends``, ``move_retries``, ``capture_retries``, ``lost_in_transport``,
``malformed``, and this scan's seconds of ``motion_s`` (command to settled)
and ``shutter_s`` (shutter call to frame in hand). Parameters: :data:`PARAMS`.
"""

from __future__ import annotations

import json
import math
import queue
import threading
import time
import traceback
from collections import OrderedDict

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import Image, JointState
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from sfs_ros.cell.capture_ledger import CaptureLedger, EncoderHistory
from sfs_ros.cell.scan_plan import ScanPlan, load_plan
from sfs_ros.cell.settle import SettleDetector
from sfs_ros.nodes.entry import run_node
from sfs_ros.ros import capture_qos
from sfs_ros.ros.convert import angles_from_joint_state, diagnostic_array, health, joint_state
from sfs_ros.ros.pairing import format_stamp, stamp_key
from sfs_ros.ros.params import Param, ParameterError, declare
from sfs_ros.ros.services import ServiceError, call

__all__ = ["ScanNode", "PARAMS", "main"]

NODE_NAME = "scan"
_FRAMES_KEPT = 16            # camera frames kept by stamp while waiting for the shutter's one
#: A shutter call unanswered this long is sent again (a response lost in the middleware;
#: a second frame is harmless: the first answer's frame is the one used).
_RESEND_AFTER_S = 2.0

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
    Param("reset_reconstruction", True, "scan/start resets the reconstruction node first.",
          read_only=True),
    Param("home_before_scan", True, "scan/start homes the axes first.", read_only=True),
    Param("service_timeout_s", 10.0, "Deadline of the reset and stop calls, s.",
          bounds=(0.1, 600.0), read_only=True),
    Param("home_timeout_s", 120.0, "Deadline of the homing call, s.", bounds=(0.1, 3600.0),
          read_only=True),
    Param("queue_depth", 100, "Depth of the reliable capture topics; at least the number of "
          "views of a scan.", bounds=(1, 100000), read_only=True),
]


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


class _Cancelled(Exception):
    """scan/cancel was called."""


class _Fault(Exception):
    """The scan cannot go on (retries used up); the text says why."""


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
        self._lock = threading.Lock()        # ledger, counters, state
        self._cancel = threading.Event()
        self._frame_arrived = threading.Condition(self._lock)
        self._readings: queue.Queue = queue.Queue()
        self._history = EncoderHistory()
        self._frames: OrderedDict = OrderedDict()
        self._ledger = self._new_ledger()
        self._state, self._view, self._scan = "idle", 0, 0
        self._problem = self._warning = ""
        self._counts = self._new_counts()
        self._receivers: set[bytes] = set()   # every publisher of receipts seen (by GID)
        self._prepared = False

        inputs = MutuallyExclusiveCallbackGroup()
        services = MutuallyExclusiveCallbackGroup()
        clients = ReentrantCallbackGroup()
        qos = capture_qos(self._p["queue_depth"])
        self._command_pub = self.create_publisher(JointState, "joint_command", 10)
        self._image_pub = self.create_publisher(Image, "capture/image", qos)
        self._joints_pub = self.create_publisher(JointState, "capture/joint_state", qos)
        self._diag_pub = self.create_publisher(DiagnosticArray, "diagnostics", 10)
        self.create_subscription(JointState, "joint_states", self._on_joint_state, 10,
                                 callback_group=inputs)
        self.create_subscription(Image, "image_raw", self._on_frame, capture_qos(10),
                                 callback_group=inputs)
        self._receipt_sub = self.create_subscription(Header, "capture/stored", self._on_receipt,
                                                     qos, callback_group=inputs)
        self._peers = {name: self.create_client(Trigger, name, callback_group=clients)
                         for name in ("home", "stop", "capture", "reset")}
        for name, handler in (("start", self._on_start), ("cancel", self._on_cancel),
                              ("resume", self._on_resume)):
            self.create_service(Trigger, f"scan/{name}", handler, callback_group=services)
        self.create_timer(1.0, self._tick, callback_group=inputs)
        turntable, carriage = self.plan.travel_deg()
        self.get_logger().info(f"scan plan of {len(self.plan)} views ({turntable:.0f} deg of "
                               f"turntable and {carriage:.0f} deg of carriage travel); "
                               "call scan/start")

    @staticmethod
    def _new_counts() -> dict:
        return {"resends": 0, "move_retries": 0, "capture_retries": 0, "malformed": 0,
                "motion_s": 0.0, "shutter_s": 0.0}

    def _new_ledger(self) -> CaptureLedger:
        return CaptureLedger(self._p["receipt_timeout_s"], self._p["max_sends"])

    def destroy_node(self) -> None:
        self._cancel.set()
        if self._worker is not None:
            self._worker.join(timeout=10.0)
        super().destroy_node()

    # -- inputs (executor) -------------------------------------------------------------------

    def _on_joint_state(self, msg: JointState) -> None:
        try:
            theta, phi = angles_from_joint_state(msg)
            self._history.add(stamp_key(msg.header.stamp), theta, phi)
        except ValueError as exc:
            self._malformed(f"joint state ignored: {exc}")
            return
        self._readings.put((theta, phi))

    def _on_frame(self, msg: Image) -> None:
        try:
            stamp = stamp_key(msg.header.stamp)
        except ValueError as exc:
            self._malformed(f"camera frame ignored: {exc}")
            return
        with self._frame_arrived:
            self._frames[stamp] = msg
            while len(self._frames) > _FRAMES_KEPT:
                self._frames.popitem(last=False)
            self._frame_arrived.notify_all()

    def _on_receipt(self, msg: Header) -> None:
        try:
            stamp = stamp_key(msg.stamp)
        except ValueError as exc:
            self._malformed(f"receipt ignored: {exc}")
            return
        with self._lock:
            self._ledger.receipt(stamp)

    def _malformed(self, text: str) -> None:
        with self._lock:
            self._counts["malformed"] += 1
        self.get_logger().error(text)

    def _tick(self) -> None:
        """Resend what was not receipted; notice a new receiver (a restarted reconstruction
        node: a publisher of receipts not seen before) and resend everything; diagnostics."""
        receivers = {bytes(info.endpoint_gid) for info in
                     self.get_publishers_info_by_topic(self._receipt_sub.topic_name)}
        now = time.monotonic()
        with self._lock:
            came_back = bool(receivers - self._receivers) and self._ledger.captured > 0
            self._receivers |= receivers
            resend = self._ledger.restart_downstream(now) if came_back else []
            more, lost = self._ledger.due(now)
            resend += more
            self._counts["resends"] += len(resend)
        if came_back:
            self.get_logger().warning(f"a new receiver of captures (the reconstruction "
                                      f"restarted?): sending all {len(resend)} captures of "
                                      "the scan again")
        elif resend:
            self.get_logger().warning(f"sending {len(resend)} unreceipted capture(s) again: "
                                      f"views {[e.view + 1 for e in resend]}")
        for entry in resend:
            self._image_pub.publish(entry.payload[0])
            self._joints_pub.publish(entry.payload[1])
        for entry in lost:
            self._set_problem(f"view {entry.view + 1}: capture at stamp "
                              f"{format_stamp(entry.stamp)} was never receipted after "
                              f"{entry.sends} sends (kept, not sent again)")
        self._publish_diagnostics()

    # -- services (executor) -----------------------------------------------------------------

    def _running(self) -> bool:
        return self._worker is not None and self._worker.is_alive()

    def _on_start(self, _request, response):
        if self._running():
            response.success = False
            response.message = f"a scan is running (view {self._view + 1} of {len(self.plan)}); " \
                               "call scan/cancel first"
            return response
        with self._lock:
            self._ledger = self._new_ledger()
            self._counts = self._new_counts()
            self._problem = self._warning = ""
        self._prepared = False
        self._view = 0
        self._scan += 1
        self._launch()
        response.success = True
        response.message = f"scan {self._scan} started: {len(self.plan)} views"
        return response

    def _on_resume(self, _request, response):
        response.success = False
        if self._running():
            response.message = "the scan is running"
        elif self._state == "idle":
            response.message = "no scan to resume: call scan/start"
        elif self._ledger.captured == len(self.plan):
            response.message = f"all {len(self.plan)} views are captured: nothing to resume"
        else:
            with self._lock:
                self._problem = self._warning = ""
            self._launch()
            response.success = True
            response.message = (f"resuming: {len(self.plan) - self._ledger.captured} of "
                                f"{len(self.plan)} views to go")
        return response

    def _on_cancel(self, _request, response):
        if not self._running():
            response.success = False
            response.message = f"no scan is running (state {self._state})"
            return response
        self._cancel.set()
        self._peers["stop"].call_async(Trigger.Request())   # the worker does not wait for it
        self._worker.join(timeout=self._p["service_timeout_s"])
        response.success = True
        response.message = (f"cancelled at view {self._view + 1} of {len(self.plan)}, "
                            f"{self._ledger.captured} captured; scan/resume goes on")
        return response

    def _launch(self) -> None:
        self._cancel.clear()
        self._set_state("running" if self._prepared else "starting")
        self._worker = threading.Thread(target=self._run, name="scan", daemon=True)
        self._worker.start()

    # -- the scan (worker thread) ------------------------------------------------------------

    def _run(self) -> None:
        try:
            if not self._prepared:
                self._prepare()
                self._prepared = True
            self._set_state("running")
            for view in range(len(self.plan)):
                if view in self._ledger.views():
                    continue
                self._view = view
                self._warning = ""
                self._publish_diagnostics()
                self._move(view)
                self._capture(view)
            self._set_state("done")
            self.get_logger().info(f"scan done: {len(self.plan)} views captured")
        except _Cancelled:
            self._set_state("cancelled")
            self.get_logger().info(f"scan cancelled at view {self._view + 1}")
        except _Fault as fault:
            theta, phi = (math.degrees(v) for v in self.plan.views[self._view])
            self._set_problem(f"scan paused at view {self._view + 1} of {len(self.plan)} "
                              f"(theta {theta:.2f}, phi {phi:.2f} deg): {fault}; mend it and "
                              "call scan/resume")
            self._set_state("paused")
        except Exception as exc:  # noqa: BLE001 -- a bug must not leave the scan "running"
            self.get_logger().error(traceback.format_exc())
            self._set_problem(f"scan paused at view {self._view + 1}: internal error "
                              f"{type(exc).__name__}: {exc}; call scan/resume")
            self._set_state("paused")

    def _prepare(self) -> None:
        """Reset the reconstruction and home the axes, as the parameters ask."""
        steps = [("reset", self._p["reset_reconstruction"], self._p["service_timeout_s"]),
                 ("home", self._p["home_before_scan"], self._p["home_timeout_s"])]
        for name, wanted, timeout_s in steps:
            if not wanted:
                continue
            try:
                answer = call(self._peers[name], Trigger.Request(), timeout_s=timeout_s,
                              cancelled=self._cancel)
            except ServiceError as exc:
                self._check_cancel()
                raise _Fault(str(exc)) from None
            if not answer.success:
                raise _Fault(f"{name} failed: {answer.message}")

    def _check_cancel(self) -> None:
        if self._cancel.is_set():
            raise _Cancelled()

    def _retry(self, counter: str, attempt: int, retries: int, text: str) -> None:
        if attempt < retries:
            with self._lock:
                self._counts[counter] += 1
            self._warning = f"view {self._view + 1}: {text}; retrying"
            self.get_logger().warning(self._warning)
            self._publish_diagnostics()

    def _move(self, view: int) -> None:
        theta, phi = (float(v) for v in self.plan.views[view])
        p = self._p
        reason = ""
        for attempt in range(p["move_retries"] + 1):
            while not self._readings.empty():            # readings of before this command
                self._readings.get_nowait()
            detector = SettleDetector(math.radians(p["settle_tolerance_deg"]),
                                      p["settle_samples"], p["move_timeout_s"],
                                      stall_s=p["stall_s"])
            detector.start(time.monotonic(), theta, phi)
            self._command_pub.publish(joint_state(theta, phi,
                                                  stamp=self.get_clock().now().to_msg()))
            state = detector.poll(time.monotonic())
            while not state.done:
                self._check_cancel()
                try:
                    reading = self._readings.get(timeout=0.1)
                except queue.Empty:
                    state = detector.poll(time.monotonic())
                else:
                    state = detector.update(time.monotonic(), *reading)
            with self._lock:
                self._counts["motion_s"] += state.elapsed_s
            if state.settled:
                return
            reason = f"move {state.reason}"
            self._retry("move_retries", attempt, p["move_retries"], reason)
        raise _Fault(f"{reason} (after {p['move_retries'] + 1} attempts)")

    def _capture(self, view: int) -> None:
        p = self._p
        reason = ""
        for attempt in range(p["capture_retries"] + 1):
            self._check_cancel()
            start = time.monotonic()
            try:
                frame, reading = self._shoot()
            except ValueError as exc:
                reason = str(exc)
                self._retry("capture_retries", attempt, p["capture_retries"], reason)
                continue
            stamp = stamp_key(frame.header.stamp)
            joints = joint_state(reading.theta_rad, reading.phi_rad, stamp=stamp)
            with self._lock:
                self._counts["shutter_s"] += time.monotonic() - start
                self._ledger.add(view, stamp, (frame, joints), time.monotonic())
            self._image_pub.publish(frame)
            self._joints_pub.publish(joints)
            return
        raise _Fault(f"no frame: {reason} (after {p['capture_retries'] + 1} attempts)")

    def _shoot(self):
        """Release the shutter; ``(frame, encoder reading)``, or ValueError saying why not."""
        timeout_s = self._p["capture_timeout_s"]
        try:
            answer = call(self._peers["capture"], Trigger.Request(), timeout_s=timeout_s,
                          cancelled=self._cancel, resend_after_s=_RESEND_AFTER_S)
        except ServiceError as exc:
            self._check_cancel()
            raise ValueError(str(exc)) from None
        if not answer.success:
            raise ValueError(f"the camera took no frame: {answer.message}")
        try:
            stamp = stamp_key(tuple(json.loads(answer.message)["stamp"]))
        except (ValueError, KeyError, TypeError):
            raise ValueError(f"the camera's answer {answer.message!r} has no stamp; expected "
                             "JSON with \"stamp\": [sec, nanosec]") from None
        with self._frame_arrived:
            if not self._frame_arrived.wait_for(lambda: stamp in self._frames, timeout_s):
                raise ValueError(f"frame at stamp {format_stamp(stamp)} announced by the camera "
                                 f"but not received within {timeout_s:g} s")
            frame = self._frames.pop(stamp)
        gap_s = self._p["encoder_max_gap_s"]
        deadline = time.monotonic() + gap_s
        while not self._history.has_after(stamp) and time.monotonic() < deadline:
            time.sleep(0.01)                   # the first reading after the shutter, if near
        return frame, self._history.nearest(stamp, max_gap_s=gap_s)

    # -- state and diagnostics (any thread) ---------------------------------------------------

    def _set_state(self, state: str) -> None:
        self._state = state
        self._publish_diagnostics()

    def _set_problem(self, text: str) -> None:
        self._problem = text
        self.get_logger().error(text)
        self._publish_diagnostics()

    def _publish_diagnostics(self) -> None:
        with self._lock:
            values = dict(self._counts, motion_s=round(self._counts["motion_s"], 4),
                          shutter_s=round(self._counts["shutter_s"], 4), scan=self._scan,
                          state=self._state, view=self._view + 1,
                          total=len(self.plan), captured=self._ledger.captured,
                          receipted=self._ledger.receipted,
                          lost_in_transport=self._ledger.given_up)
        level, message = health(self._problem, self._warning,
                                f"{values['state']}: {values['captured']} of {values['total']} "
                                f"views captured, {values['receipted']} receipted")
        self._diag_pub.publish(diagnostic_array(f"{self.get_name()}: scan", level, message,
                                                values, stamp=self.get_clock().now().to_msg()))


def main(args=None) -> None:
    """Entry point ``sfs-scan`` (``--ros-args --params-file config/scan.yaml``)."""
    run_node("sfs-scan", ScanNode, args, threads=4)


if __name__ == "__main__":
    main()
