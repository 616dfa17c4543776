"""Compiled inner loops of the photo-consistent refinement (:mod:`.photo`).

Plane sweep (Collins 1996) per reference pixel between the hull's front and back
surfaces, scored by normalised cross-correlation (NCC) of small patches against
neighbouring views; and the fusion of the confident depths into a truncated signed
distance (Curless and Levoy 1996) at the voxels inside the hull.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

#: Steps either side of the best depth that belong to its peak (:func:`_sweep_pixel`).
UNIQUE_STEPS = 3


@njit(cache=True, inline="always")
def _bilinear(image, u, v):
    """Bilinear value of ``image`` (H, W) float32 at pixel ``(u, v)``; NaN off the image."""
    height, width = image.shape
    if not (0.0 <= u <= width - 1.0 and 0.0 <= v <= height - 1.0):
        return np.nan
    i = min(int(u), width - 2)
    j = min(int(v), height - 2)
    fx, fy = u - i, v - j
    return ((image[j, i] * (1.0 - fx) + image[j, i + 1] * fx) * (1.0 - fy)
            + (image[j + 1, i] * (1.0 - fx) + image[j + 1, i + 1] * fx) * fy)


@njit(cache=True)
def _ncc(patch, rays, m, inv_depth, image, samples):
    """NCC of the reference ``patch`` (k,) (zero mean, unit norm) with the neighbour
    ``image`` sampled where the fronto-parallel plane at depth ``1 / inv_depth`` maps the
    patch's pixels: ``rays`` (k, 3) holds ``M x`` of each patch pixel ``x`` (homogeneous),
    so the sample is ``M x + m / depth``. -1 when a sample falls off the image or behind
    the camera; ``samples`` (k,) scratch."""
    k = patch.shape[0]
    mu, mv, mw = m[0] * inv_depth, m[1] * inv_depth, m[2] * inv_depth
    total = 0.0
    for s in range(k):
        hw = rays[s, 2] + mw
        if hw <= 0.0:
            return -1.0
        value = _bilinear(image, (rays[s, 0] + mu) / hw, (rays[s, 1] + mv) / hw)
        if math.isnan(value):
            return -1.0
        samples[s] = value
        total += value
    mean = total / k
    dot = 0.0
    norm = 0.0
    for s in range(k):
        q = samples[s] - mean
        dot += patch[s] * q
        norm += q * q
    return dot / math.sqrt(norm) if norm > 1e-6 else -1.0


@njit(cache=True)
def _reference_patch(image, r, c, offsets, patch):
    """Fill ``patch`` (k,) with the zero-mean, unit-norm values of ``image`` at
    ``(c, r) + offsets``; returns their standard deviation (grey levels), -1 off the image."""
    height, width = image.shape
    k = offsets.shape[0]
    total = 0.0
    for s in range(k):
        x, y = c + int(offsets[s, 0]), r + int(offsets[s, 1])
        if not (0 <= x < width and 0 <= y < height):
            return -1.0
        patch[s] = image[y, x]
        total += patch[s]
    mean = total / k
    norm = 0.0
    for s in range(k):
        patch[s] -= mean
        norm += patch[s] * patch[s]
    if norm <= 0.0:
        return 0.0
    for s in range(k):
        patch[s] /= math.sqrt(norm)
    return math.sqrt(norm / k)


@njit(cache=True)
def _score(patch, rays, ms, images, depth, best_of, samples, scores):
    """The score of one depth (metres): the mean of the ``best_of`` highest NCCs over the
    neighbours (``rays`` (n, k, 3), ``ms`` (n, 3), ``images`` (n, H', W')); ``scores``
    (n,) scratch."""
    for j in range(ms.shape[0]):
        scores[j] = _ncc(patch, rays[j], ms[j], 1.0 / depth, images[j], samples)
    scores.sort()
    score = 0.0
    for j in range(best_of):
        score += scores[scores.shape[0] - 1 - j]
    return score / best_of


@njit(cache=True)
def _sweep_pixel(patch, rays, ms, images, near, far, step, coarse, best_of, samples, scores):
    """Best depth (metres) on ``[near, far]`` for one reference pixel, its score
    (:func:`_score`) and the best score more than ``UNIQUE_STEPS`` steps of ``step`` from
    it (-1 if none).

    Coarse to fine: the ray is swept every ``coarse`` steps, then in steps of ``step``
    across the coarse steps either side of the best, and the best of those is refined by
    a parabola through it and its two neighbours."""
    wide = coarse * step
    count = int((far - near) / wide) + 1
    track = np.empty(count)
    at = 0
    for s in range(count):
        track[s] = _score(patch, rays, ms, images, near + s * wide, best_of, samples, scores)
        if track[s] > track[at]:
            at = s
    # A patch that matches as well elsewhere along the ray (a smooth ramp, a repeated
    # pattern) decides nothing: the rival is the best score away from the peak.
    rival = -1.0
    for s in range(count):
        if abs(s - at) * coarse > UNIQUE_STEPS:
            rival = max(rival, track[s])
    start = near + (at - 1) * wide
    fine = np.empty(2 * coarse + 1)
    best = 0
    for s in range(fine.shape[0]):
        depth = start + s * step
        fine[s] = (_score(patch, rays, ms, images, depth, best_of, samples, scores)
                   if near - step <= depth <= near + (count - 1) * wide + step else -2.0)
        if fine[s] > fine[best]:
            best = s
    best_depth = start + best * step
    if 0 < best < fine.shape[0] - 1 and fine[best - 1] > -2.0 and fine[best + 1] > -2.0:
        curvature = fine[best - 1] - 2.0 * fine[best] + fine[best + 1]
        if curvature < 0.0:
            best_depth += step * 0.5 * (fine[best - 1] - fine[best + 1]) / curvature
    return best_depth, fine[best], rival


@njit(parallel=True, cache=True)
def sweep_kernel(image, mask, front, back, offsets, Ms, ms, images, step, coarse, stride,
                 min_std, best_of, min_margin, depth_out, score_out):
    """Plane-sweep depth map of one reference view.

    ``image`` (H, W) float32 grey; ``mask`` (H, W) bool, pixels whose whole patch lies in
    the silhouette; ``front``, ``back`` (H, W) float64 depths of the hull's surfaces,
    metres (inf off the hull); ``offsets`` (k, 2) patch pixels; ``Ms`` (n, 3, 3), ``ms``
    (n, 3) homography parts of the ``n`` neighbours and ``images`` (n, H', W') float32
    their grey images; depths every ``step`` metres, first every ``coarse`` of them
    (:func:`_sweep_pixel`). Fills ``depth_out`` and ``score_out`` (H // stride + 1,
    W // stride + 1) at pixels ``(row * stride, col * stride)``: NaN depth where not swept
    (off the mask, or a patch flatter than ``min_std`` grey levels); score -1 where a
    depth more than ``UNIQUE_STEPS`` steps from the best scores within ``min_margin``
    of it.
    """
    rows, cols = depth_out.shape
    k = offsets.shape[0]
    n = Ms.shape[0]
    for rr in prange(rows):
        patch = np.empty(k)
        samples = np.empty(k)
        scores = np.empty(n)
        rays = np.empty((n, k, 3))
        for cc in range(cols):
            r, c = rr * stride, cc * stride
            depth_out[rr, cc] = np.nan
            score_out[rr, cc] = -1.0
            if r >= mask.shape[0] or c >= mask.shape[1] or not mask[r, c] \
                    or not np.isfinite(front[r, c]):
                continue
            if _reference_patch(image, r, c, offsets, patch) < min_std:
                continue
            for j in range(n):
                for s in range(k):
                    x, y = c + offsets[s, 0], r + offsets[s, 1]
                    for a in range(3):
                        rays[j, s, a] = Ms[j, a, 0] * x + Ms[j, a, 1] * y + Ms[j, a, 2]
            far = back[r, c] if np.isfinite(back[r, c]) else front[r, c]
            depth, score, rival = _sweep_pixel(
                patch, rays, ms, images, front[r, c], max(far, front[r, c]), step, coarse,
                best_of, samples, scores)
            depth_out[rr, cc] = depth
            score_out[rr, cc] = score if score - rival >= min_margin else -1.0


@njit(parallel=True, cache=True)
def fuse_kernel(points, projections, depths, rims, strides, truncation, rim_depth,
                min_views, sdf, weight):
    """Truncated signed distance (metres, positive in front of the surfaces seen) at
    ``points`` (n, 3) from depth maps ``depths`` (views, rows, cols) (NaN: no depth) taken
    by pinhole ``projections`` (views, 3, 4) at pixels ``(row, col) * strides[v]``.

    A view votes where the point lies in front of its depth or at most ``truncation``
    behind it: ``min(depth - z, truncation)``; ``sdf`` is the mean of the votes where at
    least ``min_views`` views vote (else NaN), ``weight`` their count. ``rims`` (views,
    rows, cols): the depth of the hull's front where the pixel lies on the rim of the
    view's silhouette (else inf); a point within ``rim_depth`` of it is where the
    silhouette says the surface is (a contour generator): its ``sdf`` is NaN, undecided.
    """
    rows, cols = depths.shape[1], depths.shape[2]
    for p in prange(points.shape[0]):
        x, y, z = points[p, 0], points[p, 1], points[p, 2]
        total = 0.0
        count = 0
        on_rim = False
        for v in range(projections.shape[0]):
            P = projections[v]
            w = P[2, 0] * x + P[2, 1] * y + P[2, 2] * z + P[2, 3]
            if w <= 0.0:
                continue
            col = int(math.floor((P[0, 0] * x + P[0, 1] * y + P[0, 2] * z + P[0, 3]) / w
                                 / strides[v] + 0.5))
            row = int(math.floor((P[1, 0] * x + P[1, 1] * y + P[1, 2] * z + P[1, 3]) / w
                                 / strides[v] + 0.5))
            if not (0 <= row < rows and 0 <= col < cols):
                continue
            if abs(w - rims[v, row, col]) <= rim_depth:
                on_rim = True
                break
            seen = depths[v, row, col]
            if math.isnan(seen) or seen - w < -truncation:
                continue
            total += min(seen - w, truncation)
            count += 1
        weight[p] = count
        sdf[p] = total / count if count >= min_views and not on_rim else np.nan
