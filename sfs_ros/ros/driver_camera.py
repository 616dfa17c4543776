"""The scan node's side of a camera driver: its frames, its QoS, its ``camera_info``.

:class:`DriverCamera` subscribes to the driver's frames as the driver publishes them:

* **transport** (``image_transport``): ``raw`` takes ``sensor_msgs/Image`` on the image
  topic (``image_raw``, remapped to the driver's); ``compressed`` takes
  ``sensor_msgs/CompressedImage`` on ``<image topic>/compressed`` (image_transport's
  name: JPEG or PNG). Every frame reaches the node's callback as it came; the view's frame
  alone is converted (:func:`sfs_ros.ros.convert.driver_frame`).
* **reliability** (``image_reliability``): ``auto`` (the default) follows what the
  publishers on the topic offer, looked up with ``get_publishers_info_by_topic``: best
  effort as soon as one offers only that (a sensor-data QoS driver), else reliable (our
  camera node's triggered frames must not be dropped). ``reliable`` and ``best_effort``
  force it. :meth:`update` (the node's 1 Hz timer) recreates the subscription when the
  wanted one changed: the parameters may change at any time, no restart.
* **camera_info** on ``<image topic's namespace>/camera_info`` (best effort, which
  matches any publisher): the last one is kept, read by
  :func:`sfs_ros.ros.convert.camera_info_intrinsics`.

At a scan's start (``camera_trigger`` stream), :meth:`check_intrinsics` compares the
driver's intrinsics with the rig the carving node holds (its parameters, read
with ``GetParameters``) and, by ``intrinsics_source``:

* ``rig``: the scan uses the rig; a difference beyond ``intrinsics_tolerance`` is the
  :attr:`warning` (a WARN on the scan node's diagnostics) naming the parameters and the
  differences (:mod:`sfs_ros.cell_logic.intrinsics`); no ``camera_info`` is a WARN too;
* ``driver``: the driver's ``fx``, ``fy``, ``cx``, ``cy`` and ``distortion`` are set on
  the carving node (``SetParametersAtomically``, before the scan starts: a rig
  change is refused during a scan), so that the scan's ``reset`` carves with them; the
  start is refused, with the reason, without a ``camera_info``, for another image size
  than the rig's, or when the reconstruction refuses.

Diagnostics values (:attr:`values`): ``intrinsics_source``, ``intrinsics_difference``
(the largest relative difference of fx, fy, cx, cy at the last start, %).
"""

from __future__ import annotations

import threading

from rcl_interfaces.srv import GetParameters, SetParametersAtomically
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, CompressedImage, Image

from sfs_ros.cell_logic.intrinsics import (
    DriverIntrinsics,
    describe_differences,
    intrinsics_differences,
    largest_difference,
    rig_intrinsics,
    rig_update,
)
from sfs_ros.ros.convert import camera_info_intrinsics
from sfs_ros.ros.names import CARVING_NODE
from sfs_ros.ros.params import Param
from sfs_ros.ros.services import PARAMETER_RESEND_S, ServiceError, call

__all__ = ["DriverCamera", "DRIVER_PARAMS", "TRANSPORTS", "RELIABILITIES", "INTRINSICS_SOURCES"]

TRANSPORTS = ("raw", "compressed")
RELIABILITIES = ("auto", "reliable", "best_effort")
INTRINSICS_SOURCES = ("rig", "driver")
#: The node that holds the scan's rig (relative to the scan node's namespace).
RECONSTRUCTION = CARVING_NODE
#: Rig parameters read from the carving node to compare.
_RIG_NAMES = ("projection", "width", "height", "fx", "fy", "cx", "cy", "distortion")
#: Depth of the frames' subscription (a second of a 10 Hz stream).
_DEPTH = 10

