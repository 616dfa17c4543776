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
from dataclasses import dataclass
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

__all__ = ["BASE_FRAME", "OBJECT_FRAME", "CARRIAGE_FRAME", "CAMERA_FRAME", "LINKS",
           "TURNTABLE_JOINT", "CARRIAGE_JOINT", "CAMERA_JOINT", "Joint", "cell_joints",
           "XACRO_MACRO", "cell_urdf", "cell_xacro", "rpy_from_matrix", "rig_from_parameters"]

BASE_FRAME = "base_link"
OBJECT_FRAME = "turntable"
CARRIAGE_FRAME = "carriage"
CAMERA_FRAME = "camera_optical"
TURNTABLE_JOINT = "turntable"
CARRIAGE_JOINT = "carriage"
CAMERA_JOINT = "camera_mount"
#: The cell's links, root first.
LINKS = (BASE_FRAME, OBJECT_FRAME, CARRIAGE_FRAME, CAMERA_FRAME)
#: Name of the xacro macro of :func:`cell_xacro`.
XACRO_MACRO = "sfs_cell"

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


@dataclass(frozen=True)
class Joint:
    """One joint of the cell: ``X_parent = R (Rot(axis, position) X_child) + xyz``.

    name, kind : str
        Joint name and URDF type (``continuous``, ``revolute`` or ``fixed``).
    parent, child : str
        Link names (:data:`BASE_FRAME`, ...).
    xyz : (3,) tuple of float
        Origin of the child in the parent at position 0, metres.
    rotation : (3, 3) ndarray
        Orientation of the child in the parent at position 0.
    axis : (3,) tuple of float or None
        Unit axis of a moving joint in the child's frame; None for a fixed joint.
    limits : (lower, upper) radians or None
        Range of a revolute joint.
    """

    name: str
    kind: str
    parent: str
    child: str
    xyz: tuple
    rotation: np.ndarray
    axis: tuple | None = None
    limits: tuple | None = None


def cell_joints(calibration: RigCalibration) -> list[Joint]:
    """The three joints of the cell for ``calibration`` (module docstring): turntable,
    carriage, camera mount. Raises ``ValueError`` for the ``paper`` convention."""
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
    return [
        Joint(TURNTABLE_JOINT, "continuous", BASE_FRAME, OBJECT_FRAME,
              (*c.axis_point_m, 0.0), axis, axis=(0.0, 0.0, 1.0)),
        Joint(CARRIAGE_JOINT, "revolute", BASE_FRAME, CARRIAGE_FRAME, tuple(c.aim_point_m),
              rotation_x(c.phi_zero_rad), axis=(-1.0, 0.0, 0.0),
              limits=(c.phi_zero_rad - math.pi / 2, c.phi_zero_rad + math.pi / 2)),
        Joint(CAMERA_JOINT, "fixed", CARRIAGE_FRAME, CAMERA_FRAME,
              (0.0, -c.camera_distance_m, 0.0), mount),
    ]


def _joint_xml(joint: Joint, links: dict, name: str) -> list[str]:
    lines = [f"  <joint name={quoteattr(name)} type=\"{joint.kind}\">",
             f"    <parent link={quoteattr(links[joint.parent])}/>",
             f"    <child link={quoteattr(links[joint.child])}/>",
             f"    {_origin(joint.xyz, joint.rotation)}"]
    if joint.axis is not None:
        lines.append(f'    <axis xyz="{" ".join(f"{v:g}" for v in joint.axis)}"/>')
    if joint.limits is not None:
        # The cell is driven by the motor node, not through this description: no effort
        # or speed is claimed (URDF requires the attributes of a revolute joint).
        lower, upper = (_number(v) for v in joint.limits)
        lines.append(f'    <limit lower="{lower}" upper="{upper}" effort="0" velocity="0"/>')
    return lines + ["  </joint>"]


