"""A ChArUco board on the turntable, photographed through a rig that is not the one on paper.

The *true* rig (:func:`wrong_rig`) has a tilted, off-centre turntable axis,
encoder zero offsets, lens distortion and a camera turned on its carriage; the
*nominal* rig (:func:`nominal_rig`) is what a hand measurement would say. The
images are rendered through the true rig, the encoder angles are the true
angles plus the true zeros: a calibration must recover the true rig from them.
:func:`wrong_world` makes the same errors in any nominal rig: the mock
hardware's wrong world. :class:`BoardPicture` renders
the board through any camera (the mock camera's board on the plate).

Rendering: every output pixel is supersampled, each sample undistorted to a
ray (the inverse of the true lens), the ray met with the board plane, and the
board's picture sampled there (``cv2.remap``); samples missing the printed
face see a grey backdrop. Mild Gaussian noise is added.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from ..calibration.board import BoardSpec
from ..calibration.model import BoardPose
from ..geometry.camera import Camera
from ..geometry.rig import RigCalibration, rig_camera

__all__ = ["BoardPicture", "BoardScene", "board_scene", "nominal_rig", "true_board_pose",
           "wrong_rig", "wrong_world"]

DEG = math.pi / 180
_BACKDROP = 90           # grey level around the board
_MARGIN_M = 0.01         # white margin of the printed board, metres
_PIXELS_PER_M = 8000.0   # resolution of the board's picture (>= 2 x finer than the samples)
_SUPERSAMPLE = 2         # samples per pixel along each axis


def nominal_rig() -> RigCalibration:
    """The rig as measured by hand: 640 x 480, a 45 degree lens, ideal axes, 0.35 m radius."""
    return RigCalibration(width=640, height=480, projection="pinhole", fx=800.0, fy=800.0,
                          camera_distance_m=0.35, aim_point_m=(0.0, 0.0, 0.08))


def wrong_world(nominal: RigCalibration) -> RigCalibration:
    """The cell ``nominal`` (pinhole, ``physical``, an ideal lens and axes) as it really is:
    focal lengths 0.75 % and 1.125 % longer, the principal point (+5, -3.5) px off the
    image centre, a barrel lens (k1 -0.18, k2 0.08, p1 0.0012, p2 -0.0008), the C-arm
    radius 2 % shorter, the turntable axis 3.1 mm and -2.4 mm off and tilted 0.4 and -0.6
    degrees about lab X and Y, the camera turned (0.6, -0.8, 0.5) degrees on its
    carriage, and the axes' true zeros at encoder readings 1.7 and 1.2 degrees past the
    nominal ones (homing switches that are not where the drawing puts them)."""
    if nominal.projection != "pinhole" or nominal.convention != "physical" \
            or not nominal.is_ideal or any(nominal.distortion):
        raise ValueError("the wrong world is made from a pinhole, 'physical' rig with an "
                         f"ideal lens and axes, got {nominal.projection!r}, "
                         f"{nominal.convention!r}, distortion {nominal.distortion}, ideal axes "
                         f"{nominal.is_ideal}")
    K = nominal.K
    return replace(
        nominal, theta_zero_rad=nominal.theta_zero_rad + 1.7 * DEG,
        phi_zero_rad=nominal.phi_zero_rad + 1.2 * DEG,
        fx=nominal.fx * 806.0 / 800.0, fy=nominal.fy * 809.0 / 800.0,
        cx=float(K[0, 2]) + 5.0, cy=float(K[1, 2]) - 3.5,
        camera_distance_m=nominal.camera_distance_m * 0.98,
        distortion=(-0.18, 0.08, 0.0012, -0.0008, 0.0),
        axis_point_m=(0.0031, -0.0024), axis_tilt_x_rad=0.4 * DEG, axis_tilt_y_rad=-0.6 * DEG,
        mount_rotation_rad=(0.6 * DEG, -0.8 * DEG, 0.5 * DEG))


def wrong_rig() -> RigCalibration:
    """The true rig: the nominal one with every error the calibration must find."""
    return wrong_world(nominal_rig())


def true_board_pose(board: BoardSpec) -> BoardPose:
    """The board standing on the plate beside the axis, leaning back 25 degrees."""
    pose = BoardPose(tilt_x_rad=-25 * DEG, tilt_y_rad=1.5 * DEG, offset_m=(0.0, 0.0, 0.0))
    width_m, height_m = board.size_m
    # Its centre 35 mm right of and 2 mm in front of the axis (so it swings across the
    # image as the turntable turns), its lower edge 12 mm above the plate.
    centre = np.array([0.035, -0.002, 0.012 + 0.5 * height_m * math.cos(25 * DEG)])
    offset = centre - pose.rotation @ np.array([width_m / 2, height_m / 2, 0.0])
    return BoardPose(pose.tilt_x_rad, pose.tilt_y_rad, tuple(float(v) for v in offset))


def _sample_rays(camera: Camera, supersample: int) -> np.ndarray:
    """(h * s, w * s, 3) float64 rays (x, y, 1), camera frame, of the sub-pixel samples."""
    s = supersample
    u = (np.arange(camera.width * s) + 0.5) / s - 0.5
    v = (np.arange(camera.height * s) + 0.5) / s - 0.5
    uv = np.stack(np.meshgrid(u, v), axis=-1).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 1e-12)
    xy = cv2.undistortPointsIter(uv, camera.K, camera.distortion, None, None, criteria)
    xy = xy.reshape(camera.height * s, camera.width * s, 2)
    return np.concatenate([xy, np.ones(xy.shape[:2] + (1,))], axis=-1)


def _picture(board: BoardSpec) -> np.ndarray:
    return board.image(_PIXELS_PER_M, margin_px=round(_MARGIN_M * _PIXELS_PER_M))


def _render(picture: np.ndarray, rays: np.ndarray, pose: BoardPose, camera: Camera,
            noise: float, rng: np.random.Generator, backdrop: int = _BACKDROP) -> np.ndarray:
    """(H, W, 3) uint8 RGB image of the board's ``picture`` at ``pose`` seen along ``rays``
    (:func:`_sample_rays` of ``camera``), with Gaussian noise of ``noise`` grey levels, on
    a ``backdrop`` grey level."""
    to_cam = camera.R @ pose.rotation                        # board -> camera rotation
    origin = camera.R @ np.asarray(pose.offset_m) + camera.t  # board origin, camera frame
    normal = to_cam[:, 2]
    facing = rays @ normal
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = (origin @ normal) / facing
    board_xy = (rays * depth[..., None] - origin) @ to_cam[:, :2]   # on the board, metres
    pix = (board_xy + _MARGIN_M) * _PIXELS_PER_M - 0.5
    pix[~((facing > 0) & (depth > 0))] = -1e6                 # the back or behind the camera
    grey = cv2.remap(picture, pix[..., 0].astype(np.float32), pix[..., 1].astype(np.float32),
                     cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=backdrop)
    grey = cv2.resize(grey.astype(np.float32), (camera.width, camera.height),
                      interpolation=cv2.INTER_AREA)
    grey = grey + rng.normal(0.0, noise, grey.shape)
    grey = np.clip(np.rint(grey), 0, 255).astype(np.uint8)
    return np.repeat(grey[..., None], 3, axis=2)


class BoardPicture:
    """The board standing on the turntable, as any camera sees it.

    board : BoardSpec
    pose : BoardPose
        Its pose on the turntable (default :func:`true_board_pose`).
    backdrop : int, keyword-only
        Grey level around the board, 0..255.

    :meth:`render` draws it through a camera's lens (the rays of the lens are
    computed once per lens: ``K``, distortion and image size).
    """

    def __init__(self, board: BoardSpec | None = None, pose: BoardPose | None = None, *,
                 backdrop: int = _BACKDROP):
        self.board = BoardSpec() if board is None else board
        self.pose = true_board_pose(self.board) if pose is None else pose
        if not 0 <= int(backdrop) <= 255:
            raise ValueError(f"backdrop must be a grey level in 0..255, got {backdrop}")
        self.backdrop = int(backdrop)
        self.name = (f"ChArUco board {self.board.squares_x}x{self.board.squares_y} "
                     f"({self.board.dictionary})")
        self._picture = _picture(self.board)
        self._rays: tuple = (None, None)

    def render(self, camera: Camera, *, noise: float = 2.0, seed=None) -> np.ndarray:
        """(camera.height, camera.width, 3) uint8 RGB: the board through ``camera`` (pinhole,
        its lens included), with Gaussian noise of ``noise`` grey levels (``seed``)."""
        if camera.orthographic:
            raise ValueError("the board is rendered through a pinhole camera, got an "
                             "orthographic one")
        lens = (camera.K.tobytes(), camera.distortion.tobytes(), camera.width, camera.height)
        if self._rays[0] != lens:
            self._rays = (lens, _sample_rays(camera, _SUPERSAMPLE))
        return _render(self._picture, self._rays[1], self.pose, camera, float(noise),
                       np.random.default_rng(seed), self.backdrop)


@dataclass(frozen=True)
class BoardScene:
    """Board photographs with their encoder readings, and the truth they were made with.

    Attributes
    ----------
    images : list of (H, W, 3) uint8
    angles : list of (float, float)
        Encoder readings ``(theta_rad, phi_rad)`` per image (true angles plus the true zeros).
    rig : RigCalibration
        The true rig.
    board : BoardSpec
    pose : BoardPose
        The true pose of the board on the turntable.
    """

    images: list
    angles: list
    rig: RigCalibration
    board: BoardSpec
    pose: BoardPose


def board_scene(*, thetas_deg=(-60, -40, -20, 0, 20, 40, 60), phis_deg=(0, 20, 40, 60),
                board: BoardSpec | None = None, noise: float = 2.0,
                seed: int = 0) -> BoardScene:
    """Photographs of the board through :func:`wrong_rig` at every (theta, phi) pair, degrees
    (true axis angles), with Gaussian noise of ``noise`` grey levels (generator ``seed``)."""
    board = BoardSpec() if board is None else board
    rig, pose = wrong_rig(), true_board_pose(board)
    rng = np.random.default_rng(seed)
    picture = _picture(board)
    rays = _sample_rays(rig_camera(0.0, 0.0, rig), _SUPERSAMPLE)   # one lens for every view
    images, angles = [], []
    for phi in phis_deg:
        for theta in thetas_deg:
            reading = (theta * DEG + rig.theta_zero_rad, phi * DEG + rig.phi_zero_rad)
            camera = rig_camera(*reading, rig)
            images.append(_render(picture, rays, pose, camera, noise, rng))
            angles.append(reading)
    return BoardScene(images=images, angles=angles, rig=rig, board=board, pose=pose)
