"""The rig calibration as node parameters, shared by every node that needs it.

The reconstruction node turns encoder angles into cameras with it, the camera
node publishes its intrinsics as ``CameraInfo``, and the mock camera renders
with it. One file, ``config/rig.yaml`` (``/**:`` so every node reads it),
holds the values for the whole cell.
"""

from __future__ import annotations

from sfs_ros.core.geometry.rig import CONVENTIONS, RigCalibration
from sfs_ros.ros.params import Param, ParameterError

__all__ = ["RIG_PARAMS", "rig_calibration"]

_RIG = RigCalibration()

#: Parameters of :class:`RigCalibration` (all read-only: they define the scan).
RIG_PARAMS: list[Param] = [
    Param("projection", _RIG.projection, "Camera model of the rig.",
          choices=("orthographic", "pinhole"), read_only=True),
    Param("width", _RIG.width, "Image width, pixels.", bounds=(1, 100000), read_only=True),
    Param("height", _RIG.height, "Image height, pixels.", bounds=(1, 100000), read_only=True),
    Param("fx", _RIG.fx, "Pinhole: focal length, pixels; orthographic: pixels per metre.",
          bounds=(1e-9, 1e9), read_only=True),
    Param("fy", _RIG.fy, "As fx, vertically.", bounds=(1e-9, 1e9), read_only=True),
    Param("cx", -1.0, "Principal point x, pixels.", bounds=(-1.0, 1e6), read_only=True,
          constraints="below 0 = image centre"),
    Param("cy", -1.0, "Principal point y, pixels.", bounds=(-1.0, 1e6), read_only=True,
          constraints="below 0 = image centre"),
    Param("camera_distance_m", _RIG.camera_distance_m, "Distance from the C-arm centre to the "
          "camera centre, metres.", bounds=(1e-6, 1000.0), read_only=True),
    Param("aim_point_m", [float(v) for v in _RIG.aim_point_m], "C-arm centre [x, y, z] in the "
          "lab frame, metres.", read_only=True, constraints="three values"),
    Param("theta_zero_rad", _RIG.theta_zero_rad, "Turntable encoder reading at its true zero, "
          "radians.", read_only=True),
    Param("phi_zero_rad", _RIG.phi_zero_rad, "Carriage encoder reading at its true zero, "
          "radians.", read_only=True),
    Param("convention", _RIG.convention, "Angle convention of the rig.", choices=CONVENTIONS,
          read_only=True),
    Param("distortion", list(_RIG.distortion), "Lens distortion [k1, k2, p1, p2, k3] "
          "(OpenCV plumb_bob), pinhole only.", read_only=True, constraints="five values"),
    Param("axis_point_m", list(_RIG.axis_point_m), "Where the turntable axis crosses the lab "
          "plane z = 0, [x, y], metres.", read_only=True, constraints="two values"),
    Param("axis_tilt_x_rad", _RIG.axis_tilt_x_rad, "Tilt of the turntable axis about lab X, "
          "radians.", bounds=(-0.5, 0.5), read_only=True),
    Param("axis_tilt_y_rad", _RIG.axis_tilt_y_rad, "Tilt of the turntable axis about lab Y, "
          "radians.", bounds=(-0.5, 0.5), read_only=True),
    Param("mount_rotation_rad", list(_RIG.mount_rotation_rad), "Rotation vector of the camera "
          "on its carriage, radians.", read_only=True, constraints="three values"),
]


def rig_calibration(values: dict) -> RigCalibration:
    """:class:`RigCalibration` from the values of :data:`RIG_PARAMS`; :class:`ParameterError`."""
    for name, size in (("aim_point_m", 3), ("distortion", 5), ("axis_point_m", 2),
                       ("mount_rotation_rad", 3)):
        if len(values[name]) != size:
            raise ParameterError(name, f"got {values[name]!r}, expected {size} values")
    try:
        return RigCalibration(
            width=values["width"], height=values["height"], projection=values["projection"],
            fx=values["fx"], fy=values["fy"],
            cx=None if values["cx"] < 0 else values["cx"],
            cy=None if values["cy"] < 0 else values["cy"],
            camera_distance_m=values["camera_distance_m"],
            aim_point_m=tuple(values["aim_point_m"]),
            theta_zero_rad=values["theta_zero_rad"], phi_zero_rad=values["phi_zero_rad"],
            convention=values["convention"], distortion=tuple(values["distortion"]),
            axis_point_m=tuple(values["axis_point_m"]),
            axis_tilt_x_rad=values["axis_tilt_x_rad"], axis_tilt_y_rad=values["axis_tilt_y_rad"],
            mount_rotation_rad=tuple(values["mount_rotation_rad"]))
    except ValueError as exc:
        raise ParameterError("calibration", str(exc)) from None
