"""A bounding box for carving when the input gives none.

The cameras of a turntable scan all look at the object. The box is found in
two steps: the region every camera can see around the point nearest to all
optical axes, then a coarse carve inside it whose occupied voxels (grown by
a margin) give the box. :func:`refine_bounds` then shrinks a box to a finer
carve's hull plus a margin.

Both carves are coarse: a part thinner than a coarse voxel (a chair's leg, an
antenna) can fall between the voxel centres in some views, be carved, and be
cut off by the box in the hull. So each is also carved keeping the voxels whose
*footprint* meets every silhouette (:func:`footprint_masks`; no miss tolerated,
so that what one view's extra foreground leaves does not count); the box is the
first carve's, reaching out to the second's on a side where the second reaches
further than the margin and a voxel (a part the first lost, not the
footprint's shell).
"""

from __future__ import annotations

import math
from collections import Counter

import cv2
import numpy as np

from ..geometry.camera import Camera
from ..geometry.grid import VoxelGrid
from ..mask_box import foreground_box
from ..workers import map_in_threads
from .carve import Carver, PreparedMasks, carve, same_grid, view_key, view_keys
from .hull import drop_specks, occupied_bounds

__all__ = ["BoxCarve", "axes_meeting_point", "box_in_frame", "estimate_bounds",
           "footprint_masks", "footprint_radius_px", "refine_bounds", "seen_by"]

#: Resolution of :func:`refine_bounds`'s carve.
REFINE_RESOLUTION = 128


def axes_meeting_point(cameras: list[Camera]) -> np.ndarray:
    """(3,) least-squares point nearest to all optical axes, metres.

    For orthographic cameras the "axis" is the line through the image centre
    along the viewing direction.
    """
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for cam in cameras:
        d = cam.forward
        centre_px = np.array([(cam.width - 1) / 2.0, (cam.height - 1) / 2.0])
        origin = _point_on_axis(cam, centre_px)
        proj = np.eye(3) - np.outer(d, d)
        A += proj
        b += proj @ origin
    if np.linalg.matrix_rank(A, tol=1e-9) < 3:
        raise ValueError(
            "cannot estimate a bounding box: the optical axes are parallel; give bounds explicitly")
    return np.linalg.solve(A, b)


def _point_on_axis(cam: Camera, pixel: np.ndarray) -> np.ndarray:
    """A world point that projects to ``pixel`` (depth 0 for orthographic cameras)."""
    K = cam.K
    y = (pixel[1] - K[1, 2]) / K[1, 1]
    x = (pixel[0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
    if cam.orthographic:
        local = np.array([x, y, 0.0])
    else:
        local = np.array([x, y, 1.0])
    return cam.R.T @ (local - cam.t)


def _visible_half_size(cam: Camera, centre: np.ndarray) -> float:
    """Half the larger image side, back-projected to the depth of ``centre``, metres."""
    half_px = 0.5 * max(cam.width, cam.height)
    if cam.orthographic:
        return half_px / min(cam.K[0, 0], cam.K[1, 1])
    depth = float(cam.depth(centre[None])[0])
    if depth <= 0:
        raise ValueError("cannot estimate a bounding box: a camera looks away from the object")
    return half_px * depth / min(cam.K[0, 0], cam.K[1, 1])


def footprint_radius_px(camera: Camera, grid: VoxelGrid) -> int:
    """Pixels a voxel of ``grid`` can reach from its centre's pixel in ``camera``'s image.

    A cube of side ``s`` projects within ``R = f * s * sqrt(3) / 2 / d`` pixels of its
    centre's projection (``d`` its depth; orthographic: ``f * s * sqrt(3) / 2``), taken
    at the nearest depth of the grid's box (at least a tenth of its centre's) and the
    larger focal length; the centre's pixel is within ``sqrt(2) / 2`` of the
    projection, so pixel centres within ``R`` of it are within ``R + 0.71`` of its pixel.
    """
    reach = 0.5 * math.sqrt(3.0) * grid.voxel_size
    focal = float(max(abs(camera.K[0, 0]), abs(camera.K[1, 1])))
    if camera.orthographic:
        return int(math.ceil(focal * reach + 0.71))
    lo, hi = grid.bounds_min, grid.bounds_max
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])])
    centre_depth = float(camera.depth(0.5 * (lo + hi)[None])[0])
    near = max(float(camera.depth(corners).min()), 0.1 * abs(centre_depth))
    return int(math.ceil(focal * reach / max(near, 1e-12) + 0.71))


