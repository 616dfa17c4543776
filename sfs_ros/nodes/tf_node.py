"""State publisher node: the cell's TF from its joint states (robot_state_publisher's work).

| kind | name | type | notes |
|---|---|---|---|
| sub | ``joint_states`` | sensor_msgs/JointState | encoder read-back (from the motor node) |
| pub | ``/tf`` | tf2_msgs/TFMessage | base -> turntable, base -> carriage; the joint state's stamp |
| pub | ``/tf_static`` | tf2_msgs/TFMessage | carriage -> camera and parent -> base; at start and on changes |
| pub | ``robot_description`` | std_msgs/String | the cell's URDF in its frames (RViz's robot model) |

``/tf`` and ``/tf_static`` are the global TF topics (absolute names, whatever the
cell's namespace). ``/tf``: reliable, volatile, depth 100; ``/tf_static`` and
``robot_description``: reliable, transient local, depth 1, as tf2_ros's static
broadcaster and robot_state_publisher: a listener started later gets them.

The transforms are :mod:`sfs_ros.core.geometry.frames`' (the rig model's joints),
in the frames of :data:`sfs_ros.ros.frames.FRAME_PARAMS` (``config/frames.yaml``).
A joint state with none of the cell's joints (another machine's) is ignored, said
once; a malformed one is logged and ignored.

Parameters: the rig calibration (:data:`sfs_ros.ros.rig_params.WRITABLE_RIG_PARAMS`,
``config/rig.yaml``) and the cell's place in its parent frame (:data:`PLACEMENT`), settable
at run time (a new calibration, the cell moved on the robot); the frames' names are read
at start, as every node that stamps them does. The rig follows the rules of every node that
holds it (:class:`sfs_ros.ros.rig_params.RigParameters`: checked as one rig, the image
size fixed, refused while the scan node reports a scan under way); a set is also checked
with the frames as one model (a set that gives no valid frames or no chain of joints is
refused with the reason, the old values kept); then ``/tf_static`` and
``robot_description`` are published again at once.
"""

from __future__ import annotations

from dataclasses import replace

from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

from sfs_ros.cell_logic.message_fields import ForeignJointState
from sfs_ros.core.geometry.frames import moving_transforms, static_transforms
from sfs_ros.core.geometry.urdf import cell_urdf
from sfs_ros.nodes.entry import run_node
from sfs_ros.process import configure_process
from sfs_ros.ros import capture_qos, result_qos
from sfs_ros.ros.convert import angles_from_joint_state
from sfs_ros.ros.frames import FRAME_PARAMS, frame_names, tf_message
from sfs_ros.ros.params import Param, ParameterError, declare, read, validating_callback
from sfs_ros.ros.rig_params import WRITABLE_RIG_PARAMS, RigParameters, rig_calibration

__all__ = ["StatePublisherNode", "PARAMS", "main"]

NODE_NAME = "state_publisher"
#: The global TF topics.
TF_TOPIC = "/tf"
TF_STATIC_TOPIC = "/tf_static"
#: The frame parameters that may change at run time: where the cell stands in its parent.
PLACEMENT = ("parent_frame", "parent_pose")

#: The rig (writable, as on every node that holds it) and the frames (writable here; the
#: shared list stays read-only).
PARAMS: list[Param] = [*WRITABLE_RIG_PARAMS,
                       *(replace(p, read_only=p.name not in PLACEMENT) for p in FRAME_PARAMS)]


def _model(values: dict):
    """``(calibration, frame names)`` of the parameter values; :class:`ParameterError` when
    they make no rig, no frames, or no chain of joints (the paper's convention)."""
    calibration, names = rig_calibration(values), frame_names(values)
    try:
        static_transforms(calibration, names)
    except ValueError as exc:
        raise ParameterError("convention", str(exc)) from None
    return calibration, names


class StatePublisherNode(Node):
    """Publishes the cell's TF and URDF; see the module's description.

    Raises :class:`ParameterError` at construction for invalid parameters.
    """

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        try:
            self._calibration, self._names = _model(declare(self, PARAMS))
            RigParameters(self)
        except ParameterError:
            super().destroy_node()
            raise
        self._foreign_seen = False
        self._tf_pub = self.create_publisher(TFMessage, TF_TOPIC, capture_qos(100))
        self._static_pub = self.create_publisher(TFMessage, TF_STATIC_TOPIC, result_qos())
        self._description_pub = self.create_publisher(String, "robot_description", result_qos())
        self.create_subscription(JointState, "joint_states", self._on_joint_state, 10)
        self.add_on_set_parameters_callback(validating_callback(self, PARAMS, _model))
        self.add_post_set_parameters_callback(self._on_parameters_set)
        self._publish_static()

    def _publish_static(self) -> None:
        """``/tf_static`` and ``robot_description`` of the current rig and frames."""
        stamp = self.get_clock().now().to_msg()
        self._static_pub.publish(tf_message(static_transforms(self._calibration, self._names),
                                            stamp=stamp))
        self._description_pub.publish(String(data=cell_urdf(self._calibration,
                                                            links=self._names.links())))
        names = self._names
        parent = f"{names.parent} -> " if names.parent else ""
        self.get_logger().info(f"TF: {parent}{names.base_frame} -> {names.turntable_frame}, "
                               f"{names.carriage_frame} -> {names.camera_frame}")

    def _on_parameters_set(self, parameters: list) -> None:
        if any(p.name in {q.name for q in PARAMS} for p in parameters):
            self._calibration, self._names = _model(read(self, PARAMS))
            self._publish_static()

    def _on_joint_state(self, msg: JointState) -> None:
        try:
            theta, phi = angles_from_joint_state(msg)
        except ForeignJointState as exc:
            if not self._foreign_seen:
                self._foreign_seen = True
                self.get_logger().info(f"{exc}: such joint states are ignored (another "
                                       "machine's on the same topic); said once")
            return
        except ValueError as exc:
            self.get_logger().warning(f"joint state ignored: {exc}",
                                      throttle_duration_sec=10.0)
            return
        transforms = moving_transforms(self._calibration, self._names, theta, phi)
        self._tf_pub.publish(tf_message(transforms, stamp=msg.header.stamp))


def main(args=None) -> None:
    """Entry point ``sfs-state-publisher``.

    ``sfs-state-publisher --ros-args --params-file config/rig.yaml --params-file
    config/frames.yaml``
    """
    configure_process()
    run_node("sfs-state-publisher", StatePublisherNode, args)


if __name__ == "__main__":
    main()
