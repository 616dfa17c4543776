"""Carving speed: :func:`sfs_ros.core.carving.carve.carve` against a naive numpy baseline.

The object is torus-like: a ring of spheres, whose silhouette in any view is
computed per pixel (orthographic: union of discs; pinhole: union of ray-sphere
hits). The naive baseline projects every voxel centre into every view
(chunked); where the full run would take minutes it is measured at 256^3 on
one view and on a few, and extrapolated (cost per voxel + per voxel-view);
the output says which. Results are checked equal to the naive ones (except
rounding ties: voxel centres exactly on a pixel border).

Run: ``python -m bench.bench_carve`` (``--quick`` for the small cases only).
"""

from __future__ import annotations

import math
import time

import numpy as np

from sfs_ros.core.carving.carve import Carver, carve
from sfs_ros.core.geometry.grid import VoxelGrid
from sfs_ros.core.geometry.rig import RigCalibration, rig_camera

from .timing import main

RING_RADIUS_M = 0.10
SPHERE_RADIUS_M = 0.04
N_SPHERES = 24
BOX_HALF_M = 0.16
NAIVE_CHUNK = 1 << 21


def ring_of_spheres() -> tuple[np.ndarray, float]:
    """Sphere centres (N_SPHERES, 3) on a horizontal circle, and their radius, metres."""
    a = np.linspace(0.0, 2.0 * np.pi, N_SPHERES, endpoint=False)
    centres = np.stack([RING_RADIUS_M * np.cos(a), RING_RADIUS_M * np.sin(a),
                        np.zeros_like(a)], axis=1)
    return centres, SPHERE_RADIUS_M


def silhouette(camera, centres: np.ndarray, radius: float) -> np.ndarray:
    """(H, W) bool: pixels whose centre ray hits any of the spheres.

    Each sphere is tested only inside a pixel window around its projected
    centre (twice its projected radius for the pinhole model, ample for the
    fields of view used here).
    """
    H, W = camera.height, camera.width
    mask = np.zeros((H, W), dtype=bool)
    K_inv_R = np.linalg.inv(camera.K).T @ camera.R
    for c, (uc, vc) in zip(centres, camera.project(centres)):
        if camera.orthographic:
            r_px = radius * camera.K[0, 0]
        else:
            r_px = 2.0 * camera.K[0, 0] * radius / (camera.depth(c[None])[0] - radius)
        u0, u1 = max(0, int(uc - r_px) - 1), min(W, int(uc + r_px) + 2)
        v0, v1 = max(0, int(vc - r_px) - 1), min(H, int(vc + r_px) + 2)
        if u0 >= u1 or v0 >= v1:
            continue
        u, v = np.meshgrid(np.arange(u0, u1, dtype=np.float64),
                           np.arange(v0, v1, dtype=np.float64))
        if camera.orthographic:
            hit = (u - uc) ** 2 + (v - vc) ** 2 <= r_px ** 2
        else:
            rays = np.stack([u, v, np.ones_like(u)], axis=-1) @ K_inv_R
            rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
            w = c - camera.center
            along = rays @ w
            hit = (along > 0) & (w @ w - along ** 2 <= radius ** 2)
        mask[v0:v1, u0:u1] |= hit
    return mask


def rig_views(n_theta: int, phis_deg, calibration: RigCalibration):
    cams = [rig_camera(t, math.radians(p), calibration)
            for p in phis_deg for t in np.linspace(0, 2 * np.pi, n_theta, endpoint=False)]
    centres, radius = ring_of_spheres()
    return cams, [silhouette(c, centres, radius) for c in cams]


def naive_carve(grid: VoxelGrid, cameras, masks) -> np.ndarray:
    """Project every voxel centre into every view (chunks of NAIVE_CHUNK voxels)."""
    n = int(np.prod(grid.shape))
    out = np.empty(n, dtype=bool)
    for start in range(0, n, NAIVE_CHUNK):
        idx = np.stack(np.unravel_index(np.arange(start, min(n, start + NAIVE_CHUNK)),
                                        grid.shape), axis=1)
        pts = grid.index_to_world(idx)
        keep = np.ones(len(pts), dtype=bool)
        for cam, m in zip(cameras, masks):
            uv = cam.project(pts)  # NaN behind a pinhole camera: outside
            with np.errstate(invalid="ignore"):
                pu = np.floor(uv[:, 0] + 0.5)
                pv = np.floor(uv[:, 1] + 0.5)
            inside = (pu >= 0) & (pu < cam.width) & (pv >= 0) & (pv < cam.height)
            hit = np.ones(len(pts), dtype=bool)
            hit[inside] = m[pv[inside].astype(np.int64), pu[inside].astype(np.int64)]
            keep &= hit
        out[start:start + len(pts)] = keep
    return out.reshape(grid.shape)


def _best_time(fn, repeats: int) -> tuple[float, object]:
    best, result = math.inf, None
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - t0)
    return best, result


def _check_same(name, grid, cameras, masks, fast, naive) -> int:
    """Fast and naive must agree except where a voxel centre projects exactly
    onto a pixel border in some view (a tie the two round differently, the
    arithmetic order differing); returns the number of such voxels."""
    diff = np.argwhere(fast != naive)
    if len(diff):
        pts = grid.index_to_world(diff)
        tie = np.zeros(len(diff), dtype=bool)
        for cam in cameras:
            uv = cam.project(pts)
            tie |= np.any(np.abs(uv - np.floor(uv) - 0.5) < 1e-6, axis=1)
        if not tie.all():
            raise AssertionError(f"{name}: fast and naive carving differ at "
                                 f"{int((~tie).sum())} voxels that are not pixel-border ties")
    return len(diff)