def _grown(mask: np.ndarray, radius_px: int) -> np.ndarray:
    """``mask`` (H, W) bool grown by ``radius_px`` pixels (Euclidean; the 5 x 5 chamfer
    metric's distances, within 2 % of it, are taken 2 % long)."""
    box = foreground_box(mask, margin_px=radius_px + 1)
    if box is None or radius_px <= 0:
        return mask
    distance = cv2.distanceTransform(np.ascontiguousarray(~mask[box]).view(np.uint8),
                                     cv2.DIST_L2, cv2.DIST_MASK_5)
    out = np.zeros_like(mask)
    out[box] = distance <= 1.02 * radius_px
    return out


def footprint_masks(cameras: list[Camera], masks, grid: VoxelGrid) -> list[np.ndarray]:
    """The ``masks`` (n (H, W) bool, or PreparedMasks) grown by the footprint of a voxel of
    ``grid`` in each view (:func:`footprint_radius_px`): a voxel whose centre lands in the
    grown mask may meet the silhouette; one outside it cannot. Carving ``grid`` with
    them keeps every voxel any part of which every view sees in its silhouette. The views
    are grown side by side (:func:`~sfs_ros.core.workers.map_in_threads`)."""
    if isinstance(masks, PreparedMasks):
        masks = masks.masks
    return list(map_in_threads(
        lambda pair: _grown(np.asarray(pair[1], dtype=bool), footprint_radius_px(pair[0], grid)),
        zip(cameras, masks, strict=True)))


def estimate_bounds(cameras: list[Camera], masks: list[np.ndarray], *,
                    resolution: int = 48, margin_voxels: float = 2.0,
                    max_misses: int = 0) -> np.ndarray:
    """(2, 3) bounding box ``[min, max]`` of the object seen in ``masks``, metres.

    Carves a ``resolution``^3 grid over the region all cameras can see around
    :func:`axes_meeting_point`, keeping only voxels inside the image in at
    least half the views, and grows the occupied box by ``margin_voxels``
    coarse voxels, reaching out to the carve of the voxels whose footprint meets the
    silhouettes (module docstring). ``max_misses`` views may see a voxel outside their mask
    (one view that lost part of the object must not cut the box). Raises
    ``ValueError`` if nothing survives.
    """
    centre = axes_meeting_point(cameras)
    half = max(_visible_half_size(cam, centre) for cam in cameras)
    grid = VoxelGrid(centre - half, centre + half, 2 * half / resolution)
    pad = (0.5 + margin_voxels) * grid.voxel_size
    boxes = []
    for grown in (False, True):
        occupancy = carve(grid, cameras,
                          footprint_masks(cameras, masks, grid) if grown else masks,
                          max_misses=0 if grown else max_misses, outside_image="keep")
        points = _framed_points(grid, occupancy, cameras)
        boxes.append(None if points is None else
                     np.stack([points.min(axis=0) - pad, points.max(axis=0) + pad]))
    if boxes[1] is None:
        raise ValueError("cannot estimate a bounding box: the silhouettes have no common volume "
                         "in the frame of most views")
    return _reaching(boxes[0], boxes[1], pad + grid.voxel_size)


def _framed_points(grid: VoxelGrid, occupancy: np.ndarray, cameras: list[Camera]):
    """(k, 3) centres of the occupied voxels inside the image in at least half the views,
    metres; None when there is none."""
    points = grid.index_to_world(np.argwhere(occupancy))
    in_frame = np.zeros(len(points), dtype=np.int32)
    for cam in cameras:
        uv = cam.project(points)
        with np.errstate(invalid="ignore"):
            inside = ((uv[:, 0] > -0.5) & (uv[:, 0] < cam.width - 0.5)
                      & (uv[:, 1] > -0.5) & (uv[:, 1] < cam.height - 0.5))
        in_frame += inside
    points = points[2 * in_frame >= len(cameras)]
    return points if len(points) else None


