"""Segmentation node: captures in, silhouettes out.

| kind | name | type | notes |
|---|---|---|---|
| sub | ``capture/image`` | sensor_msgs/Image | rgb8, bgr8 or mono8 |
| sub | ``capture/joint_state`` | sensor_msgs/JointState | same stamp as its image |
| pub | ``capture/mask`` | sensor_msgs/Image | mono8, 255 = object, image's header |
| pub | ``capture/mask_joint_state`` | sensor_msgs/JointState | the capture's, same header |
| pub | ``/diagnostics`` | diagnostic_msgs/DiagnosticArray | per capture and at 1 Hz |

Capture topics: reliable, volatile, depth ``queue_depth``
(:func:`sfs_ros.ros.capture_qos`). Joint states name "turntable" and
"carriage" (radians). Diagnostics: counts and the last problem.

Every capture whose image and joint state both arrive (exactly equal
stamps, either order) gives one mask and one joint state. A capture sent
again (the scan node resends what the reconstruction has not receipted) is
segmented again and counted in ``repeats`` (a half sent twice before its
partner came is taken once): the reconstruction stores each view once. An image
without an object gives an **all-zero mask** (published, so downstream sees
every view once, and carving can reject it by its empty mask) and a WARN
diagnostic; a mask touching the image border is a WARN too. A malformed
message (unknown encoding, sizes that do not add up, a joint state without
both joints or with NaN) is logged, counted in the diagnostics (ERROR level
until the next good capture) and its capture is dropped; the node carries on.
An image whose size is not the rig's (``width`` and ``height``, from
``config/rig.yaml`` as every node that needs the rig reads it) is such a
message: refused from its header, before it is kept or segmented.

Diagnostics values: counts (masks, empty, touching_border, malformed,
unpaired_dropped, repeats), waiting halves, and ``segment_s``, the seconds
spent segmenting since start-up.

Parameters: the fields of :class:`sfs_ros.core.segmentation.segment.SegmentationParams`
(see there) with ROS-friendly encodings, plus ``preset``, ``queue_depth``
and the rig's ``width`` and ``height`` (read-only); see :data:`PARAMS`.
``preset`` (read-only) names an entry of ``PRESETS`` whose values become the
defaults of the other parameters; values given explicitly still win.
"""

from __future__ import annotations

import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from sensor_msgs.msg import Image, JointState

from sfs_ros.cell_logic.message_fields import check_image_size
from sfs_ros.core.segmentation.segment import PRESETS, SegmentationParams, segment
from sfs_ros.nodes.entry import run_node
from sfs_ros.process import configure_process
from sfs_ros.ros import capture_qos
from sfs_ros.ros.convert import (
    angles_from_joint_state,
    diagnostic_array,
    health,
    image_to_msg,
    msg_to_image,
)
from sfs_ros.ros.names import DIAGNOSTICS, status_name
from sfs_ros.ros.paired_input import PairedInput, Stream
from sfs_ros.ros.pairing import format_stamp
from sfs_ros.ros.params import Param, declare, read, validating_callback
from sfs_ros.ros.rig_params import RIG_PARAMS
from sfs_ros.ros.segmentation_params import segmentation_param_list, segmentation_params

__all__ = ["SegmentationNode", "PARAMS", "main"]

NODE_NAME = "segmentation"

PRESET = Param("preset", "", "Named segmentation preset whose values become the defaults of the "
               "other parameters (explicit values still win); empty = none.",
               choices=("",) + tuple(PRESETS), read_only=True)
QUEUE_DEPTH = Param("queue_depth", 100, "Depth of the reliable capture topics and of the buffer "
                    "of unpaired halves per topic; at least the number of views of a scan.",
                    bounds=(1, 100000), read_only=True)


#: The rig's image size (of :data:`~sfs_ros.ros.rig_params.RIG_PARAMS`): captures must have it.
SIZE_PARAMS: list[Param] = [p for p in RIG_PARAMS if p.name in ("width", "height")]

#: The node's parameters with the core defaults (``preset`` changes the defaults).
PARAMS: list[Param] = [PRESET, QUEUE_DEPTH, *SIZE_PARAMS,
                       *segmentation_param_list(SegmentationParams())]


def _decode_image(msg: Image, size: tuple[int, int]) -> tuple[Image, np.ndarray]:
    """The message and its 8-bit pixels; ValueError for another size than ``size`` (the
    rig's width, height), another depth or a bad layout."""
    check_image_size(msg, size, "image")
    image = msg_to_image(msg)
    if image.dtype != np.uint8:
        raise ValueError(f"image encoding {msg.encoding!r} is not 8-bit")
    return msg, image


