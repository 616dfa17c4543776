"""What the calibration solves for: the rig's parameters and the board's pose on the turntable.

Gauge (what images cannot tell and the solver therefore holds fixed)
-------------------------------------------------------------------
* The lab frame's origin: the C-arm centre stays at the input rig's
  ``aim_point_m`` (all three coordinates); the turntable axis point is found
  relative to it.
* The object frame's origin along the turntable axis: the point where the axis
  crosses the lab plane ``z = 0`` (so ``axis_point_m`` has only ``x, y``).
* The turntable axis tilt about lab X: it equals a change of the carriage
  encoder zero (``T(phi) Rx(a) = T(phi + a)``, :mod:`..geometry.rig`); it is
  held at 0, so ``phi_zero_rad`` is the carriage reading at which the camera
  looks square to the turntable axis. :func:`canonical` turns any rig into
  this form.
* The board's yaw about the turntable axis: it equals a change of the
  turntable encoder zero; it is held at 0, so ``theta_zero_rad`` is the
  turntable reading at which the board's x edge runs along the C-arm axis
  (lab X) and its printed face looks at the C-arm (place the board along the
  plate's zero mark).
* An offset of the camera on its carriage: across the C-arm it is a shift of
  the C-arm centre, along the arc the carriage zero plus a mounting pitch,
  along the optical axis the radius; the rig has no field for it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..geometry.rig import RigCalibration, rotation_x, rotation_y

__all__ = ["BoardPose", "STANDING", "canonical", "euler_zyx"]

#: Board frame -> object frame of an upright board facing the C-arm at theta = 0:
#: board x -> +X, board y (down the picture) -> -Z, board z (into the board) -> +Y.
STANDING = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def euler_zyx(R: np.ndarray) -> tuple[float, float, float]:
    """``(z, y, x)`` angles, radians, with ``R = Rz(z) Ry(y) Rx(x)`` for a (3, 3) rotation."""
    y = -math.asin(max(-1.0, min(1.0, float(R[2, 0]))))
    return math.atan2(R[1, 0], R[0, 0]), y, math.atan2(R[2, 1], R[2, 2])


@dataclass(frozen=True)
class BoardPose:
    """Pose of the board on the turntable: board frame -> object frame.

    ``X_object = rotation @ X_board + offset_m`` with
    ``rotation = Ry(tilt_y_rad) Rx(tilt_x_rad) STANDING`` (no yaw: see the gauge).

    Attributes
    ----------
    tilt_x_rad : float
        Lean about object X, radians (negative: the top leans away from the C-arm).
    tilt_y_rad : float
        Lean about object Y, radians.
    offset_m : (3,) tuple of float
        The board frame's origin (its top-left corner) in the object frame, metres.
    """

    tilt_x_rad: float
    tilt_y_rad: float
    offset_m: tuple

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) rotation board -> object."""
        return rotation_y(self.tilt_y_rad) @ rotation_x(self.tilt_x_rad) @ STANDING

    def to_object(self, board_points: np.ndarray) -> np.ndarray:
        """Board points (n, 3), metres -> object-frame points (n, 3), metres."""
        return board_points @ self.rotation.T + np.asarray(self.offset_m)


def canonical(rig: RigCalibration, board: BoardPose) -> tuple[RigCalibration, BoardPose]:
    """The same cameras and board with the turntable axis tilt about lab X folded
    into the carriage zero (the solver's gauge, module docstring).

    Rotating the lab frame about the C-arm axis by ``-axis_tilt_x_rad`` moves
    the axis point off the plane ``z = 0``; sliding it back along the axis moves
    the object frame's origin, hence the board's offset, along the axis.
    """
    a = rig.axis_tilt_x_rad
    pivot = np.asarray(rig.aim_point_m)
    point = rotation_x(-a) @ (np.array([*rig.axis_point_m, 0.0]) - pivot) + pivot
    direction = rotation_y(rig.axis_tilt_y_rad)[:, 2]
    slide = point[2] / direction[2]
    point = point - slide * direction
    new_rig = replace(rig, axis_tilt_x_rad=0.0, phi_zero_rad=rig.phi_zero_rad - a,
                      axis_point_m=(float(point[0]), float(point[1])))
    offset = np.asarray(board.offset_m) + np.array([0.0, 0.0, slide])
    return new_rig, replace(board, offset_m=tuple(float(v) for v in offset))
