"""Signed distance to the visual hull, for meshing below the voxel scale.

Carving decides each voxel by one pixel per view, so a surface made from the
0/1 occupancy can only sit on voxel faces: flat faces at an angle to the grid
come out as terraces, curved ones as ridges. The silhouettes themselves know
the surface to a fraction of a pixel, and this module asks them.

Per view, the mask's signed distance transform (pixels, positive outside) is
sampled bilinearly at a point's projection and turned into metres by the
pixel size at the point's depth (pinhole: ``depth / f``; orthographic:
``1 / f``). A point is inside the hull only if it is inside every silhouette,
so the hull's value is the largest of the views' values (with ``max_misses = k``,
like the carver, the (k+1)-th largest: k views may disagree). Its zero level is
the hull surface; near it the value approximates the distance to the surface
(exactly for a surface seen edge-on by the deciding view, which is where a
visual hull's surface lies).

The mask's boundary is taken half-way between a foreground and a background
pixel centre, the boundary of the carver's pixel test (nearest pixel centre):
each pixel gets ``-(distance to the nearest background pixel centre - 1/2)``
inside and ``+(distance to the nearest foreground pixel centre - 1/2)``
outside. Bilinear sampling puts the zero exactly on pixel edges along a
straight row or column and cuts the corners of a pixel staircase (a 45-degree
edge comes out straight); an edge at a shallow angle to the pixel rows keeps
its half-pixel steps, which is all a binary mask tells of it.

A mask given with its coverage (an image's alpha channel, antialiased: the
fraction of each pixel the object covers) knows its boundary to a fraction of
a pixel: each boundary pixel's coverage and the direction of its gradient
place the edge through it (Gustavson and Strand's anti-aliased distance
transform, 2011), and the pixels around move with the nearest of them.
Without it the hull is biased inward: each view's binary boundary lies up to
half a pixel inside the true silhouette somewhere along a slanted edge, and
the hull keeps only what every view keeps.

A view on which a point projects outside the image (or behind a pinhole
camera) knows nothing about it, as for the carver (``outside_image="keep"``);
the carving box bounds the hull too (its signed distance joins the views').
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np
from numba import njit, prange

from ..carving.carve import validate_masks
from ..geometry.camera import Camera
from ..mask_box import foreground_box
from ..workers import map_in_threads

__all__ = ["DistanceImages", "HullDistance", "ZeroTrace", "point_groups"]

#: Pixels kept around each silhouette's bounding box in the stored distance
#: image; beyond them a lower bound of the outside distance is used (see
#: ``_sample``), which changes nothing near the zero level.
CROP_MARGIN_PX = 8
#: Distances are clipped to this many pixels (a mask filling its whole crop
#: has no boundary, and OpenCV then reports ~1.8e19).
MAX_DISTANCE_PX = 1.0e6
#: A boundary pixel's centre stays at least this far on its side of the edge its
#: coverage places, pixels: the mask decides every pixel centre (as the carver's
#: pixel test does), the coverage only where between them the edge runs. Half a
#: pixel would be the binary mask's own edge; none would leave a pixel half covered
#: (its centre on the edge) to chance.
_DECIDED_MARGIN_PX = 0.25
#: Pixels this far (or nearer) from a pixel the edge crosses move with it; farther
#: ones keep their distance (the zero level lies within a pixel of those pixels).
_COVERAGE_REACH_PX = 2.0
#: How much the coverage of a mask (:func:`_coverage_correction`) moves its
#: distance image at most, from one pixel to another, pixels: a boundary pixel
#: moves by at most half a pixel either way.
_COVERAGE_SLACK_PX = 1.0
#: Samples along each line in :meth:`HullDistance.project`, each side of the
#: point, that find the crossing; then bisections that place it (the bilinear,
#: max-of-views distance has kinks, where regula falsi is no faster).
_SEARCH_STEPS = 4
_BISECTIONS = 20


def _silhouette_distance(mask: np.ndarray,
                         coverage: np.ndarray | None = None) -> tuple[np.ndarray, int, int]:
    """Signed distance image of one mask, cropped around the foreground.

    Parameters
    ----------
    mask : (H, W) bool
    coverage : (H, W) uint8 (0..255) or float (0..1), or None
        The fraction of each pixel the object covers (the mask's antialiased
        alpha): places the boundary within the pixels along it
        (:func:`_coverage_correction`). None: half-way between pixel centres.

    Returns
    -------
    distance : (h, w) float32
        Pixels, positive outside the silhouette, zero half-way between a
        foreground and a background pixel centre; covers the foreground's
        bounding box grown by ``CROP_MARGIN_PX`` (clipped to the image).
    u0, v0 : int
        Column and row of the crop's first pixel in the image.
    """
    box = foreground_box(mask, margin_px=CROP_MARGIN_PX)
    if box is None:
        raise ValueError("a mask is empty: an empty silhouette bounds no hull "
                         "(reject the view before meshing)")
    (v0, v1), (u0, u1) = ((part.start, part.stop) for part in box)
    # At least 2 x 2 pixels, so that bilinear sampling always has four.
    crop = np.pad(mask[v0:v1, u0:u1], ((0, max(0, 2 - (v1 - v0))), (0, max(0, 2 - (u1 - u0)))),
                  mode="edge").view(np.uint8)
    # OpenCV measures to the nearest zero pixel; pixels beyond the image are not
    # zero, so a silhouette cut by the image border has no boundary there.
    inside = cv2.distanceTransform(crop, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    outside = cv2.distanceTransform(1 - crop, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    distance = np.clip(np.where(crop.astype(bool), 0.5 - inside, outside - 0.5),
                       -MAX_DISTANCE_PX, MAX_DISTANCE_PX).astype(np.float32)
    if coverage is not None:
        covered = np.asarray(coverage[v0:v1, u0:u1], dtype=np.float32)
        if coverage.dtype == np.uint8:
            covered /= np.float32(255.0)
        covered = np.pad(covered, ((0, crop.shape[0] - (v1 - v0)),
                                   (0, crop.shape[1] - (u1 - u0))), mode="edge")
        distance += _coverage_correction(distance, crop.astype(bool), covered)
    return distance, u0, v0


@njit(cache=True)
def _edge_distances(coverage, gx, gy, rows, cols, out):
    """``out[k]``: signed distance (pixels, positive outside) from the centre of pixel
    ``(rows[k], cols[k])`` to the straight edge that covers ``coverage`` of it with its
    normal along the coverage gradient ``(gx, gy)`` (Gustavson and Strand's ``edgedf``:
    linear in the coverage where the edge crosses the pixel's middle, quadratic where it
    cuts a corner)."""
    for k in range(rows.size):
        a = min(max(coverage[rows[k], cols[k]], 0.0), 1.0)
        x, y = abs(gx[rows[k], cols[k]]), abs(gy[rows[k], cols[k]])
        if x == 0.0 or y == 0.0:
            out[k] = 0.5 - a  # an edge along the pixel rows or columns (or no gradient)
            continue
        length = math.sqrt(x * x + y * y)
        x, y = max(x, y) / length, min(x, y) / length
        corner = 0.5 * y / x  # the coverage where the edge leaves the pixel's corner
        if a < corner:
            out[k] = 0.5 * (x + y) - math.sqrt(2.0 * x * y * a)
        elif a < 1.0 - corner:
            out[k] = (0.5 - a) * x
        else:
            out[k] = -0.5 * (x + y) + math.sqrt(2.0 * x * y * (1.0 - a))


def _coverage_correction(distance: np.ndarray, inside: np.ndarray,
                         coverage: np.ndarray) -> np.ndarray:
    """(h, w) float32, pixels, to add to ``distance`` (the binary mask ``inside``'s signed
    distance image) for the edge the ``coverage`` (h, w, in [0, 1]) places.

    The mask's boundary pixels (a 4-neighbour on the other side) that the edge
    crosses (coverage strictly between 0 and 1) get the distance
    :func:`_edge_distances` gives them, kept on their side of the mask; every pixel
    within ``_COVERAGE_REACH_PX`` of one moves by as much as the nearest did (a fully
    covered or empty pixel beside it knows no more than that the edge is not in it).
    The move lies in [-1/2, 1/2] pixel (:data:`_COVERAGE_SLACK_PX`).
    """
    cross = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
    mask = inside.view(np.uint8)
    alpha = np.ascontiguousarray(coverage, dtype=np.float32)
    crossed = (cv2.dilate(mask, cross) != cv2.erode(mask, cross)) & (alpha > 0) & (alpha < 1)
    rows, cols = np.nonzero(crossed)
    if rows.size == 0:
        return np.zeros_like(distance)
    edge = np.empty(rows.size, np.float32)
    _edge_distances(alpha, cv2.Sobel(alpha, cv2.CV_32F, 1, 0, ksize=3),
                    cv2.Sobel(alpha, cv2.CV_32F, 0, 1, ksize=3), rows, cols, edge)
    edge = np.where(inside[rows, cols], np.minimum(edge, -_DECIDED_MARGIN_PX),
                    np.maximum(edge, _DECIDED_MARGIN_PX))
    move = np.clip(edge - distance[rows, cols], -0.5 * _COVERAGE_SLACK_PX,
                   0.5 * _COVERAGE_SLACK_PX)
    reach, nearest = cv2.distanceTransformWithLabels(
        (~crossed).view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5,
        labelType=cv2.DIST_LABEL_PIXEL)
    by_label = np.zeros(int(nearest.max()) + 1, np.float32)
    by_label[nearest[rows, cols]] = move
    return np.where(reach <= _COVERAGE_REACH_PX, by_label[nearest], np.float32(0.0))


class DistanceImages:
    """Silhouettes' signed distance images (:func:`_silhouette_distance`), kept by content.

    A scan received view by view computes each mask's image on arrival, while the
    rig moves; :class:`HullDistance` given this store then finds them instead of
    computing them again. Any mask is found by what it holds (its packed bits), so a
    mask that was changed since (undistorted, repaired) is computed anew: the
    same images either way.

    Memory per mask kept: its packed bits (1 bit per pixel) and its distance
    image (float32, the silhouette's bounding box plus ``CROP_MARGIN_PX``).
    """

    def __init__(self):
        self._kept: dict[bytes, tuple[np.ndarray, int, int]] = {}

    def __len__(self) -> int:
        return len(self._kept)

    @staticmethod
    def _key(mask: np.ndarray) -> bytes:
        return repr(mask.shape).encode() + np.packbits(mask, axis=None).tobytes()

    def add(self, mask) -> None:
        """Compute and keep the distance image of ``mask`` (H, W) bool; ValueError if it
        is empty."""
        mask = np.asarray(mask, dtype=bool)
        key = self._key(mask)
        if key not in self._kept:
            self._kept[key] = _silhouette_distance(mask)

    def get(self, mask: np.ndarray) -> tuple[np.ndarray, int, int]:
        """What :func:`_silhouette_distance` returns for ``mask`` (H, W) bool: kept, else
        computed now (and not kept)."""
        found = self._kept.get(self._key(mask))
        return found if found is not None else _silhouette_distance(mask)


@njit(cache=True, inline="always")
def _sample(images, offset, width, height, u0, v0, margin, u, v):
    """Bilinear value (pixels) of one cropped distance image at image point ``(u, v)``."""
    x = u - u0
    y = v - v0
    # Outside the crop: the distance to the crop's outer pixel centres plus
    # ``margin`` (the distance from them to the silhouette's bounding box,
    # whose edges lie half a pixel beyond its outer pixel centres) bounds the
    # distance to the silhouette from below.
    if x < 0.0 or y < 0.0 or x > width - 1 or y > height - 1:
        dx = max(0.0, -x, x - (width - 1))
        dy = max(0.0, -y, y - (height - 1))
        return margin + math.sqrt(dx * dx + dy * dy)
    i = min(int(x), width - 2)
    j = min(int(y), height - 2)
    fx = x - i
    fy = y - j
    k = offset + j * width + i
    a = images[k]
    b = images[k + 1]
    c = images[k + width]
    d = images[k + width + 1]
    return (a * (1.0 - fx) + b * fx) * (1.0 - fy) + (c * (1.0 - fx) + d * fx) * fy


@njit(cache=True, inline="always")
def _pixel(proj, orthographic, v, x, y, z):
    """``(u, v, depth)``: the pixel of the point ``(x, y, z)`` in view ``v`` and its depth
    (metres; 1 in an orthographic view, whose pixel size does not change with it). A
    depth <= 0 is behind a pinhole camera: no pixel (u, v are not divided)."""
    # (indexed in place: a view of ``proj`` per point and view costs a reference count)
    hu = proj[v, 0, 0] * x + proj[v, 0, 1] * y + proj[v, 0, 2] * z + proj[v, 0, 3]
    hv = proj[v, 1, 0] * x + proj[v, 1, 1] * y + proj[v, 1, 2] * z + proj[v, 1, 3]
    if orthographic[v]:
        return hu, hv, 1.0
    depth = proj[v, 2, 0] * x + proj[v, 2, 1] * y + proj[v, 2, 2] * z + proj[v, 2, 3]
    if depth <= 0.0:
        return hu, hv, depth
    return hu / depth, hv / depth, depth


@njit(cache=True, inline="always")
def _view_numbers(hull, v):
    """View ``v``'s numbers for :func:`_value_in_view`, read once for a run of points (so
    that they stay in registers): its projection's rows, whether it is orthographic, its
    metres a pixel at depth 1, its image size and its distance image's crop."""
    proj, orthographic, metres_per_px, image_size, crops = \
        hull[0], hull[1], hull[2], hull[3], hull[4]
    return (proj[v, 0, 0], proj[v, 0, 1], proj[v, 0, 2], proj[v, 0, 3],
            proj[v, 1, 0], proj[v, 1, 1], proj[v, 1, 2], proj[v, 1, 3],
            proj[v, 2, 0], proj[v, 2, 1], proj[v, 2, 2], proj[v, 2, 3],
            orthographic[v], metres_per_px[v], image_size[v, 0], image_size[v, 1],
            crops[v, 0], crops[v, 1], crops[v, 2], crops[v, 3], crops[v, 4])


