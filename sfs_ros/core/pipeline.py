"""The whole reconstruction: tagged images in, a checked mesh and a report out.

Two halves: :func:`carve_scan` runs the stages of :mod:`sfs_ros.core.stages`
(segmentation, the grid, consensus, fusion of the silhouettes, carving,
refinement below the hull on request, the mesher's input, the views to colour
from); its :class:`~sfs_ros.core.carved_scan.CarvedScan` may cross a process (the
cell's carving and meshing nodes) to :func:`sfs_ros.core.mesh_scan.mesh_scan`
(meshing, then colour beside the mesh checks and the reprojection of the mesh
into every view). :func:`reconstruct` runs both. Each stage is timed in the
report, which :mod:`sfs_ros.core.scan_report` assembles from the stages' pieces.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from .carved_scan import CarvedScan, ScanView
from .carving.bounds import BoxCarve
from .carving.carve import KeptCarve, same_grid, unpack_bits, view_keys
from .carving.directions import check_directions
from .carving.fusion import reference_misses
from .carving.resolution import choose_voxel_size, default_memory_budget
from .exchange.views import View, ViewSet, as_bounds
from .geometry.grid import VoxelGrid
from .geometry.lens import is_distorted, lens_problem
from .mesh_scan import Reconstruction, mesh_scan, timed
from .meshing.hull_distance import DistanceImages, HullDistance
from .meshing.kept_band import KeptBand
from .meshing.meshers import MESHER, Mesher, mesher
from .scan_report import carving_report
from .segmentation.segment import SegmentationParams
from .settings import RESOLUTION
from .stages import (
    Fused,
    Hull,
    Progress,
    Segmented,
    UsedViews,
    carve_hull,
    check_max_misses,
    choose_colour_views,
    choose_grid,
    fuse_views,
    fusion_grid,
    refine_hull,
    resegment_views,
    segment_views,
)

__all__ = ["CarvedScan", "ComputedOnArrival", "ExpectedCarves", "ReconstructionParams",
           "Reconstruction", "carve_scan", "reconstruct"]

@dataclass(frozen=True)
class ReconstructionParams:
    """Options of :func:`reconstruct`.

    Attributes
    ----------
    resolution : int or None
        Voxels along the longest side of the bounding box, in
        :data:`sfs_ros.core.settings.RESOLUTION`'s range (ignored when
        ``voxel_size_m`` is set). None: the voxel is the finest pixel footprint
        at the box centre over the views (1.5 of it when the masks have next to no
        thin parts), coarsened only to fit ``max_memory_bytes``
        (:func:`sfs_ros.core.carving.resolution.choose_voxel_size`).
    voxel_size_m : float or None
        Voxel edge, metres.
    max_memory_bytes : int or None
        Working memory the grid may take, bytes; None: a quarter of the
        machine's memory. A given resolution or voxel size that needs more is
        refused before anything is allocated.
    bounds_m : (2, 3) sequence or None
        Carving box ``[min, max]``, metres; else the input's, else estimated
        from the silhouettes. The input's and the estimated box are then
        shrunk to a tolerant carve's hull plus a margin.
    mesher : str
        A name in :data:`sfs_ros.core.meshing.meshers.MESHERS`.
    mesher_options : dict
        ``{option name: value}`` of the mesher's own options (its ``options``, e.g. the
        advancing front's ``block``); those not given take their defaults.
    max_misses : int
        A voxel survives if at most this many views see it outside their
        silhouette (after the fusion repaired the masks).
    check_consistency : bool
        Fuse the silhouettes (:func:`sfs_ros.core.carving.fusion.fuse_silhouettes`):
        where the hull the other views agree on lies deep outside one view's
        mask, that view is overruled there (its mask is filled); a view that
        disagrees as a whole is dropped. Every decision is in the report.
    consistency_max_missing : float
        A view is dropped as a whole when more than this fraction of the
        projection of the hull the others agree on is missing from its mask.
    holdout : tuple of str
        Names of views kept out of carving and only used to evaluate the mesh.
    segmentation : SegmentationParams or None
        None: the input's stored parameters, else the defaults.
    consensus : bool
        Re-segment every view (graph-cut segmentation only) with the projection
        of the hull all views agree on as a prior, before the fusion
        (:mod:`sfs_ros.core.segmentation.consensus`).
    colour : bool
        Colour the mesh's vertices from the images of the views used
        (:func:`sfs_ros.core.meshing.colour.vertex_colours`: the views that see each
        point, blended), at most
        :data:`~sfs_ros.core.meshing.colour.MAX_COLOUR_VIEWS` of them, spread out.
    refine : bool
        Go below the visual hull where the colours show empty space (stage
        ``refinement``, :func:`sfs_ros.core.refinement.photo.refine_hull`): concavities
        no silhouette shows; the hull is kept where the images cannot tell. Needs
        colour images and pinhole cameras (else skipped, with the reason in the report).
    """

    resolution: int | None = None
    voxel_size_m: float | None = None
    max_memory_bytes: int | None = None
    bounds_m: tuple | None = None
    mesher: str = MESHER.default
    mesher_options: dict = field(default_factory=dict)
    max_misses: int = 0
    check_consistency: bool = True
    consistency_max_missing: float = 0.35
    holdout: tuple = ()
    segmentation: SegmentationParams | None = None
    colour: bool = False
    consensus: bool = True
    refine: bool = False

    def __post_init__(self) -> None:
        mesher(self.mesher).option_values(self.mesher_options)
        if self.resolution is not None:
            RESOLUTION.check(int(self.resolution))
        if self.voxel_size_m is not None and not 0 < self.voxel_size_m < math.inf:
            raise ValueError(f"voxel size must be a finite number of metres > 0, got "
                             f"{self.voxel_size_m}")
        if self.max_memory_bytes is not None and not int(self.max_memory_bytes) > 0:
            raise ValueError(f"max_memory_bytes must be > 0, got {self.max_memory_bytes}")
        if int(self.max_misses) < 0:
            raise ValueError(f"max_misses must be >= 0, got {self.max_misses}")
        if not 0.0 <= self.consistency_max_missing <= 1.0:
            raise ValueError(f"consistency_max_missing must be in [0, 1], "
                             f"got {self.consistency_max_missing}")


@dataclass(frozen=True)
class ComputedOnArrival:
    """What a scan received view by view computed as its views arrived (while the rig
    moved), for :func:`reconstruct` to find instead of computing it: the same result
    either way. Each part is used only for the views it holds.

    distances : the masks' distance images, for the mesh.
    box : the coarse carve that refines an input box (:func:`.carving.bounds.refine_bounds`).
    undistorted_masks : {view name: (H, W) bool} the given masks (``masks`` of
        :func:`carve_scan`) already undistorted onto their views' ideal pinholes, for the
        views whose lens distorts (the others' masks are their own undistortion).
    carves : carves of the grids the reconstruction was expected to choose
        (:class:`.carving.carve.KeptCarve`): the fusion's reference hull and the hull,
        taken from one that holds them.
    band : the views' values at the voxels near the hull's surface, on the grid the
        reconstruction was expected to choose (:class:`.meshing.kept_band.KeptBand`), for
        the marching cubes' signed distance.
    """

    distances: DistanceImages | None = None
    box: BoxCarve | None = None
    undistorted_masks: dict = field(default_factory=dict)
    carves: tuple = ()
    band: KeptBand | None = None


class ExpectedCarves:
    """The carves :func:`carve_scan` is expected to make of a scan received view by view,
    kept as its views arrive (:class:`.carving.carve.KeptCarve`), for
    :attr:`ComputedOnArrival.carves`: the hull and the fusion's reference hull, on the
    grid it is expected to choose for the input box ``bounds_m`` (2, 3), metres, at
    ``resolution`` voxels along the longest side (the box refined by ``box``, the coarse
    carve kept of the same views, as :func:`.stages.choose_grid` refines it). When a
    view changes that grid (it shrinks the box), the carves start again on the new one
    with every view so far: the box settles within the first views. Starting again
    waits until the views have grown by a quarter since the last start
    (:data:`RESTART_GROWTH`), so that a box that never settles costs a few carves per
    view, not one per view so far. A reconstruction that chooses another grid, or
    carves other masks, carves anew: the same result. Given the views' distance images
    (``known``, each view's added before the view), it also keeps the views' values at the
    voxels near the hull's surface (:attr:`band`, a
    :class:`.meshing.kept_band.KeptBand` following the hull carved so far), for
    :attr:`ComputedOnArrival.band`.

    Memory: a byte per voxel of the grid and of the reference grid, and each view's
    packed mask (twice with ``known``); with ``known``, the band's voxels
    (:class:`.meshing.kept_band.KeptBand`: 48 bytes each without misses).
    """

    #: The carves start again on a new grid only once the views have grown by this
    #: factor since they last started.
    RESTART_GROWTH = 1.25
    #: :attr:`band` follows the hull every this many views of one grid (the first time
    #: with every view so far): the voxels the band reaches in between are evaluated
    #: after the last view.
    BAND_FOLLOWS_EVERY = 8

    def __init__(self, bounds_m, resolution: int, max_misses: int, box: BoxCarve,
                 known: DistanceImages | None = None):
        self._bounds = as_bounds(bounds_m, what="bounds_m")
        self._resolution, self._max_misses, self._box = int(resolution), int(max_misses), box
        self._known = known
        self._views: list[tuple] = []   # (camera, packed mask, mask shape)
        self._grid: VoxelGrid | None = None
        self._started_with = 0   # views when the carves last started
        self.carves: tuple = ()
        self.band: KeptBand | None = None

    def _expected_grid(self) -> tuple[np.ndarray, VoxelGrid] | None:
        """The box (2, 3), metres, and grid :func:`.stages.choose_grid` chooses for the
        views so far (the input box refined, at the resolution); None before three views
        or when it refuses."""
        cameras = [camera for camera, _, _ in self._views]
        if len(cameras) < 3:
            return None
        bounds = self._box.refined(reference_misses(len(cameras)))
        try:
            choice = choose_voxel_size(bounds, cameras, resolution=self._resolution,
                                       max_memory_bytes=default_memory_budget())
        except ValueError:
            return None
        return bounds, VoxelGrid(bounds[0], bounds[1], choice.voxel_size_m)

    def _mask(self, index: int) -> np.ndarray:
        _, packed, shape = self._views[index]
        return unpack_bits(packed, shape)

    def add(self, camera, mask: np.ndarray) -> None:
        """Count one more view: its ideal pinhole ``camera`` and ``mask`` (H, W) bool on it."""
        self._views.append((camera, np.packbits(mask, axis=None), mask.shape))
        expected = self._expected_grid()
        if expected is None:
            self._grid, self.carves, self.band = None, (), None
            return
        bounds, grid = expected
        if self._grid is not None and same_grid(grid, self._grid):
            for store in self.carves:
                store.add(camera, mask)
            self._follow_hull(camera, mask)
            return
        self._grid, self.carves, self.band = None, (), None
        if len(self._views) < self.RESTART_GROWTH * self._started_with:
            return
        self._grid, self._started_with = grid, len(self._views)
        self.carves = (KeptCarve(grid, most_misses=self._max_misses),
                       KeptCarve(fusion_grid(bounds, grid), most_misses=BoxCarve.MOST_MISSES))
        for index, (view_camera, _, _) in enumerate(self._views):
            view_mask = mask if index == len(self._views) - 1 else self._mask(index)
            for store in self.carves:
                store.add(view_camera, view_mask)

    def _follow_hull(self, camera, mask: np.ndarray) -> None:
        """Add one more view (``camera``, ``mask``) to :attr:`band` (none without
        ``known``), which follows the hull carved so far every :data:`BAND_FOLLOWS_EVERY`
        views. It starts once the grid has held that many views past the carves' start (a
        box still settling would start it again and again), with every view so far."""
        if self._known is None:
            return
        if self.band is not None:
            self.band.add(camera, mask)
        if (len(self._views) - self._started_with) % self.BAND_FOLLOWS_EVERY:
            return
        if self.band is None:
            self.band = KeptBand(self._grid, max_misses=self._max_misses, known=self._known)
            for index, (view_camera, _, _) in enumerate(self._views):
                self.band.add(view_camera,
                              mask if index == len(self._views) - 1 else self._mask(index))
        self.band.follow(self.carves[0].occupancy(self._max_misses))


def _check_holdout(view_set: ViewSet, holdout: tuple) -> None:
    names = [v.name for v in view_set.views]
    unknown = sorted(set(holdout) - set(names))
    if unknown:
        raise ValueError(f"held-out views {unknown} are not in the input (views: {names[:5]}...)")


def _check_lenses(views: list[View]) -> None:
    """ValueError naming the first view whose lens cannot be its camera's
    (:func:`.geometry.lens.lens_problem`)."""
    for view in views:
        camera = view.camera
        if is_distorted(camera):
            problem = lens_problem(camera.K, camera.distortion, camera.width, camera.height)
            if problem:
                raise ValueError(f"view {view.name}: {problem}")


def _box_centre(box) -> np.ndarray | None:
    """(3,) centre of a ``[min, max]`` box, metres; None if there is none or it is not a
    box (:func:`.exchange.views.as_bounds`; refused with the reason where it is used)."""
    if box is None:
        return None
    try:
        return as_bounds(box, what="bounding box").mean(axis=0)
    except ValueError:
        return None


def _first_used(segmented: Segmented, holdout: tuple, n_input: int) -> list[int]:
    """Indices into ``segmented.views`` of the views not held out; refused when none."""
    used = [i for i, v in enumerate(segmented.views) if v.name not in holdout]
    if not used:
        raise ValueError(
            f"no usable view: {n_input} in the input, {len(segmented.rejected)} rejected, "
            f"{len(holdout)} held out")
    return used


def _check_left(segmented: Segmented, used: UsedViews, rejected: list[dict],
                bounds: np.ndarray, max_misses: int) -> None:
    """Refuse to carve with the views the consensus and the fusion left when they cannot
    make a hull."""
    if not used.indices:
        raise ValueError(f"no usable view: all {len(rejected)} views were rejected "
                         f"(first: {rejected[0]['view']}: {rejected[0]['reason']})")
    check_directions(used.cameras, used.names(segmented.views), bounds.mean(axis=0))
    check_max_misses(max_misses, len(used.cameras), " left")


def _kept_band(band, grid: VoxelGrid, used: UsedViews, coverage: list, max_misses: int):
    """``band`` (:attr:`ComputedOnArrival.band`) if it holds the values of the views that
    carve, on ``grid``, for ``max_misses``, and no view's mask comes with its coverage;
    else None."""
    if band is None or any(alpha is not None for alpha in coverage):
        return None
    return band if band.holds(grid, view_keys(used.cameras, used.prepared), max_misses) \
        else None


def _mesher_and_options(params: ReconstructionParams, grid: VoxelGrid) -> tuple[Mesher, dict]:
    """The mesher asked for and its options' values, refused if the grid cannot take them."""
    chosen = mesher(params.mesher)
    options = chosen.option_values(params.mesher_options)
    if chosen.check is not None:
        chosen.check(grid, **options)
    return chosen, options


