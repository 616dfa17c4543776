"""Lens distortion: from the image a distorted lens forms to the ideal pinhole, and back.

A pinhole :class:`Camera` with ``distortion`` forms its image through the lens
(:meth:`Camera.project_distorted`); carving, fusion, meshing and the metrics use
the ideal pinhole ``K [R | t]`` (:meth:`Camera.project`). The two meet here, once
per view:

* :func:`undistort_mask` (:func:`undistort_image`) resamples a mask (an image)
  taken through the lens onto the
  pixel grid of :func:`ideal_camera` (same ``K``, ``R``, ``t``, no distortion):
  ideal pixel ``(u, v)`` takes the mask pixel nearest to where the lens forms
  the ray through ``(u, v)``. A voxel centre projecting into ideal pixel
  ``(u, v)`` is then tested against the mask pixel its distorted projection
  falls nearest to, within the half pixel that rounding to a pixel already
  allows. Ideal pixels the lens forms outside the image are background.
* :func:`distort_mask` is the way back: a mask on the ideal pixel grid resampled
  into the image the lens forms (each lens pixel takes the ideal pixel nearest to
  where its ray crosses the ideal image), for masks decided on the ideal grid and
  shown over the images as taken.
* :func:`render_through_lens` renders through an ideal camera on a canvas
  large enough for the lens's field of view and resamples the result into the
  image the lens forms (the renderer of a distorted camera).

The resampling maps depend only on ``K``, the distortion and the image size,
so they are computed once per lens and cached.
"""

from __future__ import annotations

import math
from dataclasses import replace
from functools import lru_cache
from typing import Callable

import cv2
import numpy as np

from .camera import Camera, distort_normalized

__all__ = ["ideal_camera", "is_distorted", "undistort_image", "undistort_mask", "distort_mask",
           "render_through_lens", "lens_problem", "MAX_LENS_SCALE"]

#: Extra canvas around the lens's field of view, pixels (room for interpolation).
_CANVAS_MARGIN_PX = 2
#: Farthest a lens may move a point of the image's border from the principal point, as a
#: factor of its ideal distance (and nearest, as its inverse): a lens beyond that is not
#: a ``plumb_bob`` lens of a camera that sees its image (fisheyes are refused anyway).
MAX_LENS_SCALE = 2.0
#: Samples along each side of the image where the lens is checked.
_LENS_SAMPLES = 41


def is_distorted(camera: Camera) -> bool:
    """Whether ``camera`` has a lens distortion (non-zero coefficients)."""
    return not camera.orthographic and bool(np.any(camera.distortion))


def ideal_camera(camera: Camera) -> Camera:
    """The same camera (``K``, ``R``, ``t``, size) with an ideal lens."""
    if not is_distorted(camera):
        return camera
    return replace(camera, distortion=None)


def lens_problem(K: np.ndarray, distortion, width: int, height: int) -> str:
    """Why the lens ``distortion`` (``plumb_bob``) of a pinhole with ``K`` and a
    ``width`` x ``height`` image cannot be that camera's, or "".

    A lens maps the ideal image onto the image as taken one to one: over the image's
    extent (sampled on a grid, its border included) the map's Jacobian must have a
    positive determinant (no fold, no mirror), and no point of the border may move
    farther than :data:`MAX_LENS_SCALE` times (nor nearer than its inverse) from the
    principal point.
    """
    return _lens_problem((tuple(np.asarray(K, dtype=np.float64).ravel().tolist()),
                          tuple(float(d) for d in distortion), int(width), int(height)))