@njit(cache=True, inline="always")
def _value_in_view(view, images, margin, x, y, z):
    """Signed distance (metres) of the point ``(x, y, z)`` to the silhouette cone of the
    view whose :func:`_view_numbers` are ``view``; -inf where the view knows nothing of
    the point (behind it, or outside its image)."""
    a00, a01, a02, a03, a10, a11, a12, a13, a20, a21, a22, a23, orthographic, per_px, \
        width, height, offset, crop_w, crop_h, u0, v0 = view
    hu = a00 * x + a01 * y + a02 * z + a03
    hv = a10 * x + a11 * y + a12 * z + a13
    depth = 1.0          # an orthographic view's pixel size does not change with depth
    if not orthographic:
        depth = a20 * x + a21 * y + a22 * z + a23
        if depth <= 0.0:
            return -np.inf
        hu = hu / depth
        hv = hv / depth
    # The carver's pixel is floor(u + 1/2): inside the image for u in [-1/2, W - 1/2).
    if not (-0.5 <= hu < width - 0.5 and -0.5 <= hv < height - 0.5):
        return -np.inf
    # Within the outer half pixel, the edge pixel's value holds.
    hu = min(max(hu, 0.0), width - 1.0)
    hv = min(max(hv, 0.0), height - 1.0)
    return per_px * depth * _sample(images, offset, crop_w, crop_h, u0, v0, margin, hu, hv)


