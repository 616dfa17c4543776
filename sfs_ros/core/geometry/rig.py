"""Rig model: encoder angles (theta, phi) plus a calibration -> a :class:`Camera`.

Frames
------
*Object frame* (the frame the reconstruction lives in): fixed to the turntable,
origin on the turntable axis, Z up along the axis, metres.

*Lab frame*: the C-arm's. X is the C-arm's rotation axis, which passes through
the C-arm centre ``aim_point_m``; Z is up. With the default (ideal) rig the
turntable axis is the lab Z axis and the lab frame is the object frame at
``theta = 0``. The camera rides the C-arm in the lab's Y-Z plane at elevation
``phi`` above the horizon (``phi = 0``: looking horizontally along +Y;
``phi = pi/2``: looking straight down), aimed at the C-arm centre from
``camera_distance_m`` away, with image right = +X.

Kinematic chain (``physical`` convention), object point ``X`` -> camera point::

    theta = theta_encoder - theta_zero_rad        phi = phi_encoder - phi_zero_rad
    X_lab = Rx(axis_tilt_x_rad) Ry(axis_tilt_y_rad) Rz(theta) X + (axis_x, axis_y, 0)
    X_arm = T(phi) (X_lab - aim_point_m) + (0, 0, camera_distance_m)
    X_cam = Rodrigues(mount_rotation_rad) X_arm

1. the turntable turns the object by ``theta`` about its own axis (+Z of the
   object frame, counter-clockwise seen from above);
2. the turntable axis is tilted, first about lab Y then about lab X, and
   crosses the lab plane ``z = 0`` at ``axis_point_m = (axis_x, axis_y)``;
3. the carriage frame ``T(phi)`` (rows: image right, image down, forward)
   looks at the C-arm centre from elevation ``phi``; ``T(phi) = T(0) Rx(phi)``;
4. the camera sits on its carriage turned by the small rotation vector
   ``mount_rotation_rad`` (carriage frame, radians);
5. the lens maps the camera point to pixels through ``K`` and the OpenCV
   ``plumb_bob`` distortion ``(k1, k2, p1, p2, k3)`` (:mod:`.camera`).

Two things images cannot tell apart from others: a tilt of the turntable axis
about lab X is a change of the carriage zero (``T(phi) Rx(a) = T(phi + a)``), so
a calibration holds ``axis_tilt_x_rad`` at 0; an offset of the camera on its
carriage is a shift of the C-arm centre (across the arc), the carriage zero
with a mounting pitch (along it) or the radius (along the view), so the rig has
no field for it (:mod:`sfs_ros.core.calibration.model`).

Conventions
-----------
``physical`` (default)
    ``R = R_tilt(phi) @ R_turntable(theta)``: rotate the object about the
    vertical axis, then view it from elevation ``phi``. At constant ``phi`` the
    viewing directions sweep a latitude circle.
``paper``
    The paper's printed matrix, rows ``(cos t, -sin t cos p, -sin t sin p)`` and
    ``(0, sin p, -cos p)``, completed to a rotation. Its viewing direction is
    ``(sin t, cos t cos p, cos t sin p)`` up to sign: at constant ``phi`` it
    sweeps a great circle through +-X, and ``theta`` and ``theta + pi`` give
    mirror-image silhouettes. Kept so the paper's results can be reproduced.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np

from .camera import MAX_IMAGE_SIDE_PX, Camera

__all__ = ["CONVENTIONS", "MAX_ENCODER_RAD", "RigCalibration", "camera_tilt", "rig_rotation", "rig_camera",
           "rotation_from_vector", "rotation_x", "rotation_y", "rotation_z"]

CONVENTIONS = ("physical", "paper")

#: Vector fields of :class:`RigCalibration` and their lengths.
_VECTORS = {"aim_point_m": 3, "distortion": 5, "axis_point_m": 2, "mount_rotation_rad": 3}
#: Focal length (pinhole, pixels) or scale (orthographic, pixels per metre) accepted.
_FOCAL_RANGE = (1e-3, 1e9)
#: Camera distance accepted, metres (positions in the lab are bounded by the upper end too).
_DISTANCE_RANGE_M = (1e-4, 1e4)
#: Largest magnitude of a distortion coefficient accepted.
_MAX_DISTORTION = 1e3
#: Largest magnitude of an encoder reading accepted, radians. A reading counts the turns
#: since the axis was homed, so it may exceed 2 pi; 1e6 rad is 159 000 turns, more than a
#: cell turns between homings (a scan is about one turn), and float64 still resolves 1.2e-10
#: rad there, far below a pixel's angle, so a reading within the bound gives its camera as
#: exactly as a small one. Beyond it the float's own spacing grows toward a whole turn
#: (2 rad at 1e16): such a number (1e308, 1e20) is a damaged value, not an angle.
MAX_ENCODER_RAD = 1e6


def _brief(value, limit: int = 60) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


@dataclass(frozen=True)
class RigCalibration:
    """What turns encoder angles into a camera.

    Attributes
    ----------
    width, height : int
        Image size, pixels.
    projection : str
        ``"orthographic"`` or ``"pinhole"``.
    fx, fy : float
        Pinhole: focal length in pixels. Orthographic: scale in pixels per metre.
    cx, cy : float or None
        Principal point, pixels; ``None`` means the image centre.
    camera_distance_m : float
        Distance from the C-arm centre to the camera centre, metres.
    aim_point_m : (3,) tuple of float
        C-arm centre (where the camera aims) in the lab frame, metres.
    theta_zero_rad, phi_zero_rad : float
        Encoder readings at the true zero of each axis, radians.
    convention : str
        ``"physical"`` (default) or ``"paper"``, see the module docstring.
    distortion : (5,) tuple of float
        Lens distortion ``(k1, k2, p1, p2, k3)``, OpenCV ``plumb_bob``
        (pinhole only); all zero = an ideal lens.
    axis_point_m : (2,) tuple of float
        Where the turntable axis crosses the lab plane ``z = 0``, ``(x, y)``, metres.
    axis_tilt_x_rad, axis_tilt_y_rad : float
        Tilt of the turntable axis about lab X and lab Y, radians.
    mount_rotation_rad : (3,) tuple of float
        Rotation vector of the camera on its carriage (carriage frame), radians.

    The last five (with the defaults, an ideal rig) need the ``physical`` convention.
    """

    width: int = 512
    height: int = 512
    projection: str = "orthographic"
    fx: float = 2000.0
    fy: float = 2000.0
    cx: float | None = None
    cy: float | None = None
    camera_distance_m: float = 1.0
    aim_point_m: tuple = field(default=(0.0, 0.0, 0.0))
    theta_zero_rad: float = 0.0
    phi_zero_rad: float = 0.0
    convention: str = "physical"
    distortion: tuple = field(default=(0.0, 0.0, 0.0, 0.0, 0.0))
    axis_point_m: tuple = field(default=(0.0, 0.0))
    axis_tilt_x_rad: float = 0.0
    axis_tilt_y_rad: float = 0.0
    mount_rotation_rad: tuple = field(default=(0.0, 0.0, 0.0))

    def __post_init__(self) -> None:
        if self.projection not in ("orthographic", "pinhole"):
            raise ValueError(
                f"rig projection must be 'orthographic' or 'pinhole', got {_brief(self.projection)}")
        if self.convention not in CONVENTIONS:
            raise ValueError(f"rig convention must be one of {CONVENTIONS}, got "
                             f"{_brief(self.convention)}")
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) \
                    or not 0 < value <= MAX_IMAGE_SIDE_PX:
                raise ValueError(f"rig {name} must be a whole number of pixels in "
                                 f"1..{MAX_IMAGE_SIDE_PX}, got {_brief(value)}")
        for name, size in _VECTORS.items():
            value = getattr(self, name)
            if not isinstance(value, (tuple, list, np.ndarray)) or len(value) != size:
                raise ValueError(f"rig {name} must be {size} numbers, got {_brief(value)}")
        far = _DISTANCE_RANGE_M[1]
        ranges = {"fx": _FOCAL_RANGE, "fy": _FOCAL_RANGE,
                  "cx": (-MAX_IMAGE_SIDE_PX, 2 * MAX_IMAGE_SIDE_PX),
                  "cy": (-MAX_IMAGE_SIDE_PX, 2 * MAX_IMAGE_SIDE_PX),
                  "camera_distance_m": _DISTANCE_RANGE_M,
                  "theta_zero_rad": (-2 * math.pi, 2 * math.pi),
                  "phi_zero_rad": (-2 * math.pi, 2 * math.pi),
                  "axis_tilt_x_rad": (-math.pi / 2, math.pi / 2),
                  "axis_tilt_y_rad": (-math.pi / 2, math.pi / 2)}
        vector_ranges = {"aim_point_m": (-far, far), "axis_point_m": (-far, far),
                         "distortion": (-_MAX_DISTORTION, _MAX_DISTORTION),
                         "mount_rotation_rad": (-math.pi, math.pi)}
        checks = [(name, getattr(self, name), *bounds) for name, bounds in ranges.items()]
        checks += [(f"{name}[{i}]", v, *bounds) for name, bounds in vector_ranges.items()
                   for i, v in enumerate(getattr(self, name))]
        for name, value, low, high in checks:
            if value is None and name in ("cx", "cy"):
                continue
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number)) \
                    or not math.isfinite(value) or not low <= value <= high:
                raise ValueError(f"rig {name} must be a finite number in [{low:g}, {high:g}], "
                                 f"got {_brief(value)}")
        for name in _VECTORS:
            object.__setattr__(self, name, tuple(float(v) for v in getattr(self, name)))
        if any(self.distortion) and self.projection != "pinhole":
            raise ValueError("rig distortion needs the pinhole projection, got "
                             f"{self.projection!r} with distortion {self.distortion}")
        if not self.is_ideal and self.convention != "physical":
            raise ValueError("rig axis_point_m, axis tilts and mount_rotation_rad need the "
                             f"'physical' convention, got {self.convention!r}")

    @property
    def is_ideal(self) -> bool:
        """True when the turntable axis is the lab Z axis and the camera sits square."""
        return not (any(self.axis_point_m) or self.axis_tilt_x_rad or self.axis_tilt_y_rad
                    or any(self.mount_rotation_rad))

    @classmethod
    def from_dict(cls, values: dict) -> "RigCalibration":
        """Build from a mapping (e.g. parsed YAML); unknown keys are an error."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(map(str, set(values) - known))
        if unknown:
            raise ValueError(f"unknown rig calibration keys {_brief(unknown)}; expected some of "
                             f"{sorted(known)}")
        return cls(**values)

    def to_dict(self) -> dict:
        """Plain mapping of all fields (round-trips through :meth:`from_dict`)."""
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        for name in _VECTORS:
            out[name] = list(out[name])
        return out

    @property
    def K(self) -> np.ndarray:
        """(3, 3) intrinsic matrix."""
        cx = (self.width - 1) / 2.0 if self.cx is None else self.cx
        cy = (self.height - 1) / 2.0 if self.cy is None else self.cy
        return np.array([[self.fx, 0.0, cx], [0.0, self.fy, cy], [0.0, 0.0, 1.0]])


