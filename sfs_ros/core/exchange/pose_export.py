"""A scan's views for other tools: a plain session folder, COLMAP text, NeRF transforms.

Turntable captures are what photogrammetry and neural tools often fail to
register (the background does not move with the object); the cell knows every
camera, so it hands them over:

* :func:`export_session` -- a session folder (``images/`` + ``views.csv`` +
  ``session.yaml``, :mod:`.session`): encoder angles with the rig calibration
  when the views have them, else a table of 3x4 projection matrices;
* :func:`write_colmap` -- COLMAP's text model (``cameras.txt``,
  ``images.txt``, ``points3D.txt``): ``PINHOLE`` cameras (``OPENCV`` with the
  lens ``k1, k2, p1, p2`` for a distorted one; ``k3`` is refused), world-to-camera
  poses as ``QW QX QY QZ TX TY TZ`` (the same OpenCV axes as ours), the
  principal point in COLMAP's pixel convention (the centre of the top-left
  pixel at (0.5, 0.5): ours + 0.5); ``points3D.txt`` holds optional points
  (e.g. the hull's surface, which seeds a dense reconstruction);
* :func:`write_nerf_transforms` -- NeRF / instant-ngp ``transforms.json``:
  ``fl_x``, ``fl_y``, ``cx``, ``cy`` (pixel corners at integers: ours + 0.5),
  ``w``, ``h``, the lens ``k1``, ``k2``, ``p1``, ``p2``, ``k3``, and per frame
  ``file_path`` with a camera-to-world ``transform_matrix`` in OpenGL axes (x
  right, y up, z backwards), as :func:`sfs_ros.core.exchange.nerf.read_transforms`
  reads it back; plus ``bounds_m``.

Both pose formats describe pinhole cameras; orthographic views are refused.
World frame: the object frame (metres, Z up on the turntable axis).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..geometry.camera import Camera
from ..geometry.rig import RigCalibration
from .files import write_atomic
from .session import write_session
from .views import ViewSet, read_image

__all__ = ["export_session", "write_colmap", "write_nerf_transforms"]

#: OpenCV camera axes (x right, y down, z forward) <-> OpenGL (x right, y up, z back).
_CV_TO_GL = np.diag([1.0, -1.0, -1.0])


def _pinhole(view_set: ViewSet) -> list[Camera]:
    if not view_set.views:
        raise ValueError("no views to export")
    cameras = [v.camera for v in view_set.views]
    bad = [v.name for v in view_set.views if v.camera.orthographic]
    if bad:
        raise ValueError(f"{len(bad)} orthographic view(s) ({', '.join(bad[:3])}): COLMAP and "
                         "NeRF poses describe pinhole cameras")
    return cameras


def _png_names(view_set: ViewSet) -> list[str]:
    """One ``.png`` file name per view, unique, from the view names."""
    names = []
    for view in view_set.views:
        stem = Path(view.name).with_suffix("").as_posix().replace("/", "_")
        name, n = f"{stem}.png", 1
        while name in names:
            name, n = f"{stem}_{n}.png", n + 1
        names.append(name)
    return names


def _write_text(path: Path, text: str) -> None:
    """Write ``text`` as UTF-8, atomically."""
    write_atomic(path, text.encode("utf-8"))


def export_session(view_set: ViewSet, folder) -> Path:
    """Write ``view_set`` as a session folder (images as PNG); returns ``folder``.

    Angles and the rig calibration when every view has encoder angles and the
    set has a calibration; otherwise pinhole projection matrices (the image
    size from the first view). Bounds and segmentation parameters are kept.
    """
    if not view_set.views:
        raise ValueError("no views to export")
    images = [(name, read_image(v.image_path))
              for name, v in zip(_png_names(view_set), view_set.views)]
    angles = [(v.theta_rad, v.phi_rad) for v in view_set.views]
    if view_set.calibration is not None and all(None not in pair for pair in angles):
        return write_session(folder, images, angles, view_set.calibration,
                             bounds_m=view_set.bounds_m, segmentation=view_set.segmentation)
    first = view_set.views[0].camera
    return write_session(folder, images, None,
                         RigCalibration(width=first.width, height=first.height),
                         cameras=_pinhole(view_set), bounds_m=view_set.bounds_m,
                         segmentation=view_set.segmentation)


def write_colmap(view_set: ViewSet, folder, *, points=None) -> Path:
    """Write COLMAP's text model of ``view_set`` into ``folder`` (created); returns it.

    points : (n, 3) float, optional
        Written to ``points3D.txt`` (no tracks, grey); default: none.
    Image names are the view names (paths relative to COLMAP's image folder).
    """
    cameras = _pinhole(view_set)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    intrinsics: dict[tuple, int] = {}
    camera_lines, image_lines = [], []
    for n, (view, camera) in enumerate(zip(view_set.views, cameras), start=1):
        K = camera.K
        if abs(K[0, 1]) > 1e-9:
            raise ValueError(f"view {view.name}: skewed intrinsics are not a COLMAP PINHOLE camera")
        lens = tuple(camera.distortion.tolist())
        if lens[4]:
            raise ValueError(f"view {view.name}: a lens with k3 = {lens[4]} is not a COLMAP "
                             "OPENCV camera (k1, k2, p1, p2 only)")
        key = (camera.width, camera.height, K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5)
        key += lens[:4] if any(lens) else ()
        if key not in intrinsics:
            intrinsics[key] = len(intrinsics) + 1
            camera_lines.append(f"{intrinsics[key]} {'OPENCV' if any(lens) else 'PINHOLE'} "
                                f"{key[0]} {key[1]} " + " ".join(repr(float(v)) for v in key[2:]))
        # A writable copy: SciPy 1.11 (Ubuntu 24.04's) refuses the camera's read-only R.
        qx, qy, qz, qw = Rotation.from_matrix(np.array(camera.R)).as_quat()
        values = [qw, qx, qy, qz, *camera.t]
        image_lines.append(f"{n} " + " ".join(repr(float(v)) for v in values)
                           + f" {intrinsics[key]} {view.name}\n\n")   # no 2-D points
    _write_text(folder / "cameras.txt", "# CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
                + "\n".join(camera_lines) + "\n")
    _write_text(folder / "images.txt", "# IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, "
                "NAME\n# POINTS2D[] as (X, Y, POINT3D_ID)\n" + "".join(image_lines))
    pts = np.zeros((0, 3)) if points is None else np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must be (n, 3), got shape {pts.shape}")
    _write_text(folder / "points3D.txt", "# POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[]\n"
                + "".join(f"{i} {x!r} {y!r} {z!r} 128 128 128 0\n"
                          for i, (x, y, z) in enumerate(pts.tolist(), start=1)))
    return folder


def write_nerf_transforms(view_set: ViewSet, path, *, image_root=None) -> Path:
    """Write ``transforms.json`` for ``view_set``; returns its path.

    image_root : path-like, optional
        Folder the image paths are made relative to (default: the images'
        own places, relative to the json file's folder).

    The images must lie inside the json file's folder: NeRF tools, and
    :func:`~sfs_ros.core.exchange.nerf.read_transforms`, read a ``file_path``
    only from there (no ``..``, no absolute paths). ValueError otherwise.
    """
    cameras = _pinhole(view_set)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    root = Path(image_root) if image_root is not None else None
    frames = []
    for view, camera in zip(view_set.views, cameras):
        c2w = np.eye(4)
        c2w[:3, :3] = camera.R.T @ _CV_TO_GL
        c2w[:3, 3] = camera.center
        image = view.image_path if root is None else root / view.name
        relative = Path(os.path.relpath(image, path.parent)).as_posix()
        if relative.startswith("../") or os.path.isabs(relative):
            raise ValueError(f"image {image} of view {view.name} is outside {path.parent}: NeRF "
                             "readers take images only from inside the transforms file's "
                             "folder; write it beside the images (e.g. sfs-export --session DIR "
                             "--nerf DIR/transforms.json)")
        K = camera.K
        frames.append({"file_path": relative,
                       "fl_x": K[0, 0], "fl_y": K[1, 1], "cx": K[0, 2] + 0.5,
                       "cy": K[1, 2] + 0.5, "w": camera.width, "h": camera.height,
                       **dict(zip(("k1", "k2", "p1", "p2", "k3"), camera.distortion.tolist())),
                       "transform_matrix": c2w.tolist()})
    document = {"camera_model": "OPENCV", "frames": frames}
    if view_set.bounds_m is not None:
        document["bounds_m"] = view_set.bounds_m.tolist()
    _write_text(path, json.dumps(document, indent=2))
    return path
