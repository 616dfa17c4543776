"""Advancing-front triangulation speed, 10k and 50k points.

Rows: evenly spread sphere points with exact normals (baseline: scipy's convex
hull of the same points, which for a convex surface is a triangulation of them
too), the same with estimated normals, and the cloud of points of a voxel torus
(no baseline). Run: ``python -m bench.bench_mesh``.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.spatial import ConvexHull

from sfs_ros.core.geometry.grid import VoxelGrid
from sfs_ros.core.meshing.advancing_front import advancing_front
from sfs_ros.core.meshing.cloud import cloud_of_points

from .timing import main


def _fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    polar = np.arccos(1.0 - 2.0 * i / n)
    azimuth = np.pi * (1.0 + 5.0 ** 0.5) * i
    return np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar),
                     np.cos(polar)], axis=1)


def _torus_occupancy(grid: VoxelGrid) -> np.ndarray:
    x = grid.centers_axis(0)[:, None, None]
    y = grid.centers_axis(1)[None, :, None]
    z = grid.centers_axis(2)[None, None, :]
    return (np.hypot(x, y) - 0.6) ** 2 + z ** 2 <= 0.3 ** 2


def _timed(fn):
    start = time.perf_counter()
    out = fn()
    return time.perf_counter() - start, out


def _row(name, seconds, baseline=None):
    return {"name": name, "seconds": seconds, "baseline_seconds": baseline,
            "ratio": None if baseline is None else baseline / seconds}


def run_advancing_front(quick: bool = False) -> list[dict]:
    """Time ``advancing_front`` on 10k (and, unless quick, 50k) points.

    Returns rows ``{name, seconds, baseline_seconds, ratio}`` with
    ratio = baseline_seconds / seconds (None without a baseline). The stats of
    each mesh (closed or not) are put in the row name.
    """
    warm = _fibonacci_sphere(200)
    advancing_front(warm, warm)  # numba compilation (cached on disk) is not timed
    rows = []
    for n in (10_000,) if quick else (10_000, 50_000):
        points = _fibonacci_sphere(n)
        seconds, result = _timed(lambda: advancing_front(points, points))
        baseline, _ = _timed(lambda: ConvexHull(points))
        closed = "closed" if result.stats["closed"] else "OPEN"
        rows.append(_row(f"advancing front, sphere {n} pts, given normals ({closed})",
                         seconds, baseline))
        seconds, result = _timed(lambda: advancing_front(points, None))
        closed = "closed" if result.stats["closed"] else "OPEN"
        rows.append(_row(f"advancing front, sphere {n} pts, estimated normals ({closed})",
                         seconds))
    resolution = 160 if quick else 320
    grid = VoxelGrid.cube([-1.0, -1.0, -0.4], [1.0, 1.0, 0.4], resolution)
    occupancy = _torus_occupancy(grid)
    seconds, cloud = _timed(lambda: cloud_of_points(occupancy, grid, block=2))
    rows.append(_row(f"cloud of points, torus {resolution}^3-ish, M=2 -> {len(cloud.points)} pts",
                     seconds))
    seconds, result = _timed(lambda: advancing_front(cloud.points, cloud.normals))
    closed = "closed" if result.stats["closed"] else "OPEN"
    rows.append(_row(f"advancing front, voxel torus {len(cloud.points)} pts ({closed})", seconds))
    return rows


if __name__ == "__main__":
    main(__doc__, run_advancing_front, quick_help="10k points only")