def _grid(resolution: int) -> VoxelGrid:
    return VoxelGrid.cube([-BOX_HALF_M] * 3, [BOX_HALF_M] * 3, resolution)


def _case(name, grid, cams, masks, naive_views: int, repeats: int, notes: list) -> dict:
    carve(grid, cams[:2], masks[:2])  # compile / load the cached kernels
    seconds, occ = _best_time(lambda: carve(grid, cams, masks), repeats)
    n_vox = int(np.prod(grid.shape))
    if naive_views >= len(cams):
        baseline, ref = _best_time(lambda: naive_carve(grid, cams, masks), 1)
        ties = _check_same(name, grid, cams, masks, occ, ref)
        how = "measured"
    else:
        # Extrapolate from 256^3 runs on 1 and on naive_views views (spread over
        # the rig): time = per voxel (index set-up) + per voxel-view (projection).
        small = _grid(min(256, grid.shape[0]))
        step = len(cams) // naive_views
        sub_c, sub_m = cams[::step][:naive_views], masks[::step][:naive_views]
        t_one, _ = _best_time(lambda: naive_carve(small, sub_c[:1], sub_m[:1]), 1)
        t_few, ref = _best_time(lambda: naive_carve(small, sub_c, sub_m), 1)
        ties = _check_same(name, small, sub_c, sub_m, carve(small, sub_c, sub_m), ref)
        n_small = int(np.prod(small.shape))
        per_view = max(t_few - t_one, 0.0) / (naive_views - 1) / n_small
        per_voxel = max(t_one / n_small - per_view, 0.0)
        baseline = (per_voxel + per_view * len(cams)) * n_vox
        how = (f"extrapolated from 1 and {naive_views} views at {small.shape[0]}^3 "
               f"({t_one:.2f} s, {t_few:.2f} s: {per_voxel * 1e9:.0f} ns per voxel + "
               f"{per_view * 1e9:.0f} ns per voxel-view)")
    notes.append(f"{name}: naive baseline {how}; results identical except {ties} voxels "
                 "whose centre projects exactly onto a pixel border (rounding ties)")
    return {"name": name, "seconds": seconds, "baseline_seconds": baseline,
            "ratio": baseline / seconds, "occupied": int(occ.sum())}


def _incremental_case(notes: list) -> dict:
    """Carver.add_view, orthographic 512^2 views into 256^3: seconds per view."""
    name = "Carver.add_view 256^3, 512^2 orthographic (per view)"
    ortho = RigCalibration(width=512, height=512, projection="orthographic", fx=1400.0,
                           fy=1400.0)
    cams, masks = rig_views(36, (0, 20, 40, 60), ortho)
    grid = _grid(256)
    Carver(grid).add_view(cams[0], masks[0])  # compile / load the cached kernels
    carver = Carver(grid)
    t0 = time.perf_counter()
    for cam, mask in zip(cams, masks):
        carver.add_view(cam, mask)
    per_view = (time.perf_counter() - t0) / len(cams)
    baseline, ref = _best_time(lambda: naive_carve(grid, cams[:1], masks[:1]), 1)
    if not np.array_equal(carver.occupancy, carve(grid, cams, masks)):
        raise AssertionError(f"{name}: incremental and batch carving differ")
    notes.append(f"{name}: mean over {len(cams)} views; naive baseline: one view, all voxels, "
                 "measured")
    return {"name": name, "seconds": per_view, "baseline_seconds": baseline,
            "ratio": baseline / per_view, "occupied": int(carver.occupancy.sum())}


def run(quick: bool = False) -> list[dict]:
    """Benchmark rows: name, seconds (best of a few), baseline_seconds, ratio (+ notes)."""
    notes: list[str] = []
    rows = []
    few = 2 if quick else 8  # views the naive baseline runs on before extrapolating
    ortho = RigCalibration(width=512, height=512, projection="orthographic", fx=1400.0,
                           fy=1400.0)
    cams, masks = rig_views(36, (0, 20, 40, 60), ortho)  # 144 views
    rows.append(_case("orthographic 256^3 x 144 views 512^2", _grid(256), cams, masks,
                      naive_views=few, repeats=3, notes=notes))
    if not quick:
        rows.append(_case("orthographic 512^3 x 144 views 512^2", _grid(512), cams, masks,
                          naive_views=8, repeats=3, notes=notes))
    # Middlebury-like: 16 views of 640x480 on one ring, camera 1 m away.
    mid = RigCalibration(width=640, height=480, projection="pinhole", fx=900.0, fy=900.0,
                         camera_distance_m=1.0)
    cams, masks = rig_views(16, (30,), mid)
    rows.append(_case("pinhole 256^3 x 16 views 640x480", _grid(256), cams, masks,
                      naive_views=few if quick else 16, repeats=3, notes=notes))
    pin = RigCalibration(width=512, height=512, projection="pinhole", fx=1000.0, fy=1000.0,
                         camera_distance_m=0.8)
    cams, masks = rig_views(24, (0, 30, 60), pin)  # 72 views
    rows.append(_case("pinhole 256^3 x 72 views 512^2", _grid(256), cams, masks,
                      naive_views=few, repeats=3, notes=notes))
    rows.append(_incremental_case(notes))
    for row in rows:
        row["notes"] = [n for n in notes if n.startswith(row["name"])]
    return rows


if __name__ == "__main__":
    main(__doc__, run, quick_help="small cases only")
