"""Calibrate the rig from board photographs tagged with encoder angles.

One least-squares problem (``scipy.optimize.least_squares``) over the
reprojection error of every detected board corner in every view, through the
rig's own kinematic chain (:func:`sfs_ros.core.geometry.rig.rig_camera`). The
unknowns (:data:`PARAMETERS`): intrinsics ``fx, fy, cx, cy``; distortion
``k1, k2, p1, p2`` (and ``k3`` with ``radial_terms=3``); the turntable axis
point ``(x, y)`` and its tilt about lab Y; the C-arm radius; the camera's
mounting rotation; both encoder zeros; the board's pose on the turntable (two
leans and an offset). What the images cannot determine is held fixed, as
:mod:`.model` explains, and listed in :attr:`RigFit.fixed`.

Start, robust to views tagged with wrong angles (a garbled or shifted encoder
reading): a view whose angles give no camera (not finite, the carriage beyond
the C-arm) is rejected by name. ``cv2.calibrateCamera`` over the views (every
view with a free board pose: no angle is used) gives the intrinsics,
distortion and each view's board pose in the camera. The rig's turntable axis,
radius, camera mounting, encoder zeros and the board's pose on the turntable
are then fitted to those board poses alone (six numbers a view, a Cauchy loss,
from the component-wise median of the board's pose in the object frame over
the views, so neither the start nor the fit follows a minority). A view whose
board pose its tagged angles then miss by more than
:data:`MAX_POSE_DISAGREEMENT_DEG` is rejected by name, with the disagreement,
and the poses fitted again without it. A first robust pass over every corner
(soft-L1 loss) is followed by plain least squares; a view whose corners then
miss by more than ``max_view_rms_px`` (RMS) is rejected, worst first, and the
fit repeated.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

import cv2
import numpy as np
from scipy.optimize import least_squares

from ..geometry.rig import RigCalibration, rig_camera, rotation_from_vector
from .board import BoardSpec, Detection
from .model import STANDING, BoardPose, euler_zyx

__all__ = ["PARAMETERS", "FIXED", "MAX_POSE_DISAGREEMENT_DEG", "RADIUS_WARNING_FACTOR",
           "RADIUS_ERROR_FACTOR", "RigFit", "calibrate_rig"]

_log = logging.getLogger(__name__)

#: The fitted C-arm radius may differ from the hand-measured one by this factor (either
#: way) without a warning, and by :data:`RADIUS_ERROR_FACTOR` at most: the board's size
#: sets the scale of every length the fit finds, so a wrong ``square_m`` scales the radius.
RADIUS_WARNING_FACTOR, RADIUS_ERROR_FACTOR = 1.1, 1.5

#: A view whose tagged angles miss the board pose seen in its image by more than this,
#: degrees, once the rig is fitted to the other views' board poses, is rejected before the
#: fit of the corners (consistent views miss by a few tenths of a degree; a smaller
#: error of the angles is left to the reprojection check after that fit).
MAX_POSE_DISAGREEMENT_DEG = 5.0

#: Every parameter the solver can estimate, in the order of its vector.
PARAMETERS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3",
              "axis_x_m", "axis_y_m", "axis_tilt_y_rad", "camera_distance_m",
              "mount_x_rad", "mount_y_rad", "mount_z_rad", "theta_zero_rad", "phi_zero_rad",
              "board_tilt_x_rad", "board_tilt_y_rad", "board_x_m", "board_y_m", "board_z_m")

#: The lens: what the fit to the views' board poses takes as ``cv2.calibrateCamera`` found it.
_LENS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")

#: What is always held fixed, and why.
FIXED = {
    "aim_point_m": "the lab frame's origin: held at the input rig's C-arm centre",
    "axis_tilt_x_rad": "the same as the carriage encoder zero; held at 0 (phi_zero_rad is "
                       "the reading at which the camera looks square to the turntable axis)",
    "board yaw": "the same as the turntable encoder zero; held at 0 (theta_zero_rad is the "
                 "reading at which the board's x edge runs along the C-arm axis)",
    "axis point z": "the object frame's origin along the turntable axis: where the axis "
                    "crosses the lab plane z = 0",
    "camera offset on the carriage": "the same as the C-arm centre, carriage zero and radius; "
                                     "the rig has no field for it",
}


@dataclass(frozen=True)
class RigFit:
    """A calibration's result.

    Attributes
    ----------
    rig : RigCalibration
        The calibrated rig (pinhole, ``physical``, ``axis_tilt_x_rad = 0``).
    board : BoardPose
        The board's pose on the turntable.
    rms_px : float
        RMS reprojection error over all corners of the used views, pixels.
    view_rms_px : dict of str -> float
        RMS reprojection error per used view, pixels.
    rejected : list of (str, str)
        ``(view name, reason)`` of every view not used.
    uncertainty : dict of str -> float
        Standard uncertainty of each estimated parameter (:data:`PARAMETERS`, in
        the parameter's unit), from the Jacobian at the solution scaled by the
        residual variance.
    fixed : dict of str -> str
        Parameters held fixed and why.
    corners : int
        Number of corners used.
    warnings : tuple of str
        What the fit found doubtful (a radius far from the hand-measured one).
    """

    rig: RigCalibration
    board: BoardPose
    rms_px: float
    view_rms_px: dict
    rejected: list
    uncertainty: dict
    fixed: dict
    corners: int
    warnings: tuple = ()


@dataclass(frozen=True)
class _View:
    name: str
    theta_rad: float
    phi_rad: float
    detection: Detection


def _unpack(x: np.ndarray, free: np.ndarray, template: np.ndarray, start: RigCalibration):
    values = template.copy()
    values[free] = x
    v = dict(zip(PARAMETERS, values))
    rig = replace(start, fx=v["fx"], fy=v["fy"], cx=v["cx"], cy=v["cy"],
                  distortion=(v["k1"], v["k2"], v["p1"], v["p2"], v["k3"]),
                  axis_point_m=(v["axis_x_m"], v["axis_y_m"]),
                  axis_tilt_y_rad=v["axis_tilt_y_rad"], camera_distance_m=v["camera_distance_m"],
                  mount_rotation_rad=(v["mount_x_rad"], v["mount_y_rad"], v["mount_z_rad"]),
                  theta_zero_rad=v["theta_zero_rad"], phi_zero_rad=v["phi_zero_rad"])
    board = BoardPose(v["board_tilt_x_rad"], v["board_tilt_y_rad"],
                      (v["board_x_m"], v["board_y_m"], v["board_z_m"]))
    return rig, board


def _residuals(rig: RigCalibration, board: BoardPose, views: list[_View],
               points: np.ndarray) -> np.ndarray:
    """(sum of 2 n_i,) pixel errors of every corner of every view, pixels."""
    out = []
    for view in views:
        camera = rig_camera(view.theta_rad, view.phi_rad, rig)
        uv = camera.project_distorted(board.to_object(points[view.detection.ids]))
        out.append((uv - view.detection.pixels).ravel())
    return np.concatenate(out)


def _view_rms(residuals: np.ndarray, views: list[_View]) -> np.ndarray:
    sizes = [2 * len(v.detection.ids) for v in views]
    parts = np.split(residuals, np.cumsum(sizes)[:-1])
    return np.array([math.sqrt(np.mean(p ** 2)) for p in parts])


def _usable(views: list[_View], rig: RigCalibration, rejected: list) -> list[_View]:
    """The views whose tagged angles give a camera of ``rig``; the others go to ``rejected``
    (``(name, reason)``)."""
    kept = []
    for view in views:
        try:
            rig_camera(view.theta_rad, view.phi_rad, rig)
        except ValueError as exc:
            rejected.append((view.name, f"its tagged angles cannot be used: {exc}"))
        else:
            kept.append(view)
    return kept


def _board_poses(views: list[_View], points: np.ndarray, nominal: RigCalibration,
                 radial_terms: int) -> tuple[np.ndarray, np.ndarray, list]:
    """``cv2.calibrateCamera`` over the views (angles unused): K (3, 3), distortion (5,) and
    each view's board pose in the camera, ``(R (3, 3), t (3,) metres)`` board -> camera."""
    flags = cv2.CALIB_FIX_K3 if radial_terms == 2 else 0
    obj = [points[v.detection.ids].astype(np.float32) for v in views]
    img = [v.detection.pixels.astype(np.float32) for v in views]
    _, K, D, rvecs, tvecs = cv2.calibrateCamera(obj, img, (nominal.width, nominal.height),
                                                nominal.K.copy(), None,
                                                flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS)
    poses = [(cv2.Rodrigues(r)[0], t.ravel()) for r, t in zip(rvecs, tvecs)]
    return K, D.ravel(), poses


def _start(views: list[_View], poses: list, K: np.ndarray, D: np.ndarray,
           nominal: RigCalibration, radial_terms: int) -> np.ndarray:
    """Initial parameter vector (:data:`PARAMETERS` order): the lens ``K``, ``D``, the
    nominal rig, and the board's pose carried into the object frame through it
    (component-wise median over the views' ``poses``)."""
    rig = replace(nominal, fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2])
    rotations, offsets = [], []
    for view, (board_to_cam, t) in zip(views, poses):
        cam = rig_camera(view.theta_rad, view.phi_rad, rig)
        rotations.append(cam.R.T @ board_to_cam)
        offsets.append(cam.R.T @ (t - cam.t))
    u, _, vt = np.linalg.svd(np.median(rotations, axis=0))
    rotation = u @ vt
    yaw, tilt_y, tilt_x = euler_zyx(rotation @ STANDING.T)
    # A board yaw is a turntable zero: move it there (module docstring of .model).
    offset = rotation_from_vector([0.0, 0.0, -yaw]) @ np.median(offsets, axis=0)
    return np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], D[0], D[1], D[2], D[3],
                     D[4] if radial_terms == 3 else 0.0,
                     *nominal.axis_point_m, 0.0, nominal.camera_distance_m,
                     *nominal.mount_rotation_rad, nominal.theta_zero_rad - yaw,
                     nominal.phi_zero_rad, tilt_x, tilt_y, *offset])


