"""Exact silhouettes of analytic shapes, for tests that must not depend on the renderer."""

import numpy as np

from sfs_ros.core.geometry.camera import Camera


def sphere_mask(camera: Camera, centre, radius: float) -> np.ndarray:
    """(H, W) bool: pixels whose centre ray hits the sphere (``centre`` (3,), ``radius``, metres)."""
    u, v = np.meshgrid(np.arange(camera.width, dtype=float), np.arange(camera.height, dtype=float))
    if camera.orthographic:
        uc, vc = camera.project(np.asarray(centre, float)[None])[0]
        return (u - uc) ** 2 + (v - vc) ** 2 <= (radius * camera.K[0, 0]) ** 2
    rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(camera.K).T @ camera.R
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    w = np.asarray(centre, float) - camera.center
    along = rays @ w
    return (along > 0) & (w @ w - along ** 2 <= radius ** 2)