def _reaching(box: np.ndarray | None, reach: np.ndarray, beyond_m: float) -> np.ndarray:
    """``box`` (2, 3) moved out to ``reach``'s sides that lie more than ``beyond_m``
    further out (``reach`` itself when there is no ``box``)."""
    if box is None:
        return reach
    return np.stack([np.where(reach[0] < box[0] - beyond_m, reach[0], box[0]),
                     np.where(reach[1] > box[1] + beyond_m, reach[1], box[1])])


class BoxCarve:
    """:func:`refine_bounds`'s carve of a box, kept up to date as views arrive.

    That carve counts, per voxel of a coarse grid over the box, the views whose
    silhouette misses it and the views that do not frame it. Here both counts grow a
    view at a time (:class:`.carve.Carver`, which counts as :func:`.carve.carve` does),
    while the rig moves; :func:`refine_bounds` given this store, for the same box and
    the same views (cameras and masks, in any order), takes the voxels from it instead
    of carving: the same box either way. For other views it carves as without.

    Parameters
    ----------
    bounds_m : (2, 3)
        The box ``[min, max]``, metres.
    resolution : int, keyword-only
        Of the coarse grid, as :func:`refine_bounds`'s.

    Memory: three bytes per voxel of the coarse grid (6 MiB at 128^3) and a key per view
    (its camera and its packed mask).
    """

    #: Most misses a voxel may be allowed: :func:`.fusion.reference_misses` at most.
    MOST_MISSES = 2
    #: Most views that may be allowed not to frame a voxel (uint8 counts).
    MOST_UNFRAMED = 254

    def __init__(self, bounds_m, *, resolution: int = REFINE_RESOLUTION):
        self._bounds = np.asarray(bounds_m, dtype=np.float64)
        self.grid = VoxelGrid.cube(self._bounds[0], self._bounds[1], resolution)
        self._misses = Carver(self.grid, max_misses=self.MOST_MISSES)
        self._reach = Carver(self.grid, max_misses=self.MOST_MISSES)
        self._unframed = Carver(self.grid, max_misses=self.MOST_UNFRAMED,
                                outside_image="carve")
        self._views: Counter = Counter()

    def add(self, camera: Camera, mask) -> None:
        """Count one more view: ``mask`` (camera.height, camera.width) bool."""
        self._misses.add_view(camera, mask)
        self._reach.add_view(camera, footprint_masks([camera], [mask], self.grid)[0])
        self._unframed.add_view(camera, np.ones((camera.height, camera.width), bool))
        self._views[view_key(camera, mask)] += 1

    def carved(self, grid: VoxelGrid, cameras: list[Camera], masks, max_misses: int,
               framed_by: int) -> tuple[np.ndarray, np.ndarray] | None:
        """Two (nx, ny, nz) bool: the voxels of ``grid`` at most ``max_misses`` of the
        views miss, and those no view misses with their footprint
        (:func:`footprint_masks`), of those at least ``framed_by`` of them frame, if this
        store counted exactly these views (``masks`` as :func:`.carve.carve` takes them)
        on this grid; else None."""
        unframed = len(cameras) - framed_by
        if not same_grid(grid, self.grid) or not 0 <= max_misses <= self.MOST_MISSES \
                or not 0 <= unframed <= self.MOST_UNFRAMED:
            return None
        if len(cameras) != sum(self._views.values()) \
                or self._views != Counter(view_keys(cameras, masks)):
            return None
        framed = self._unframed.tolerating(unframed)
        return (self._misses.tolerating(max_misses) & framed,
                self._reach.tolerating(0) & framed)

    def refined(self, max_misses: int) -> np.ndarray:
        """(2, 3) box, metres: what :func:`refine_bounds` gives for this store's box and
        resolution, the views counted and ``max_misses`` (at most :attr:`MOST_MISSES`),
        without their masks (up to ``2 * MOST_UNFRAMED + 1`` views: past that, the voxels
        framed by all but ``MOST_UNFRAMED`` of them: a box no larger)."""
        if not 0 <= max_misses <= self.MOST_MISSES:
            raise ValueError(f"max_misses must lie in [0, {self.MOST_MISSES}], got {max_misses}")
        n = sum(self._views.values())
        framed = self._unframed.tolerating(min(n // 2, self.MOST_UNFRAMED))
        return _box_of_carves((self._misses.tolerating(max_misses) & framed,
                               self._reach.tolerating(0) & framed), self.grid, self._bounds, 2.0)


def refine_bounds(cameras: list[Camera], masks: list[np.ndarray], bounds_m, *,
                  resolution: int = REFINE_RESOLUTION, max_misses: int = 0,
                  margin_voxels: float = 2.0, known: BoxCarve | None = None) -> np.ndarray:
    """(2, 3) box of the hull carved inside ``bounds_m`` (2, 3), grown by a margin, metres.

    Carves a ``resolution`` grid over ``bounds_m`` with ``max_misses`` tolerated
    misses per voxel (so that one bad mask cannot shrink the box), keeps the
    voxels inside the image in at least half the views (as
    :func:`estimate_bounds`: what most views cannot see is no evidence), drops specks
    (:func:`~.hull.drop_specks`), and grows the box of what is left by
    ``margin_voxels`` of that grid's voxels (a finer carve can occupy voxels
    whose coarse cell's centre was outside: half a voxel; the rest is room for
    the surface), reaching out to the same carve of the voxels whose footprint meets
    the silhouettes (module docstring). The result never leaves ``bounds_m``; ``bounds_m`` itself is
    returned when nothing survives. ``known``: the carve kept as the views arrived
    (:class:`BoxCarve`), used when it holds these views on this grid.
    """
    bounds = np.asarray(bounds_m, dtype=np.float64)
    grid = VoxelGrid.cube(bounds[0], bounds[1], resolution)
    framed_by = len(cameras) - len(cameras) // 2
    carved = None if known is None else known.carved(grid, cameras, masks, max_misses,
                                                     framed_by)
    if carved is None:
        framed = seen_by(grid, cameras, framed_by)
        carved = [carve(grid, cameras, masks, max_misses=max_misses) & framed,
                  carve(grid, cameras, footprint_masks(cameras, masks, grid)) & framed]
    return _box_of_carves(carved, grid, bounds, margin_voxels)


def _box_of_carves(carved, grid: VoxelGrid, bounds: np.ndarray,
                   margin_voxels: float) -> np.ndarray:
    """:func:`refine_bounds`'s box from its two carves of ``grid`` over ``bounds``."""
    pad = (0.5 + margin_voxels) * grid.voxel_size
    boxes = []
    for occupancy in carved:
        box = occupied_bounds(drop_specks(occupancy)[0])
        boxes.append(None if box is None else
                     np.stack([grid.index_to_world(box[0])[0] - pad,
                               grid.index_to_world(box[1] - 1)[0] + pad]))
    if boxes[1] is None:
        return bounds
    lo, hi = _reaching(boxes[0], boxes[1], pad + grid.voxel_size)
    return np.stack([np.maximum(lo, bounds[0]), np.minimum(hi, bounds[1])])


def box_in_frame(cameras: list[Camera], bounds_m) -> bool:
    """Whether the whole box ``bounds_m`` (2, 3), metres, lies in front of every camera
    and projects inside its image (a box in front of a camera projects into the
    convex hull of its corners' projections)."""
    lo, hi = np.asarray(bounds_m, dtype=np.float64)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])])
    for cam in cameras:
        if not cam.orthographic and np.any(cam.depth(corners) <= 0):
            return False
        uv = cam.project(corners)
        if not (np.all(uv > -0.5) and np.all(uv[:, 0] < cam.width - 0.5)
                and np.all(uv[:, 1] < cam.height - 0.5)):
            return False
    return True


def seen_by(grid: VoxelGrid, cameras: list[Camera], n_views: int) -> np.ndarray:
    """(nx, ny, nz) bool: voxels whose centre lands inside the image of at least
    ``n_views`` of ``cameras`` (all of them, at no cost, when the grid's box is in
    every frame)."""
    if box_in_frame(cameras, [grid.bounds_min, grid.bounds_max]):
        return np.ones(grid.shape, dtype=bool)
    frames: dict[tuple[int, int], np.ndarray] = {}   # one full frame per image size, shared
    return carve(grid, cameras,
                 [frames.setdefault((c.height, c.width), np.ones((c.height, c.width), bool))
                  for c in cameras],
                 max_misses=len(cameras) - int(n_views), outside_image="carve")
