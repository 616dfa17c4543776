"""The whole reconstruction: tagged images in, a checked mesh and a report out.

Two halves: :func:`carve_scan` (stages: segmentation, bounding box, consensus,
fusion of the silhouettes, carving, refinement below the hull on request, the
mesher's input), whose :class:`~sfs_ros.core.carved_scan.CarvedScan` may cross a
process (the cell's carving and meshing nodes), and
:func:`sfs_ros.core.mesh_scan.mesh_scan` (meshing, mesh checks, colour on
request, reprojection of the mesh into every view, the report).
:func:`reconstruct` runs both. Each stage is timed in the report.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from .carved_scan import CarvedScan, ScanView
from .carving.bounds import BoxCarve, estimate_bounds, refine_bounds
from .carving.carve import PreparedMasks, carve
from .carving.consistency import bbox_clips_object
from .carving.directions import check_directions
from .carving.fusion import fuse_silhouettes, reference_misses
from .carving.hull import drop_specks
from .carving.resolution import choose_voxel_size, default_memory_budget
from .exchange.views import View, ViewSet, as_bounds, read_image
from .geometry.grid import VoxelGrid
from .geometry.lens import (
    distort_mask,
    ideal_camera,
    is_distorted,
    lens_problem,
    undistort_image,
    undistort_mask,
)
from .mesh_scan import Reconstruction, mesh_scan
from .mesh_scan import timed as _timed
from .meshing.colour import MAX_COLOUR_VIEWS, spread_views
from .meshing.hull_distance import DistanceImages, HullDistance
from .meshing.meshers import MESHER, mesher
from .refinement.scan import refine_views
from .resegment import Consensus, consensus_masks
from .segment import SegmentationParams, segment
from .settings import RESOLUTION
from .workers import map_in_threads

__all__ = ["CarvedScan", "Precomputed", "ReconstructionParams", "Reconstruction", "carve_scan",
           "reconstruct"]

#: Progress callback: (stage name, fraction of the stage done in [0, 1]).
Progress = Callable[[str, float], None]


@dataclass(frozen=True)
class ReconstructionParams:
    """Options of :func:`reconstruct`.

    Attributes
    ----------
    resolution : int or None
        Voxels along the longest side of the bounding box, in
        :data:`sfs_ros.core.settings.RESOLUTION`'s range (ignored when
        ``voxel_size_m`` is set). None: the voxel is the finest pixel footprint
        at the box centre over the views, coarsened only to fit
        ``max_memory_bytes`` (:func:`sfs_ros.core.carving.resolution.choose_voxel_size`).
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
        (:mod:`sfs_ros.core.resegment`).
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
class Precomputed:
    """What a scan received view by view computed as its views arrived (while the rig
    moved), for :func:`reconstruct` to find instead of computing it: the same result
    either way. Each part is used only for the views it holds.

    distances : the masks' distance images, for the mesh.
    box : the coarse carve that refines an input box (:func:`.carving.bounds.refine_bounds`).
    """

    distances: DistanceImages | None = None
    box: BoxCarve | None = None


def _read_and_segment(view: View, params: SegmentationParams,
                      given: np.ndarray | None) -> tuple[np.ndarray, bool] | str:
    """The view's silhouette (H, W) bool (``given``, else segmented from its image) and
    whether it is exact (its image's alpha channel), or why it cannot be used."""
    if given is not None:
        expected = (view.camera.height, view.camera.width)
        if np.shape(given) != expected or np.asarray(given).dtype != np.bool_:
            return (f"given silhouette is {np.asarray(given).dtype} {np.shape(given)}, "
                    f"expected {expected} bool (the camera's size)")
        return (given, False) if given.any() else "empty silhouette: no object found"
    try:
        image = read_image(view.image_path, keep_alpha=not params.ignore_alpha,
                           expected_size=(view.camera.width, view.camera.height))
    except ValueError as err:
        return str(err)
    result = segment(image, params)
    exact = image.ndim == 3 and image.shape[2] == 4 and not params.ignore_alpha
    return "empty silhouette: no object found" if result.empty else (result.mask, exact)


