"""Re-segmentation of a view with the hull of all views as a prior (multi-view consensus).

One view's segmentation sees one picture: an object whose colours reach the
frame joins the backdrop model, a cast shadow joins the object. The hull
carved from all views, projected into the view, says where the object can be:
:func:`resegment` runs a GrabCut (colour GMMs + graph cut) in mask mode on the
neighbourhood of that projection, where

* pixels inside the projection are *probable object*, and *sure object* where
  the view's first mask agrees deep inside it (by ``3 %`` of the object size);
* pixels outside it, up to a band ``_BAND_FRACTION`` of the object size
  wide (at least ``_BAND_MIN_PX``), are *probable backdrop* (the object
  could still be there if most views cut it);
* pixels beyond the band are *sure backdrop*, and so are those of a gap the view's
  first mask encloses (a see-through between two parts) that the projection leaves out
  too: the hull's miss tolerance forgives the view that sees through, so the projection
  covers most of such a gap, the object's model learns the gap's colour there, and the
  cut would fill the rest of it.

The colour models are learnt from these labels, not from the image border:
the object's colours come from where the views agree the object is, the
backdrop's from what surrounds it (plate, shadow, cloth), so neither a
backdrop that resembles part of the object far away nor an object touching
the frame misleads them. GrabCut runs at full resolution on the
neighbourhood when it holds at most ``_WORK_PIXELS`` pixels; a larger one is
cut on a reduced copy, where the colour models are learnt, then its outline
again at full size with those models frozen
(:func:`~sfs_ros.core.segmentation.band_cut.coarse_to_fine_grabcut`).

:func:`consensus_masks` leaves alone the views whose first mask is already
:func:`settled` on the hull's projection: with many views, most clean ones.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit

from ..carving.bounds import seen_by
from ..carving.carve import PreparedMasks, carve
from ..carving.consistency import hull_silhouettes
from ..carving.fusion import MIN_MEDIAN_IOU, deepest_cut_px, reference_misses
from ..geometry.camera import Camera
from ..geometry.grid import VoxelGrid
from ..mask_box import foreground_box
from ..metrics import silhouette_iou
from ..workers import map_in_threads
from .band_cut import coarse_to_fine_grabcut
from .segment import close_mask, fill_small_holes

__all__ = ["resegment", "settled", "Consensus", "consensus_masks"]

#: A view not settled on the hull is cut again with the prior of a hull that keeps a
#: voxel at most this fraction of the views miss (when more than the first hull's
#: tolerance): a whole ring of views can lose the same part the same way (the dark side
#: of an object next to its cast shadow, seen from above), which a miss or two does not
#: hold. Measured on the 48-view hostile hemisphere (test_hostile_hemisphere.py), mesh
#: IoU against the exact silhouettes, white / black: 0.890 / 0.969 with the first hull
#: (3 misses), 0.972 / 0.975 with 5 (this). A tolerance loosened for every view instead
#: (4: 0.928 / 0.974, 5: the same as this, 7: 0.975 / 0.973) unsettles clean views:
#: with 7, sfs-simulate (73 views) cut 34 views again instead of 7, for the same mesh
#: IoU, and its consensus took 3.6 s instead of 1.6 s.
_PRIOR_MISS_FRACTION = 0.1
#: GrabCut's working size (pixels of the neighbourhood), and iterations. Two iterations
#: found the masks of three (Middlebury rings, against their README masks: dino 0.9789
#: and 0.9782, temple 0.9546 and 0.9545); a smaller working copy lost the temple's
#: detail (40 000 pixels: 0.9467).
_WORK_PIXELS = 80_000
_ITERATIONS = 2
#: Width of the probable-backdrop band around the hull's projection, as a
#: fraction of the square root of the projection's area, and at least this
#: many pixels.
_BAND_FRACTION = 0.06
_BAND_MIN_PX = 4
#: Sure object: where the view's own mask and the projection agree, eroded by
#: this fraction of the square root of the projection's area.
_SURE_FRACTION = 0.03
#: Backdrop context around the band, as a fraction of the object size: the
#: backdrop colours GrabCut learns come from this ring.
_CONTEXT_FRACTION = 0.3
#: The result's closing radius (a fraction of the object size, bridges dark
#: cracks) and the largest hole filled (a fraction of its area), as the graph cut's.
_CLOSE_FRACTION = 0.02
_FILL_HOLES_FRACTION = 0.002
#: The view's first mask is kept within this fraction of the object size of the new one.
_EDGE_FRACTION = 0.01
#: A view is settled, and not re-segmented, when no part of its mask lies outside the
#: projection (beyond a pixel) and the projection reaches beyond the mask by at most
#: the voxel footprint plus this fraction of the object's radius (its own image, px).
_SETTLED_FRACTION = 0.03
_SETTLED_MIN_PX = 3.0
#: Chromaticity features: grey levels per unit of (difference / brightness),
#: and the brightness added below the division (grey levels).
_CHROMA_GAIN = 64.0
_DARK_FLOOR = 16.0


def _disk(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


def _dilated_by_disk(mask: np.ndarray, radius: int) -> np.ndarray:
    """``cv2.dilate(mask, _disk(radius))`` of (h, w) uint8 ``mask`` (0 or 1): the same (h, w)
    uint8 0 or 1, in time that does not grow with the radius (OpenCV's takes every pixel of
    the disk, about 3 radius^2 of them).

    The disk's rows are runs centred on its middle column. So a pixel is reached from the
    row ``k`` rows away when that row holds a mask pixel no farther along it than the
    half-width of the disk's ``k``-th row from the middle: each pixel's gap to the nearest
    mask pixel of its own row, then down and up the columns how far each gap reaches
    (:func:`_rows_reached`)."""
    return _dilate_kernel(np.ascontiguousarray(mask, np.uint8), _rows_reached(radius))


def _rows_reached(radius: int) -> np.ndarray:
    """(radius + 1,) int64: for a gap of ``g`` pixels along a row (0..radius), the most rows
    away from the middle a row of ``_disk(radius)`` at least ``g`` pixels wide each side is."""
    half_widths = _disk(radius).sum(axis=1) // 2
    rows_away = np.abs(np.arange(-radius, radius + 1))
    return np.array([rows_away[half_widths >= g].max() for g in range(radius + 1)], np.int64)


@njit(cache=True, nogil=True)
def _dilate_kernel(mask, reach):
    """:func:`_dilated_by_disk` of (h, w) uint8 ``mask`` with ``reach`` from
    :func:`_rows_reached`."""
    h, w = mask.shape
    radius = reach.shape[0] - 1
    far = 1 << 40
    gap = np.empty((h, w), np.int64)          # to the nearest mask pixel of the row
    for y in range(h):
        last = -far
        for x in range(w):
            if mask[y, x]:
                last = x
            gap[y, x] = x - last
        last = far
        for x in range(w - 1, -1, -1):
            if mask[y, x]:
                last = x
            gap[y, x] = min(gap[y, x], last - x)
    out = np.zeros((h, w), np.uint8)
    down = np.full(w, -far, np.int64)         # the last row reached from the rows above
    for y in range(h):
        for x in range(w):
            if gap[y, x] <= radius:
                down[x] = max(down[x], y + reach[gap[y, x]])
            if down[x] >= y:
                out[y, x] = 1
    up = np.full(w, far, np.int64)            # the first row reached from the rows below
    for y in range(h - 1, -1, -1):
        for x in range(w):
            if gap[y, x] <= radius:
                up[x] = min(up[x], y - reach[gap[y, x]])
            if up[x] <= y:
                out[y, x] = 1
    return out


def _features(rgb: np.ndarray) -> np.ndarray:
    """(h, w, 3) uint8 colours GrabCut models: brightness and two opponent
    chromaticities, each divided by the brightness plus ``_DARK_FLOOR``.

    A cast shadow is a darker backdrop of the same chromaticity, a shaded side
    of the object a darker object: in RGB both crowd near black, here they keep
    their hue apart (the floor keeps the noise of near-black pixels from
    turning into colour)."""
    return _features_kernel(np.ascontiguousarray(rgb), np.empty(rgb.shape, np.uint8))


@njit(cache=True, nogil=True)
def _features_kernel(rgb, out):
    """:func:`_features` of ``rgb`` (h, w, 3) uint8 into ``out``, a pixel at a time in
    float32: brightness ``(r + g + b) / 3``, ``128 + (r - g) s`` and
    ``128 + (b - (r + g) / 2) s`` with ``s = _CHROMA_GAIN / (brightness + _DARK_FLOOR)``,
    each rounded to the nearest integer (ties to even) and clipped to 0..255."""
    three, gain = np.float32(3.0), np.float32(_CHROMA_GAIN)
    floor, middle, half = np.float32(_DARK_FLOOR), np.float32(128.0), np.float32(0.5)
    low, high = np.float32(0.0), np.float32(255.0)
    for i in range(rgb.shape[0]):
        for j in range(rgb.shape[1]):
            r, g, b = np.float32(rgb[i, j, 0]), np.float32(rgb[i, j, 1]), np.float32(rgb[i, j, 2])
            brightness = (r + g + b) / three
            scale = gain / (brightness + floor)
            red_green = middle + (r - g) * scale
            blue_yellow = middle + (b - half * (r + g)) * scale
            out[i, j, 0] = np.uint8(min(max(np.rint(brightness), low), high))
            out[i, j, 1] = np.uint8(min(max(np.rint(red_green), low), high))
            out[i, j, 2] = np.uint8(min(max(np.rint(blue_yellow), low), high))
    return out


def resegment(rgb: np.ndarray, prior: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Re-decide the object in one view with the hull's projection as a prior.

    rgb : (H, W, 3) uint8, the view's image
    prior : (H, W) bool, the projection of the hull of all views into this view
    mask : (H, W) bool, the view's own first mask

    Returns (H, W) bool, the new mask (all False when the prior is empty).
    """
    h, w = rgb.shape[:2]
    prior = np.asarray(prior, bool)
    area = int(np.count_nonzero(prior))
    if area == 0:
        return np.zeros((h, w), bool)
    size = np.sqrt(area)
    band = max(_BAND_MIN_PX, int(round(_BAND_FRACTION * size)))
    context = band + int(round(_CONTEXT_FRACTION * size))
    x, y, bw, bh = cv2.boundingRect(prior.view(np.uint8))
    x0, y0 = max(0, x - context), max(0, y - context)
    x1, y1 = min(w, x + bw + context), min(h, y + bh + context)
    crop = _features(rgb[y0:y1, x0:x1])
    p = prior[y0:y1, x0:x1].view(np.uint8)
    m_full = np.asarray(mask, bool).view(np.uint8)
    m = m_full[y0:y1, x0:x1]
    labels = np.full(p.shape, cv2.GC_BGD, np.uint8)
    labels[_dilated_by_disk(p, band) > 0] = cv2.GC_PR_BGD
    labels[p > 0] = cv2.GC_PR_FGD
    every_hole_filled, _ = fill_small_holes(m, np.inf)
    labels[(p == 0) & (every_hole_filled > m)] = cv2.GC_BGD
    sure = max(1, int(round(_SURE_FRACTION * size)))
    labels[cv2.erode(p & m, _disk(sure)) > 0] = cv2.GC_FGD
    chosen = coarse_to_fine_grabcut(crop, labels, work_pixels=_WORK_PIXELS,
                                    iterations=_ITERATIONS)
    out = np.zeros((h, w), np.uint8)
    out[y0:y1, x0:x1] = chosen
    # The view's own full-resolution edge where it is the more inclusive (partly
    # covered pixels): near the new mask only, so far shadows and clutter stay out.
    edge = max(1, int(round(_EDGE_FRACTION * size)))
    out |= m_full & (cv2.dilate(out, _disk(edge)) > 0)
    out = close_mask(out, int(round(_CLOSE_FRACTION * size)))
    out, _ = fill_small_holes(out, _FILL_HOLES_FRACTION)
    return out.astype(bool)


