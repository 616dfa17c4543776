"""The cell's TF tree: its frames' names and the transforms between them (no ROS).

Frame tree (the joints of :func:`sfs_ros.core.geometry.urdf.cell_joints`, one source of
the kinematics for the URDF and for TF)::

    parent (optional, the robot's)  --static, parent_pose-->  base
    base --turntable joint (theta)--> turntable
    base --carriage joint (phi)-----> carriage --fixed, camera mount--> camera

Each frame's name is :class:`FrameNames`' ``prefix`` + its name (``"cell1/"`` +
``"base_link"`` = ``"cell1/base_link"``); the parent frame is the robot's and is not
prefixed. Joint names ("turntable", "carriage") are not frame names: they stay.

A :class:`Transform` is TF's: ``X_parent = rotation @ X_child + translation`` (the pose
of the child frame in the parent frame), metres. :func:`static_transforms` are the fixed
ones (published once, on ``/tf_static``), :func:`moving_transforms` the two joints at an
encoder reading (on ``/tf``). For every reading ``(theta, phi)`` the pose of the camera
frame in the turntable frame is the inverse of ``rig_camera(theta, phi, calibration)``'s
object -> camera ``R``, ``t``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .rig import RigCalibration, rotation_from_vector, rotation_x, rotation_y, rotation_z
from .urdf import (
    BASE_FRAME,
    CAMERA_FRAME,
    CAMERA_JOINT,
    CARRIAGE_FRAME,
    CARRIAGE_JOINT,
    OBJECT_FRAME,
    TURNTABLE_JOINT,
    Joint,
    cell_joints,
)

__all__ = ["FrameNames", "Transform", "static_transforms", "moving_transforms",
           "pose_rotation", "quaternion_from_matrix"]


def _check_frame(what: str, name) -> None:
    """tf2's rules for a frame id: a non-empty string without a leading "/" or spaces."""
    if not isinstance(name, str) or not name or name.startswith("/") \
            or any(ch.isspace() for ch in name):
        raise ValueError(f"frame {what} must be a non-empty name without a leading '/' or "
                         f"spaces, got {name!r}")


@dataclass(frozen=True)
class FrameNames:
    """The names of the cell's frames and where the cell sits.

    prefix : str
        Put in front of every frame of the cell (``"cell1/"``); ``""`` = none.
    base, turntable, carriage, camera : str
        The frames' names before the prefix.
    parent : str
        The frame the cell's base is attached to (a robot's, not prefixed); ``""`` = the
        base is a root of the TF tree.
    parent_pose : (6,) or (7,) tuple of float
        The base in ``parent``: ``(x, y, z, roll, pitch, yaw)`` (metres; radians, URDF
        rpy: ``Rz(yaw) Ry(pitch) Rx(roll)``) or ``(x, y, z, qx, qy, qz, qw)`` (a
        quaternion, normalised here).
    """

    prefix: str = ""
    base: str = BASE_FRAME
    turntable: str = OBJECT_FRAME
    carriage: str = CARRIAGE_FRAME
    camera: str = CAMERA_FRAME
    parent: str = ""
    parent_pose: tuple = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if not isinstance(self.prefix, str) or self.prefix.startswith("/") \
                or any(ch.isspace() for ch in self.prefix):
            raise ValueError(f"frame prefix must be text without a leading '/' or spaces, "
                             f"got {self.prefix!r}")
        for what in ("base", "turntable", "carriage", "camera"):
            _check_frame(what, getattr(self, what))
        names = [self.base, self.turntable, self.carriage, self.camera]
        if len(set(names)) != len(names):
            raise ValueError(f"the cell's frames must have four different names, got {names}")
        if self.parent:
            _check_frame("parent", self.parent)
            if self.parent in self.links().values():
                raise ValueError(f"parent frame {self.parent!r} is one of the cell's own")
        object.__setattr__(self, "parent_pose", tuple(float(v) for v in self.parent_pose))
        pose_rotation(self.parent_pose)     # checks its length and values

    def frame(self, name: str) -> str:
        """The published name of a frame of the cell given by its name before the prefix."""
        return self.prefix + name

    @property
    def base_frame(self) -> str:
        return self.frame(self.base)

    @property
    def turntable_frame(self) -> str:
        return self.frame(self.turntable)

    @property
    def carriage_frame(self) -> str:
        return self.frame(self.carriage)

    @property
    def camera_frame(self) -> str:
        return self.frame(self.camera)

    def links(self) -> dict[str, str]:
        """``{URDF link name: published frame name}`` (for ``cell_urdf(links=...)``)."""
        return {BASE_FRAME: self.base_frame, OBJECT_FRAME: self.turntable_frame,
                CARRIAGE_FRAME: self.carriage_frame, CAMERA_FRAME: self.camera_frame}