def _pose_misses(rig: RigCalibration, board: BoardPose, views: list[_View],
                 poses: list) -> np.ndarray:
    """(n, 2, 3) how the board pose seen in each view misses the one its angles give:
    the rotation vector from the predicted to the seen rotation, radians, and the seen
    minus the predicted position over the C-arm radius (metres / metres)."""
    out = np.empty((len(views), 2, 3))
    for i, (view, (R, t)) in enumerate(zip(views, poses)):
        cam = rig_camera(view.theta_rad, view.phi_rad, rig)
        out[i, 0] = cv2.Rodrigues((cam.R @ board.rotation).T @ R)[0].ravel()
        out[i, 1] = (t - cam.R @ np.asarray(board.offset_m) - cam.t) / rig.camera_distance_m
    return out


def _fit_poses(template: np.ndarray, views: list[_View], poses: list,
               nominal: RigCalibration) -> tuple[np.ndarray, np.ndarray]:
    """The rig and board parameters fitted to the views' board ``poses`` (the lens held as
    in ``template``; a Cauchy loss of scale 1 degree): the new template, and each view's
    disagreement, degrees (the angle between its seen and predicted board rotation)."""
    free = np.array([p not in _LENS for p in PARAMETERS])

    def fun(x):
        return _pose_misses(*_unpack(x, free, template, nominal), views, poses).ravel()

    low, high = _bounds(template, nominal)
    result = least_squares(fun, template[free], bounds=(low[free], high[free]), loss="cauchy",
                           f_scale=math.radians(1.0), x_scale="jac", method="trf")
    fitted = template.copy()
    fitted[free] = result.x
    misses = result.fun.reshape(-1, 2, 3)
    return fitted, np.degrees(np.linalg.norm(misses[:, 0], axis=1))


