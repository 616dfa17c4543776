"""Marching cubes speed on a carved-like occupancy (a torus) at 256^3 and 512^3.

Baseline: scikit-image's marching cubes alone on the same cropped volume
(what ``marching_cubes_mesh`` wraps), so the ratio (baseline / ours, below 1)
shows the cost of cropping, padding, smoothing and orientation.

Sub-voxel surface rows: the pipeline's meshing of a carved hull at 192^3 (the
torus object seen by 73 exact silhouettes, 640 x 480 pinhole views), on the
signed distance to the hull (distance images, band, contour), against the 0/1
occupancy mesher on the same hull; and moving the cloud of points onto the
hull, against making the cloud.

Band row: the hull mesher's marching cubes (``lewiner.march_band``: only the cubes with a
corner in the band, vertices placed on the edges' crossings) on a band as wide as the
Middlebury dino's grid (390x506x401, a torus across it), against scikit-image's marching
cubes alone on the same volume with the mask of those cubes (built beforehand, not
timed; the same mesh before the vertices are placed). Run: ``python -m bench.bench_marching``.
"""

from __future__ import annotations

import numpy as np
from skimage import measure

from sfs_ros.core.carving.carve import carve
from sfs_ros.core.geometry.grid import VoxelGrid
from sfs_ros.core.geometry.rig import RigCalibration, rig_camera
from sfs_ros.core.meshing.cloud import cloud_of_points
from sfs_ros.core.meshing.hull_distance import HullDistance
from sfs_ros.core.meshing.lewiner import march_band
from sfs_ros.core.meshing.marching import (
    _CROSSING_MARGIN,
    LEVEL,
    band_voxel_indices,
    crossing_edges,
    hull_marching_cubes_mesh,
    marching_cubes_mesh,
)
from sfs_ros.core.meshing.mesh_checks import check_mesh
from sfs_ros.core.render import rasterize_silhouette
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.core.simulation.plan import ring_plan
from sfs_ros.core.simulation.synthetic import carving_box

from .timing import best_of, main

#: Torus (metres) in a 0.2 m box, axis Z: like a carved ring-shaped object.
MAJOR_RADIUS_M = 0.06
MINOR_RADIUS_M = 0.025
BOX_MIN_M = (-0.1, -0.1, -0.05)
BOX_MAX_M = (0.1, 0.1, 0.15)


def torus_occupancy(grid: VoxelGrid) -> np.ndarray:
    """(nx, ny, nz) bool torus, built per column (no 3-D float temporaries)."""
    x = grid.centers_axis(0)[:, None]
    y = grid.centers_axis(1)[None, :]
    z = grid.centers_axis(2)
    ring = np.hypot(x, y) - MAJOR_RADIUS_M
    half_height = np.sqrt(np.maximum(MINOR_RADIUS_M ** 2 - ring ** 2, 0.0))
    half_height[ring ** 2 > MINOR_RADIUS_M ** 2] = -1.0
    return np.abs(z - 0.05)[None, None, :] <= half_height[:, :, None]


def run(quick: bool = False) -> list[dict]:
    """Time marching cubes (and the mesh check) at 256^3 and, unless quick, 512^3.

    Returns rows ``{name, seconds, baseline_seconds, ratio}`` (seconds: best
    of a few runs; ratio = baseline_seconds / seconds).
    """
    rows = []
    for resolution in (256,) if quick else (256, 512):
        grid = VoxelGrid.cube(BOX_MIN_M, BOX_MAX_M, resolution)
        occ = torus_occupancy(grid)
        repeats = 3 if resolution <= 256 else 2
        ii, jj, kk = (np.flatnonzero(occ.any(axis=tuple(a for a in range(3) if a != axis)))
                      for axis in range(3))
        cropped = np.pad(occ[ii[0]:ii[-1] + 1, jj[0]:jj[-1] + 1, kk[0]:kk[-1] + 1]
                         .astype(np.float32), 1)
        baseline = best_of(lambda: measure.marching_cubes(cropped, LEVEL), repeats)
        for sigma in (0.0, 0.5):
            seconds = best_of(lambda: marching_cubes_mesh(occ, grid, smooth_sigma_vox=sigma),
                              repeats)
            rows.append({"name": f"marching_cubes_mesh {resolution}^3 torus sigma={sigma}",
                         "seconds": seconds, "baseline_seconds": baseline,
                         "ratio": baseline / seconds})
        vertices, faces = marching_cubes_mesh(occ, grid)
        seconds = best_of(lambda: check_mesh(vertices, faces), repeats)
        rows.append({"name": f"check_mesh {resolution}^3 torus ({len(faces)} faces)",
                     "seconds": seconds, "baseline_seconds": None, "ratio": None})
    return rows