@dataclass(frozen=True)
class Transform:
    """The pose of frame ``child`` in frame ``parent``: ``X_parent = rotation @ X_child +
    translation``.

    parent, child : str
        Frame names as published.
    rotation : (3, 3) ndarray
    translation : (3,) ndarray, metres
    """

    parent: str
    child: str
    rotation: np.ndarray
    translation: np.ndarray

    def matrix(self) -> np.ndarray:
        """(4, 4) homogeneous transform, child -> parent coordinates."""
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.rotation, self.translation
        return T

    def quaternion(self) -> tuple[float, float, float, float]:
        """The rotation as a unit quaternion ``(x, y, z, w)``, ``w >= 0``."""
        return quaternion_from_matrix(self.rotation)


def quaternion_from_matrix(R) -> tuple[float, float, float, float]:
    """Unit quaternion ``(x, y, z, w)``, ``w >= 0``, of a (3, 3) rotation (Shepperd's method:
    the largest of the four diagonal combinations is the pivot, so no cancellation)."""
    R = np.asarray(R, dtype=np.float64)
    trace = R[0, 0] + R[1, 1] + R[2, 2]
    pivots = [trace, R[0, 0], R[1, 1], R[2, 2]]
    k = int(np.argmax(pivots))
    if k == 0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = ((R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, s / 4)
    else:
        i, j, m = k - 1, k % 3, (k + 1) % 3
        s = 2.0 * math.sqrt(1.0 + 2.0 * R[i, i] - trace)
        v = [0.0, 0.0, 0.0]
        v[i], v[j], v[m] = s / 4, (R[j, i] + R[i, j]) / s, (R[m, i] + R[i, m]) / s
        q = (*v, (R[m, j] - R[j, m]) / s)
    q = np.asarray(q) / np.linalg.norm(q)
    return tuple(float(v) for v in (-q if q[3] < 0 else q))


def pose_rotation(pose) -> tuple[np.ndarray, np.ndarray]:
    """``(rotation (3, 3), translation (3,))`` of a pose ``(x, y, z, roll, pitch, yaw)`` or
    ``(x, y, z, qx, qy, qz, qw)`` (metres, radians); ``ValueError`` for any other."""
    values = [float(v) for v in pose]
    if len(values) not in (6, 7) or not all(map(math.isfinite, values)):
        raise ValueError(f"parent pose must be six finite numbers [x, y, z, roll, pitch, yaw] "
                         f"or seven [x, y, z, qx, qy, qz, qw], got {list(pose)}")
    translation = np.array(values[:3])
    if len(values) == 6:
        roll, pitch, yaw = values[3:]
        return rotation_z(yaw) @ rotation_y(pitch) @ rotation_x(roll), translation
    q = np.array(values[3:])
    norm = float(np.linalg.norm(q))
    if norm < 1e-9:
        raise ValueError(f"parent pose quaternion {values[3:]} has no direction")
    x, y, z, w = q / norm
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]), \
        translation


def _joint_transform(joint: Joint, names: FrameNames, position: float = 0.0) -> Transform:
    """``T(origin) T(Rot(axis, position))`` of ``joint``, as robot_state_publisher composes."""
    links = names.links()
    rotation = joint.rotation
    if joint.axis is not None:
        rotation = rotation @ rotation_from_vector(np.asarray(joint.axis) * position)
    return Transform(links[joint.parent], links[joint.child], rotation,
                     np.asarray(joint.xyz, dtype=np.float64))


def static_transforms(calibration: RigCalibration, names: FrameNames) -> list[Transform]:
    """The fixed transforms: the camera mount (carriage -> camera) and, with a parent
    frame, parent -> base. ``ValueError`` for the ``paper`` convention (no chain)."""
    mount = next(j for j in cell_joints(calibration) if j.name == CAMERA_JOINT)
    transforms = [_joint_transform(mount, names)]
    if names.parent:
        rotation, translation = pose_rotation(names.parent_pose)
        transforms.insert(0, Transform(names.parent, names.base_frame, rotation, translation))
    return transforms


def moving_transforms(calibration: RigCalibration, names: FrameNames, theta_rad: float,
                      phi_rad: float) -> list[Transform]:
    """base -> turntable and base -> carriage at the encoder readings ``theta_rad``,
    ``phi_rad`` (radians, as on ``joint_states``: the zeros are in the joints' origins).
    ``ValueError`` for non-finite angles or the ``paper`` convention."""
    if not (math.isfinite(theta_rad) and math.isfinite(phi_rad)):
        raise ValueError(f"encoder angles must be finite, got theta={theta_rad}, phi={phi_rad}")
    positions = {TURNTABLE_JOINT: theta_rad, CARRIAGE_JOINT: phi_rad}
    return [_joint_transform(joint, names, positions[joint.name])
            for joint in cell_joints(calibration) if joint.name in positions]
