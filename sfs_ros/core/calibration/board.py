"""ChArUco calibration board: its definition, its picture and finding it in images.

Board frame (OpenCV's): origin at the board's top-left outer corner, x along
the ``squares_x`` columns, y along the ``squares_y`` rows (down in the
board's picture), z into the board, metres. Chessboard corner ``i`` (the id
the detector reports) sits at ``object_points[i]``.

Finding the corners: OpenCV's ChArUco detector reads the markers and places
the chessboard corners (``cv2.cornerSubPix``, which leaves an error of a few
hundredths of a pixel that depends on where the corner falls on the pixel
grid, the same in every image of the same view); each corner is then refined
to the saddle point of the smoothed image (:func:`refine_saddle_points`). The
principal point is where this matters: a camera turned on its carriage looks
almost like a shifted principal point, so the calibration magnifies the corners'
error many times there (doc/calibration.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["BoardSpec", "Detection", "detect_board", "refine_saddle_points", "MIN_SQUARE_M",
           "MAX_SQUARE_M", "MAX_SQUARES"]

#: Range of a chessboard square's side, metres: a printed board on a turntable.
MIN_SQUARE_M, MAX_SQUARE_M = 1e-4, 1.0
#: Most squares along a side of the board.
MAX_SQUARES = 100

#: The saddle-point refinement: the image is smoothed by a Gaussian of this standard
#: deviation, pixels, and a quadratic fitted to the (2 h + 1)^2 samples about the corner,
#: h = ``_SADDLE_HALF_PX``; it stops when a step is shorter than ``_SADDLE_STEP_PX``.
_SADDLE_SIGMA_PX = 1.5
_SADDLE_HALF_PX = 3
_SADDLE_STEP_PX = 1e-3
_SADDLE_ITERATIONS = 20
#: A refined corner further than this from the detector's, pixels, is not trusted (the
#: detector's is kept).
_SADDLE_REACH_PX = 1.0


@dataclass(frozen=True)
class BoardSpec:
    """A ChArUco board.

    Attributes
    ----------
    squares_x, squares_y : int
        Chessboard squares along x and y (3 to :data:`MAX_SQUARES` each).
    square_m : float
        Side of a chessboard square, metres (:data:`MIN_SQUARE_M` to :data:`MAX_SQUARE_M`).
    marker_m : float
        Side of an ArUco marker, metres (smaller than ``square_m``).
    dictionary : str
        OpenCV predefined dictionary name, e.g. ``"DICT_5X5_100"``.
    """

    squares_x: int = 7
    squares_y: int = 5
    square_m: float = 0.03
    marker_m: float = 0.022
    dictionary: str = "DICT_5X5_100"

    def __post_init__(self) -> None:
        if not hasattr(getattr(cv2, "aruco", None), "CharucoDetector"):
            raise ValueError(f"ChArUco calibration needs OpenCV 4.7 or later (its ChArUco "
                             f"detector); this is OpenCV {cv2.__version__}")
        if int(self.squares_x) < 3 or int(self.squares_y) < 3:
            raise ValueError(f"board needs at least 3x3 squares, got "
                             f"{self.squares_x}x{self.squares_y}")
        if not MIN_SQUARE_M <= self.square_m <= MAX_SQUARE_M:
            raise ValueError(f"board square_m must be {MIN_SQUARE_M}..{MAX_SQUARE_M} metres, got "
                             f"{self.square_m}")
        if int(self.squares_x) > MAX_SQUARES or int(self.squares_y) > MAX_SQUARES:
            raise ValueError(f"board needs at most {MAX_SQUARES} squares a side, got "
                             f"{self.squares_x}x{self.squares_y}")
        if not (0 < self.marker_m < self.square_m):
            raise ValueError(f"board needs 0 < marker_m < square_m, got marker_m={self.marker_m}, "
                             f"square_m={self.square_m} (metres)")
        if not self.dictionary.startswith("DICT_") or not hasattr(cv2.aruco, self.dictionary):
            raise ValueError(f"unknown ArUco dictionary {self.dictionary!r}; expected an OpenCV "
                             "name such as 'DICT_5X5_100'")
        markers = (int(self.squares_x) * int(self.squares_y)) // 2
        size = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary)) \
            .bytesList.shape[0]
        if markers > size:
            raise ValueError(f"a {self.squares_x}x{self.squares_y} board needs {markers} markers, "
                             f"dictionary {self.dictionary} holds {size}")

    @property
    def cv_board(self) -> cv2.aruco.CharucoBoard:
        """The OpenCV board object."""
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((int(self.squares_x), int(self.squares_y)),
                                      float(self.square_m), float(self.marker_m), dictionary)

    @property
    def object_points(self) -> np.ndarray:
        """(n, 3) float64 chessboard corners in the board frame, metres, indexed by id."""
        return np.asarray(self.cv_board.getChessboardCorners(), dtype=np.float64).reshape(-1, 3)

    @property
    def size_m(self) -> tuple[float, float]:
        """Board width and height (the squares, without a margin), metres."""
        return self.squares_x * self.square_m, self.squares_y * self.square_m

    def image(self, pixels_per_m: float, *, margin_px: int = 0) -> np.ndarray:
        """(H, W) uint8 picture of the board at ``pixels_per_m``, with a white margin.

        The board point ``(x, y)`` (metres) is at pixel ``(margin_px + x * pixels_per_m - 0.5,
        margin_px + y * pixels_per_m - 0.5)`` (integer values at pixel centres).
        """
        width_m, height_m = self.size_m
        size = (round(width_m * pixels_per_m) + 2 * margin_px,
                round(height_m * pixels_per_m) + 2 * margin_px)
        return self.cv_board.generateImage(size, marginSize=margin_px, borderBits=1)


@dataclass(frozen=True)
class Detection:
    """The board corners found in one image.

    Attributes
    ----------
    ids : (n,) int64
        Chessboard corner ids (rows of :attr:`BoardSpec.object_points`).
    pixels : (n, 2) float64
        Their sub-pixel positions ``(u, v)``, pixels (integer values at pixel centres).
    """

    ids: np.ndarray
    pixels: np.ndarray


def detect_board(image: np.ndarray, board: BoardSpec, *,
                 min_corners: int = 8) -> tuple[Detection | None, str]:
    """Find the ChArUco corners of ``board`` in ``image``.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) uint8
        Grey or RGB image.
    board : BoardSpec
    min_corners : int, keyword-only
        Fewer corners than this make the view unusable.

    Returns
    -------
    (Detection, "") or (None, reason)
        The reason says why the view cannot be used (no marker, too few corners).
    """
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim not in (2, 3):
        raise ValueError(f"board image must be (H, W) or (H, W, 3) uint8, got {image.shape} "
                         f"{image.dtype}")
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    corners, ids, markers, _ = cv2.aruco.CharucoDetector(board.cv_board).detectBoard(grey)
    if markers is None or len(markers) == 0:
        return None, f"no marker of the {board.dictionary} board found"
    found = 0 if ids is None else len(ids)
    if found < min_corners:
        return None, (f"only {found} board corners found from {len(markers)} markers "
                      f"(need {min_corners})")
    pixels = refine_saddle_points(grey, corners.reshape(-1, 2).astype(np.float64))
    return Detection(ids=ids.reshape(-1).astype(np.int64), pixels=pixels), ""


def _saddle_fit() -> np.ndarray:
    """(6, (2 h + 1)^2) least-squares solution of the quadratic
    ``a x^2 + b x y + c y^2 + d x + e y + f`` over the samples at integer offsets
    ``-h..h`` (rows of the patch: y; columns: x), h = ``_SADDLE_HALF_PX``."""
    r = np.arange(-_SADDLE_HALF_PX, _SADDLE_HALF_PX + 1, dtype=np.float64)
    x, y = np.meshgrid(r, r)
    design = np.stack([x * x, x * y, y * y, x, y, np.ones_like(x)], axis=-1).reshape(-1, 6)
    return np.linalg.pinv(design)


def _saddle_point(smooth: np.ndarray, start: np.ndarray, fit: np.ndarray) -> np.ndarray | None:
    """(2,) the saddle point of ``smooth`` (float32 image) near ``start`` (u, v), pixels,
    or None when the image there is not a saddle or the search does not settle within
    ``_SADDLE_REACH_PX`` of ``start``."""
    side = 2 * _SADDLE_HALF_PX + 1
    point = start.copy()
    for _ in range(_SADDLE_ITERATIONS):
        patch = cv2.getRectSubPix(smooth, (side, side), (float(point[0]), float(point[1])))
        a, b, c, d, e, _ = fit @ patch.astype(np.float64).ravel()
        hessian = np.array([[2.0 * a, b], [b, 2.0 * c]])
        if np.linalg.det(hessian) >= 0.0:             # a blob or an edge, not a corner
            return None
        step = np.linalg.solve(hessian, [-d, -e])
        point = point + step
        if np.hypot(*(point - start)) > _SADDLE_REACH_PX:
            return None
        if np.hypot(*step) < _SADDLE_STEP_PX:
            return point
    return None


def refine_saddle_points(grey: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Chessboard corners moved to the saddle point of the smoothed image.

    A chessboard corner (two dark and two light sectors meeting, under any perspective)
    is a saddle of the image's brightness, point-symmetric about the corner; smoothed
    and fitted with a quadratic over a window centred on it, the quadratic's saddle is
    the corner, wherever the corner falls on the pixel grid. The fit is repeated at the
    new point (sampled between pixels) until it stays put.

    Parameters
    ----------
    grey : (H, W) uint8
    corners : (n, 2) float64
        The corners' ``(u, v)`` as the detector placed them, pixels (integer values at
        pixel centres).

    Returns
    -------
    (n, 2) float64
        The refined corners; a corner too near the image border for the window, or where
        the fit finds no saddle within ``_SADDLE_REACH_PX``, keeps the detector's position.
    """
    smooth = cv2.GaussianBlur(grey.astype(np.float32), (0, 0), _SADDLE_SIGMA_PX)
    fit = _saddle_fit()
    border = _SADDLE_HALF_PX + 3 * _SADDLE_SIGMA_PX + 1
    height, width = grey.shape
    refined = corners.copy()
    for i, corner in enumerate(corners):
        if not (border <= corner[0] <= width - 1 - border
                and border <= corner[1] <= height - 1 - border):
            continue
        point = _saddle_point(smooth, corner, fit)
        if point is not None:
            refined[i] = point
    return refined
