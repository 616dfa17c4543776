"""Below the visual hull: carve what the colours show is empty, keep the hull elsewhere.

Silhouettes bound the object from outside; a cup comes back as a solid cylinder.
The images show more where the surface is textured: a point of the true surface
looks the same (up to its shading) from the views that see it, a point of empty
space inside the hull does not. This module finds, per view, the depth of the
surface each pixel sees and carves the hull's voxels that lie in front of it.

1. **Depth maps** by plane sweep (Collins 1996): for each pixel inside the view's
   silhouette (its whole patch inside), depths from the hull's front surface to its
   back surface (the first stretch of the pixel's ray inside the hull: the hull mesh
   drawn into a z-buffer), in steps of a voxel. At each depth the pixel's patch
   (fronto-parallel) is mapped into the neighbouring views (the nearest viewing
   directions) and compared by normalised cross-correlation (NCC: blind to the gain and
   offset of the shading, which changes from view to view under a light fixed in the
   lab as the object turns). The score is the mean of the best few neighbours' NCCs
   (a neighbour may not see the point: the rim of a cup hides its inside from some
   views). A depth is kept only if its score reaches ``min_ncc``; flat patches (no
   texture) are not swept at all, so they keep the hull.
2. **Fusion** into a truncated signed distance (Curless and Levoy 1996) at the voxel
   centres inside the hull: each view with a depth at the voxel's pixel votes
   ``min(depth - z, truncation)`` if the voxel lies in front of its surface or at most
   ``truncation`` behind it (farther behind, the view does not see the voxel). A voxel
   is carved when at least ``min_views`` views vote and their mean is positive: empty
   space, on the evidence of views that see through it. Nothing outside the hull is
   ever added; only parts of the hull are removed. Nor is a voxel that lies on the
   rim of a silhouette near the hull's front (a contour generator: the silhouette
   itself says the surface is there).
3. The refined surface is the zero level of ``max(hull distance, fused distance)``
   (:class:`RefinedDistance`), which the meshers take in place of the hull's own.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import cv2
import numpy as np

from ..carving.hull import drop_specks
from ..geometry.camera import Camera
from ..geometry.grid import VoxelGrid
from ..meshing.marching import marching_cubes_mesh
from ..render import rasterize_depth
from .photo_kernels import fuse_kernel, sweep_kernel

__all__ = ["RefineParams", "Refinement", "RefinedDistance", "neighbour_views", "refine_hull"]


@dataclass(frozen=True)
class RefineParams:
    """Options of :func:`refine_hull`.

    neighbours : views each reference view is compared with (nearest viewing directions).
    best_of : the score of a depth is the mean of this many best neighbour NCCs.
    patch_radius, patch_spacing_px : the patch is (2 radius + 1)^2 pixels this far apart.
    stride_px : a depth every this many pixels, along rows and columns.
    depth_step_px : depths are swept in steps that move the point this many pixels in the
        nearest neighbour (at the hull's median depth), and never finer than half a voxel.
    coarse_steps : the whole ray is swept first every this many steps, then every step
        only either side of its best depth (coarse to fine).
    min_ncc : a depth is kept when its score reaches this.
    min_margin : ... and beats every depth off its peak by this much (unique).
    min_std : grey levels; a flatter patch is not swept (textureless: the hull holds).
    min_views : views that must vote at a voxel for it to be decided.
    truncation_voxels : the fused distance is truncated to this many voxels.
    max_angle_deg : neighbours are at most this far (optical axes), degrees.
    """

    neighbours: int = 4
    best_of: int = 2
    patch_radius: int = 2
    patch_spacing_px: int = 2
    stride_px: int = 3
    depth_step_px: float = 1.0
    coarse_steps: int = 2
    min_ncc: float = 0.7
    min_margin: float = 0.15
    min_std: float = 4.0
    min_views: int = 3
    truncation_voxels: float = 3.0
    max_angle_deg: float = 50.0


@dataclass
class Refinement:
    """What :func:`refine_hull` returns: ``occupancy`` (nx, ny, nz) bool, the hull with the
    carved voxels removed; ``distance`` for the meshers; ``report`` (JSON-ready)."""

    occupancy: np.ndarray
    distance: "RefinedDistance"
    report: dict = field(default_factory=dict)


class RefinedDistance:
    """Signed distance (metres, positive outside) to the refined shape: the larger of the
    hull's (``hull``, a :class:`~sfs_ros.core.meshing.hull_distance.HullDistance`) and the
    fused photo distance ``sdf`` (nx, ny, nz) float32 on ``grid`` (nearest voxel centre;
    -inf where undecided), so the hull stays the outer bound."""

    #: No values kept as the views arrived (:attr:`HullDistance.kept`) are this distance's.
    kept = None

    def __init__(self, hull, sdf: np.ndarray, grid: VoxelGrid):
        self.hull, self.sdf, self.grid = hull, sdf, grid

    def _photo(self, points: np.ndarray) -> np.ndarray:
        index = np.rint((points - self.grid.origin) / self.grid.voxel_size).astype(np.int64)
        inside = np.all((index >= 0) & (index < np.array(self.grid.shape)), axis=1)
        out = np.full(len(points), -np.inf)
        i = index[inside]
        out[inside] = self.sdf[i[:, 0], i[:, 1], i[:, 2]]
        return out

    def __call__(self, points, *, floor_m: float | None = None) -> np.ndarray:
        """Signed distances (n,) of ``points`` (n, 3), metres; ``floor_m`` as the hull's."""
        points = np.ascontiguousarray(points, dtype=np.float64)
        return np.maximum(self.hull(points, floor_m=floor_m), self._photo(points))

    def segment_zeros(self, starts, ends, start_values, end_values, *, iterations: int,
                      tolerance_m: float = 0.0, floor_m: float | None = None) -> np.ndarray:
        """(n,) fractions along segments ``starts`` -> ``ends`` (n, 3) where the distance is
        zero, as :meth:`HullDistance.segment_zeros`: the hull's where it decides both ends,
        else the chord between the ends' values (the photo distance is known at voxel
        centres only, and the chord interpolates them)."""
        starts = np.ascontiguousarray(starts, dtype=np.float64)
        ends = np.ascontiguousarray(ends, dtype=np.float64)
        start_values = np.asarray(start_values, dtype=np.float64)
        end_values = np.asarray(end_values, dtype=np.float64)
        out = start_values / (start_values - end_values)
        photo_start, photo_end = self._photo(starts), self._photo(ends)
        hull = (photo_start == -np.inf) & (photo_end == -np.inf)   # (most: undecided)
        asked = ~hull
        hull[asked] = ((photo_start[asked] <= self.hull(starts[asked]))
                       & (photo_end[asked] <= self.hull(ends[asked])))
        out[hull] = self.hull.segment_zeros(starts[hull], ends[hull], start_values[hull],
                                            end_values[hull], iterations=iterations,
                                            tolerance_m=tolerance_m, floor_m=floor_m)
        return out

    def project(self, points, directions, *, reach_m: float) -> tuple[np.ndarray, np.ndarray]:
        """Points (n, 3) moved along ``directions`` (n, 3) to the nearest inside -> outside
        crossing within ``reach_m`` metres (8 steps, then 20 bisections); and (n,) bool,
        which were moved (as :meth:`HullDistance.project`)."""
        points = np.asarray(points, dtype=np.float64)
        unit = directions / np.linalg.norm(directions, axis=1, keepdims=True)
        steps = np.linspace(-reach_m, reach_m, 9)
        values = np.stack([self(points + t * unit) for t in steps], axis=1)
        crossing = (values[:, :-1] <= 0) & (values[:, 1:] > 0)
        centre = np.abs(steps[:-1] + steps[1:])
        pick = np.argmin(np.where(crossing, centre, np.inf), axis=1)
        found = crossing.any(axis=1)
        lo, hi = steps[pick], steps[pick + 1]
        for _ in range(20):
            mid = 0.5 * (lo + hi)
            outside = self(points + mid[:, None] * unit) > 0
            hi, lo = np.where(outside, mid, hi), np.where(outside, lo, mid)
        t = np.where(found, 0.5 * (lo + hi), 0.0)
        return points + t[:, None] * unit, found


def neighbour_views(cameras: list[Camera], count: int, max_angle_deg: float) -> list[list[int]]:
    """For each camera, the indices of up to ``count`` others with the nearest optical axes
    (nearest first), at most ``max_angle_deg`` apart and not the same direction."""
    axes = np.array([c.R[2] for c in cameras])
    cosines = np.clip(axes @ axes.T, -1.0, 1.0)
    np.fill_diagonal(cosines, -2.0)
    limit = math.cos(math.radians(max_angle_deg))
    out = []
    for row in cosines:
        order = [int(j) for j in np.argsort(-row) if limit <= row[j] < 1.0 - 1e-9]
        out.append(order[:count])
    return out


def _homography_parts(reference: Camera, other: Camera) -> tuple[np.ndarray, np.ndarray]:
    """``M`` (3, 3) and ``m`` (3,): a reference pixel ``x`` (homogeneous) seen at depth ``d``
    maps to the homogeneous pixel ``M x + m / d`` of ``other`` (pinhole cameras)."""
    relative = other.R @ reference.R.T
    M = other.K @ relative @ np.linalg.inv(reference.K)
    m = other.K @ (other.t - relative @ reference.t)
    return M, m


def _patch_offsets(params: RefineParams) -> np.ndarray:
    """(k, 2) float64 pixel offsets ``(du, dv)`` of the patch."""
    span = np.arange(-params.patch_radius, params.patch_radius + 1) * params.patch_spacing_px
    du, dv = np.meshgrid(span, span)
    return np.column_stack([du.ravel(), dv.ravel()]).astype(np.float64)


def _depth_step(reference: Camera, other: Camera, depth_m: float, params: RefineParams,
                voxel_m: float) -> float:
    """Depth step, metres, that moves a point at ``depth_m`` by ``depth_step_px`` pixels in
    ``other`` (the baseline's angle and the pixel footprint), at least half a voxel."""
    cosine = float(np.clip(reference.R[2] @ other.R[2], -1.0, 1.0))
    footprint = depth_m / math.sqrt(reference.K[0, 0] * reference.K[1, 1])
    return max(0.5 * voxel_m, params.depth_step_px * footprint
               / max(math.sqrt(1.0 - cosine * cosine), 1e-3))


def _depth_map(n: int, cameras, greys, masks, fronts, backs, neighbours, voxel_m: float,
               params: RefineParams) -> np.ndarray:
    """(rows, cols) float64 confident depths (metres, NaN elsewhere) of view ``n`` at every
    ``stride_px``-th pixel (:func:`.photo_kernels.sweep_kernel`)."""
    seen = fronts[n][np.isfinite(fronts[n])]
    step_m = _depth_step(cameras[n], cameras[neighbours[n][0]], float(np.median(seen)),
                         params, voxel_m)
    reach = params.patch_radius * params.patch_spacing_px
    kernel = np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)
    inner = cv2.erode(masks[n].view(np.uint8), kernel).astype(bool)
    others = neighbours[n]
    parts = [_homography_parts(cameras[n], cameras[j]) for j in others]
    height, width = masks[n].shape
    shape = (height // params.stride_px + 1, width // params.stride_px + 1)
    depth, score = np.empty(shape), np.empty(shape)
    # The front and back come from a coarser hull than the carved one: a step wider.
    sweep_kernel(greys[n], inner, fronts[n] - step_m, backs[n] + step_m, _patch_offsets(params),
                 np.array([p[0] for p in parts]), np.array([p[1] for p in parts]),
                 np.stack([greys[j] for j in others]), float(step_m), params.coarse_steps,
                 params.stride_px,
                 float(params.min_std), min(params.best_of, len(others)),
                 float(params.min_margin), depth, score)
    depth[~(score >= params.min_ncc)] = np.nan
    return depth


def _rim_depths(mask: np.ndarray, front: np.ndarray, stride: int) -> np.ndarray:
    """(H // stride + 1, W // stride + 1) float32: at the pixels ``(row, col) * stride``, the
    nearest depth of the hull's front (``front`` (H, W), metres) over the rim of the
    silhouette ``mask`` (H, W) bool (its pixels beside the background) within the block of
    pixels that rounds to it; inf where the block holds no rim."""
    inner = cv2.erode(mask.view(np.uint8), np.ones((3, 3), np.uint8),
                      borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
    rim = np.where(mask & ~inner, front, np.inf).astype(np.float32)
    height, width = mask.shape
    rows, cols = height // stride + 1, width // stride + 1
    half = stride // 2
    padded = np.full((rows * stride, cols * stride), np.inf, dtype=np.float32)
    padded[half:half + height, half:half + width] = rim[:rows * stride - half,
                                                        :cols * stride - half]
    return padded.reshape(rows, stride, cols, stride).min(axis=(1, 3))


def _removed_report(carved: np.ndarray, grid: VoxelGrid, hull_voxels: int,
                    weights: np.ndarray) -> dict:
    """Where and how much was carved: voxels, volume, fraction of the hull, the box of the
    carved voxels' centres (``[min, max]``, metres) and the mean count of views whose
    depths carved them."""
    where = np.argwhere(carved)
    box = ([grid.index_to_world(where.min(axis=0)).reshape(3).tolist(),
            grid.index_to_world(where.max(axis=0)).reshape(3).tolist()]
           if len(where) else None)
    return {"removed_voxels": int(len(where)),
            "removed_volume_m3": float(len(where) * grid.voxel_size ** 3),
            "removed_fraction_of_hull": float(len(where) / max(1, hull_voxels)),
            "removed_box_m": box,
            "mean_votes_removed": float(weights.mean()) if len(weights) else 0.0}


def _coarse_hull(occupancy: np.ndarray, grid: VoxelGrid) -> tuple[np.ndarray, np.ndarray]:
    """A closed mesh (vertices (n, 3) metres, faces (m, 3)) holding the hull: its voxels
    merged in 2 x 2 x 2 blocks (a block is in if any of its voxels is), for z-buffers."""
    nx, ny, nz = (-(-n // 2) * 2 for n in occupancy.shape)
    padded = np.zeros((nx, ny, nz), dtype=bool)
    padded[:occupancy.shape[0], :occupancy.shape[1], :occupancy.shape[2]] = occupancy
    blocks = padded.reshape(nx // 2, 2, ny // 2, 2, nz // 2, 2).any(axis=(1, 3, 5))
    coarse = VoxelGrid(grid.bounds_min, grid.bounds_min + 2 * grid.voxel_size
                       * np.array(blocks.shape), 2 * grid.voxel_size)
    return marching_cubes_mesh(blocks, coarse, smooth_sigma_vox=0.0)


def refine_hull(occupancy: np.ndarray, grid: VoxelGrid, cameras: list[Camera], masks,
                images, hull, params: RefineParams = RefineParams()) -> Refinement:
    """Carve the hull where the colours show empty space (see the module doc).

    Parameters
    ----------
    occupancy : (nx, ny, nz) bool, the carved hull on ``grid``.
    cameras : pinhole cameras without distortion (the views that carved it).
    masks : their silhouettes, (H, W) bool each.
    images : their RGB images, (H, W, 3) uint8 each, on the cameras' pixel grid.
    hull : the hull's signed distance (:class:`~sfs_ros.core.meshing.hull_distance.HullDistance`).
    """
    greys = [np.ascontiguousarray(np.asarray(im, np.float32).mean(axis=2)) for im in images]
    vertices, faces = _coarse_hull(occupancy, grid)
    fronts = [rasterize_depth(vertices, faces, c, closed=True) for c in cameras]
    backs = [rasterize_depth(vertices, faces[:, ::-1], c, closed=True) for c in cameras]
    neighbours = neighbour_views(cameras, params.neighbours, params.max_angle_deg)
    depths = [(_depth_map(n, cameras, greys, masks, fronts, backs, neighbours,
                          grid.voxel_size, params) if neighbours[n] and masks[n].any() and
               np.isfinite(fronts[n]).any() else None)
              for n in range(len(cameras))]
    rows = max(m.shape[0] // params.stride_px + 1 for m in masks)
    cols = max(m.shape[1] // params.stride_px + 1 for m in masks)
    stack = np.full((len(cameras), rows, cols), np.nan, dtype=np.float32)
    for n, d in enumerate(depths):
        if d is not None:
            stack[n, :d.shape[0], :d.shape[1]] = d
    rims = np.full_like(stack, np.inf)
    for n in range(len(cameras)):
        rim = _rim_depths(masks[n], fronts[n], params.stride_px)
        rims[n, :rim.shape[0], :rim.shape[1]] = rim
    index = np.argwhere(occupancy)
    sdf, weight = np.empty(len(index)), np.empty(len(index), dtype=np.int64)
    # The coarse hull's front lies up to a coarse voxel before the hull's: the band kept
    # behind a rim reaches two coarse voxels.
    fuse_kernel(grid.index_to_world(index), np.stack([c.projection_matrix for c in cameras]),
                stack, rims, np.full(len(cameras), float(params.stride_px)),
                params.truncation_voxels * grid.voxel_size, 4.0 * grid.voxel_size,
                params.min_views, sdf, weight)
    carved_at = sdf > 0
    refined = occupancy.copy()
    refined[tuple(index[carved_at].T)] = False
    refined, specks = drop_specks(refined)
    field_ = np.full(grid.shape, -np.inf, dtype=np.float32)
    decided = ~np.isnan(sdf)
    field_[tuple(index[decided].T)] = sdf[decided]
    carved = occupancy & ~refined
    field_[carved & ~(field_ > 0)] = 0.5 * grid.voxel_size   # specks dropped: outside
    report = {"views_with_depths": int(sum(np.isfinite(d).any() for d in depths
                                           if d is not None)),
              "confident_depths": int(np.isfinite(stack).sum()),
              "decided_voxels": int(decided.sum()), "specks_removed": int(specks),
              **_removed_report(carved, grid, len(index), weight[carved_at]),
              "parameters": asdict(params)}
    return Refinement(occupancy=refined, distance=RefinedDistance(hull, field_, grid),
                      report=report)
