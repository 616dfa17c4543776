"""Fusion of the silhouettes: one view's mistake must not carve what the others agree on.

A visual hull trusts every view: a mask with a chunk missing (a shadow taken
for background, a hand in front of the object) carves that chunk away from the
hull of all views. :func:`fuse_silhouettes` decides, per view and per pixel,
where a view is outvoted:

1. the *reference hull* is carved with a tolerance (a voxel stays when at most
   ``k`` views see it outside their silhouette; ``k`` from the number of views,
   :func:`reference_misses`);
2. it is projected into every view; where the projection falls outside the
   view's mask, the view disagrees with (at least) all but ``k`` of the others;
3. a disagreement *deeper* than what correct views produce is a mask error:
   those pixels are filled in the view's mask (the view is *overruled* there),
   unless the mask is exact (an image's alpha channel): a region only the
   views at the horizon see empty (under a seat, between legs) is kept by the
   reference hull's tolerance, and an exact view that carves it is right.
   Correct views cut the reference hull too (it sticks out of a true
   silhouette by the facets one view carves), and all views of a scan cut
   about equally deep for their silhouette's size; so the bar is set from the
   views themselves: the median over views of the deepest cut relative to the
   silhouette's radius, and never below the facet depth of a round section
   (:func:`facet_depth_px`), times a safety factor. Shallower cuts are the view
   doing its job (sharpening the hull) and are left alone. With few views (16
   on a ring) the facets are deep and only a gross error is outvoted: every
   view is precious there;
4. when the views do not agree on one object at all (most masks hold much
   more than the hull: a calibration that does not fit), that is an error;
   a view missing more than ``max_missing`` of the reference hull's projection
   is wrong as a whole (wrong calibration, another object, most of the object
   lost) and is dropped. Extra foreground (background clutter) carves nothing
   and is no reason to drop a view.

The hull is then carved from the repaired masks with no tolerance, so every view
still carves everywhere it is not overruled, and batch and incremental carving
agree on it (the masks are ordinary masks). Every overruled pixel is counted and
reported per view.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

from ..geometry.camera import Camera
from ..geometry.grid import VoxelGrid
from ..mask_box import foreground_box
from ..metrics import silhouette_iou
from ..workers import map_in_threads
from .bounds import seen_by
from .carve import KeptCarve, PreparedMasks, kept_or_carved
from .consistency import hull_silhouettes

__all__ = ["ViewVerdict", "Fusion", "reference_misses", "neighbour_angle_rad",
           "facet_depth_px", "fuse_silhouettes"]

#: Views from which the reference hull tolerates two misses per voxel instead of one.
_TWO_MISSES_FROM = 40
#: The facet depth a correct view may cut is multiplied by this before a
#: disagreement counts as a mask error (the formula holds for a round
#: cross-section; corners and saddles cut somewhat deeper).
_FACET_SAFETY = 1.5
#: Below this median IoU of a view's mask with the reference hull's projection
#: the views do not agree on one object (a calibration centimetres off). Masks with
#: shadows or clutter hold more than the hull: the bar is low, for gross errors
#: (the medians measured on good and bad inputs: doc/accuracy.md).
MIN_MEDIAN_IOU = 0.5
#: Disagreements shallower than this never count as mask errors, pixels (the
#: voxel footprint adds to it): segmentation edges are this uncertain anyway.
_MIN_DEPTH_PX = 3.0


@dataclass(frozen=True)
class ViewVerdict:
    """What the fusion decided about one view.

    Attributes
    ----------
    index : int
        View index.
    iou : float
        IoU of the mask with the projection of the reference hull.
    missing_fraction : float
        Fraction of that projection outside the mask, beyond the voxel footprint.
    depth_threshold_px : float
        Disagreements deeper than this (pixels from the mask) overrule the view.
    overruled_pixels : int
        Pixels the view calls background that the fusion filled as object.
    overruled_depth_px : float
        Largest distance of an overruled pixel from the view's own mask, pixels.
    dropped : bool
        The view disagrees as a whole (``missing_fraction > max_missing``) and is not used.
    reason : str or None
        Why the view was overruled or dropped, None when it was neither.
    """

    index: int
    iou: float
    missing_fraction: float
    depth_threshold_px: float
    overruled_pixels: int
    overruled_depth_px: float
    dropped: bool
    reason: str | None


@dataclass(frozen=True)
class Fusion:
    """Result of :func:`fuse_silhouettes`.

    masks : list of n (H, W) bool, the repaired masks (the input mask where not
    overruled); verdicts : list of n ViewVerdict; reference_misses : int, the
    tolerance of the reference hull; neighbour_angle_rad : float, the median
    angle between a view and its nearest neighbour.
    """

    masks: list
    verdicts: list
    reference_misses: int
    neighbour_angle_rad: float

    @property
    def kept(self) -> list[int]:
        """Indices of the views not dropped."""
        return [v.index for v in self.verdicts if not v.dropped]


def reference_misses(n_views: int) -> int:
    """Misses per voxel the reference hull tolerates: 1, or 2 from 40 views.

    With few views (16 on a ring) every view carves a large facet and a second
    tolerated miss would let whole facets through; with many views a region
    two masks both miss (a shadow seen from neighbouring views) is still cheap
    to keep in the reference.
    """
    if n_views < 3:
        raise ValueError(f"fusion needs at least 3 views to outvote one, got {n_views}")
    return 2 if n_views >= _TWO_MISSES_FROM else 1


def neighbour_angle_rad(cameras: Sequence[Camera]) -> float:
    """Median over views of the angle between a view's direction and its nearest other's, rad."""
    d = np.array([c.forward for c in cameras], dtype=np.float64)
    if len(d) < 2:
        raise ValueError(f"need at least 2 views to measure their spacing, got {len(d)}")
    cos = np.clip(d @ d.T, -1.0, 1.0)
    np.fill_diagonal(cos, -1.0)
    return float(np.median(np.arccos(cos.max(axis=1))))


def facet_depth_px(radius_px: float, angle_rad: float, misses: int) -> float:
    """How far a hull carved with ``misses`` views ignored sticks out of a true silhouette, px.

    For a round cross-section of radius ``radius_px`` seen by views
    ``angle_rad`` apart, the silhouettes' tangent lines meet at radius
    ``r / cos(angle / 2)``; ignoring ``misses`` neighbouring views widens the gap
    to ``(misses + 1) * angle`` and the corner moves out to
    ``r / cos((misses + 1) * angle / 2)``. The gap is capped at 120 degrees.
    """
    half_gap = min((misses + 1) * angle_rad / 2.0, math.pi / 3.0)
    return float(radius_px * (1.0 / math.cos(half_gap) - 1.0))


def _distance_to_mask(mask: np.ndarray, projection: np.ndarray) -> np.ndarray:
    """(H, W) float32: distance to the nearest pixel of ``mask``, pixels, over the
    bounding box of ``mask | projection`` (+inf elsewhere; the mask lies inside
    the box, so the distances there are those of the whole image). 5 x 5
    chamfer metric: within 2 % of the Euclidean distance."""
    out = np.full(mask.shape, np.inf, np.float32)
    box = foreground_box(mask, projection)
    if box is None or not mask.any():
        return out
    out[box] = cv2.distanceTransform(np.ascontiguousarray(~mask[box]).view(np.uint8),
                                     cv2.DIST_L2, cv2.DIST_MASK_5)
    return out


def _cut(mask: np.ndarray, projection: np.ndarray) -> tuple:
    """Where ``projection`` lies outside ``mask`` (bool), the distance to the mask there
    (:func:`_distance_to_mask`; None when nowhere) and its largest value (pixels; 0)."""
    outside = projection & ~mask
    if not outside.any():
        return outside, None, 0.0
    distance = _distance_to_mask(mask, projection)
    return outside, distance, float(distance[outside].max())


def deepest_cut_px(mask: np.ndarray, projection: np.ndarray) -> float:
    """Largest distance from ``mask`` of a pixel of ``projection`` outside it, pixels."""
    return _cut(mask, projection)[2]


@dataclass(frozen=True)
class _Look:
    """One view's mask against the reference hull's projection, on the box around both:
    ``box`` (rows, columns) slices; ``outside`` (h, w) bool, projected but not in the mask;
    ``distance`` (h, w) float32 to the mask (pixels; None when nothing is outside);
    ``cut_px``, the largest of it outside; ``n_proj``, projected pixels; ``iou``."""

    box: tuple
    outside: np.ndarray
    distance: np.ndarray | None
    cut_px: float
    n_proj: int
    iou: float


def _look(pair: tuple[np.ndarray, np.ndarray]) -> _Look:
    """:class:`_Look` of ``(mask, projection)``, two (H, W) bool images."""
    mask, proj = pair
    box = foreground_box(mask, proj)
    empty = box is None
    if empty:
        box = (slice(0, 0), slice(0, 0))
    mask, proj = mask[box], proj[box]
    outside, distance, cut_px = _cut(mask, proj)
    return _Look(box=box, outside=outside, distance=distance, cut_px=cut_px,
                 n_proj=int(np.count_nonzero(proj)),
                 iou=1.0 if empty else float(silhouette_iou(proj, mask)))


@dataclass(frozen=True)
class _Judge:
    """What :func:`fuse_silhouettes` judges each view by: its ``masks``, their ``looks``
    at the reference hull's projections (whose half voxel footprint is ``half_px``, (n,)
    pixels), each projection's ``radius_px`` and deepest cut ``cut_px`` (n,), the
    ``typical`` cut relative to the radius, the ``angle`` between neighbouring views
    (radians), the reference hull's tolerance ``k``, ``max_missing`` and which views are
    ``exact`` (never overruled)."""

    masks: list
    looks: list
    half_px: np.ndarray
    radius_px: np.ndarray
    cut_px: np.ndarray
    typical: float
    angle: float
    k: int
    max_missing: float
    exact: list

    def verdict(self, v: int) -> tuple[np.ndarray, ViewVerdict]:
        """View ``v``'s repaired mask and verdict."""
        look, max_missing = self.looks[v], self.max_missing
        floor_px = max(_MIN_DEPTH_PX, self.half_px[v] + 1.0)
        threshold = floor_px + _FACET_SAFETY * self.radius_px[v] * max(
            self.typical, facet_depth_px(1.0, self.angle, 1))
        n_fill, missing, depth = 0, 0.0, 0.0
        if self.cut_px[v] > floor_px:
            outside, dist = look.outside, look.distance
            missing = float(np.count_nonzero(outside & (dist > floor_px))) / max(1, look.n_proj)
            deep = outside & (dist > threshold)
            if deep.any() and missing <= max_missing and not self.exact[v]:
                # the whole gap around the deep pixels, down to the mask's edge
                r = int(math.ceil(threshold)) + 1
                disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
                fill = outside & (cv2.dilate(deep.view(np.uint8), disk) > 0)
                n_fill, depth = int(np.count_nonzero(fill)), float(dist[fill].max())
        dropped = missing > max_missing
        if dropped:
            reason = (f"silhouette inconsistent with the other views as a whole: "
                      f"{100 * missing:.1f}% of the hull they agree on is missing from it "
                      f"(more than {100 * max_missing:.0f}%; IoU {look.iou:.3f})")
        elif n_fill:
            reason = (f"overruled on {n_fill} px: the hull all but {self.k} of the other "
                      f"{len(self.masks) - 1} views agree on lies up to {depth:.1f} px "
                      f"outside this mask, deeper than a correct view cuts ({threshold:.1f} px)")
        else:
            reason = None
        repaired = self.masks[v]
        if n_fill:
            repaired = repaired.copy()
            repaired[look.box] |= fill
        return repaired, ViewVerdict(
            index=v, iou=look.iou, missing_fraction=missing, depth_threshold_px=float(threshold),
            overruled_pixels=n_fill, overruled_depth_px=depth, dropped=bool(dropped),
            reason=reason)


