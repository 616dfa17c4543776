"""NeRF / instant-ngp ``transforms*.json``: images with camera-to-world poses.

Read keys (each intrinsic may be given at the top level or per frame, the
frame's value winning):

* focal length: ``fl_x`` / ``fl_y`` in pixels, or ``camera_angle_x`` /
  ``camera_angle_y`` (full field of view, radians; ``fx = w / 2 / tan(angle / 2)``).
  Without a vertical value, ``fy = fx``.
* ``w``, ``h``: image size, pixels; when absent, read from the first image.
* ``cx``, ``cy``: principal point in the file's convention (pixel corners at
  integer values, image centre ``w / 2``); converted to ours (integer values at
  pixel centres) by subtracting 0.5. Default: the image centre.
* lens distortion ``k1``, ``k2``, ``k3``, ``p1``, ``p2`` (instant-ngp's, on
  normalised coordinates): OpenCV ``plumb_bob`` ``(k1, k2, p1, p2, k3)``, 0 when
  absent; masks are undistorted once before carving
  (:mod:`sfs_ros.core.geometry.lens`). ``k4`` (a fisheye or rational term) and
  ``is_fisheye`` are other lens models: non-zero values are an error (undistort first).
* ``frames[].file_path``: image path relative to the json file, with or
  without the file extension (NeRF synthetic omits ``.png``).
* ``frames[].transform_matrix``: 4x4 camera-to-world pose, camera axes in the
  OpenGL / Blender convention (x right, y up, z backwards); converted to our
  world-to-camera OpenCV axes (x right, y down, z forward).
* ``bounds_m`` (this package's key) or ``aabb``: ``[[xmin, ymin, zmin],
  [xmax, ymax, zmax]]`` bounding box in world units. ``aabb_scale``, ``scale``
  and ``offset`` (instant-ngp's mapping into its unit cube) are ignored: the
  world frame and units are those of the poses.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from ..geometry.camera import Camera
from .limits import brief, confined_path, load_json
from .views import IMAGE_SUFFIXES, View, ViewError, ViewSet, as_bounds, image_size, nearest_rotation

__all__ = ["read_transforms"]

#: transforms.json keys of the OpenCV plumb_bob coefficients, in its order (k1, k2, p1, p2, k3).
_DISTORTION_KEYS = ("k1", "k2", "p1", "p2", "k3")
#: Keys of lens models this reader does not take.
_OTHER_LENS_KEYS = ("k4",)
#: OpenGL camera axes (x right, y up, z back) -> OpenCV (x right, y down, z forward).
_GL_TO_CV = np.diag([1.0, -1.0, -1.0])


def _number(levels: list[dict], key: str, where: str) -> float | None:
    for level in levels:
        if key in level:
            try:
                value = float(level[key])
            except (TypeError, ValueError):
                value = math.nan
            if not math.isfinite(value):
                raise ViewError(f"{where}: {key} must be a finite number, got {brief(level[key])}")
            return value
    return None


def _focal(levels: list[dict], pixels_key: str, angle_key: str, size: int, where: str) -> float | None:
    """Focal length in pixels from the first level giving it (as pixels or as an angle)."""
    for level in levels:
        if pixels_key in level:
            return _number([level], pixels_key, where)
        if angle_key in level:
            angle = _number([level], angle_key, where)
            if not 0.0 < angle < math.pi:
                raise ViewError(f"{where}: {angle_key} must be in (0, pi) radians, got {angle}")
            return 0.5 * size / math.tan(0.5 * angle)
    return None


def _image_path(json_dir: Path, file_path, where: str) -> Path:
    if not isinstance(file_path, str) or not file_path:
        raise ViewError(f"{where}: file_path must be a non-empty string, got {brief(file_path)}")
    base = confined_path(json_dir, file_path, f"{where}: file_path")
    if base.is_file():
        return base
    for suffix in IMAGE_SUFFIXES:
        candidate = base.with_name(base.name + suffix)
        if candidate.is_file():
            return confined_path(json_dir, f"{file_path}{suffix}", f"{where}: file_path")
    raise ViewError(f"{where}: image {base} does not exist (also tried the extensions "
                    f"{', '.join(IMAGE_SUFFIXES)})")


def _pose(matrix, where: str) -> tuple[np.ndarray, np.ndarray]:
    """World -> camera ``(R, t)`` (OpenCV axes) from a camera-to-world OpenGL pose."""
    try:
        m = np.array(matrix, dtype=np.float64)
    except (TypeError, ValueError):
        m = np.zeros(0)
    if m.shape not in ((4, 4), (3, 4)) or not np.all(np.isfinite(m)):
        raise ViewError(f"{where}: transform_matrix must be a finite 4x4 camera-to-world matrix")
    if m.shape == (4, 4) and not np.allclose(m[3], (0.0, 0.0, 0.0, 1.0), atol=1e-6):
        raise ViewError(f"{where}: transform_matrix last row must be [0, 0, 0, 1], got {m[3].tolist()}")
    cam_to_world = nearest_rotation(m[:3, :3], what=f"{where}: transform_matrix") @ _GL_TO_CV
    R = cam_to_world.T
    return R, -R @ m[:3, 3]


def _bounds(data: dict, path: Path) -> np.ndarray | None:
    key = "bounds_m" if "bounds_m" in data else "aabb" if "aabb" in data else None
    return None if key is None else as_bounds(data[key], what=f"{path}: {key}")


def read_transforms(json_path: Path | str) -> ViewSet:
    """Load a NeRF / instant-ngp ``transforms*.json`` (keys in the module docstring).

    Returns
    -------
    ViewSet
        ``source="nerf"``, pinhole cameras, view names = image paths relative to
        the json file, bounds from ``bounds_m`` or ``aabb`` when present.

    Raises
    ------
    ViewError
        Invalid JSON, missing keys, missing images, a lens model other than
        plumb_bob, or a pose that is not rigid.
    """
    json_path = Path(json_path)
    data = load_json(json_path, "transforms file")
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list) or not data["frames"]:
        raise ViewError(f"{json_path}: expected a JSON object with a non-empty 'frames' list")

    views, seen = [], {}
    default_size = None
    for n, frame in enumerate(data["frames"]):
        where = f"{json_path} frame {n}"
        if not isinstance(frame, dict):
            raise ViewError(f"{where}: expected an object with file_path and transform_matrix")
        levels = [frame, data]
        path = _image_path(json_path.parent, frame.get("file_path"), where)
        name = Path(os.path.relpath(path, json_path.parent)).as_posix()
        if name in seen:
            raise ViewError(f"{where}: image {name!r} is listed twice (first in frame {seen[name]})")
        seen[name] = n
        for key in _OTHER_LENS_KEYS:
            if _number(levels, key, where) not in (None, 0.0):
                raise ViewError(f"{where}: lens distortion {key} is not supported (only k1, k2, "
                                "k3, p1, p2: OpenCV plumb_bob); undistort the images and set it "
                                "to 0")
        if any(level.get("is_fisheye") for level in levels):
            raise ViewError(f"{where}: fisheye cameras are not supported")
        distortion = [_number(levels, key, where) for key in _DISTORTION_KEYS]
        distortion = tuple(0.0 if d is None else d for d in distortion)
        width, height = _number(levels, "w", where), _number(levels, "h", where)
        if width is None or height is None:
            if default_size is None:
                default_size = image_size(path)
            width = default_size[0] if width is None else width
            height = default_size[1] if height is None else height
        width, height = int(round(width)), int(round(height))
        fx = _focal(levels, "fl_x", "camera_angle_x", width, where)
        if fx is None:
            raise ViewError(f"{where}: no focal length; expected camera_angle_x or fl_x")
        fy = _focal(levels, "fl_y", "camera_angle_y", height, where)
        fy = fx if fy is None else fy
        cx, cy = _number(levels, "cx", where), _number(levels, "cy", where)
        K = np.array([[fx, 0.0, (width / 2 if cx is None else cx) - 0.5],
                      [0.0, fy, (height / 2 if cy is None else cy) - 0.5],
                      [0.0, 0.0, 1.0]])
        R, t = _pose(frame.get("transform_matrix"), where)
        try:
            camera = Camera(K=K, R=R, t=t, width=width, height=height, distortion=distortion)
        except ValueError as err:
            raise ViewError(f"{where}: {err}") from None
        views.append(View(name=name, image_path=path, camera=camera))
    return ViewSet(views=views, source="nerf", bounds_m=_bounds(data, json_path))