def _drop_mistagged(views: list[_View], poses: list, template: np.ndarray,
                    nominal: RigCalibration, rejected: list,
                    min_views: int) -> tuple[list, np.ndarray]:
    """Fit the rig to the board poses (:func:`_fit_poses`) and reject, into ``rejected``,
    the views that miss by more than :data:`MAX_POSE_DISAGREEMENT_DEG`, fitting again
    until none does or fewer than ``min_views`` are left: the views kept and the
    template fitted to them."""
    while len(views) >= min_views:
        template, disagreement = _fit_poses(template, views, poses, nominal)
        bad = disagreement > MAX_POSE_DISAGREEMENT_DEG
        if not bad.any():
            break
        for view, degrees in zip(views, disagreement):
            if degrees > MAX_POSE_DISAGREEMENT_DEG:
                rejected.append((view.name, (
                    f"its tagged angles (theta_rad {view.theta_rad:.6g}, phi_rad "
                    f"{view.phi_rad:.6g}) disagree with its board pose by {degrees:.1f} degrees "
                    f"(more than {MAX_POSE_DISAGREEMENT_DEG:g} from the rig fitted to the "
                    "other views: a wrong encoder reading?)")))
        views = [v for v, b in zip(views, bad) if not b]
        poses = [p for p, b in zip(poses, bad) if not b]
    return views, template