@dataclass
class Consensus:
    """What :func:`consensus_masks` did.

    masks : n (H, W) bool, the masks to carve with (the first ones when not applied)
    applied : bool, whether the views were re-segmented
    reason : str, why not (None when applied)
    prior_iou : (n,) float, IoU of each view's first mask with the hull's projection
    resegmented : (n,) bool, the views re-segmented (the others were settled:
        :func:`settled`, or kept an alpha mask)
    added_px, removed_px : (n,) int, pixels the re-segmentation added to and
        removed from each view's first mask
    """

    masks: list
    applied: bool
    reason: str | None
    prior_iou: np.ndarray
    resegmented: np.ndarray
    added_px: np.ndarray
    removed_px: np.ndarray


def settled(prior: np.ndarray, mask: np.ndarray, footprint_px: float) -> bool:
    """Whether a view's first mask already is what the hull of all views says.

    prior : (H, W) bool, the hull's projection; mask : (H, W) bool, the first
    mask; footprint_px : half the size of the hull's voxels in the image, px.

    Settled: no blob of the mask (wider than a pixel) lies outside the projection
    dilated by a pixel, and no pixel of the projection lies farther from the mask
    than the footprint plus ``_SETTLED_FRACTION`` of the projection's radius. The
    re-segmentation could move such a mask by no more than that; a shadow, clutter
    or a part missed shows as a deeper difference. With few views the tolerant hull
    sticks out of the object by whole facets, so nearly every view is re-segmented.
    Decided on the box around both widened by 2 pixels: beyond it both are empty, so a
    3 x 3 dilation of the prior and a 3 x 3 opening of the mask outside it read nothing
    else, and the distances from the mask are taken over the same box of both as on the
    whole frame (:func:`~sfs_ros.core.carving.fusion.deepest_cut_px`).
    """
    box = foreground_box(prior, mask, margin_px=2)
    if box is None:
        return True     # nothing projected, nothing in the mask
    prior, mask = prior[box], mask[box]
    prior8 = prior.view(np.uint8)
    outside = mask.view(np.uint8) & (cv2.dilate(prior8, np.ones((3, 3), np.uint8)) == 0)
    if cv2.morphologyEx(outside, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)).any():
        return False
    radius = np.sqrt(np.count_nonzero(prior) / np.pi)
    tolerance = max(_SETTLED_MIN_PX, footprint_px + 1.0) + _SETTLED_FRACTION * radius
    return deepest_cut_px(mask, prior) <= tolerance