def _scan_views(views: list[View], used_names: set, holdout: tuple) -> list[ScanView]:
    return [ScanView(v.name, v.camera, "used" if v.name in used_names
                     else "held-out" if v.name in holdout else "rejected",
                     None if v.theta_rad is None else (v.theta_rad, v.phi_rad))
            for v in views]


def carve_scan(view_set: ViewSet, params: ReconstructionParams = ReconstructionParams(), *,
               progress: Progress | None = None, masks: dict | None = None,
               images: dict | None = None,
               precomputed: ComputedOnArrival = ComputedOnArrival()) -> CarvedScan:
    """The carving half of :func:`reconstruct`: the views' hull and what its meshing needs
    (:class:`~sfs_ros.core.carved_scan.CarvedScan`), the stages of :mod:`.stages` in turn.

    ``masks`` ({view name: (H, W) bool}, optional) are silhouettes the caller already
    has (e.g. a live scan's received masks): those views are not read nor segmented.
    ``images`` ({view name: (H, W, 3) uint8 RGB as taken, or the path of its file},
    optional): with ``params.colour``, the images that colour the mesh instead of the
    views' files (e.g. a live scan's or a bag's captures); a used view without one takes
    no part. ``precomputed`` (optional): what a live scan computed as its views arrived
    (:class:`ComputedOnArrival`); the result is the same without.

    Views that cannot be read, have an empty silhouette or disagree with the
    others are rejected and reported, never silently used or dropped. Raises
    ``ValueError`` with a one-line reason when no mesh can be made (no usable
    view, views from fewer than three distinct directions
    (:mod:`.carving.directions`), a lens that does not map its image onto itself
    (:func:`.geometry.lens.lens_problem`), a bounding box that misses the object,
    an empty hull).
    """
    progress = progress or (lambda stage, fraction: None)
    timings: dict[str, float] = {}
    seg_params = params.segmentation or SegmentationParams.from_dict(view_set.segmentation or {})
    _check_holdout(view_set, params.holdout)
    _check_lenses(view_set.views)
    with timed(timings, "segmentation"):
        segmented = segment_views(view_set, seg_params, masks or {}, progress,
                                  undistorted=precomputed.undistorted_masks,
                                  keep_images=params.consensus and seg_params.method == "graph-cut")
    first = _first_used(segmented, params.holdout, len(view_set.views))
    box = params.bounds_m if params.bounds_m is not None else view_set.bounds_m
    check_directions([segmented.views[i].camera for i in first],
                     [segmented.views[i].name for i in first], _box_centre(box))

    with timed(timings, "bounds"):
        used = UsedViews.of(segmented.views, first, [segmented.masks[i] for i in first])
        chosen = choose_grid(segmented.views, used, given_box=params.bounds_m,
                             input_box=view_set.bounds_m, max_misses=params.max_misses,
                             resolution=params.resolution, voxel_size_m=params.voxel_size_m,
                             max_memory_bytes=params.max_memory_bytes,
                             known_box=precomputed.box)
        grid = chosen.grid
        the_mesher, mesher_options = _mesher_and_options(params, grid)

    resegmentation = None
    if params.consensus and len(used.cameras) >= 3 and seg_params.method == "graph-cut":
        with timed(timings, "consensus"):
            again = resegment_views(segmented, used, grid, seg_params)
        segmented, used, resegmentation = again.segmented, again.used, again.report

    fused = Fused(used, [], None, [])
    with timed(timings, "fusion"):
        if params.check_consistency and len(used.cameras) >= 3:
            fused = fuse_views(segmented.views, used, chosen, params.consistency_max_missing,
                               progress, exact=segmented.exact, kept=precomputed.carves)
    used, rejected = fused.used, segmented.rejected + fused.dropped
    _check_left(segmented, used, rejected, chosen.bounds, params.max_misses)

    # The views' distance images (per view, in threads) are made while the hull is
    # carved: they need the masks alone.
    coverage = [segmented.coverage.get(name) for name in used.names(segmented.views)]
    with ThreadPoolExecutor(max_workers=1) as beside:
        distance = beside.submit(
            HullDistance, used.cameras, used.masks, max_misses=params.max_misses,
            bounds_m=(grid.bounds_min, grid.bounds_max), known=precomputed.distances,
            coverage=coverage,
            kept=_kept_band(precomputed.band, grid, used, coverage, params.max_misses))
        with timed(timings, "carving"):
            occupancy, specks_removed = carve_hull(grid, used, params.max_misses, progress,
                                                   kept=precomputed.carves)
        hull = Hull(occupancy, distance.result(), specks_removed)
    if params.refine:
        with timed(timings, "refinement"):
            hull = refine_hull(hull, grid, segmented, used, images, progress)
    with timed(timings, "mesher_input"):
        mesher_input = the_mesher.prepare(hull.occupancy, grid, hull.distance, **mesher_options)
    colour = choose_colour_views(segmented, used, images, params.colour)
    report = carving_report(
        source=view_set.source, n_views=len(view_set.views), params=params,
        mesher_options=mesher_options, segmentation=seg_params, box=chosen,
        segmented=segmented, used=used, rejected=rejected, resegmentation=resegmentation,
        fused=fused, hull=hull, timings=timings)
    return CarvedScan(
        grid=grid, occupancy=hull.occupancy, mesher=params.mesher, mesher_input=mesher_input,
        views=_scan_views(segmented.views, set(used.names(segmented.views)), params.holdout),
        masks=segmented.masks, colour_views=colour.indices, colour_masks=colour.masks,
        colour_images=colour.images, report=report, taken=segmented.taken)


def reconstruct(view_set: ViewSet, params: ReconstructionParams = ReconstructionParams(), *,
                progress: Progress | None = None, masks: dict | None = None,
                images: dict | None = None,
                precomputed: ComputedOnArrival = ComputedOnArrival()) -> Reconstruction:
    """Reconstruct the object seen in ``view_set``: :func:`carve_scan`, then
    :func:`sfs_ros.core.mesh_scan.mesh_scan` (the arguments as :func:`carve_scan`'s).

    Views that cannot be read, have an empty silhouette or disagree with the
    others are rejected and reported, never silently used or dropped. Raises
    ``ValueError`` with a one-line reason when no mesh can be made.
    """
    carved = carve_scan(view_set, params, progress=progress, masks=masks, images=images,
                        precomputed=precomputed)
    return mesh_scan(carved, progress=progress)