@njit(cache=True, inline="always")
def _view_value(hull, v, x, y, z):
    """:func:`_value_in_view` of view ``v`` at the point ``(x, y, z)``."""
    return _value_in_view(_view_numbers(hull, v), hull[5], hull[6], x, y, z)


@njit(cache=True, inline="always")
def _keep_largest(top, p, value):
    """Insert ``value`` into row ``p`` of ``top`` (n, rank) float64: the largest values so
    far, descending."""
    slot = top.shape[1] - 1
    if value > top[p, slot]:
        while slot > 0 and top[p, slot - 1] < value:
            top[p, slot] = top[p, slot - 1]
            slot -= 1
        top[p, slot] = value


@njit(cache=True, inline="always")
def _add_view(hull, v, points, first, stop, top):
    """Insert view ``v``'s value (:func:`_view_value`) at ``points[p]`` into row ``p`` of
    ``top`` (:func:`_keep_largest`) for ``p`` in ``first:stop``, the view's numbers read
    once for the points (where they stay in registers beside the writes to ``top``)."""
    view, images, margin = _view_numbers(hull, v), hull[5], hull[6]
    for p in range(first, stop):
        _keep_largest(top, p, _value_in_view(view, images, margin,
                                             points[p, 0], points[p, 1], points[p, 2]))


@njit(cache=True, inline="always")
def _box_value(hull, x, y, z):
    """Signed distance (metres, Chebyshev) of ``(x, y, z)`` to the carving box."""
    box_lo, box_hi = hull[7], hull[8]
    return max(box_lo[0] - x, x - box_hi[0], box_lo[1] - y, y - box_hi[1],
               box_lo[2] - z, z - box_hi[2])


@njit(cache=True)
def _distance_at(hull, x, y, z, top, p):
    """Signed distance (metres) of the point ``(x, y, z)`` to the hull (see the module doc).

    ``hull`` is :attr:`HullDistance._kernel_data`; row ``p`` of ``top`` (n, rank)
    float64 is scratch for the ``rank`` largest view values.
    """
    top[p] = -np.inf
    for v in range(hull[0].shape[0]):
        _keep_largest(top, p, _view_value(hull, v, x, y, z))
    return max(top[p, top.shape[1] - 1], _box_value(hull, x, y, z))


#: Points per block of :func:`_distance_kernel`: a block goes through the views one
#: at a time, so that neighbouring points read neighbouring pixels of one distance
#: image (point by point, every view's image passes through the cache).
_BLOCK_POINTS = 16384