def _segment_views(views: list[View], params: SegmentationParams, progress: Progress,
                   rejected: list[dict], given: dict
                   ) -> tuple[list[View], list[np.ndarray], dict, set]:
    """Read and segment every view not in ``given`` (in threads, results in input order);
    bad ones go to ``rejected`` with the reason.

    Returns the kept views with ideal cameras, their masks undistorted onto them
    (:mod:`.geometry.lens`), ``{name: mask as taken}`` and the names of the views whose
    mask is their image's alpha channel (exact: the fusion never overrules it)."""
    kept, masks, taken, exact = [], [], {}, set()
    progress("segmentation", 0.0)
    results = map_in_threads(lambda view: _read_and_segment(view, params, given.get(view.name)),
                             views)
    for n, (view, result) in enumerate(zip(views, results)):
        if isinstance(result, str):
            rejected.append({"view": view.name, "reason": result})
        else:
            mask, is_exact = result
            # Segmented as taken, carved as an ideal pinhole: the mask is undistorted once.
            kept.append(replace(view, camera=ideal_camera(view.camera)))
            masks.append(undistort_mask(mask, view.camera))
            taken[view.name] = mask
            if is_exact:
                exact.add(view.name)
        progress("segmentation", (n + 1) / max(1, len(views)))
    return kept, masks, taken, exact


def _some(names: list[str], limit: int = 3) -> str:
    return ", ".join(names[:limit]) + (f" and {len(names) - limit} more"
                                       if len(names) > limit else "")


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


def _fills_frame(mask: np.ndarray) -> bool:
    """Whether the silhouette touches two opposite sides of its image."""
    return bool((mask[:, 0].any() and mask[:, -1].any()) or (mask[0].any() and mask[-1].any()))


def _consensus(views: list[View], used: list[int], cameras, masks, prepared: PreparedMasks,
               grid: VoxelGrid, seg_params: SegmentationParams, lenses: dict) -> Consensus:
    """The used views' masks re-segmented with the hull of all views as a prior
    (:func:`sfs_ros.core.resegment.consensus_masks`); alpha masks are kept. The masks
    and ``cameras`` are on the ideal pinhole's pixel grid, so each image is undistorted
    through its lens (``lenses``: {view name: Camera as taken}) before it is read."""
    reference = (VoxelGrid(grid.bounds_min, grid.bounds_max, 2 * grid.voxel_size)
                 if max(grid.shape) >= 128 else grid)

    def read_rgb(n: int) -> np.ndarray | None:
        view = views[used[n]]
        image = read_image(view.image_path, keep_alpha=not seg_params.ignore_alpha)
        if image.ndim != 3 or image.shape[2] != 3:
            return None
        return undistort_image(image, lenses[view.name])

    return consensus_masks(reference, cameras, masks, read_rgb, prepared=prepared)


def _colour_image(view: View, images: dict | None) -> np.ndarray:
    """The RGB image ``view`` colours the mesh with: ``images[view.name]`` (read if a
    path), or the view's own file when ``images`` is None."""
    given = view.image_path if images is None else images[view.name]
    return read_image(given) if isinstance(given, (str, os.PathLike)) else given


def _refine(occupancy: np.ndarray, grid: VoxelGrid, views: list[View], cameras, masks,
            images: dict | None, lenses: dict, hull: HullDistance) -> tuple:
    """The refinement below the hull (:func:`.refinement.scan.refine_views`) from the used
    views' RGB images: ``(occupancy, distance, report)``."""
    if images is not None and any(v.name not in images for v in views):
        return occupancy, hull, {"applied": False,
                                 "reason": "not every view used has an image"}
    rgb = [undistort_image(_colour_image(v, images), lenses[v.name]) for v in views]
    return refine_views(occupancy, grid, cameras, masks, rgb, hull)


