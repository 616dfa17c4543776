"""Rig model: encoder angles (theta, phi) plus a calibration -> a :class:`Camera`.

Frames
------
*Object frame* (the frame the reconstruction lives in): fixed to the turntable,
origin at the centre of the plate, Z up along the turntable axis, metres.

*Lab frame*: the same at ``theta = 0``. The turntable turns the object by
``theta`` about +Z (counter-clockwise seen from above). The camera rides a
vertical C-arm in the lab's Y-Z plane at elevation ``phi`` above the horizon
(``phi = 0``: looking horizontally along +Y; ``phi = pi/2``: looking straight
down), always aimed at the C-arm centre ``aim_point_m``, with image right = +X.

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

__all__ = ["CONVENTIONS", "RigCalibration", "rig_rotation", "rig_camera"]

CONVENTIONS = ("physical", "paper")

#: Focal length (pinhole, pixels) or scale (orthographic, pixels per metre) accepted.
_FOCAL_RANGE = (1e-3, 1e9)
#: Camera distance accepted, metres (|aim point| is bounded by the upper end too).
_DISTANCE_RANGE_M = (1e-4, 1e4)


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
        if not isinstance(self.aim_point_m, (tuple, list, np.ndarray)) or len(self.aim_point_m) != 3:
            raise ValueError(f"rig aim_point_m must be 3 numbers (x, y, z metres), got "
                             f"{_brief(self.aim_point_m)}")
        for name, value, low, high in (
                ("fx", self.fx, *_FOCAL_RANGE), ("fy", self.fy, *_FOCAL_RANGE),
                ("cx", self.cx, -MAX_IMAGE_SIDE_PX, 2 * MAX_IMAGE_SIDE_PX),
                ("cy", self.cy, -MAX_IMAGE_SIDE_PX, 2 * MAX_IMAGE_SIDE_PX),
                ("camera_distance_m", self.camera_distance_m, *_DISTANCE_RANGE_M),
                ("theta_zero_rad", self.theta_zero_rad, -2 * math.pi, 2 * math.pi),
                ("phi_zero_rad", self.phi_zero_rad, -2 * math.pi, 2 * math.pi),
                *((f"aim_point_m[{i}]", v, -_DISTANCE_RANGE_M[1], _DISTANCE_RANGE_M[1])
                  for i, v in enumerate(self.aim_point_m))):
            if value is None and name in ("cx", "cy"):
                continue
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number)) \
                    or not math.isfinite(value) or not low <= value <= high:
                raise ValueError(f"rig {name} must be a finite number in [{low:g}, {high:g}], "
                                 f"got {_brief(value)}")
        object.__setattr__(self, "aim_point_m", tuple(float(v) for v in self.aim_point_m))

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
        out["aim_point_m"] = list(self.aim_point_m)
        return out

    @property
    def K(self) -> np.ndarray:
        """(3, 3) intrinsic matrix."""
        cx = (self.width - 1) / 2.0 if self.cx is None else self.cx
        cy = (self.height - 1) / 2.0 if self.cy is None else self.cy
        return np.array([[self.fx, 0.0, cx], [0.0, self.fy, cy], [0.0, 0.0, 1.0]])


def _rz(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _tilt(phi: float) -> np.ndarray:
    """Lab -> camera rotation for a camera at elevation ``phi`` (rows: right, down, forward)."""
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[1.0, 0.0, 0.0], [0.0, -s, -c], [0.0, c, -s]])


def rig_rotation(theta_rad: float, phi_rad: float, convention: str = "physical") -> np.ndarray:
    """(3, 3) rotation object frame -> camera frame for true axis angles, radians."""
    if convention == "physical":
        return _tilt(phi_rad) @ _rz(theta_rad)
    if convention == "paper":
        ct, st, cp, sp = math.cos(theta_rad), math.sin(theta_rad), math.cos(phi_rad), math.sin(phi_rad)
        r1 = np.array([ct, -st * cp, -st * sp])
        r2 = np.array([0.0, sp, -cp])
        return np.vstack([r1, r2, np.cross(r1, r2)])
    raise ValueError(f"convention must be one of {CONVENTIONS}, got {convention!r}")


def rig_camera(theta_rad: float, phi_rad: float, calibration: RigCalibration) -> Camera:
    """The camera that took an image at encoder readings ``(theta_rad, phi_rad)``.

    Raises ``ValueError`` for non-finite angles or a carriage angle outside
    [-pi/2, pi/2] (after removing the encoder zero).
    """
    theta_rad, phi_rad = float(theta_rad), float(phi_rad)
    if not (math.isfinite(theta_rad) and math.isfinite(phi_rad)):
        raise ValueError(f"encoder angles must be finite, got theta={theta_rad}, phi={phi_rad}")
    theta = theta_rad - calibration.theta_zero_rad
    phi = phi_rad - calibration.phi_zero_rad
    if abs(phi) > math.pi / 2 + 1e-9:
        raise ValueError(
            f"carriage angle phi={math.degrees(phi):.3f} deg is outside the C-arm range "
            "[-90, 90] deg")
    R = rig_rotation(theta, phi, calibration.convention)
    # The camera aims at the C-arm centre from camera_distance_m away, so in
    # camera coordinates the aim point sits at (0, 0, camera_distance_m). The
    # aim point is fixed in the lab; the turntable only turns the object. (The
    # paper's matrix has no lab frame: there the aim point is in object frame.)
    lab_to_cam = _tilt(phi) if calibration.convention == "physical" else R
    t = np.array([0.0, 0.0, calibration.camera_distance_m]) - lab_to_cam @ np.asarray(
        calibration.aim_point_m)
    return Camera(K=calibration.K, R=R, t=t, width=calibration.width, height=calibration.height,
                  orthographic=calibration.projection == "orthographic")