@lru_cache(maxsize=32)
def _lens_problem(lens: tuple) -> str:
    K = np.asarray(lens[0]).reshape(3, 3)
    width, height = lens[2], lens[3]
    u, v = np.meshgrid(np.linspace(-0.5, width - 0.5, _LENS_SAMPLES),
                       np.linspace(-0.5, height - 0.5, _LENS_SAMPLES))
    pixels = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], axis=1)
    xy = (pixels @ np.linalg.inv(K).T)[:, :2]
    step = 1e-6 * max(float(np.abs(xy).max()), 1e-9)
    with np.errstate(all="ignore"):
        dx = distort_normalized(xy + [step, 0.0], lens[1]) - distort_normalized(xy - [step, 0.0], lens[1])
        dy = distort_normalized(xy + [0.0, step], lens[1]) - distort_normalized(xy - [0.0, step], lens[1])
        det = dx[:, 0] * dy[:, 1] - dx[:, 1] * dy[:, 0]
        border = (u.ravel() <= 0) | (u.ravel() >= width - 1) | (v.ravel() <= 0) | \
            (v.ravel() >= height - 1)
        ideal = np.hypot(*xy[border].T)
        scale = np.hypot(*distort_normalized(xy[border], lens[1]).T) / np.maximum(ideal, 1e-300)
    if not np.all(det > 0):
        return (f"the lens distortion {list(lens[1])} folds the image over (not one to one "
                f"within the {width}x{height} image); expected a lens that maps the image "
                "onto itself")
    worst = float(scale[np.argmax(np.abs(np.log(scale)))])
    if not 1 / MAX_LENS_SCALE <= worst <= MAX_LENS_SCALE:
        return (f"the lens distortion {list(lens[1])} moves the image's border {worst:.3g} "
                f"times its distance from the principal point; expected within "
                f"{1 / MAX_LENS_SCALE:g}..{MAX_LENS_SCALE:g}")
    return ""


def _lens(camera: Camera) -> tuple:
    """Hashable key of the lens: ``K``, distortion and image size."""
    return (tuple(camera.K.ravel().tolist()), tuple(camera.distortion.tolist()),
            camera.width, camera.height)


@lru_cache(maxsize=8)
def _ideal_to_distorted(lens: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Nearest distorted pixel ``(row, col)`` (H, W) int64 each of every ideal pixel centre;
    -1 where the lens forms that ray outside the image."""
    K = np.asarray(lens[0]).reshape(3, 3)
    width, height = lens[2], lens[3]
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    pixels = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], axis=1)
    xy = (pixels @ np.linalg.inv(K).T)[:, :2]
    uv = distort_normalized(xy, lens[1]) @ K[:2, :2].T + K[:2, 2]
    return _nearest_pixels(uv, width, height)


def _nearest_pixels(uv: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """``(row, col)`` (height, width) int64 each: the pixel nearest each of the
    ``height * width`` points ``uv`` (n, 2) (row-major), -1 where it is outside the image."""
    col, row = np.rint(uv[:, 0]), np.rint(uv[:, 1])
    inside = np.isfinite(uv).all(axis=1) & (col >= 0) & (col < width) & (row >= 0) \
        & (row < height)
    row = np.where(inside, row, -1).astype(np.int64).reshape(height, width)
    col = np.where(inside, col, -1).astype(np.int64).reshape(height, width)
    return row, col


def undistort_image(image: np.ndarray, camera: Camera) -> np.ndarray:
    """An image or mask ``(camera.height, camera.width[, c])`` taken through ``camera``'s lens,
    seen by :func:`ideal_camera` (nearest pixel, module docstring; zero where the lens forms
    the ray outside the image); unchanged for an ideal lens."""
    return _resample(np.asarray(image), camera, _ideal_to_distorted, "image")


def undistort_mask(mask: np.ndarray, camera: Camera) -> np.ndarray:
    """(H, W) bool: :func:`undistort_image` of a silhouette mask."""
    return undistort_image(np.asarray(mask, dtype=bool), camera)


@lru_cache(maxsize=8)
def _distorted_to_ideal(lens: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Nearest ideal pixel ``(row, col)`` (H, W) int64 each of every pixel centre of the
    lens's image; -1 where that ray crosses the ideal image outside its frame."""
    K = np.asarray(lens[0]).reshape(3, 3)
    width, height = lens[2], lens[3]
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    pixels = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    # Inverting the lens model is iterative; 1e-9 normalised units is ~1e-6 pixel.
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-9)
    uv = cv2.undistortPointsIter(pixels, K, np.asarray(lens[1], np.float64), None, K,
                                 criteria).reshape(-1, 2)
    return _nearest_pixels(uv, width, height)