def carve_scan(view_set: ViewSet, params: ReconstructionParams = ReconstructionParams(), *,
               progress: Progress | None = None, masks: dict | None = None,
               images: dict | None = None,
               precomputed: Precomputed = Precomputed()) -> CarvedScan:
    """The carving half of :func:`reconstruct`: the views' hull and what its meshing needs
    (:class:`~sfs_ros.core.carved_scan.CarvedScan`).

    ``masks`` ({view name: (H, W) bool}, optional) are silhouettes the caller already
    has (e.g. a live scan's received masks): those views are not read nor segmented.
    ``images`` ({view name: (H, W, 3) uint8 RGB as taken, or the path of its file},
    optional): with ``params.colour``, the images that colour the mesh instead of the
    views' files (e.g. a live scan's or a bag's captures); a used view without one takes
    no part. ``precomputed`` (optional): what a live scan computed as its views arrived
    (:class:`Precomputed`); the result is the same without.

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
    rejected = [{"view": name, "reason": reason} for name, reason in view_set.rejected]
    seg_params = params.segmentation or SegmentationParams.from_dict(view_set.segmentation or {})

    names = [v.name for v in view_set.views]
    unknown = sorted(set(params.holdout) - set(names))
    if unknown:
        raise ValueError(f"held-out views {unknown} are not in the input (views: {names[:5]}...)")

    _check_lenses(view_set.views)
    with _timed(timings, "segmentation"):
        views, masks, taken, exact = _segment_views(view_set.views, seg_params, progress,
                                                    rejected, masks or {})
    lenses = {v.name: v.camera for v in view_set.views}   # the cameras as taken, with their lens
    used = [i for i, v in enumerate(views) if v.name not in params.holdout]
    if not used:
        raise ValueError(
            f"no usable view: {len(view_set.views)} in the input, {len(rejected)} rejected, "
            f"{len(params.holdout)} held out")
    cameras = [views[i].camera for i in used]
    used_masks = [masks[i] for i in used]
    box = params.bounds_m if params.bounds_m is not None else view_set.bounds_m
    check_directions(cameras, [views[i].name for i in used], _box_centre(box))

    with _timed(timings, "bounds"):
        # The masks' carving tables, built once for every carve of these views.
        prepared = PreparedMasks(cameras, used_masks)
        if params.bounds_m is not None:
            bounds, bounds_source = np.asarray(params.bounds_m, dtype=np.float64), "given"
        elif view_set.bounds_m is not None:
            bounds, bounds_source = np.asarray(view_set.bounds_m, dtype=np.float64), "input"
        else:
            bounds, bounds_source = estimate_bounds(
                cameras, prepared, max_misses=reference_misses(len(cameras))
                if len(cameras) >= 3 else 0), "estimated"
        bounds = as_bounds(bounds, what=f"the {bounds_source} bounding box")
        clipped = [views[used[i]].name
                   for i in bbox_clips_object(VoxelGrid.cube(bounds[0], bounds[1], 2), cameras,
                                              prepared)]
        # An estimated box holds all the views agree on: foreground outside it
        # is clutter the other views carve away, not object the box misses.
        if (bounds_source == "given" and clipped) or \
                (bounds_source == "input" and 2 * len(clipped) > len(cameras)):
            raise ValueError(
                f"the {bounds_source} bounding box {bounds.round(4).tolist()} m misses part of "
                f"the object in {len(clipped)} of {len(cameras)} views ({_some(clipped)}); "
                "enlarge it")
        framed = [views[used[i]].name for i, m in enumerate(used_masks) if _fills_frame(m)]
        if len(framed) == len(cameras):
            raise ValueError(
                f"the object is cut by the frame on two opposite sides in every view "
                f"({len(framed)}): the hull would be bounded by the frames, not the object; "
                "move the camera back or use a wider lens")
        if params.max_misses >= len(cameras):
            raise ValueError(
                f"max_misses {params.max_misses} lets every one of the {len(cameras)} views "
                f"miss a voxel, so nothing would be carved; expected fewer than {len(cameras)}")
        refined = bounds_source != "given" and len(cameras) >= 3
        if refined:
            bounds = refine_bounds(cameras, prepared, bounds,
                                   max_misses=reference_misses(len(cameras)),
                                   known=precomputed.box)
        choice = choose_voxel_size(bounds, cameras, resolution=params.resolution,
                                   voxel_size_m=params.voxel_size_m,
                                   max_memory_bytes=params.max_memory_bytes
                                   or default_memory_budget())
        grid = VoxelGrid(bounds[0], bounds[1], choice.voxel_size_m)
        chosen = mesher(params.mesher)
        mesher_options = chosen.option_values(params.mesher_options)
        if chosen.check is not None:
            chosen.check(grid, **mesher_options)

    resegmentation = None
    if params.consensus and len(cameras) >= 3 and seg_params.method == "graph-cut":
        with _timed(timings, "consensus"):
            consensus = _consensus(views, used, cameras, used_masks, prepared, grid,
                                   seg_params, lenses)
            resegmentation = {
                "applied": consensus.applied, "reason": consensus.reason,
                "resegmented": int(consensus.resegmented.sum()),
                "per_view": [{"view": views[i].name, "prior_iou": float(iou),
                              "resegmented": bool(again), "added_px": int(a), "removed_px": int(r)}
                             for i, iou, again, a, r in zip(
                                 used, consensus.prior_iou, consensus.resegmented,
                                 consensus.added_px, consensus.removed_px)]}
            if consensus.applied:
                used_masks = consensus.masks
                for i, mask in zip(used, used_masks):
                    masks[i] = mask
                    taken[views[i].name] = distort_mask(mask, lenses[views[i].name])
                prepared = PreparedMasks(cameras, used_masks)

    consistency, fusion_report = [], None
    with _timed(timings, "fusion"):
        if params.check_consistency and len(cameras) >= 3:
            progress("fusion", 0.0)
            # The reference hull needs the shape, not the finest detail: voxels
            # twice the carving grid's (the fill follows its projection, a
            # footprint wider only where a view is overruled).
            reference = (VoxelGrid(bounds[0], bounds[1], 2 * grid.voxel_size)
                         if max(grid.shape) >= 128 else grid)
            fusion = fuse_silhouettes(reference, cameras, prepared,
                                      max_missing=params.consistency_max_missing,
                                      exact=[views[i].name in exact for i in used])
            for verdict in fusion.verdicts:
                name = views[used[verdict.index]].name
                consistency.append({"view": name, "iou": verdict.iou,
                                    "missing_fraction": verdict.missing_fraction,
                                    "consistent": not verdict.dropped,
                                    "overruled_pixels": verdict.overruled_pixels,
                                    "overruled_depth_px": verdict.overruled_depth_px,
                                    "depth_threshold_px": verdict.depth_threshold_px,
                                    "reason": verdict.reason})
                if verdict.dropped:
                    rejected.append({"view": name, "reason": verdict.reason})
            fusion_report = {
                "reference_misses": fusion.reference_misses,
                "neighbour_angle_deg": float(np.degrees(fusion.neighbour_angle_rad)),
                "overruled": [c["view"] for c in consistency
                              if c["consistent"] and c["overruled_pixels"]]}
            if fusion_report["overruled"] or len(fusion.kept) < len(used):
                used_masks = [fusion.masks[n] for n in fusion.kept]
                used = [used[n] for n in fusion.kept]
                cameras = [views[i].camera for i in used]
                prepared = PreparedMasks(cameras, used_masks)
            progress("fusion", 1.0)

    if not used:
        raise ValueError(f"no usable view: all {len(rejected)} views were rejected "
                         f"(first: {rejected[0]['view']}: {rejected[0]['reason']})")
    check_directions(cameras, [views[i].name for i in used], bounds.mean(axis=0))
    if params.max_misses >= len(cameras):
        raise ValueError(
            f"max_misses {params.max_misses} lets every one of the {len(cameras)} views left "
            f"miss a voxel, so nothing would be carved; expected fewer than {len(cameras)}")

    with _timed(timings, "carving"):
        progress("carving", 0.0)
        occupancy = carve(grid, cameras, prepared, max_misses=params.max_misses)
        progress("carving", 1.0)
        occupancy, specks_removed = drop_specks(occupancy)
    if not occupancy.any():
        raise ValueError(
            "the visual hull is empty: the silhouettes have no common volume inside the "
            "bounding box (check the bounding box, the camera calibration and the masks)")

    hull = HullDistance(cameras, used_masks, max_misses=params.max_misses,
                        bounds_m=(grid.bounds_min, grid.bounds_max), known=precomputed.distances)
    refinement = None
    if params.refine:
        with _timed(timings, "refinement"):
            progress("refinement", 0.0)
            occupancy, hull, refinement = _refine(occupancy, grid, [views[i] for i in used],
                                                  cameras, used_masks, images, lenses, hull)
            progress("refinement", 1.0)
    with _timed(timings, "mesher_input"):
        mesher_input = chosen.prepare(occupancy, grid, hull, **mesher_options)
    # The used views with an image to colour from (all of them, from their files, unless
    # the caller gives the images), at most MAX_COLOUR_VIEWS spread out.
    coloured = ([n for n, i in enumerate(used) if images is None or views[i].name in images]
                if params.colour else [])
    coloured = [coloured[k] for k in spread_views([cameras[n] for n in coloured],
                                                  MAX_COLOUR_VIEWS)] if coloured else []
    used_names = {views[i].name for i in used}
    report = {
        "input": {"source": view_set.source, "views": len(view_set.views)},
        "parameters": {
            **{k: v for k, v in asdict(params).items() if k != "segmentation"},
            "mesher_options": mesher_options,
            "segmentation": asdict(seg_params),
        },
        "grid": {"shape": list(grid.shape), "voxel_size_m": grid.voxel_size,
                 "bounds_m": [grid.bounds_min.tolist(), grid.bounds_max.tolist()],
                 "bounds_source": bounds_source, "bounds_refined": refined,
                 "resolution_source": choice.source, "resolution_reason": choice.reason,
                 "pixel_footprint_m": {"finest": choice.footprint_m,
                                       "median": choice.footprint_median_m},
                 "memory_bytes": choice.memory_bytes,
                 "max_memory_bytes": choice.max_memory_bytes},
        "views": {"used": [views[i].name for i in used], "held_out": list(params.holdout),
                  "rejected": rejected, "clipped_by_bounds": clipped},
        "resegmentation": resegmentation,
        "consistency": consistency,
        "fusion": fusion_report,
        "refinement": refinement,
        "occupied_voxels": int(occupancy.sum()),
        "specks_removed": specks_removed,
        "timings_s": timings,
    }
    return CarvedScan(
        grid=grid, occupancy=occupancy, mesher=params.mesher, mesher_input=mesher_input,
        views=[ScanView(v.name, v.camera, "used" if v.name in used_names
                        else "held-out" if v.name in params.holdout else "rejected",
                        None if v.theta_rad is None else (v.theta_rad, v.phi_rad))
               for v in views],
        masks=masks, colour_views=[used[n] for n in coloured],
        colour_masks=[used_masks[n] for n in coloured],
        colour_images=[undistort_image(_colour_image(views[used[n]], images),
                                       lenses[views[used[n]].name]) for n in coloured],
        report=report, taken=taken)


def reconstruct(view_set: ViewSet, params: ReconstructionParams = ReconstructionParams(), *,
                progress: Progress | None = None, masks: dict | None = None,
                images: dict | None = None,
                precomputed: Precomputed = Precomputed()) -> Reconstruction:
    """Reconstruct the object seen in ``view_set``: :func:`carve_scan`, then
    :func:`sfs_ros.core.mesh_scan.mesh_scan` (the arguments as :func:`carve_scan`'s).

    Views that cannot be read, have an empty silhouette or disagree with the
    others are rejected and reported, never silently used or dropped. Raises
    ``ValueError`` with a one-line reason when no mesh can be made.
    """
    carved = carve_scan(view_set, params, progress=progress, masks=masks, images=images,
                        precomputed=precomputed)
    return mesh_scan(carved, progress=progress)
