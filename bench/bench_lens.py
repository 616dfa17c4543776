"""Carving through a distorted lens: masks undistorted once, against every voxel projected
through the lens.

The scene is an off-axis sphere (exact silhouettes: each pixel centre's ray through the
lens) seen from 24 views through the calibration scene's barrel lens (k1 -0.18, k2 0.08,
f = 800 px, 640 x 480). Ours: :func:`sfs_ros.core.geometry.lens.undistort_mask` per view,
then :func:`~sfs_ros.core.carving.carve.carve` with the ideal cameras. Baseline: every
voxel centre projected through the lens (:meth:`Camera.project_distorted`, numpy,
chunked) and tested in its pixel, the exact pixel test. The notes give both hulls' volume
IoU against the true sphere, their agreement, and the hull that ignores the lens.

Run: ``python -m bench.bench_lens`` (``--quick``: 96^3 instead of 160^3).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from sfs_ros.core.carving.carve import carve
from sfs_ros.core.geometry.grid import VoxelGrid
from sfs_ros.core.geometry.lens import ideal_camera, undistort_mask
from sfs_ros.core.geometry.rig import RigCalibration, rig_camera
from sfs_ros.core.metrics import occupancy_from_contains, volume_iou

from .timing import best_of, main

LENS = (-0.18, 0.08, 0.0012, -0.0008, 0.0)
RIG = RigCalibration(width=640, height=480, projection="pinhole", fx=800.0, fy=800.0,
                     cx=324.5, cy=236.0, camera_distance_m=0.3, aim_point_m=(0.0, 0.0, 0.05),
                     distortion=LENS)
CENTRE, RADIUS = np.array([0.04, -0.005, 0.05]), 0.045
CHUNK = 1 << 20


def sphere_mask(camera) -> np.ndarray:
    """(H, W) bool: pixel centres whose ray through the lens meets the sphere."""
    u, v = np.meshgrid(np.arange(camera.width, dtype=float), np.arange(camera.height, dtype=float))
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
    xy = cv2.undistortPointsIter(np.stack([u, v], -1).reshape(-1, 1, 2), camera.K,
                                 camera.distortion, None, None, criteria).reshape(-1, 2)
    rays = np.concatenate([xy, np.ones((len(xy), 1))], axis=1) @ camera.R
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    w = CENTRE - camera.center
    along = rays @ w
    return ((along > 0) & (w @ w - along ** 2 <= RADIUS ** 2)).reshape(u.shape)


def exact_carve(grid, cameras, masks) -> np.ndarray:
    """Baseline: every voxel centre through the lens, tested in its (rounded) pixel."""
    keep = np.ones(int(np.prod(grid.shape)), bool)
    for start in range(0, len(keep), CHUNK):
        index = np.arange(start, min(start + CHUNK, len(keep)))
        centres = grid.index_to_world(np.stack(np.unravel_index(index, grid.shape), axis=1))
        alive = np.ones(len(index), bool)
        for camera, mask in zip(cameras, masks):
            uv = np.rint(camera.project_distorted(centres))
            inside = np.all(np.isfinite(uv), axis=1) & (uv[:, 0] >= 0) & \
                (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
            col = np.where(inside, uv[:, 0], 0).astype(int)
            row = np.where(inside, uv[:, 1], 0).astype(int)
            alive &= ~inside | mask[row, col]
        keep[index] = alive
    return keep.reshape(grid.shape)


def run(quick: bool = False) -> list[dict]:
    """Rows ``{name, seconds, baseline_seconds, ratio, notes}``."""
    resolution = 96 if quick else 160
    views = [(math.radians(t), math.radians(p)) for p in (5, 35, 65) for t in range(0, 360, 45)]
    cameras = [rig_camera(t, p, RIG) for t, p in views]
    masks = [sphere_mask(c) for c in cameras]
    ideal = [ideal_camera(c) for c in cameras]
    grid = VoxelGrid.cube(CENTRE - 1.2 * RADIUS, CENTRE + 1.2 * RADIUS, resolution)

    def ours():
        return carve(grid, ideal, [undistort_mask(m, c) for m, c in zip(masks, cameras)])

    ours()                                   # compile the kernels, build the lens maps
    seconds = best_of(ours, 3)
    baseline = best_of(lambda: exact_carve(grid, cameras, masks), 1)
    truth = occupancy_from_contains(lambda x: np.linalg.norm(x - CENTRE, axis=1) <= RADIUS,
                                    grid)
    got, exact = ours(), exact_carve(grid, cameras, masks)
    ignored = carve(grid, ideal, masks)
    note = (f"lens {resolution}^3, {len(views)} views: volume IoU against the sphere, masks "
            f"undistorted {volume_iou(got, truth):.4f}, exact projection "
            f"{volume_iou(exact, truth):.4f} (agreement {volume_iou(got, exact):.4f}), lens "
            f"ignored {volume_iou(ignored, truth):.4f}")
    return [{"name": f"carve {resolution}^3 through a lens, {len(views)} views 640x480",
             "seconds": seconds, "baseline_seconds": baseline, "ratio": baseline / seconds,
             "notes": [note]}]


if __name__ == "__main__":
    main(__doc__, run, quick_help="96^3 instead of 160^3")