def fuse_silhouettes(grid: VoxelGrid, cameras: Sequence[Camera], masks, *,
                     max_missing: float = 0.35, exact: Sequence[bool] | None = None,
                     kept: Sequence[KeptCarve] = ()) -> Fusion:
    """Decide per view and pixel where a view's mask is outvoted by the others.

    Parameters
    ----------
    grid : VoxelGrid
        Grid of the reference hull: the carving grid or a coarser one over the
        same box (overruled pixels follow its projection).
    cameras : sequence of n >= 3 Camera
    masks : sequence of n (H, W) bool (or 0/1), or PreparedMasks
    max_missing : float
        A view missing a larger fraction of the reference hull's projection
        (beyond the voxel footprint) is dropped as a whole; below, its deep
        disagreements are overruled.
    exact : sequence of n bool, optional
        Views whose mask is exact (an alpha channel): never overruled (still
        dropped when they disagree as a whole). Default: none.
    kept : sequence of KeptCarve, optional
        Carves kept as the views arrived: the reference hull is taken from one that
        holds it (:func:`.carve.kept_or_carved`), the same hull.

    Returns
    -------
    Fusion
        Repaired masks and one verdict per view, in order.

    Raises
    ------
    ValueError
        When the views do not agree on one object (median IoU of a mask with
        the reference hull's projection below ``MIN_MEDIAN_IOU``): a calibration
        that does not fit the images, which would otherwise carve a smaller,
        wrong hull without a word.
    """
    if not 0.0 <= max_missing <= 1.0:
        raise ValueError(f"max_missing must lie in [0, 1], got {max_missing}")
    cameras = list(cameras)
    prepared = masks if isinstance(masks, PreparedMasks) else PreparedMasks(cameras, masks)
    masks = prepared.masks
    n = len(cameras)
    exact = [False] * n if exact is None else [bool(e) for e in exact]
    if len(exact) != n:
        raise ValueError(f"exact must give one flag per view ({n}), got {len(exact)}")
    k = reference_misses(n)
    angle = neighbour_angle_rad(cameras)
    hull = kept_or_carved(kept, grid, cameras, prepared, k)
    # A voxel inside the image of at most k views is never carved by the
    # tolerant hull, whatever the masks say: it is no evidence, leave it out.
    hull &= seen_by(grid, cameras, k + 1)
    projections, half_px = hull_silhouettes(grid, hull, cameras)
    # How deep each view cuts into the reference hull, relative to its size. Views in
    # threads (OpenCV's distance transforms and numpy's counts release Python's lock),
    # each on the box around its mask and projection (nothing of either lies outside).
    looks = list(map_in_threads(_look, zip(masks, projections)))
    radius_px = np.array([math.sqrt(look.n_proj / math.pi) for look in looks])
    cut_px = np.array([look.cut_px for look in looks])
    typical = float(np.median(cut_px / np.maximum(radius_px, 1.0)))

    judge = _Judge(masks, looks, half_px, radius_px, cut_px, typical, angle, k, max_missing,
                   exact)
    repaired, verdicts = map(list, zip(*map_in_threads(judge.verdict, range(n))))
    median_iou = float(np.median([v.iou for v in verdicts]))
    if median_iou < MIN_MEDIAN_IOU:
        raise ValueError(
            f"the views do not agree on one object: a view's mask and the hull of all views "
            f"have a median IoU of {median_iou:.2f} (below {MIN_MEDIAN_IOU}); check the camera "
            f"calibration (poses, intrinsics, units) and the masks")
    return Fusion(masks=repaired, verdicts=verdicts, reference_misses=k,
                  neighbour_angle_rad=angle)