def _checked_joint_state(msg: JointState) -> JointState:
    """The message itself, once it has both joints with finite positions (ValueError)."""
    angles_from_joint_state(msg)
    return msg


class SegmentationNode(Node):
    """Pairs ``capture/image`` with ``capture/joint_state`` by stamp and publishes masks.

    Raises :class:`ParameterError` at construction for invalid parameters.
    """

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        preset = declare(self, [PRESET])["preset"]
        defaults = SegmentationParams.from_dict(PRESETS[preset]) if preset \
            else SegmentationParams()
        self._param_list = segmentation_param_list(defaults)
        depth = declare(self, [QUEUE_DEPTH])["queue_depth"]
        declared = declare(self, SIZE_PARAMS)
        size = (declared["width"], declared["height"])
        self._seg = segmentation_params(declare(self, self._param_list))
        self.add_on_set_parameters_callback(
            validating_callback(self, self._param_list, segmentation_params))
        self.add_post_set_parameters_callback(self._parameters_changed)

        self._counts = {"masks": 0, "empty": 0, "touching_border": 0, "malformed": 0,
                        "unpaired_dropped": 0}
        self._segment_s = 0.0   # time spent segmenting, for the benchmark
        self._problem = ""  # the last malformed / dropped input, "" after a good capture
        self._warning = ""  # about the last mask (empty, touches border)
        qos = capture_qos(depth)
        self._mask_pub = self.create_publisher(Image, "capture/mask", qos)
        self._joints_pub = self.create_publisher(JointState, "capture/mask_joint_state", qos)
        self._diag_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS, 10)
        self._input = PairedInput(
            self, Stream(Image, "capture/image", "image", lambda msg: _decode_image(msg, size)),
            Stream(JointState, "capture/joint_state", "joint state", _checked_joint_state),
            depth, qos, unit="capture", on_pair=self._process, on_problem=self._dropped)
        self.create_timer(1.0, self._publish_diagnostics)
        self.get_logger().info(f"segmenting the rig's {size[0]}x{size[1]} images with "
                               f"{self._seg} (preset {preset or 'none'}, queue depth {depth})")

    def _parameters_changed(self, _changed) -> None:
        self._seg = segmentation_params(read(self, self._param_list))
        self.get_logger().info(f"segmentation parameters now {self._seg}")

    # -- inputs ------------------------------------------------------------------------------

    def _dropped(self, kind: str, text: str) -> None:
        """A message of a capture was dropped: ``kind`` is its counter."""
        self._counts[kind] += 1
        self._report_problem(text)

    def _report_problem(self, text: str) -> None:
        self._problem = text
        self.get_logger().error(text)
        self._publish_diagnostics()

    # -- output ------------------------------------------------------------------------------

    def _process(self, stamp, decoded: tuple[Image, np.ndarray], joints: JointState) -> None:
        image_msg, image = decoded
        start = time.perf_counter()
        try:
            result = segment(image, self._seg)
        except ValueError as exc:  # e.g. an image smaller than the core accepts
            self._input.malformed(stamp, "image", exc)
            return
        self._segment_s += time.perf_counter() - start
        mask_msg = image_to_msg(result.mask, stamp=image_msg.header.stamp,
                                frame_id=image_msg.header.frame_id)
        self._mask_pub.publish(mask_msg)
        self._joints_pub.publish(joints)
        self._counts["masks"] += 1
        self._problem = ""
        at = format_stamp(stamp)
        if result.empty:
            self._counts["empty"] += 1
            self._warning = f"view at stamp {at}: empty silhouette (all-zero mask published)"
            self.get_logger().warning(self._warning)
        elif result.touches_border:
            self._counts["touching_border"] += 1
            self._warning = f"view at stamp {at}: silhouette touches the image border"
            self.get_logger().warning(self._warning)
        else:
            self._warning = ""
        self._publish_diagnostics()

    def _publish_diagnostics(self) -> None:
        level, message = health(self._problem, self._warning, f"{self._counts['masks']} masks")
        values = dict(self._counts)
        values.update(repeats=self._input.pairer.repeated, segment_s=round(self._segment_s, 4),
                      waiting_images=self._input.pending("first"),
                      waiting_joint_states=self._input.pending("second"))
        self._diag_pub.publish(diagnostic_array(
            status_name(self, "segmentation"), level, message, values,
            stamp=self.get_clock().now().to_msg()))


def main(args=None) -> None:
    """Entry point ``sfs-segmentation`` (``--ros-args --params-file config/rig.yaml
    --params-file config/segmentation.yaml``)."""
    configure_process()
    run_node("sfs-segmentation", SegmentationNode, args)


if __name__ == "__main__":
    main()
