"""The scan sequence's ports (:class:`sfs_ros.cell_logic.scan_sequence.ScanSequence`) on the
scan node's topics and services: moves, the shutter, captures sent and kept as bytes.

A capture kept in the progress folder is its frame's and joint state's serialized
messages, the first one's length in front (:data:`CAPTURE_LENGTH`, big-endian).
"""

from __future__ import annotations

import json
import struct
import threading

from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import Image, JointState
from std_srvs.srv import Trigger

from sfs_ros.cell_logic.capture_ledger import EncoderReading
from sfs_ros.cell_logic.scan_sequence import MonotonicClock, StepFailed
from sfs_ros.ros.capture_listeners import wait_for_listeners
from sfs_ros.ros.convert import driver_frame, joint_state
from sfs_ros.ros.log import log_at
from sfs_ros.ros.pairing import stamp_key
from sfs_ros.ros.services import ServiceError, call
from sfs_ros_interfaces.srv import NewScan

__all__ = ["CAPTURE_LENGTH", "RESEND_AFTER_S", "RosPorts"]

#: A shutter call unanswered this long is sent again (a response lost in the middleware;
#: a second frame is harmless: the first answer's frame is the one used).
RESEND_AFTER_S = 2.0
#: Bytes of the length of the first message in a capture's bytes (big-endian).
CAPTURE_LENGTH = struct.Struct(">Q")


class RosPorts(MonotonicClock):
    """The sequence's ports on ``node``'s topics and services (called from its threads).

    ``node`` (the scan node) has ``command_pub`` (``joint_command``), ``peers`` (the
    ``home``, ``stop`` and ``capture`` clients), ``new_scan`` (the carving node's),
    ``outputs`` (the capture publishers by the scan's object), ``scan_name``,
    ``scan_object``, ``publish_diagnostics`` and ``publish_status``.
    """

    def __init__(self, node, service_timeout_s: float):
        self._node = node
        self._service_timeout_s = service_timeout_s

    def command_move(self, theta_rad: float, phi_rad: float) -> None:
        node = self._node
        node.command_pub.publish(joint_state(theta_rad, phi_rad,
                                             stamp=node.get_clock().now().to_msg()))

    def stop_axes(self) -> None:
        # Waited for: a stop still on its way when the next goal starts would halt its homing.
        try:
            answer = call(self._node.peers["stop"], Trigger.Request(),
                          timeout_s=self._service_timeout_s)
        except ServiceError as exc:
            self.log("warning", f"the axes' stop was not confirmed: {exc}")
            return
        if not answer.success:
            self.log("warning", f"the axes' stop failed: {answer.message}")

    def prepare(self, step: str, *, timeout_s: float, cancelled: threading.Event) -> None:
        if step == "listeners":
            node = self._node
            wait_for_listeners(node, node.scan_object, node.outputs[node.scan_object],
                               timeout_s, cancelled)
            return
        try:
            # Both steps may be asked twice (a reset before the scan's first view; a home
            # that comes while homing joins it): sent again when the answer is late, as the
            # shutter is (services.call: a lost answer).
            client, request = ((self._node.new_scan, NewScan.Request(
                scan_name=self._node.scan_name)) if step == "reset"
                else (self._node.peers[step], Trigger.Request()))
            answer = call(client, request, timeout_s=timeout_s,
                          cancelled=cancelled, resend_after_s=RESEND_AFTER_S)
        except ServiceError as exc:
            raise StepFailed(str(exc)) from None
        if not answer.success:
            raise StepFailed(f"{step} failed: {answer.message}")

    def stamp_now(self):
        return stamp_key(self._node.get_clock().now().to_msg())

    def shutter(self, *, timeout_s: float, cancelled: threading.Event):
        try:
            answer = call(self._node.peers["capture"], Trigger.Request(), timeout_s=timeout_s,
                          cancelled=cancelled, resend_after_s=RESEND_AFTER_S)
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
        return CAPTURE_LENGTH.pack(len(frame)) + frame + joints

    def decode_capture(self, data: bytes):
        if len(data) < CAPTURE_LENGTH.size:
            raise ValueError(f"{len(data)} bytes is too short for a capture")
        (length,) = CAPTURE_LENGTH.unpack_from(data)
        if length > len(data) - CAPTURE_LENGTH.size:
            raise ValueError(f"a capture of {len(data)} bytes cannot hold a frame of {length}")
        start = CAPTURE_LENGTH.size
        try:
            return (deserialize_message(data[start:start + length], Image),
                    deserialize_message(data[start + length:], JointState))
        except Exception as exc:  # noqa: BLE001 -- rclpy raises several kinds for bad bytes
            raise ValueError(f"not a capture: {exc}") from None

    def log(self, level: str, text: str) -> None:
        log_at(self._node.get_logger(), level, text)

    def changed(self) -> None:
        self._node.publish_diagnostics()
        self._node.publish_status()