def distort_mask(mask: np.ndarray, camera: Camera) -> np.ndarray:
    """(H, W) bool: a mask on :func:`ideal_camera`'s pixel grid, as ``camera``'s lens forms
    it (nearest pixel; the inverse of :func:`undistort_mask` up to the pixels on the mask's
    edge); unchanged for an ideal lens."""
    return _resample(np.asarray(mask, dtype=bool), camera, _distorted_to_ideal, "mask")


def _resample(image: np.ndarray, camera: Camera, lookup, what: str) -> np.ndarray:
    """``image`` (H, W[, c]) on one of the two pixel grids, resampled onto the other: each
    output pixel takes the pixel ``lookup(lens)`` names, zero where it names -1; unchanged
    for an ideal lens."""
    if image.shape[:2] != (camera.height, camera.width):
        raise ValueError(f"{what} has shape {image.shape}, expected the camera's (height, width) "
                         f"= ({camera.height}, {camera.width})")
    if not is_distorted(camera):
        return image
    row, col = lookup(_lens(camera))
    out = image[np.maximum(row, 0), np.maximum(col, 0)]
    out[row < 0] = 0
    return out


@lru_cache(maxsize=8)
def _canvas(lens: tuple) -> tuple[np.ndarray, int, int, np.ndarray, np.ndarray]:
    """The ideal canvas covering the lens's image: its ``K`` (3, 3), width, height, and the
    canvas position ``(map_x, map_y)`` (H, W) float32 of every pixel of the lens's image."""
    K = np.asarray(lens[0]).reshape(3, 3)
    D = np.asarray(lens[1])
    width, height = lens[2], lens[3]
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    uv = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-12)
    ideal = cv2.undistortPointsIter(uv, K, D, None, K, criteria).reshape(-1, 2)
    low = np.floor(ideal.min(axis=0)) - _CANVAS_MARGIN_PX
    high = np.ceil(ideal.max(axis=0)) + _CANVAS_MARGIN_PX
    canvas_K = K.copy()
    canvas_K[:2, 2] -= low
    size = (high - low + 1).astype(int)
    shifted = (ideal - low).astype(np.float32).reshape(height, width, 2)
    return canvas_K, int(size[0]), int(size[1]), shifted[..., 0].copy(), shifted[..., 1].copy()


def render_through_lens(camera: Camera, render: Callable[[Camera], np.ndarray], *,
                        nearest: bool = False) -> np.ndarray:
    """The image ``camera``'s lens forms of what ``render`` draws through an ideal camera.

    Parameters
    ----------
    camera : Camera
        A pinhole camera, usually with distortion (without, ``render(camera)``).
    render : callable Camera -> (h, w) or (h, w, c) array
        Draws the scene through an ideal pinhole camera of any size.
    nearest : bool, keyword-only
        Nearest-pixel resampling (for masks); linear otherwise.

    Returns
    -------
    (camera.height, camera.width[, c]) array of ``render``'s dtype.
    """
    if not is_distorted(camera):
        return render(camera)
    K, width, height, map_x, map_y = _canvas(_lens(camera))
    if max(width, height) > 4 * max(camera.width, camera.height) or not math.isfinite(K[0, 2]):
        raise ValueError(f"the lens distortion {camera.distortion.tolist()} spreads a "
                         f"{camera.width}x{camera.height} image over {width}x{height} ideal "
                         "pixels: not a lens this renderer can draw")
    canvas = Camera(K=K, R=camera.R, t=camera.t, width=width, height=height)
    image = np.asarray(render(canvas))
    dtype = image.dtype
    if np.issubdtype(dtype, np.bool_):
        image = image.astype(np.uint8)
    out = cv2.remap(image, map_x, map_y, cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    return out.astype(dtype)