def rotation_z(angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` radians about the Z axis (right-handed)."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_x(angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` radians about the X axis (right-handed)."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rotation_y(angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` radians about the Y axis (right-handed)."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rotation_from_vector(rotvec) -> np.ndarray:
    """(3, 3) rotation of the rotation vector ``rotvec`` (3,), radians (Rodrigues)."""
    rotvec = np.asarray(rotvec, dtype=np.float64)
    angle = float(np.linalg.norm(rotvec))
    if angle == 0.0:
        return np.eye(3)
    k = rotvec / angle
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * cross + (1.0 - math.cos(angle)) * cross @ cross


def camera_tilt(phi: float) -> np.ndarray:
    """Lab -> camera rotation for a camera at elevation ``phi`` (rows: right, down, forward)."""
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[1.0, 0.0, 0.0], [0.0, -s, -c], [0.0, c, -s]])


def rig_rotation(theta_rad: float, phi_rad: float, convention: str = "physical") -> np.ndarray:
    """(3, 3) rotation object frame -> camera frame for true axis angles, radians."""
    if convention == "physical":
        return camera_tilt(phi_rad) @ rotation_z(theta_rad)
    if convention == "paper":
        ct, st, cp, sp = math.cos(theta_rad), math.sin(theta_rad), math.cos(phi_rad), math.sin(phi_rad)
        r1 = np.array([ct, -st * cp, -st * sp])
        r2 = np.array([0.0, sp, -cp])
        return np.vstack([r1, r2, np.cross(r1, r2)])
    raise ValueError(f"convention must be one of {CONVENTIONS}, got {convention!r}")