@njit(parallel=True, cache=True)
def _distance_kernel(hull, points, top, out):
    """``out[p]``: signed distance (metres) of ``points[p]``; ``top`` (n, rank) scratch.

    The same values as :func:`_distance_at` point by point (a largest value does not
    depend on the order it is looked for in), in blocks of ``_BLOCK_POINTS``.
    """
    n = points.shape[0]
    for b in prange((n + _BLOCK_POINTS - 1) // _BLOCK_POINTS):
        start = b * _BLOCK_POINTS
        stop = min(n, start + _BLOCK_POINTS)
        top[start:stop] = -np.inf
        for v in range(hull[0].shape[0]):
            _add_view(hull, v, points, start, stop, top)
        for p in range(start, stop):
            out[p] = max(top[p, top.shape[1] - 1],
                         _box_value(hull, points[p, 0], points[p, 1], points[p, 2]))


#: With a floor (:meth:`HullDistance.__call__`), points go in cubic groups this many
#: floors deep on a side: a group is small enough for most views to see all of it deep
#: inside their silhouette, large enough that testing that costs little per point.
_GROUP_FLOORS = 4.0
#: Largest slope of a distance image (:func:`_below_floor`), pixels per pixel: sqrt(2)
#: for exact pixel values, with room for their float32 rounding (6e-8 of a value).
_MAX_SLOPE = 1.5


@njit(cache=True, inline="always")
def _below_floor(hull, v, lo, hi, floor):
    """Whether view ``v``'s value (:func:`_view_value`) is below ``floor`` (metres, < 0) at
    every point of the box ``[lo, hi]`` (metres): False when that is not certain.

    The distance image is interpolated bilinearly from pixel values whose
    4-neighbours differ by at most 1 px, so it changes by at most sqrt(2) px per
    pixel moved (:data:`_MAX_SLOPE`), plus the view's slack (a mask's coverage moves
    its pixels by different amounts, :data:`_COVERAGE_SLACK_PX`). The box projects
    into the convex hull of its corners' projections (all in front of the camera), so
    no point of it projects farther from the centre's projection than a corner does;
    and no point is nearer the camera than the nearest corner. A point that projects
    outside the image has the value -inf.
    """
    proj, orthographic, metres_per_px, image_size = hull[0], hull[1], hull[2], hull[3]
    width, height = image_size[v, 0], image_size[v, 1]
    uc, vc, nearest = _pixel(proj, orthographic, v, 0.5 * (lo[0] + hi[0]),
                             0.5 * (lo[1] + hi[1]), 0.5 * (lo[2] + hi[2]))
    if nearest <= 0.0 or not (-0.5 <= uc < width - 0.5 and -0.5 <= vc < height - 0.5):
        return False
    reach = 0.0
    for corner in range(8):
        u, w, depth = _pixel(proj, orthographic, v, hi[0] if corner & 1 else lo[0],
                             hi[1] if corner & 2 else lo[1], hi[2] if corner & 4 else lo[2])
        if depth <= 0.0:
            return False
        nearest = min(nearest, depth)
        reach = max(reach, math.sqrt((u - uc) ** 2 + (w - vc) ** 2))
    crops, images, margin = hull[4], hull[5], hull[6]
    centre = _sample(images, crops[v, 0], crops[v, 1], crops[v, 2], crops[v, 3], crops[v, 4],
                     margin, min(max(uc, 0.0), width - 1.0), min(max(vc, 0.0), height - 1.0))
    bound = centre + _MAX_SLOPE * reach + hull[9][v]
    return bound < 0.0 and metres_per_px[v] * nearest * bound < floor


@njit(cache=True, inline="always")
def _group_largest(hull, points, first, stop, floor, top):
    """Insert the views' values at ``points[first:stop]`` into rows ``first:stop`` of
    ``top`` (:func:`_keep_largest`), but those of a view below ``floor`` over the
    points' box (:func:`_below_floor`), which change nothing in rows that start at
    ``floor`` or above."""
    lo = np.empty(3)
    hi = np.empty(3)
    for axis in range(3):
        lo[axis] = points[first:stop, axis].min()
        hi[axis] = points[first:stop, axis].max()
    for v in range(hull[0].shape[0]):
        if not _below_floor(hull, v, lo, hi, floor):
            _add_view(hull, v, points, first, stop, top)


@njit(cache=True, inline="always")
def _floored_value(hull, x, y, z, top, p, floor):
    """The signed distance of ``(x, y, z)`` or ``floor``, whichever is larger, from row
    ``p`` of ``top``: the ``rank`` largest view values, started at ``floor``."""
    return max(top[p, top.shape[1] - 1], _box_value(hull, x, y, z), floor)


@njit(parallel=True, cache=True)
def _floored_kernel(hull, points, order, starts, floor, top, out):
    """``out[p]``: the signed distance of ``points[p]`` or ``floor``, whichever is larger.

    The points come group by group, group ``g`` the points ``order[starts[g]:starts[g +
    1]]`` (each group's copied together, not the whole array in their order). A view
    whose value is below ``floor`` over a group's box (:func:`_below_floor`) is not
    evaluated there. The ``rank`` largest values start as ``floor`` (``top`` (n, rank)
    scratch, in the groups' order): the ``rank``-th largest of the views evaluated and
    ``rank`` floors is the ``rank``-th largest of all views, or ``floor`` if that is lower
    (the views left out are all below ``floor``).
    """
    for g in prange(starts.shape[0] - 1):
        first, stop = starts[g], starts[g + 1]
        at = np.empty((stop - first, 3))
        for q in range(first, stop):
            for axis in range(3):
                at[q - first, axis] = points[order[q], axis]
        rows = top[first:stop]
        rows[:] = floor
        _group_largest(hull, at, 0, stop - first, floor, rows)
        for q in range(stop - first):
            out[order[first + q]] = _floored_value(hull, at[q, 0], at[q, 1], at[q, 2], rows,
                                                   q, floor)


@njit(parallel=True, cache=True)
def _largest_kernel(hull, points, starts, floor, top):
    """:func:`_floored_kernel`'s ``top``, the views' values added to the rows as they are
    (started at ``floor`` or above, by the caller), group by group."""
    for g in prange(starts.shape[0] - 1):
        _group_largest(hull, points, starts[g], starts[g + 1], floor, top)


@njit(parallel=True, cache=True)
def _floored_values_kernel(hull, points, top, floor, out):
    """``out[p]``: :func:`_floored_value` of ``points[p]`` from row ``p`` of ``top``."""
    for p in prange(points.shape[0]):
        out[p] = _floored_value(hull, points[p, 0], points[p, 1], points[p, 2], top, p, floor)


def point_groups(points: np.ndarray, floor_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The groups in which :meth:`HullDistance.__call__` with ``floor_m`` evaluates the
    points (n, 3) metres: ``(order (n,) int64, starts (groups + 1,) int64)``
    (:func:`_groups`)."""
    return _groups(points, _GROUP_FLOORS * -floor_m)


def _groups(points: np.ndarray, edge_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The points (n, 3) in cubes of ``edge_m`` metres: ``order`` (n,) int64, the point
    indices cube by cube (cubes in C order from the points' lowest corner, points in their
    order within a cube), and ``starts`` (groups + 1,) int64, where each cube's begin."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    if not len(pts):
        return np.zeros(0, np.int64), np.zeros(1, np.int64)
    keys, n_keys = _cube_keys(pts, float(edge_m))
    if n_keys <= _COUNTING_SORT_KEYS_PER_POINT * len(pts) + (1 << 16):
        order = _counting_order(keys, int(n_keys))
    else:       # cubes far apart: as many counters as cubes would not pay
        order = np.argsort(keys, kind="stable")
    return order, _group_starts(keys, order)


#: Cube keys per point up to which :func:`_groups` sorts by counting (one counter per key).
_COUNTING_SORT_KEYS_PER_POINT = 4


@njit(parallel=True, cache=True, nogil=True)
def _cube_keys(points, edge_m):
    """(n,) int64: each point's cube of ``edge_m`` metres from the points' lowest corner,
    in C order (``(cx * size_y + cy) * size_z + cz``), and how many keys there are (a
    float: there may be more than int64 holds). The points side by side, each key made in
    one go: the cubes along an axis are as many as the highest point's (a cube's number
    does not decrease as the coordinate grows), so no (n, 3) array of cubes is needed."""
    lo, hi = _corners(points)
    size = np.empty(3, np.int64)
    for axis in range(3):
        size[axis] = _cube(hi[axis], lo[axis], edge_m) + 1
    keys = np.empty(points.shape[0], np.int64)
    for p in prange(points.shape[0]):
        keys[p] = ((_cube(points[p, 0], lo[0], edge_m) * size[1]
                    + _cube(points[p, 1], lo[1], edge_m)) * size[2]
                   + _cube(points[p, 2], lo[2], edge_m))
    return keys, np.float64(size[0]) * np.float64(size[1]) * np.float64(size[2])


@njit(cache=True, nogil=True)
def _corners(points):
    """The lowest and the highest coordinates (3,) of ``points`` (n >= 1, 3), in one pass
    (in a parallel kernel each of the six reductions would be a parallel loop of its
    own)."""
    lo = points[0].copy()
    hi = points[0].copy()
    for p in range(1, points.shape[0]):
        for axis in range(3):
            lo[axis] = min(lo[axis], points[p, axis])
            hi[axis] = max(hi[axis], points[p, axis])
    return lo, hi


@njit(cache=True, inline="always")
def _cube(x, lo, edge_m):
    """The cube of ``edge_m`` from ``lo`` that holds the coordinate ``x`` (>= ``lo``)."""
    return np.int64(np.floor((x - lo) / edge_m))


@njit(cache=True, nogil=True)
def _counting_order(keys, n_keys):
    """(n,) int64: a stable order of ``keys`` (n,) int64 in ``[0, n_keys)`` (a counting
    sort: ``np.argsort(keys, kind="stable")``)."""
    first = np.zeros(n_keys + 1, np.int64)
    for p in range(keys.shape[0]):
        first[keys[p] + 1] += 1
    for k in range(n_keys):
        first[k + 1] += first[k]
    order = np.empty(keys.shape[0], np.int64)
    for p in range(keys.shape[0]):
        order[first[keys[p]]] = p
        first[keys[p]] += 1
    return order


@njit(cache=True, nogil=True)
def _group_starts(keys, order):
    """(groups + 1,) int64: where each run of equal ``keys[order]`` begins, and the end."""
    n = order.shape[0]
    starts = np.empty(n + 1, np.int64)
    count = 0
    for q in range(n):
        if q == 0 or keys[order[q]] != keys[order[q - 1]]:
            starts[count] = q
            count += 1
    starts[count] = n
    return starts[:count + 1].copy()


@njit(parallel=True, cache=True)
def _project_kernel(hull, points, unit, steps, bisections, top, moved, found):
    """Move ``points[p]`` along ``unit[p]`` to the inside -> outside crossing nearest it.

    The crossing is looked for between consecutive ``steps`` (metres along the
    line, ascending) and placed by ``bisections`` halvings; ``found[p]`` tells
    whether there was one (else ``moved[p]`` is the point itself).
    """
    for p in prange(points.shape[0]):
        x, y, z = points[p, 0], points[p, 1], points[p, 2]
        ux, uy, uz = unit[p, 0], unit[p, 1], unit[p, 2]
        pick = -1
        previous = _distance_at(hull, x + steps[0] * ux, y + steps[0] * uy, z + steps[0] * uz,
                                top, p)
        for j in range(1, steps.shape[0]):
            t = steps[j]
            current = _distance_at(hull, x + t * ux, y + t * uy, z + t * uz, top, p)
            if previous <= 0.0 < current and (
                    pick < 0 or abs(steps[j - 1] + t) < abs(steps[pick] + steps[pick + 1])):
                pick = j - 1
            previous = current
        found[p] = pick >= 0
        t = 0.0
        if pick >= 0:
            lo, hi = steps[pick], steps[pick + 1]
            for _ in range(bisections):
                mid = 0.5 * (lo + hi)
                if _distance_at(hull, x + mid * ux, y + mid * uy, z + mid * uz, top, p) > 0.0:
                    hi = mid
                else:
                    lo = mid
            t = 0.5 * (lo + hi)
        moved[p, 0] = x + t * ux
        moved[p, 1] = y + t * uy
        moved[p, 2] = z + t * uz


@njit(parallel=True, cache=True)
def _segment_zero_kernel(hull, starts, ends, f_start, f_end, order, groups, floor, iterations,
                         tolerance, top, out, traced, trace_points, trace_values, trace_counts):
    """``out[p]``: the fraction along ``starts[p] -> ends[p]`` where the distance is zero,
    the two ends' values ``f_start[p]``, ``f_end[p]`` (metres) of opposite signs:
    ``iterations`` steps of regula falsi, Illinois variant (an end kept twice in a row
    has its value halved), from the chord between the ends; done early where the
    distance is within ``tolerance`` (metres) of zero.

    The segments come group by group (``order[groups[g]:groups[g + 1]]``); a view below
    ``floor`` (metres, < 0; -inf: none) over a group's box is not evaluated there
    (:func:`_below_floor`), and the distance is taken no lower than ``floor``. A group's
    segments not yet done take each step together, view by view (:func:`_add_view`);
    ``top`` (n, rank) is scratch, in the groups' order.

    ``traced``: each point the distance was evaluated at and its value recorded in
    ``trace_points[p, i]`` (metres) and ``trace_values[p, i]``, ``trace_counts[p]`` of
    them (``(n, iterations, 3)``, ``(n, iterations)`` and ``(n,)``; else not written)."""
    n_all = hull[0].shape[0]
    for g in prange(groups.shape[0] - 1):
        first, stop = groups[g], groups[g + 1]
        lo = np.empty(3)
        hi = np.empty(3)
        for axis in range(3):
            start_lo, start_hi = _extent(starts, order, first, stop, axis)
            end_lo, end_hi = _extent(ends, order, first, stop, axis)
            lo[axis] = min(start_lo, end_lo)
            hi[axis] = max(start_hi, end_hi)
        views = np.empty(n_all, np.int64)
        n_views = 0
        for v in range(n_all):
            if floor == -np.inf or not _below_floor(hull, v, lo, hi, floor):
                views[n_views] = v
                n_views += 1
        n = stop - first
        # Each segment's bracket: t and f at its start side and its end side, its next t,
        # and which end its last step kept (-1 the start side, 1 the end side).
        lo_t, hi_t, f_lo, f_hi, t = (np.zeros(n), np.ones(n), f_start[order[first:stop]],
                                     f_end[order[first:stop]], np.empty(n))
        kept = np.zeros(n, np.int64)
        going = np.arange(n)        # the segments not done, the first ``n_going``
        n_going = n
        at = np.empty((n, 3))
        rows = top[first:stop]
        for q in range(n):
            t[q] = f_lo[q] / (f_lo[q] - f_hi[q])
        for step in range(iterations):
            for r in range(n_going):
                q = going[r]
                p = order[first + q]
                for axis in range(3):
                    at[r, axis] = starts[p, axis] + t[q] * (ends[p, axis] - starts[p, axis])
                rows[r] = floor
            for m in range(n_views):
                _add_view(hull, views[m], at, 0, n_going, rows)
            still = 0
            for r in range(n_going):
                q = going[r]
                p = order[first + q]
                f = _floored_value(hull, at[r, 0], at[r, 1], at[r, 2], rows, r, floor)
                if traced:
                    for axis in range(3):
                        trace_points[p, step, axis] = at[r, axis]
                    trace_values[p, step] = f
                    trace_counts[p] = step + 1
                if abs(f) <= tolerance:
                    continue
                if (f > 0.0) == (f_lo[q] > 0.0):
                    lo_t[q], f_lo[q] = t[q], f
                    if kept[q] == 1:
                        f_hi[q] *= 0.5
                    kept[q] = 1
                else:
                    hi_t[q], f_hi[q] = t[q], f
                    if kept[q] == -1:
                        f_lo[q] *= 0.5
                    kept[q] = -1
                if math.isfinite(f_lo[q]) and math.isfinite(f_hi[q]):
                    t[q] = lo_t[q] + (hi_t[q] - lo_t[q]) * f_lo[q] / (f_lo[q] - f_hi[q])
                else:         # (no view sees a point there and no box bounds it)
                    t[q] = 0.5 * (lo_t[q] + hi_t[q])
                going[still] = q
                still += 1
            n_going = still
        for q in range(n):
            out[order[first + q]] = t[q]


@njit(cache=True, inline="always")
def _extent(points, order, first, stop, axis):
    """The lowest and the highest ``points[p, axis]`` of ``p`` in ``order[first:stop]``
    (``stop > first``), the first of equals kept (as numpy's ``min`` and ``max`` of them in
    that order)."""
    low = high = points[order[first], axis]
    for q in range(first + 1, stop):
        value = points[order[q], axis]
        if value < low:
            low = value
        if value > high:
            high = value
    return low, high


@njit(parallel=True, cache=True)
def _raises_kernel(hull, points, values, counts, out):
    """``out[p]``: whether a view's value (:func:`_view_value`) is above ``values[p, i]``
    at ``points[p, i]`` (metres) for an ``i < counts[p]``."""
    for p in prange(counts.shape[0]):
        raised = False
        for i in range(counts[p]):
            for v in range(hull[0].shape[0]):
                if _view_value(hull, v, points[p, i, 0], points[p, i, 1],
                               points[p, i, 2]) > values[p, i]:
                    raised = True
                    break
            if raised:
                break
        out[p] = raised


def _check_coverage(masks: list, coverage) -> list:
    """One (H, W) array or None per mask; ValueError naming the view whose coverage does
    not fit its mask."""
    if coverage is None:
        return [None] * len(masks)
    coverage = list(coverage)
    if len(coverage) != len(masks):
        raise ValueError(f"coverage must give one image (or None) per view ({len(masks)}), "
                         f"got {len(coverage)}")
    out = []
    for index, (mask, alpha) in enumerate(zip(masks, coverage)):
        if alpha is not None:
            alpha = np.asarray(alpha)
            if alpha.shape != mask.shape:
                raise ValueError(f"view {index}: coverage is {alpha.shape}, expected its "
                                 f"mask's {mask.shape}")
        out.append(alpha)
    return out


def _segments(starts, ends, start_values, end_values, iterations, tolerance_m,
              floor_m) -> tuple:
    """:meth:`HullDistance.segment_zeros`' arguments checked: ``(starts, ends, start
    values, end values, floor, iterations, tolerance)`` as its kernel takes them;
    ValueError naming the one that is wrong."""
    a = np.ascontiguousarray(starts, dtype=np.float64)
    b = np.ascontiguousarray(ends, dtype=np.float64)
    fa = np.ascontiguousarray(start_values, dtype=np.float64)
    fb = np.ascontiguousarray(end_values, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3 or b.shape != a.shape or fa.shape != (len(a),) \
            or fb.shape != fa.shape:
        raise ValueError(f"starts and ends must be (n, 3) and their values (n,), got "
                         f"{a.shape}, {b.shape}, {fa.shape} and {fb.shape}")
    if np.any((fa > 0) == (fb > 0)) or np.any(fa == 0) or np.any(fb == 0):
        raise ValueError("each segment's end values must be non-zero and of opposite signs")
    if isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer)) \
            or iterations < 0:
        raise ValueError(f"iterations must be an integer >= 0, got {iterations!r}")
    if not (math.isfinite(tolerance_m) and tolerance_m >= 0):
        raise ValueError(f"tolerance_m must be a finite distance >= 0 metres, got "
                         f"{tolerance_m}")
    floor = -np.inf if floor_m is None else float(floor_m)
    if not (floor == -np.inf or (math.isfinite(floor) and floor < 0)):
        raise ValueError(f"floor_m must be a finite distance < 0 metres, got {floor_m}")
    return a, b, fa, fb, floor, int(iterations), float(tolerance_m)


@dataclass(frozen=True)
class ZeroTrace:
    """Where :meth:`HullDistance.segment_zeros` evaluated the distance on each segment:
    ``points`` (n, iterations, 3) metres and the ``values`` there (n, iterations), the
    first ``counts`` (n,) of each row (the others undefined). The steps follow from those
    values alone: views whose values stay at or below them there
    (:meth:`HullDistance.raises`) leave every step, and the zero found, as they were."""

    points: np.ndarray
    values: np.ndarray
    counts: np.ndarray

    @classmethod
    def empty(cls, n: int, iterations: int) -> "ZeroTrace":
        """The trace of ``n`` segments of up to ``iterations`` steps, none recorded yet."""
        return cls(np.empty((n, iterations, 3)), np.empty((n, iterations)),
                   np.zeros(n, np.int64))

    def __getitem__(self, rows) -> "ZeroTrace":
        """The trace of the segments ``rows`` (an index array or a bool mask)."""
        return ZeroTrace(self.points[rows], self.values[rows], self.counts[rows])


class HullDistance:
    """Signed distance to the visual hull of calibrated silhouettes (metres, positive outside).

    Parameters
    ----------
    cameras : sequence of Camera
        The views that carved the hull.
    masks : sequence of (H, W) bool
        Their silhouettes, one per camera, each of its camera's image size.
    max_misses : int, keyword-only
        As for the carver: a point is inside when at most this many views see
        it outside their silhouette (the value is the (k+1)-th largest view value;
        with as many misses allowed as there are views, only the box bounds the hull).
    bounds_m : (2, 3) array-like or None, keyword-only
        The carving box ``[min, max]``, metres; the hull is cut by it. None: no box.
    known : DistanceImages or None, keyword-only
        Distance images computed beforehand; a mask not among them is computed here.
    coverage : sequence of (H, W) uint8 (0..255) or float (0..1) or None, keyword-only
        Per view, the fraction of each pixel the object covers (an antialiased alpha
        channel whose threshold gave the mask), which places its silhouette's edge
        within the pixels (module docstring); None for a view without. None: no view
        has one.
    kept : :class:`.kept_band.KeptBand` or None, keyword-only
        The views' values kept at the voxels near the hull's surface as the views
        arrived, of these very views, masks and ``max_misses``, without coverage:
        :func:`.marching.hull_band_distance` reads them (:attr:`kept`).

    Memory: one float32 distance image per view, cropped to the silhouette's
    bounding box plus ``CROP_MARGIN_PX``.
    """

    def __init__(self, cameras: Sequence[Camera], masks, *, max_misses: int = 0,
                 bounds_m=None, known: DistanceImages | None = None, coverage=None,
                 kept=None):
        cameras = list(cameras)
        if not cameras:
            raise ValueError("need at least one camera and mask to define a hull")
        masks = validate_masks(cameras, masks)
        if isinstance(max_misses, bool) or not isinstance(max_misses, (int, np.integer)) \
                or max_misses < 0:
            raise ValueError(f"max_misses must be an integer >= 0, got {max_misses!r}")
        if bounds_m is None:
            box = np.array([[-np.inf] * 3, [np.inf] * 3])
        else:
            box = np.asarray(bounds_m, dtype=np.float64)
            if box.shape != (2, 3) or np.any(np.isnan(box)) or np.any(box[1] <= box[0]):
                raise ValueError(f"bounds_m must be [[xmin, ymin, zmin], [xmax, ymax, zmax]] "
                                 f"with min < max, got {box.tolist()}")
        coverage = _check_coverage(masks, coverage)
        images, crops, offset = [], [], 0
        known_image = _silhouette_distance if known is None else known.get
        distances = map_in_threads(  # in order, in threads
            lambda pair: known_image(pair[0]) if pair[1] is None else _silhouette_distance(*pair),
            zip(masks, coverage))
        for index in range(len(masks)):
            try:
                distance, u0, v0 = next(distances)
            except ValueError as err:
                raise ValueError(f"view {index}: {err}") from None
            images.append(distance.ravel())
            crops.append((offset, distance.shape[1], distance.shape[0], u0, v0))
            offset += distance.size
        self._rank = int(max_misses) + 1
        self.kept = kept
        # What the kernels read (see ``_distance_at``). Distance images assume
        # square pixels: the mean focal length converts them to metres.
        self._kernel_data = (
            np.stack([c.projection_matrix for c in cameras]),
            np.array([c.orthographic for c in cameras]),
            np.array([1.0 / math.sqrt(c.K[0, 0] * c.K[1, 1]) for c in cameras]),
            np.array([(c.width, c.height) for c in cameras], dtype=np.float64),
            np.array(crops, dtype=np.int64),
            np.concatenate(images),
            float(CROP_MARGIN_PX) - 0.5,
            np.ascontiguousarray(box[0]),
            np.ascontiguousarray(box[1]),
            np.array([0.0 if c is None else _COVERAGE_SLACK_PX for c in coverage]),
        )

    def __call__(self, points, *, floor_m: float | None = None) -> np.ndarray:
        """Signed distances of ``points`` (n, 3) float64, metres -> (n,) float64, metres.

        Negative inside the hull; ``-inf`` where no view sees the point and no
        box bounds it. With ``floor_m`` (metres, < 0), a value below it comes back
        as ``floor_m`` (``max(value, floor_m)``, the same as without it otherwise):
        a view is not evaluated where it can only give values below the floor,
        which spares most views at points near the surface (the meshers need the
        distance only within a few voxels of it).
        """
        pts = np.ascontiguousarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"points must be an (n, 3) array, got shape {pts.shape}")
        if not np.all(np.isfinite(pts)):
            raise ValueError("points must be finite")
        out = np.empty(len(pts))
        top = np.empty((len(pts), self._rank))
        if floor_m is None:
            _distance_kernel(self._kernel_data, pts, top, out)
            return out
        if not (math.isfinite(floor_m) and floor_m < 0):
            raise ValueError(f"floor_m must be a finite distance < 0 metres, got {floor_m}")
        if len(pts):
            order, starts = _groups(pts, _GROUP_FLOORS * -floor_m)
            _floored_kernel(self._kernel_data, pts, order, starts, float(floor_m), top, out)
        return out

    def add_largest(self, points: np.ndarray, top: np.ndarray, *, floor_m: float,
                    starts: np.ndarray | None = None) -> None:
        """Insert the views' values at ``points`` (n, 3) float64 metres into the rows of
        ``top`` (n, k) float64, each row its ``k`` largest values so far, descending, and
        at least ``floor_m`` (metres, < 0): a value below it is left out (its view may be
        not evaluated there). Values of other views added before or after, the rows are
        what :meth:`__call__` would keep for all of them, in any order. ``starts``: the
        points are in groups already (:func:`point_groups`, its ``starts``; ``points`` and
        ``top`` in its order), else they are grouped here."""
        pts = np.ascontiguousarray(points, dtype=np.float64)
        if not len(pts):
            return
        if starts is not None:
            _largest_kernel(self._kernel_data, pts, starts, float(floor_m), top)
            return
        order, starts = point_groups(pts, floor_m)
        grouped = np.ascontiguousarray(top[order])
        _largest_kernel(self._kernel_data, pts[order], starts, float(floor_m), grouped)
        top[order] = grouped

    def floored(self, points: np.ndarray, top: np.ndarray, *, floor_m: float) -> np.ndarray:
        """(n,) float64: what :meth:`__call__` with ``floor_m`` gives at ``points`` (n, 3)
        metres, from ``top`` (n, ``max_misses + 1``): every view's largest values there
        (:meth:`add_largest`, this hull's views), and this hull's box."""
        out = np.empty(len(points))
        _floored_values_kernel(self._kernel_data, np.ascontiguousarray(points, np.float64),
                               np.ascontiguousarray(top), float(floor_m), out)
        return out

    def project(self, points, directions, *, reach_m: float) -> tuple[np.ndarray, np.ndarray]:
        """Move points along lines to the hull surface (the zero level).

        Parameters
        ----------
        points : (n, 3) float64
            Points near the surface, metres.
        directions : (n, 3) float64
            Outward directions of the lines (e.g. normals); need not be unit.
        reach_m : float, keyword-only
            Largest move, metres, either way along the line.

        Returns
        -------
        moved : (n, 3) float64
            For each point, the crossing from inside to outside nearest to it
            on ``point + t * unit(direction)``, ``|t| <= reach_m``, found
            between samples ``reach_m / 4`` apart and placed by bisection to
            within 1e-6 of ``reach_m``; the point itself where the line has no
            crossing there.
        found : (n,) bool
            Which points were moved.
        """
        pts = np.asarray(points, dtype=np.float64)
        dirs = np.asarray(directions, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3 or dirs.shape != pts.shape:
            raise ValueError(f"points and directions must be (n, 3) arrays of the same shape, "
                             f"got {pts.shape} and {dirs.shape}")
        length = np.linalg.norm(dirs, axis=1, keepdims=True)
        if not np.all(np.isfinite(dirs)) or np.any(length == 0):
            raise ValueError("directions must be finite and non-zero")
        if not (math.isfinite(reach_m) and reach_m > 0):
            raise ValueError(f"reach_m must be a finite distance > 0 metres, got {reach_m}")
        unit = np.ascontiguousarray(dirs / length)
        moved = np.empty_like(unit)
        found = np.empty(len(unit), dtype=bool)
        _project_kernel(self._kernel_data, np.ascontiguousarray(pts), unit,
                        np.linspace(-reach_m, reach_m, 2 * _SEARCH_STEPS + 1), _BISECTIONS,
                        np.empty((len(unit), self._rank)), moved, found)
        return moved, found

    def segment_zeros(self, starts, ends, start_values, end_values, *, iterations: int,
                      tolerance_m: float = 0.0, floor_m: float | None = None) -> np.ndarray:
        """Where the hull surface crosses segments whose ends lie on either side of it.

        Parameters
        ----------
        starts, ends : (n, 3) float64
            The segments' ends, metres.
        start_values, end_values : (n,) float
            The distance at the ends, metres (or a bound of it, as the meshers' clipped
            samples), of opposite signs, none zero.
        iterations : int >= 0, keyword-only
            Evaluations of the distance per segment (regula falsi, Illinois variant);
            0 gives the chord's zero, the linear interpolation of the ends' values.
        tolerance_m : float >= 0, keyword-only
            A segment is done where the distance is this near zero, metres.
        floor_m : float < 0 or None, keyword-only
            As for :meth:`__call__`: the distance taken no lower than this, metres, and a
            view not evaluated where it can only give values below it (segments near
            the surface go in groups, as points do there).

        Returns
        -------
        (n,) float64 in (0, 1): the fraction from start to end of the zero found
        (the distance is a largest of views' values, with kinks where two views meet:
        the chord misplaces it there, the steps do not).
        """
        return self._segment_zeros(*_segments(starts, ends, start_values, end_values,
                                              iterations, tolerance_m, floor_m), None)

    def traced_segment_zeros(self, starts, ends, start_values, end_values, *,
                             iterations: int, tolerance_m: float = 0.0,
                             floor_m: float | None = None) -> tuple[np.ndarray, ZeroTrace]:
        """:meth:`segment_zeros` (the same zeros, the same checks) and where it evaluated
        the distance (:class:`ZeroTrace`), for :meth:`raises`."""
        segments = _segments(starts, ends, start_values, end_values, iterations, tolerance_m,
                             floor_m)
        trace = ZeroTrace.empty(len(segments[0]), iterations)
        return self._segment_zeros(*segments, trace), trace

    def _segment_zeros(self, a, b, fa, fb, floor: float, iterations: int, tolerance: float,
                       trace: ZeroTrace | None) -> np.ndarray:
        """The zeros of checked segments (:func:`_segments`), their steps written into
        ``trace`` (its rows in the segments' order) when one is given."""
        out = np.empty(len(a))
        if not len(a):
            return out
        if floor == -np.inf:    # (in blocks, for the threads)
            order = np.arange(len(a))
            groups = np.append(np.arange(0, len(a), _BLOCK_POINTS), len(a)).astype(np.int64)
        else:
            order, groups = _groups(0.5 * (a + b), _GROUP_FLOORS * -floor)
        traced = trace is not None
        if not traced:
            trace = ZeroTrace.empty(0, iterations)
        _segment_zero_kernel(self._kernel_data, a, b, fa, fb, order, groups, floor, iterations,
                             tolerance, np.empty((len(a), self._rank)), out, traced,
                             trace.points, trace.values, trace.counts)
        return out

    def raises(self, trace: ZeroTrace) -> np.ndarray:
        """(n,) bool: for each segment of ``trace`` (of another hull's
        :meth:`traced_segment_zeros`), whether a view of this hull gives a value above the
        distance recorded at one of its points. Where none does, that hull with these
        views added finds the same zero on the segment, the ends' values the same (its
        distance there is the same: a ``rank``-th largest value, or the box's, or the
        floor, stays where no value above it is added)."""
        out = np.empty(len(trace.counts), bool)
        if len(out):
            _raises_kernel(self._kernel_data, np.ascontiguousarray(trace.points),
                           np.ascontiguousarray(trace.values),
                           np.ascontiguousarray(trace.counts), out)
        return out
