"""The cell as a URDF: the frames and joints of the rig model (:mod:`.rig`), plain XML.

Frame tree (joint names as the motor node publishes them on ``joint_states``)::

    base_link                  lab frame of the rig model (C-arm axis = X, Z up)
    |-- turntable              object frame: the mesh, hull and cloud are published in it
    |     joint "turntable", continuous about its +Z; origin: the axis point, the axis
    |     tilt and the encoder zero (theta_zero_rad)
    `-- carriage               turns with the carriage about the C-arm axis; origin at the
          |                    C-arm centre, axes = lab axes at phi = 0
          |  joint "carriage", revolute about lab -X (phi up = towards +Z);
          |  origin: the C-arm centre and the encoder zero (phi_zero_rad)
          `-- camera_optical   OpenCV axes (x right, y down, z forward); fixed joint
                               "camera_mount": camera_distance_m back from the C-arm
                               centre, turned by mount_rotation_rad

Joint positions are the *encoder readings*: the zero offsets are folded into the
joints' origins, so a ``sensor_msgs/JointState`` from the cell drives the model as it is.
The chain is the ``physical`` convention's; the paper's matrix is no chain of joints of
this cell, so :func:`cell_urdf` refuses it. The lens (``K``, distortion) is not part of a
URDF: ``camera_info`` carries it.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from .rig import (
    RigCalibration,
    camera_tilt,
    rotation_from_vector,
    rotation_x,
    rotation_y,
    rotation_z,
)

__all__ = ["BASE_FRAME", "OBJECT_FRAME", "CARRIAGE_FRAME", "CAMERA_FRAME", "TURNTABLE_JOINT",
           "CARRIAGE_JOINT", "cell_urdf", "rpy_from_matrix", "rig_from_parameters"]

BASE_FRAME = "base_link"
OBJECT_FRAME = "turntable"
CARRIAGE_FRAME = "carriage"
CAMERA_FRAME = "camera_optical"
TURNTABLE_JOINT = "turntable"
CARRIAGE_JOINT = "carriage"
CAMERA_JOINT = "camera_mount"

#: Below this ``cos(pitch)`` roll and yaw are one rotation (gimbal lock); see rpy_from_matrix.
_GIMBAL_LOCK = 1e-9


def rpy_from_matrix(R) -> tuple[float, float, float]:
    """URDF ``rpy`` (roll about X, then pitch about Y, then yaw about Z, fixed axes:
    ``R = Rz(yaw) Ry(pitch) Rx(roll)``) of a (3, 3) rotation, radians.

    Away from pitch = +-pi/2 the angles come from well-conditioned ``atan2`` pairs
    (round trip to ~1e-15); at the lock only ``roll -+ yaw`` is defined and yaw is 0.
    """
    R = np.asarray(R, dtype=np.float64)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise ValueError(f"expected a finite (3, 3) rotation, got shape {R.shape}")
    cos_pitch = math.hypot(R[0, 0], R[1, 0])
    pitch = math.atan2(-R[2, 0], cos_pitch)
    if cos_pitch > _GIMBAL_LOCK:
        return math.atan2(R[2, 1], R[2, 2]), pitch, math.atan2(R[1, 0], R[0, 0])
    # R = Ry(+-pi/2) Rx(roll): row 0 is (0, +-sin roll, +-cos roll), row 1 (0, cos roll, -sin roll).
    return math.atan2(-R[1, 2], R[1, 1]), pitch, 0.0


def _number(value: float) -> str:
    """Shortest text that reads back as the same float (``repr``), without ``-0``."""
    value = float(value)
    return repr(value) if value != 0.0 else "0"


def _origin(xyz, R) -> str:
    xyz = " ".join(_number(v) for v in xyz)
    rpy = " ".join(_number(v) for v in rpy_from_matrix(R))
    return f'<origin xyz="{xyz}" rpy="{rpy}"/>'


def cell_urdf(calibration: RigCalibration, *, name: str = "sfs_cell") -> str:
    """URDF (XML text) of the cell for ``calibration`` (module docstring).

    For every encoder reading ``(theta, phi)`` the pose of ``camera_optical`` relative
    to ``turntable`` is ``rig_camera(theta, phi, calibration)``'s ``R``, ``t`` (object
    -> camera), inverted. Raises ``ValueError`` for the ``paper`` convention.
    """
    if not isinstance(calibration, RigCalibration):
        raise ValueError(f"expected a RigCalibration, got {type(calibration).__name__}")
    if calibration.convention != "physical":
        raise ValueError("the cell's URDF needs the 'physical' rig convention: the paper's "
                         f"matrix is no chain of joints (got {calibration.convention!r})")
    c = calibration
    # Turntable: X_lab = A Rz(theta_enc - theta_zero) X + (axis_x, axis_y, 0).
    axis = (rotation_x(c.axis_tilt_x_rad) @ rotation_y(c.axis_tilt_y_rad)
            @ rotation_z(-c.theta_zero_rad))
    # Carriage: X_lab = aim + Rx(-(phi_enc - phi_zero)) Y, i.e. origin Rx(phi_zero),
    # axis -X. Camera: X_cam = M (T(phi) (X_lab - aim) + d e_z) with T(phi) = T(0) Rx(phi),
    # so Y = (0, -d, 0) + T(0)^T M^T X_cam.
    mount = camera_tilt(0.0).T @ rotation_from_vector(c.mount_rotation_rad).T
    lower, upper = c.phi_zero_rad - math.pi / 2, c.phi_zero_rad + math.pi / 2
    return "\n".join([
        '<?xml version="1.0"?>',
        "<!-- The turntable + C-arm cell of sfs_ros, made by sfs_ros.core.geometry.urdf."
        " Joint positions are encoder readings, radians. -->",
        f"<robot name={quoteattr(name)}>",
        f'  <link name="{BASE_FRAME}"/>',
        f'  <link name="{OBJECT_FRAME}"/>',
        f'  <link name="{CARRIAGE_FRAME}"/>',
        f'  <link name="{CAMERA_FRAME}"/>',
        f'  <joint name="{TURNTABLE_JOINT}" type="continuous">',
        f'    <parent link="{BASE_FRAME}"/>',
        f'    <child link="{OBJECT_FRAME}"/>',
        f"    {_origin((*c.axis_point_m, 0.0), axis)}",
        '    <axis xyz="0 0 1"/>',
        "  </joint>",
        f'  <joint name="{CARRIAGE_JOINT}" type="revolute">',
        f'    <parent link="{BASE_FRAME}"/>',
        f'    <child link="{CARRIAGE_FRAME}"/>',
        f"    {_origin(c.aim_point_m, rotation_x(c.phi_zero_rad))}",
        '    <axis xyz="-1 0 0"/>',
        # The cell is driven by the motor node, not through this description: no effort
        # or speed is claimed (URDF requires the attributes of a revolute joint).
        f'    <limit lower="{_number(lower)}" upper="{_number(upper)}" effort="0" velocity="0"/>',
        "  </joint>",
        f'  <joint name="{CAMERA_JOINT}" type="fixed">',
        f'    <parent link="{CARRIAGE_FRAME}"/>',
        f'    <child link="{CAMERA_FRAME}"/>',
        f"    {_origin((0.0, -c.camera_distance_m, 0.0), mount)}",
        "  </joint>",
        "</robot>",
        "",
    ])


def rig_from_parameters(values: dict) -> RigCalibration:
    """:class:`RigCalibration` from ``rig.yaml``'s ``ros__parameters`` (``cx``/``cy``
    below 0 = the image centre, as the nodes read them)."""
    values = dict(values)
    for key in ("cx", "cy"):
        if isinstance(values.get(key), (int, float)) and values[key] < 0:
            values[key] = None
    return RigCalibration.from_dict(values)


def main(argv=None) -> int:
    """``python -m sfs_ros.core.geometry.urdf RIG_YAML``: print the cell's URDF."""
    import yaml

    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1:
        print("usage: python -m sfs_ros.core.geometry.urdf RIG_YAML > sfs_cell.urdf",
              file=sys.stderr)
        return 2
    try:
        parameters = yaml.safe_load(Path(argv[0]).read_text())["/**"]["ros__parameters"]
        sys.stdout.write(cell_urdf(rig_from_parameters(parameters)))
    except (OSError, KeyError, TypeError, ValueError, yaml.YAMLError) as exc:
        print(f"error: {argv[0]}: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