#: How far (+-) the solver may move each parameter from its start: focal lengths and
#: radius by a factor of two, the principal point within the image, angles by 0.2 rad
#: (11 degrees), the axis point by 50 mm; distortion and the board's pose are free.
_REACH = {"axis_x_m": 0.05, "axis_y_m": 0.05, "axis_tilt_y_rad": 0.2, "mount_x_rad": 0.2,
          "mount_y_rad": 0.2, "mount_z_rad": 0.2, "theta_zero_rad": 0.2, "phi_zero_rad": 0.2}


def _bounds(start: np.ndarray, rig: RigCalibration) -> tuple[np.ndarray, np.ndarray]:
    low, high = np.full(len(PARAMETERS), -np.inf), np.full(len(PARAMETERS), np.inf)
    for i, name in enumerate(PARAMETERS):
        if name in _REACH:
            low[i], high[i] = start[i] - _REACH[name], start[i] + _REACH[name]
        elif name in ("fx", "fy", "camera_distance_m"):
            low[i], high[i] = start[i] / 2, start[i] * 2
    low[2:4], high[2:4] = 0.0, (rig.width - 1, rig.height - 1)
    return low, high


def _solve(x0, free, template, start, views, points, loss):
    def fun(x):
        return _residuals(*_unpack(x, free, template, start), views, points)
    low, high = _bounds(template, start)
    result = least_squares(fun, x0, bounds=(low[free], high[free]), loss=loss, f_scale=1.0,
                           x_scale="jac", method="trf")
    at_limit = [p for p, a in zip(np.array(PARAMETERS)[free], result.active_mask) if a]
    if at_limit and loss == "linear":
        raise ValueError(f"the fit ran into the limit of {', '.join(at_limit)}: the input rig "
                         "is too far from the real one (see the solver's reach)")
    return result


def _uncertainty(result, free: np.ndarray) -> dict:
    """Standard uncertainties from the Jacobian; ValueError when it is rank deficient."""
    J = result.jac
    m, n = J.shape
    scale = np.linalg.norm(J, axis=0)
    names = [p for p, f in zip(PARAMETERS, free) if f]
    if np.any(scale == 0):
        raise ValueError(f"the views do not constrain {names[int(np.argmin(scale))]}")
    _, s, vt = np.linalg.svd(J / scale, full_matrices=False)
    if s[-1] < 1e-7 * s[0]:   # a well-posed fit: ~1e-3; one turntable angle: ~1e-10
        worst = [names[i] for i in np.argsort(-np.abs(vt[-1]))[:2]]
        raise ValueError(f"the views cannot tell {worst[0]} from {worst[1]}: spread the "
                         "turntable and carriage angles more")
    variance = 2.0 * result.cost / max(m - n, 1)
    cov = (vt.T / s ** 2) @ vt / np.outer(scale, scale) * variance
    return dict(zip(names, np.sqrt(np.diag(cov)).tolist()))


def _check_options(nominal: RigCalibration, radial_terms: int, max_view_rms_px: float) -> None:
    """ValueError naming the first of :func:`calibrate_rig`'s options it cannot take."""
    if nominal.projection != "pinhole" or nominal.convention != "physical":
        raise ValueError("calibration needs a pinhole rig with the 'physical' convention, got "
                         f"{nominal.projection!r}, {nominal.convention!r}")
    if radial_terms not in (2, 3):
        raise ValueError(f"radial_terms must be 2 or 3, got {radial_terms}")
    if not (math.isfinite(max_view_rms_px) and max_view_rms_px > 0):
        raise ValueError(f"max_view_rms_px must be a number of pixels > 0, got "
                         f"{max_view_rms_px}")