def cell_urdf(calibration: RigCalibration, *, name: str = "sfs_cell",
              links: dict[str, str] | None = None) -> str:
    """URDF (XML text) of the cell for ``calibration`` (module docstring).

    For every encoder reading ``(theta, phi)`` the pose of ``camera_optical`` relative
    to ``turntable`` is ``rig_camera(theta, phi, calibration)``'s ``R``, ``t`` (object
    -> camera), inverted. ``links`` renames links (``{"base_link": "cell1/base_link",
    ...}``, :meth:`sfs_ros.core.geometry.frames.FrameNames.links`); joint names stay.
    Raises ``ValueError`` for the ``paper`` convention.
    """
    joints = cell_joints(calibration)
    links = {link: link for link in LINKS} | dict(links or {})
    return "\n".join([
        '<?xml version="1.0"?>',
        "<!-- The turntable + C-arm cell of sfs_ros, made by sfs_ros.core.geometry.urdf."
        " Joint positions are encoder readings, radians. -->",
        f"<robot name={quoteattr(name)}>",
        *(f"  <link name={quoteattr(links[link])}/>" for link in LINKS),
        *(line for joint in joints for line in _joint_xml(joint, links, joint.name)),
        "</robot>",
        "",
    ])


def cell_xacro(calibration: RigCalibration, *, macro: str = XACRO_MACRO) -> str:
    """A xacro macro (XML text) of the cell for a robot's description: ``<xacro:sfs_cell
    prefix="cell1/" parent="world"><origin .../></xacro:sfs_cell>`` adds the links and
    joints of :func:`cell_urdf` with ``prefix`` in front of every link and joint name,
    and a fixed joint ``${prefix}base_joint`` placing the base in ``parent`` at the
    ``origin`` block. Raises ``ValueError`` for the ``paper`` convention.
    """
    joints = cell_joints(calibration)
    links = {link: "${prefix}" + link for link in LINKS}
    attach = ["  <joint name=\"${prefix}base_joint\" type=\"fixed\">",
              "    <parent link=\"${parent}\"/>",
              f"    <child link={quoteattr(links[BASE_FRAME])}/>",
              "    <xacro:insert_block name=\"origin\"/>",
              "  </joint>"]
    body = [*(f"  <link name={quoteattr(links[link])}/>" for link in LINKS), *attach,
            *(line for joint in joints
              for line in _joint_xml(joint, links, "${prefix}" + joint.name))]
    return "\n".join([
        '<?xml version="1.0"?>',
        "<!-- The turntable + C-arm cell of sfs_ros as a xacro macro, made by"
        " sfs_ros.core.geometry.urdf. Joint positions are encoder readings, radians. -->",
        '<robot xmlns:xacro="http://www.ros.org/wiki/xacro">',
        f"  <xacro:macro name={quoteattr(macro)} params=\"prefix:='' parent *origin\">",
        *("  " + line for line in body),
        "  </xacro:macro>",
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
    """``python -m sfs_ros.core.geometry.urdf [--xacro] RIG_YAML``: print the cell's URDF
    (with ``--xacro``: its xacro macro, :func:`cell_xacro`)."""
    import yaml

    argv = list(sys.argv[1:] if argv is None else argv)
    make = cell_xacro if argv[:1] == ["--xacro"] else cell_urdf
    argv = argv[1:] if make is cell_xacro else argv
    if len(argv) != 1:
        print("usage: python -m sfs_ros.core.geometry.urdf RIG_YAML > sfs_cell.urdf\n"
              "       python -m sfs_ros.core.geometry.urdf --xacro RIG_YAML > sfs_cell.urdf.xacro",
              file=sys.stderr)
        return 2
    try:
        parameters = yaml.safe_load(Path(argv[0]).read_text())["/**"]["ros__parameters"]
        sys.stdout.write(make(rig_from_parameters(parameters)))
    except (OSError, KeyError, TypeError, ValueError, yaml.YAMLError) as exc:
        print(f"error: {argv[0]}: {exc}", file=sys.stderr)
        return 1
    return 0

if __name__ == "__main__":
    sys.exit(main())