def _prior(grid: VoxelGrid, cameras: list, prepared: PreparedMasks, misses: int,
           into: Sequence[int]) -> tuple[list, np.ndarray]:
    """Projections into the views ``into`` (indices; (H, W) bool each) and their footprint
    half-sizes (px) of the hull that keeps the voxels at most ``misses`` of the views
    miss, of those more views see."""
    hull = carve(grid, cameras, prepared, max_misses=misses) & seen_by(grid, cameras, misses + 1)
    return hull_silhouettes(grid, hull, [cameras[n] for n in into])


def consensus_masks(grid: VoxelGrid, cameras: Sequence[Camera], masks: Sequence[np.ndarray],
                    read_rgb: Callable[[int], np.ndarray | None], *,
                    prepared: PreparedMasks | None = None) -> Consensus:
    """Re-segment the views with the projection of the hull the others agree on.

    grid : VoxelGrid of the hull (coarse is enough: the prior only has to
        hold the object; its footprint widens the projection)
    cameras : n Camera; masks : n (H, W) bool, the views' first masks
    read_rgb : view index -> its (H, W, 3) uint8 RGB image, or None to keep
        that view's mask (e.g. an alpha mask, exact already)
    prepared : the masks' carving tables when the caller has them (else built here)

    The hull tolerates one miss per voxel more than the fusion's reference
    hull (:func:`~sfs_ros.core.carving.fusion.reference_misses`): it is only a
    prior, where a part lost by a few views (an object touching the frame, a
    shaded side next to its shadow) must stay for GrabCut to find again; a
    voxel seen by too few views to be judged is left out. A view whose first
    mask is :func:`settled` on that hull is kept as it is (neither read nor cut
    again). The others are cut again with the prior of a hull that tolerates
    misses by a tenth of the views, when that is more (``_PRIOR_MISS_FRACTION``):
    a whole ring of views can lose the same part. When
    the views do not agree on one object (median IoU of a first mask with the
    projection below :data:`~sfs_ros.core.carving.fusion.MIN_MEDIAN_IOU`: a
    calibration that does not fit), nothing is re-segmented: the masks must
    not be bent to a wrong hull, and the fusion names the error.
    """
    cameras = list(cameras)
    k = reference_misses(len(cameras)) + 1
    prepared = prepared or PreparedMasks(cameras, masks)
    projections, footprint_px = _prior(grid, cameras, prepared, k, range(len(cameras)))
    prior_iou = np.array(list(map_in_threads(
        lambda n: silhouette_iou(projections[n], masks[n]), range(len(masks)))))
    zeros = np.zeros(len(masks), np.int64)
    median = float(np.median(prior_iou))
    if median < MIN_MEDIAN_IOU:
        return Consensus(list(masks), False,
                         f"the views do not agree on one object (median IoU of a mask with "
                         f"the hull's projection {median:.2f}, below {MIN_MEDIAN_IOU})",
                         prior_iou, zeros.astype(bool), zeros, zeros)

    unsettled = [n for n, done in enumerate(map_in_threads(
        lambda n: settled(projections[n], masks[n], footprint_px[n]), range(len(masks))))
        if not done]
    loose = round(_PRIOR_MISS_FRACTION * len(cameras))
    if unsettled and loose > k:
        for n, projection in zip(unsettled, _prior(grid, cameras, prepared, loose, unsettled)[0]):
            projections[n] = projection

    def one_view(n: int) -> tuple[np.ndarray, int, int] | None:
        """View ``n`` cut again, and how many pixels the cut added to and removed from its
        first mask."""
        rgb = read_rgb(n)
        if rgb is None:
            return None
        new = resegment(rgb, projections[n], masks[n])
        return new, np.count_nonzero(new & ~masks[n]), np.count_nonzero(masks[n] & ~new)

    out, added, removed = list(masks), zeros.copy(), zeros.copy()
    resegmented = np.zeros(len(masks), bool)
    for n, found in zip(unsettled, map_in_threads(one_view, unsettled)):   # views side by side
        if found is not None:
            out[n], added[n], removed[n] = found
            resegmented[n] = True
    return Consensus(out, True, None, prior_iou, resegmented, added, removed)
