"""The cell's frame names as node parameters, shared by every node that names a frame.

The state publisher publishes the cell's TF in these frames, the reconstruction
node stamps its hull, mesh and camera poses with the turntable frame, the camera
node (and the mock camera) its images with the camera frame. One file,
``config/frames.yaml`` (``/**:`` so every node reads it), holds the values for the
whole cell. Joint names ("turntable", "carriage" on ``joint_states``) are not
parameters: they are the cell's interface, whatever the frames are called.
"""

from __future__ import annotations

from geometry_msgs.msg import Quaternion, Transform, TransformStamped, Vector3
from tf2_msgs.msg import TFMessage

from sfs_ros.core.geometry.frames import FrameNames
from sfs_ros.ros.convert import header
from sfs_ros.ros.params import Param, ParameterError

__all__ = ["FRAME_PARAMS", "frame_names", "tf_message"]

_NAMES = FrameNames()

#: Parameters of :class:`FrameNames` (read-only, except on the state publisher).
FRAME_PARAMS: list[Param] = [
    Param("frame_prefix", _NAMES.prefix, "Put in front of every frame of the cell "
          "(e.g. 'cell1/' gives 'cell1/base_link'); not in front of parent_frame.",
          read_only=True, constraints="empty = none"),
    Param("base_frame", _NAMES.base, "The cell's base (lab) frame.", read_only=True),
    Param("turntable_frame", _NAMES.turntable, "The object frame on the turntable: the "
          "hull, mesh and camera poses are published in it.", read_only=True),
    Param("carriage_frame", _NAMES.carriage, "The carriage frame on the C-arm.",
          read_only=True),
    Param("camera_frame", _NAMES.camera, "The camera's optical frame (x right, y down, z "
          "forward): frame id of the images and camera_info.", read_only=True),
    Param("parent_frame", _NAMES.parent, "The frame the cell's base is attached to (a "
          "robot's frame, not prefixed).", read_only=True,
          constraints="empty = the base is a root of the TF tree"),
    Param("parent_pose", list(_NAMES.parent_pose), "The base in parent_frame: [x, y, z, roll, "
          "pitch, yaw], metres and radians (URDF rpy), or [x, y, z, qx, qy, qz, qw].",
          read_only=True, constraints="six or seven values; used with parent_frame"),
]


def frame_names(values: dict) -> FrameNames:
    """:class:`FrameNames` from the values of :data:`FRAME_PARAMS`; :class:`ParameterError`."""
    try:
        return FrameNames(prefix=values["frame_prefix"], base=values["base_frame"],
                          turntable=values["turntable_frame"],
                          carriage=values["carriage_frame"], camera=values["camera_frame"],
                          parent=values["parent_frame"],
                          parent_pose=tuple(values["parent_pose"]))
    except ValueError as exc:
        raise ParameterError("frames", str(exc)) from None


def tf_message(transforms, *, stamp):
    """``tf2_msgs/TFMessage`` of :class:`~sfs_ros.core.geometry.frames.Transform` s, each
    stamped ``stamp`` (a ``builtin_interfaces/Time`` or ``(sec, nanosec)``)."""
    return TFMessage(transforms=[_stamped(t, stamp) for t in transforms])


def _stamped(transform, stamp) -> TransformStamped:
    x, y, z = (float(v) for v in transform.translation)
    qx, qy, qz, qw = transform.quaternion()
    return TransformStamped(
        header=header(stamp=stamp, frame_id=transform.parent),
        child_frame_id=transform.child,
        transform=Transform(translation=Vector3(x=x, y=y, z=z),
                            rotation=Quaternion(x=qx, y=qy, z=qz, w=qw)))