DRIVER_PARAMS: list[Param] = [
    Param("image_reliability", "auto", "QoS reliability of the frames' subscription: auto "
          "(best effort when a publisher on the topic offers only that, as a driver with the "
          "sensor-data QoS does; else reliable), reliable or best_effort.",
          choices=RELIABILITIES, constraints="applied within a second"),
    Param("image_transport", "raw", "raw: sensor_msgs/Image on image_raw; compressed: "
          "sensor_msgs/CompressedImage (JPEG, PNG) on <image topic>/compressed.",
          choices=TRANSPORTS, constraints="applied within a second"),
    Param("intrinsics_source", "rig", "stream: rig (the scan uses the rig's intrinsics; a "
          "driver's camera_info that disagrees is a WARN) or driver (the driver's camera_info "
          "is set on the carving node's rig at each scan start).",
          choices=INTRINSICS_SOURCES, constraints="takes effect at the next scan/start"),
    Param("intrinsics_tolerance", 0.005, "Largest difference between the driver's and the "
          "rig's intrinsics that is not reported: relative for fx, fy, cx, cy, absolute for a "
          "distortion coefficient.", bounds=(0.0, 1.0)),
]


class DriverCamera:
    """Frames and ``camera_info`` of the driver behind ``image_raw`` (module docstring).

    node : the scan node, :data:`DRIVER_PARAMS` declared. on_frame : called with each
    frame (``Image`` or ``CompressedImage``) in ``inputs``. inputs, clients : callback
    groups of the subscriptions and of the parameter clients.
    """

    def __init__(self, node: Node, on_frame, *, inputs, clients):
        self._node = node
        self._on_frame = on_frame
        self._inputs = inputs
        self.image_topic = node.resolve_topic_name("image_raw")
        self.info_topic = self.image_topic.rsplit("/", 1)[0] + "/camera_info"
        self._sub = None
        self._wanted: tuple[str, str, ReliabilityPolicy] | None = None
        self._lock = threading.Lock()
        self._info: DriverIntrinsics | None = None
        self._info_problem = ""
        self._said_incompatible = False
        self.warning = ""
        self.values = {"intrinsics_source": self._param("intrinsics_source"),
                       "intrinsics_difference": ""}
        node.create_subscription(CameraInfo, self.info_topic, self._on_info,
                                 QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT),
                                 callback_group=inputs)
        self._get = node.create_client(GetParameters, f"{RECONSTRUCTION}/get_parameters",
                                       callback_group=clients)
        self._set = node.create_client(SetParametersAtomically,
                                       f"{RECONSTRUCTION}/set_parameters_atomically",
                                       callback_group=clients)
        self.update()

    def _param(self, name: str):
        return self._node.get_parameter(name).value

    # -- frames (the inputs group) -----------------------------------------------------------

    def topic(self) -> str:
        """The topic the frames are taken from now."""
        compressed = self._param("image_transport") == "compressed"
        return self.image_topic + "/compressed" if compressed else self.image_topic

    def _reliability(self, topic: str) -> ReliabilityPolicy:
        choice = self._param("image_reliability")
        if choice != "auto":
            return ReliabilityPolicy.BEST_EFFORT if choice == "best_effort" \
                else ReliabilityPolicy.RELIABLE
        offered = [info.qos_profile.reliability
                   for info in self._node.get_publishers_info_by_topic(topic)]
        return ReliabilityPolicy.BEST_EFFORT if ReliabilityPolicy.BEST_EFFORT in offered \
            else ReliabilityPolicy.RELIABLE

    def update(self) -> None:
        """Subscribe as the parameters and the publishers now want, if that changed."""
        topic = self.topic()
        wanted = (topic, self._param("image_transport"), self._reliability(topic))
        if wanted == self._wanted:
            return
        if self._sub is not None:
            self._node.destroy_subscription(self._sub)
        kind = CompressedImage if wanted[1] == "compressed" else Image
        qos = QoSProfile(depth=_DEPTH, reliability=wanted[2])
        self._sub = self._node.create_subscription(
            kind, topic, self._on_frame, qos, callback_group=self._inputs,
            event_callbacks=SubscriptionEventCallbacks(incompatible_qos=self._on_incompatible))
        self._wanted, self._said_incompatible = wanted, False
        self._node.get_logger().info(f"camera frames from {topic} ({kind.__name__}, "
                                     f"{wanted[2].name.lower()})")

    def _on_incompatible(self, event) -> None:
        """A publisher whose QoS the subscription cannot take: ``auto`` follows it at the
        next :meth:`update`; a forced reliability says what to set, once."""
        if self._param("image_reliability") == "auto" or self._said_incompatible:
            return
        self._said_incompatible = True
        self._node.get_logger().warning(
            f"a publisher on {self.topic()} offers a QoS this subscription "
            f"(image_reliability {self._param('image_reliability')}) cannot take (policy "
            f"{event.last_policy_kind.name}): its frames are not received; set "
            "image_reliability auto")

    def _on_info(self, msg: CameraInfo) -> None:
        try:
            info, problem = camera_info_intrinsics(msg), ""
        except ValueError as exc:
            info, problem = None, str(exc)
        with self._lock:
            said = self._info_problem
            self._info, self._info_problem = info, problem
        if problem and problem != said:
            self._node.get_logger().error(f"camera_info on {self.info_topic} ignored: {problem}")

    # -- a scan's start (a service thread) ---------------------------------------------------

    def check_intrinsics(self, timeout_s: float) -> str:
        """Compare (and with ``intrinsics_source`` driver, set) the scan's intrinsics; the
        reason the scan may not start ("" if it may). Sets :attr:`warning` and
        :attr:`values`."""
        source = self._param("intrinsics_source")
        self.values = {"intrinsics_source": source, "intrinsics_difference": ""}
        self.warning = ""
        with self._lock:
            info, problem = self._info, self._info_problem
        if info is None:
            text = f"no usable camera_info on {self.info_topic}" + \
                (f" ({problem})" if problem else "")
            if source == "driver":
                return f"intrinsics_source driver: {text}; expected the driver's calibration"
            self.warning = f"{text}: the rig's intrinsics are used unchecked"
            return ""
        try:
            rig_values = self._rig_values(timeout_s)
        except ServiceError as exc:
            if source == "driver":
                return f"intrinsics_source driver: the rig cannot be read: {exc}"
            self.warning = f"the driver's intrinsics not compared: {exc}"
            return ""
        differences = intrinsics_differences(rig_intrinsics(rig_values), info)
        text = describe_differences(differences, self._param("intrinsics_tolerance"))
        self.values["intrinsics_difference"] = f"{100 * largest_difference(differences):.2f} %"
        if source == "rig":
            if text:
                self.warning = (f"the driver's camera_info on {self.info_topic} disagrees with "
                                f"the rig: {text} (driver against rig); the scan uses the rig "
                                "(intrinsics_source rig)")
            return ""
        return self._apply_intrinsics(info, rig_values, text, timeout_s)

    def _apply_intrinsics(self, info: DriverIntrinsics, rig_values: dict, text: str,
              timeout_s: float) -> str:
        """Set the driver's intrinsics on the reconstruction's rig; the refusal or ""."""
        if rig_values["projection"] != "pinhole":
            return ("intrinsics_source driver: the rig is orthographic; a driver's camera_info "
                    "describes a pinhole camera")
        if (info.width, info.height) != (rig_values["width"], rig_values["height"]):
            return (f"intrinsics_source driver: the driver's camera_info is {info.width}x"
                    f"{info.height} pixels, the rig's {rig_values['width']}x"
                    f"{rig_values['height']} (fixed while the cell runs)")
        request = SetParametersAtomically.Request(parameters=[
            Parameter(name, value=value).to_parameter_msg()
            for name, value in rig_update(info).items()])
        try:
            answer = call(self._set, request, timeout_s=timeout_s, resend_after_s=PARAMETER_RESEND_S)
        except ServiceError as exc:
            return f"intrinsics_source driver: the rig cannot be set: {exc}"
        if not answer.result.successful:
            return (f"intrinsics_source driver: the carving node refused the driver's "
                    f"intrinsics: {answer.result.reason}")
        self._node.get_logger().info(
            f"the scan carves with the driver's intrinsics (fx {info.fx:.2f}, fy {info.fy:.2f},"
            f" cx {info.cx:.2f}, cy {info.cy:.2f} px"
            + (f"; against the rig: {text})" if text else ", as the rig's)"))
        return ""

    def _rig_values(self, timeout_s: float) -> dict:
        """``{name: value}`` of the carving node's rig parameters now."""
        answer = call(self._get, GetParameters.Request(names=list(_RIG_NAMES)),
                      timeout_s=timeout_s, resend_after_s=PARAMETER_RESEND_S)
        if len(answer.values) != len(_RIG_NAMES):
            raise ServiceError(f"{RECONSTRUCTION} answered {len(answer.values)} rig values, "
                               f"expected {len(_RIG_NAMES)}")
        values = {name: parameter_value_to_python(value)
                  for name, value in zip(_RIG_NAMES, answer.values)}
        values["distortion"] = list(values["distortion"])
        return values