def rig_camera(theta_rad: float, phi_rad: float, calibration: RigCalibration) -> Camera:
    """The camera that took an image at encoder readings ``(theta_rad, phi_rad)``.

    Raises ``ValueError`` for angles that are not finite or beyond
    :data:`MAX_ENCODER_RAD`, or a carriage angle outside [-pi/2, pi/2] (after
    removing the encoder zero).
    """
    theta_rad, phi_rad = float(theta_rad), float(phi_rad)
    if not (abs(theta_rad) <= MAX_ENCODER_RAD and abs(phi_rad) <= MAX_ENCODER_RAD):
        raise ValueError(f"encoder angles must be finite and within +-{MAX_ENCODER_RAD:g} rad, "
                         f"got theta_rad={theta_rad!r}, phi_rad={phi_rad!r}")
    theta = theta_rad - calibration.theta_zero_rad
    phi = phi_rad - calibration.phi_zero_rad
    if abs(phi) > math.pi / 2 + 1e-9:
        raise ValueError(
            f"carriage angle phi={math.degrees(phi):.3f} deg is outside the C-arm range "
            "[-90, 90] deg")
    if not calibration.is_ideal:
        return _real_rig_camera(theta, phi, calibration)
    R = rig_rotation(theta, phi, calibration.convention)
    # The camera aims at the C-arm centre from camera_distance_m away, so in
    # camera coordinates the aim point sits at (0, 0, camera_distance_m). The
    # aim point is fixed in the lab; the turntable only turns the object. (The
    # paper's matrix has no lab frame: there the aim point is in object frame.)
    lab_to_cam = camera_tilt(phi) if calibration.convention == "physical" else R
    t = np.array([0.0, 0.0, calibration.camera_distance_m]) - lab_to_cam @ np.asarray(
        calibration.aim_point_m)
    return Camera(K=calibration.K, R=R, t=t, width=calibration.width, height=calibration.height,
                  orthographic=calibration.projection == "orthographic",
                  distortion=calibration.distortion)


def _real_rig_camera(theta: float, phi: float, calibration: RigCalibration) -> Camera:
    """The kinematic chain of the module docstring for true angles, radians."""
    axis = rotation_x(calibration.axis_tilt_x_rad) @ rotation_y(calibration.axis_tilt_y_rad)
    mount = rotation_from_vector(calibration.mount_rotation_rad)
    arm = camera_tilt(phi)
    axis_point = np.array([*calibration.axis_point_m, 0.0])
    R = mount @ arm @ axis @ rotation_z(theta)
    t = mount @ (arm @ (axis_point - np.asarray(calibration.aim_point_m))
                 + np.array([0.0, 0.0, calibration.camera_distance_m]))
    return Camera(K=calibration.K, R=R, t=t, width=calibration.width, height=calibration.height,
                  orthographic=calibration.projection == "orthographic",
                  distortion=calibration.distortion)