def calibrate_rig(detections: list[tuple[str, float, float, Detection]], board: BoardSpec,
                  nominal: RigCalibration, *, rejected: list | None = None,
                  radial_terms: int = 2, max_view_rms_px: float = 1.0,
                  min_views: int = 6) -> RigFit:
    """Calibrate the rig from board detections.

    Parameters
    ----------
    detections : list of (str, float, float, Detection)
        ``(view name, theta_rad, phi_rad, corners)``: encoder readings, radians.
    board : BoardSpec
    nominal : RigCalibration
        The hand-measured rig: image size, a start for every parameter, and the
        C-arm centre that anchors the lab frame (pinhole, ``physical``).
    rejected : list of (str, str), keyword-only
        Views already rejected (e.g. board not found); carried into the result.
    radial_terms : int, keyword-only
        2 (``k3`` held at 0, as most calibrations of mild lenses do) or 3.
    max_view_rms_px : float, keyword-only
        A view whose RMS reprojection error after the fit exceeds this, pixels,
        is rejected (worst first, refitting after each); finite, > 0.
    min_views : int, keyword-only
        Fewer usable views than this is an error.

    Raises
    ------
    ValueError
        Too few usable views, a rig that is not pinhole / ``physical``, views
        that cannot determine a parameter, or a fitted C-arm radius more than
        :data:`RADIUS_ERROR_FACTOR` times from the hand-measured one (beyond
        :data:`RADIUS_WARNING_FACTOR`: a warning, logged and in the result).
    """
    _check_options(nominal, radial_terms, max_view_rms_px)
    rejected = list(rejected or [])
    views = [_View(name, float(theta), float(phi), det) for name, theta, phi, det in detections]
    fixed = dict(FIXED)
    if radial_terms == 2:
        fixed["k3"] = "held at 0 (radial_terms=2): a mild lens does not determine it"

    def check_count():
        if len(views) < min_views:
            raise ValueError(f"{len(views)} usable board views, need at least {min_views}"
                             + (f" ({len(rejected)} rejected, first: {rejected[0][0]}: "
                                f"{rejected[0][1]})" if rejected else ""))

    points = board.object_points
    # The start in the solver's gauge (a tilt about lab X is a carriage zero, see .model).
    nominal = replace(nominal, axis_tilt_x_rad=0.0,
                      phi_zero_rad=nominal.phi_zero_rad - nominal.axis_tilt_x_rad)
    views = _usable(views, nominal, rejected)
    check_count()
    K, D, poses = _board_poses(views, points, nominal, radial_terms)
    start = _start(views, poses, K, D, nominal, radial_terms)
    views, template = _drop_mistagged(views, poses, start, nominal, rejected, min_views)
    check_count()
    free = np.array([p != "k3" or radial_terms == 3 for p in PARAMETERS])
    x = _solve(template[free], free, template, nominal, views, points, "soft_l1").x
    while True:
        result = _solve(x, free, template, nominal, views, points, "linear")
        rms = _view_rms(result.fun, views)
        worst = int(np.argmax(rms))
        if rms[worst] <= max_view_rms_px:
            break
        reason = (f"reprojection error {rms[worst]:.2f} px RMS after the fit exceeds "
                  f"{max_view_rms_px} px (wrong angles or a moved board?)")
        rejected.append((views[worst].name, reason))
        del views[worst]
        check_count()
        x = result.x
    rig, pose = _unpack(result.x, free, template, nominal)
    warnings = _radius_warnings(rig.camera_distance_m, nominal.camera_distance_m, board)
    return RigFit(rig=rig, board=pose, rms_px=float(np.sqrt(np.mean(result.fun ** 2))),
                  view_rms_px={v.name: float(r) for v, r in zip(views, rms)},
                  rejected=rejected, uncertainty=_uncertainty(result, free), fixed=fixed,
                  corners=sum(len(v.detection.ids) for v in views), warnings=warnings)


def _radius_warnings(fitted_m: float, measured_m: float, board: BoardSpec) -> tuple:
    """The warning when the fitted C-arm radius is more than :data:`RADIUS_WARNING_FACTOR`
    from the hand-measured one (logged too); ValueError beyond :data:`RADIUS_ERROR_FACTOR`."""
    factor = fitted_m / measured_m
    if max(factor, 1 / factor) <= RADIUS_WARNING_FACTOR:
        return ()
    text = (f"the fitted C-arm radius camera_distance_m {fitted_m:.4f} m is {factor:.3g} times "
            f"the hand-measured {measured_m:.4f} m: check the board's size (square_m "
            f"{board.square_m} m, marker_m {board.marker_m} m; a board {factor:.3g} times "
            "that size would agree) and the measured radius")
    if max(factor, 1 / factor) > RADIUS_ERROR_FACTOR:
        raise ValueError(f"{text}; more than {RADIUS_ERROR_FACTOR} times apart, the fit is "
                         "not used")
    _log.warning(text)
    return (text,)
