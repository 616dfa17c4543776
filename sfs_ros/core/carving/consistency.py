"""Checks between the hull and the views: the hull's silhouette in each view, and a box too
small for the object.

:func:`hull_silhouettes` draws each occupied voxel's footprint into every
view (the fusion compares those with the masks). :func:`bbox_clips_object`
finds views whose foreground reaches outside the projection of the grid's
box: the box misses part of the object.
"""

from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np
from numba import njit, prange

from ..geometry.camera import Camera
from ..geometry.grid import VoxelGrid
from .carve import validate_masks, view_coefficients
from .hull import surface_voxels

__all__ = ["hull_silhouettes", "bbox_clips_object"]


@njit(parallel=True, cache=True, error_model="numpy")
def _splat(coef, voxels, heights, widths, offsets, out, half_max):
    """Paint the projected footprint (bounding box of its cube, at least the
    pixel of its centre) of each voxel whose centre lands inside the image into
    the flat images ``out``; records the largest footprint half-size per view
    in ``half_max``. A view's coefficients are read once, and a footprint's corners
    turned to whole pixels once, before its rows are painted."""
    for v in prange(heights.size):
        H = heights[v]
        W = widths[v]
        a00, a01, a02, a03 = coef[v, 0, 0], coef[v, 0, 1], coef[v, 0, 2], coef[v, 0, 3]
        a10, a11, a12, a13 = coef[v, 1, 0], coef[v, 1, 1], coef[v, 1, 2], coef[v, 1, 3]
        a20, a21, a22, a23 = coef[v, 2, 0], coef[v, 2, 1], coef[v, 2, 2], coef[v, 2, 3]
        hmax = 0.0
        for n in range(voxels.shape[0]):
            i = voxels[n, 0]
            j = voxels[n, 1]
            k = voxels[n, 2]
            h0 = ((a00 + i * a01) + j * a02) + k * a03
            h1 = ((a10 + i * a11) + j * a12) + k * a13
            h2 = ((a20 + i * a21) + j * a22) + k * a23
            if not h2 > 0.0:
                continue
            u = h0 / h2
            w = h1 / h2
            # Half-size of the footprint: |d(u, v)/d(index)| summed over axes / 2.
            hu = ((0.0 + abs(a01 - u * a21)) + abs(a02 - u * a22)) + abs(a03 - u * a23)
            hv = ((0.0 + abs(a11 - w * a21)) + abs(a12 - w * a22)) + abs(a13 - w * a23)
            hu *= 0.5 / h2
            hv *= 0.5 / h2
            hmax = max(hmax, hu, hv)
            cu = np.floor(u + 0.5)
            cw = np.floor(w + 0.5)
            if not (cu >= 0.0 and cu < W and cw >= 0.0 and cw < H):
                continue  # the view says nothing about voxels outside its image
            c0 = int(max(0.0, min(cu, np.ceil(u - hu))))
            c1 = int(min(W - 1.0, max(cu, np.floor(u + hu))))
            r0 = int(max(0.0, min(cw, np.ceil(w - hv))))
            r1 = int(min(H - 1.0, max(cw, np.floor(w + hv))))
            for r in range(r0, r1 + 1):
                row = offsets[v] + r * W
                for c in range(c0, c1 + 1):
                    out[row + c] = 1
        half_max[v] = hmax


def hull_silhouettes(grid: VoxelGrid, occupancy: np.ndarray,
                     cameras: Sequence[Camera]) -> tuple[list, np.ndarray]:
    """Project a voxel volume into each camera.

    Parameters
    ----------
    grid : VoxelGrid
    occupancy : (nx, ny, nz) bool
    cameras : sequence of n Camera

    Returns
    -------
    images : list of n (H, W) bool
        Pixels covered by the footprint (bounding box of the projected cube)
        of an occupied voxel whose centre projects inside the image.
    half_px : (n,) float64
        Largest footprint half-size per view, pixels.
    """
    occupancy = np.asarray(occupancy)
    if occupancy.shape != grid.shape:
        raise ValueError(f"occupancy has shape {occupancy.shape}, expected the grid's {grid.shape}")
    cameras = list(cameras)
    heights = np.array([c.height for c in cameras], np.int64)
    widths = np.array([c.width for c in cameras], np.int64)
    offsets = np.zeros(len(cameras), np.int64)
    offsets[1:] = np.cumsum(heights * widths)[:-1]
    flat = np.zeros(int(np.sum(heights * widths)), np.uint8)
    half = np.zeros(len(cameras))
    _splat(view_coefficients(grid, cameras), surface_voxels(occupancy), heights, widths,
           offsets, flat, half)
    images = [flat[o:o + h * w].reshape(h, w).view(bool)   # the 0/1 bytes, not a copy
              for o, h, w in zip(offsets, heights, widths)]
    return images, half


def bbox_clips_object(grid: VoxelGrid, cameras: Sequence[Camera], masks, *,
                      tolerance_px: float = 1.5, min_pixels: int = 1) -> list[int]:
    """Views with foreground outside the projection of the grid's box.

    Parameters
    ----------
    grid : VoxelGrid
    cameras : sequence of n Camera
    masks : sequence of n (H, W) bool (or 0/1)
    tolerance_px : float
        Foreground up to this far outside the projected box is ignored, pixels.
    min_pixels : int
        A view is reported when at least this many foreground pixels lie
        farther out.

    Returns
    -------
    list of int
        Indices of the views where the box misses part of the object. A
        pinhole view whose camera sits inside or beside the box (a corner at
        or behind the camera plane) cannot be judged and is not reported.
    """
    if tolerance_px < 0 or int(min_pixels) < 1:
        raise ValueError(f"tolerance_px must be >= 0 and min_pixels >= 1, got {tolerance_px}, "
                         f"{min_pixels}")
    cameras = list(cameras)
    masks = validate_masks(cameras, masks)
    lo, hi = grid.bounds_min, grid.bounds_max
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])])
    clipped = []
    for v, (cam, mask) in enumerate(zip(cameras, masks)):
        if not cam.orthographic and np.any(cam.depth(corners) <= 0):
            continue
        hull = cv2.convexHull(cam.project(corners).astype(np.float32))[:, 0, :].astype(np.float64)
        # Signed distance to each edge's line, positive outside (the hull's
        # orientation fixes the sign); outside the box = beyond any edge.
        edge = np.roll(hull, -1, axis=0) - hull
        normal = np.stack([edge[:, 1], -edge[:, 0]], axis=1)
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        centre = hull.mean(axis=0)
        normal *= np.sign(np.sum((hull - centre) * normal, axis=1))[:, None]
        offset = np.sum(hull * normal, axis=1)
        # The distance beyond an edge is largest at a corner of the foreground's
        # convex hull, which is a corner of its outer contours: when none of
        # those is out, no foreground pixel is.
        contours, _ = cv2.findContours(mask.view(np.uint8), cv2.RETR_EXTERNAL,
                                       cv2.CHAIN_APPROX_SIMPLE)
        if not contours:
            continue
        outline = np.concatenate(contours)[:, 0, :].astype(np.float64)
        if not np.any(outline @ normal.T - offset > tolerance_px):
            continue
        rows, cols = np.nonzero(mask)
        dist = np.stack([cols, rows], axis=1).astype(np.float64) @ normal.T - offset
        if int(np.sum(dist.max(axis=1) > tolerance_px)) >= int(min_pixels):
            clipped.append(v)
    return clipped