def run_hull_surface(quick: bool = False) -> list[dict]:
    """Time the pipeline's meshing of a carved torus on its hull distance (192^3, or 96^3 quick).

    Returns rows ``{name, seconds, baseline_seconds, ratio}`` like :func:`run`:
    marching cubes on the hull distance (baseline: ``marching_cubes_mesh`` of
    the occupancy, sigma 0.5, the mesher it replaces), and moving the cloud of
    points onto the hull (baseline: ``cloud_of_points``).
    """
    obj = make_object("torus")
    rig = RigCalibration(width=640, height=480, projection="pinhole", fx=1400.0, fy=1400.0,
                         camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.04))
    cameras = [rig_camera(theta, phi, rig)
               for theta, phi in ring_plan([15.0, 40.0, 65.0], 24, top_view=True)]
    masks = [rasterize_silhouette(obj.mesh.vertices, obj.mesh.faces, c) for c in cameras]
    box = carving_box(obj)
    resolution = 96 if quick else 192
    grid = VoxelGrid.cube(box[0], box[1], resolution)
    occ = carve(grid, cameras, masks)
    repeats = 3

    def hull():
        return HullDistance(cameras, masks, bounds_m=(grid.bounds_min, grid.bounds_max))

    hull_marching_cubes_mesh(occ, grid, hull())  # numba compilation (cached on disk) is not timed
    baseline = best_of(lambda: marching_cubes_mesh(occ, grid), repeats)
    seconds = best_of(lambda: hull_marching_cubes_mesh(occ, grid, hull()), repeats)
    rows = [{"name": f"hull_marching_cubes_mesh {resolution}^3 torus, {len(cameras)} views",
             "seconds": seconds, "baseline_seconds": baseline, "ratio": baseline / seconds}]
    cloud = cloud_of_points(occ, grid, block=2)
    baseline = best_of(lambda: cloud_of_points(occ, grid, block=2), repeats)
    seconds = best_of(lambda: hull().project(cloud.points, cloud.normals,
                                             reach_m=2.0 * grid.voxel_size), repeats)
    rows.append({"name": f"cloud onto the hull {resolution}^3 torus, {len(cloud.points)} pts",
                 "seconds": seconds, "baseline_seconds": baseline, "ratio": baseline / seconds})
    return rows


#: The Middlebury dino's grid at its finest pixel footprint (dinoSparseRing; ``sfs-reconstruct``
#: carves it 1.5 footprints coarse by default: its silhouettes have next to no thin parts).
DINO_SHAPE = (390, 506, 401)


def torus_distance(shape) -> tuple[np.ndarray, np.ndarray]:
    """A torus across a grid of ``shape`` voxels, its axis along the first, its tube
    stretched to 0.9 of the grid's height: the signed distance in voxels (positive
    outside; across the tube, which is what the band's thickness follows) at every voxel,
    float32, and its occupancy."""
    i, j, k = (np.arange(n, dtype=np.float32) - (n - 1) / 2 for n in shape)
    major = 0.3 * min(shape[1], shape[2])
    minor = 0.6 * major
    stretch = minor / (0.45 * shape[0])
    ring = np.hypot(j[:, None], k[None, :]) - major
    distance = np.hypot(stretch * i[:, None, None], ring[None]) - minor
    return distance.astype(np.float32), distance <= 0


def run_band(quick: bool = False) -> list[dict]:
    """Time the band's marching cubes on a torus across the dino's grid (a quarter of it
    each way, quick) against scikit-image's with the band's mask.

    Returns one row ``{name, seconds, baseline_seconds, ratio, notes}`` like :func:`run`."""
    shape = tuple(n // 4 for n in DINO_SHAPE) if quick else DINO_SHAPE
    distance, inside = torus_distance(shape)
    pad = 2
    voxels = band_voxel_indices(inside, 1)
    values = np.clip(distance[tuple(voxels.T)], -pad, pad)
    del distance
    volume = np.where(inside, np.float32(pad), np.float32(-pad)).astype(np.float32)
    volume[tuple(voxels.T)] = -values     # the band's volume, written out for scikit-image
    ordinal, m = crossing_edges(inside, voxels, values)
    crossings = np.random.default_rng(0).uniform(0.0, 1.0, m).astype(np.float32)
    cubes = np.zeros(shape, bool)
    for d in np.ndindex(2, 2, 2):
        ahead = voxels + d
        cubes[tuple(ahead[np.all(ahead < shape, axis=1)].T)] = True

    def ours():
        return march_band(inside, pad, voxels, -values, ordinal, crossings,
                          margin=_CROSSING_MARGIN)

    faces = len(ours()[1])      # numba compilation (cached on disk) is not timed
    baseline = best_of(lambda: measure.marching_cubes(volume, 0.0, allow_degenerate=False,
                                                      mask=cubes), 3)
    seconds = best_of(ours, 3)
    size = "x".join(map(str, shape))
    return [{"name": f"band marching cubes {size} torus ({faces} faces)",
             "seconds": seconds, "baseline_seconds": baseline, "ratio": baseline / seconds,
             "notes": [f"band marching cubes: {len(voxels)} band voxels of {inside.size}; "
                       "baseline scikit-image's marching cubes with the band's mask"]}]


if __name__ == "__main__":
    main(__doc__, run, run_hull_surface, run_band, quick_help="smaller grids")
