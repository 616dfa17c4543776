"""A PNG preview of a mesh: the shaded mesh seen from a few directions."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from ..exchange.files import write_atomic
from ..geometry.rig import RigCalibration, rig_camera
from ..render import as_mesh_arrays, corner_normals, render_image
from ..workers import map_in_threads

__all__ = ["PREVIEW_VIEWS_DEG", "png_bytes", "preview_image", "write_png"]

#: (theta, phi) in degrees of the preview panels: three around, one from above.
PREVIEW_VIEWS_DEG = ((30.0, 20.0), (150.0, 20.0), (270.0, 20.0), (0.0, 89.0))


def preview_image(vertices: np.ndarray, faces: np.ndarray, *, size_px: int = 360,
                  views_deg=PREVIEW_VIEWS_DEG, vertex_colors=None) -> np.ndarray:
    """(size_px, size_px * len(views_deg), 3) uint8 RGB panels of the shaded mesh.

    Orthographic views of the mesh moved so that the centre of its bounding
    box is at the origin (on the turntable axis, where the rig aims), scaled
    so the whole mesh fits every panel.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    if len(vertices) == 0 or len(faces) == 0:
        raise ValueError("cannot preview an empty mesh")
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    vertices = vertices - (lo + hi) / 2
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-9)
    scale = 0.45 * size_px / radius  # pixels per metre: the bounding sphere fits with a margin
    calibration = RigCalibration(width=size_px, height=size_px, projection="orthographic",
                                 fx=scale, fy=scale, camera_distance_m=4 * radius)
    vertices, faces = as_mesh_arrays(vertices, faces)
    normals = corner_normals(vertices, faces)  # the same for every panel

    def panel(view_deg) -> np.ndarray:
        camera = rig_camera(math.radians(view_deg[0]), math.radians(view_deg[1]), calibration)
        return render_image(vertices, faces, camera, vertex_colors=vertex_colors,
                            background_rgb=(245, 245, 245), noise_sigma=0.0, normals=normals)

    return np.hstack(list(map_in_threads(panel, views_deg)))


def png_bytes(image_rgb: np.ndarray) -> bytes:
    """An RGB (H, W, 3) or grey (H, W) uint8 image encoded as PNG."""
    image = np.asarray(image_rgb)
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    ok, data = cv2.imencode(".png", image)
    if not ok:
        raise OSError(f"could not encode a {image.shape} {image.dtype} image as PNG")
    return data.tobytes()


def write_png(path, image_rgb: np.ndarray) -> Path:
    """Write an RGB (H, W, 3) or grey (H, W) uint8 image as PNG, atomically; returns the path."""
    return write_atomic(Path(path), png_bytes(image_rgb))
