"""Exact silhouettes of analytic shapes, for tests that must not depend on the renderer."""

import cv2
import numpy as np

from sfs_ros.core.geometry.camera import Camera


def sphere_mask(camera: Camera, centre, radius: float) -> np.ndarray:
    """(H, W) bool: pixels whose centre ray hits the sphere (``centre`` (3,), ``radius``, metres).

    A pinhole camera with lens distortion: each pixel centre's ray through the lens
    (OpenCV's iterative undistortion, converged to 1e-12).
    """
    u, v = np.meshgrid(np.arange(camera.width, dtype=float), np.arange(camera.height, dtype=float))
    if camera.orthographic:
        uc, vc = camera.project(np.asarray(centre, float)[None])[0]
        return (u - uc) ** 2 + (v - vc) ** 2 <= (radius * camera.K[0, 0]) ** 2
    if np.any(camera.distortion):
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
        xy = cv2.undistortPointsIter(np.stack([u, v], -1).reshape(-1, 1, 2), camera.K,
                                     camera.distortion, None, camera.K, criteria)
        u, v = xy[:, 0, 0].reshape(u.shape), xy[:, 0, 1].reshape(u.shape)
    rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(camera.K).T @ camera.R
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    w = np.asarray(centre, float) - camera.center
    along = rays @ w
    return (along > 0) & (w @ w - along ** 2 <= radius ** 2)
