"""Views: images with the cameras that took them, and reading the images.

A :class:`ViewSet` is what every input format (scan session, Middlebury,
NeRF transforms) loads into and what the reconstruction consumes. Images are
not decoded while loading; :func:`read_image` reads one when it is needed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..geometry.camera import Camera
from ..geometry.rig import RigCalibration
from .errors import ViewError
from .limits import brief, image_header

__all__ = ["IMAGE_SUFFIXES", "ViewError", "View", "ViewSet", "read_image", "image_size",
           "as_bounds", "BOX_SIDE_RANGE", "MAX_BOX_COORDINATE", "nearest_rotation"]

#: File name endings (lower case) treated as images when a folder is searched.
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp", ".ppm", ".pgm")



@dataclass(frozen=True)
class View:
    """One image and its camera.

    Attributes
    ----------
    name : str
        Identifier, unique within a :class:`ViewSet` (usually the image file name).
    image_path : Path
        The image file.
    camera : Camera
        Object frame -> pixels of this image.
    theta_rad, phi_rad : float or None
        Encoder readings (turntable, carriage) at the shutter, radians, before
        removing the calibration's zero offsets; None when the input has none.
    """

    name: str
    image_path: Path
    camera: Camera
    theta_rad: float | None = None
    phi_rad: float | None = None


@dataclass
class ViewSet:
    """The views of one input.

    Attributes
    ----------
    views : list of View
        The usable views, in input order.
    source : str
        The name of the input's format (:data:`sfs_ros.core.exchange.inputs.INPUT_FORMATS`).
    bounds_m : (2, 3) float64 or None
        Bounding box ``[min, max]`` of the object stored by the input, metres.
    segmentation : dict or None
        Segmentation parameters stored by the input (for ``SegmentationParams.from_dict``).
    rejected : list of (str, str)
        ``(name, reason)`` of views dropped while loading (e.g. NaN angles).
    calibration : RigCalibration or None
        The rig calibration, when the input is a scan session.
    """

    views: list[View]
    source: str
    bounds_m: np.ndarray | None = None
    segmentation: dict | None = None
    rejected: list[tuple[str, str]] = field(default_factory=list)
    calibration: RigCalibration | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.source, str) or not self.source:
            raise ValueError(f"view set source must name the input's format, got "
                             f"{self.source!r}")
        if self.bounds_m is not None:
            self.bounds_m = as_bounds(self.bounds_m, what="bounding box")

    @property
    def recorded_settings(self) -> dict:
        """``{setting name: value}`` the input recorded for its reconstruction
        (:mod:`sfs_ros.core.settings`; options override them): none here."""
        return {}


def _decode(path: Path, flags: int, expected_size: tuple[int, int] | None = None) -> np.ndarray:
    """Decode an image file with cv2 (works for any path encoding); ViewError if impossible.

    The header is checked first (file size, pixel count, ``expected_size``
    (width, height) when given), so a file that declares a huge or wrong size
    is refused before anything is decoded.
    """
    path = Path(path)
    width, height = image_header(path)
    if expected_size is not None and (width, height) != tuple(int(v) for v in expected_size):
        raise ViewError(f"image {path} is {width}x{height} pixels, expected "
                        f"{int(expected_size[0])}x{int(expected_size[1])} (the camera's size)")
    import cv2  # here, not at the top: reading the formats' names costs no OpenCV

    data = np.fromfile(path, dtype=np.uint8)
    image = cv2.imdecode(data, flags) if data.size else None
    if image is None or image.shape[:2] != (height, width):
        raise ViewError(f"image {path} is not a readable image (empty, corrupt or an "
                        f"unsupported format; expected e.g. {', '.join(IMAGE_SUFFIXES[:4])})")
    return image


def read_image(path: Path | str, *, expected_size: tuple[int, int] | None = None,
               keep_alpha: bool = False) -> np.ndarray:
    """Read an image file as RGB (or RGBA when it has alpha and ``keep_alpha``).

    16-bit images are scaled to 8 bits (divided by 256), grey images are
    repeated into three channels. An alpha channel is kept as a fourth
    channel when ``keep_alpha`` (segmentation takes it as the silhouette),
    otherwise dropped (the colour under transparent pixels is kept as
    stored). EXIF orientation is ignored: the pixels are those of the
    sensor, which the calibration refers to.

    Parameters
    ----------
    path : path-like
        The image file.
    expected_size : (width, height) int or None
        Raise unless the image has this size, pixels (the camera's).
    keep_alpha : bool
        Return (H, W, 4) RGBA for an image with an alpha channel.

    Returns
    -------
    (H, W, 3) or (H, W, 4) uint8
        RGB image, or RGBA (``keep_alpha`` and an alpha channel in the file).

    Raises
    ------
    ViewError
        Missing file, a file that is not a readable image, or the wrong size.
    """
    import cv2

    # As stored (any depth, with alpha), on the sensor's pixel grid (no EXIF rotation),
    # which calibrations refer to.
    image = _decode(Path(path), cv2.IMREAD_UNCHANGED | cv2.IMREAD_IGNORE_ORIENTATION,
                    expected_size)
    height, width = image.shape[:2]
    if image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)
    elif image.dtype != np.uint8:  # e.g. float TIFF: OpenCV's own conversion to 8-bit colour
        image = _decode(Path(path), cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION,
                        expected_size)
    if image.ndim == 2 or image.shape[2] == 1:
        return np.repeat(image.reshape(height, width, 1), 3, axis=2)
    if image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2RGBA if keep_alpha else cv2.COLOR_BGRA2RGB)
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def image_size(path: Path | str) -> tuple[int, int]:
    """``(width, height)`` of an image file from its header, pixels; ViewError if it cannot be read."""
    return image_header(Path(path))


#: Sides of a carving box, metres (or a COLMAP or NeRF model's own units), and the
#: largest coordinate of a corner: beyond them no voxel grid of the box is meaningful.
BOX_SIDE_RANGE, MAX_BOX_COORDINATE = (1e-6, 1e6), 1e6


def as_bounds(value, *, what: str) -> np.ndarray:
    """``value`` as a (2, 3) float64 box ``[min, max]``; ViewError (naming ``what``) unless
    it is finite, min < max, each side within :data:`BOX_SIDE_RANGE` and each corner
    within :data:`MAX_BOX_COORDINATE` of the origin."""
    try:
        bounds = np.array(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        bounds = np.zeros(0)
    if bounds.shape != (2, 3) or not np.all(np.isfinite(bounds)) or np.any(bounds[1] <= bounds[0]):
        raise ViewError(f"{what} must be [[xmin, ymin, zmin], [xmax, ymax, zmax]] with finite "
                        f"min < max, got {brief(value, 200)}")
    (low, high), sides = BOX_SIDE_RANGE, bounds[1] - bounds[0]
    if np.any(sides < low) or np.any(sides > high) or np.abs(bounds).max() > MAX_BOX_COORDINATE:
        raise ViewError(f"{what} {bounds.tolist()} has sides {sides.tolist()}; expected sides "
                        f"of {low:g}..{high:g} metres and corners within {MAX_BOX_COORDINATE:g} "
                        "of the origin")
    return bounds


def nearest_rotation(matrix: np.ndarray, *, what: str, tolerance: float = 1e-3) -> np.ndarray:
    """The rotation nearest to ``matrix`` (3, 3), for rotations stored with rounding.

    Raises ViewError (naming ``what``) if ``matrix`` is further than
    ``tolerance`` (largest element of ``M M^T - I``) from orthonormal or is a
    reflection.
    """
    matrix = np.asarray(matrix, dtype=np.float64)
    if matrix.shape != (3, 3) or not np.all(np.isfinite(matrix)):
        raise ViewError(f"{what}: rotation must be a finite 3x3 matrix")
    error = np.abs(matrix @ matrix.T - np.eye(3)).max()
    if error > tolerance or np.linalg.det(matrix) <= 0:
        raise ViewError(f"{what}: not a rotation (|R R^T - I| = {error:.2g}, det = "
                        f"{np.linalg.det(matrix):.3g}; expected orthonormal with det +1)")
    u, _, vt = np.linalg.svd(matrix)
    return u @ vt
