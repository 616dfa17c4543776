"""The stages of the carving half of a reconstruction, in the order
:func:`sfs_ros.core.pipeline.carve_scan` runs them.

``segment_views`` -> ``choose_grid`` -> ``resegment_views`` -> ``fuse_views`` ->
``carve_hull`` -> ``refine_hull`` -> ``choose_colour_views``. Each takes and returns
small typed values (:class:`Segmented`, :class:`UsedViews`, :class:`GridChoice`, ...)
and its piece of the report, which :mod:`sfs_ros.core.scan_report` assembles. A stage
raises ``ValueError`` with a one-line reason when no mesh can be made from what it got.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from .carving.bounds import BoxCarve, estimate_bounds, refine_bounds
from .carving.carve import KeptCarve, PreparedMasks, kept_or_carved
from .carving.consistency import bbox_clips_object
from .carving.fusion import fuse_silhouettes, reference_misses
from .carving.hull import drop_specks
from .carving.resolution import (
    THIN_PART_PX,
    ResolutionChoice,
    choose_voxel_size,
    default_memory_budget,
)
from .carving.thin_parts import thin_share
from .exchange.views import View, ViewSet, as_bounds, read_image
from .geometry.camera import Camera
from .geometry.grid import VoxelGrid
from .geometry.lens import distort_mask, ideal_camera, undistort_image, undistort_mask
from .meshing.colour import MAX_COLOUR_VIEWS, spread_views
from .meshing.hull_distance import HullDistance
from .refinement.scan import refine_views
from .segmentation.backdrop import BackdropModel, fit_scan_backdrop
from .segmentation.consensus import consensus_masks
from .segmentation.segment import (
    SegmentationParams,
    backdrop_samples,
    scan_backdrop_changes,
    segment,
)
from .workers import map_in_threads

__all__ = ["ColourViews", "Fused", "GridChoice", "Hull", "Resegmented", "Segmented",
           "UsedViews", "carve_hull", "check_max_misses", "choose_colour_views", "choose_grid",
           "fuse_views", "fusion_grid", "refine_hull", "resegment_views", "segment_views"]

#: Progress callback: (stage name, fraction of the stage done in [0, 1]).
Progress = Callable[[str, float], None]
#: The segmentation keeps the views' images for the consensus (which would decode them
#: again) when all of them take at most this many bytes: 100 views of 800 x 800 take 192 MB.
KEPT_IMAGES_BYTES = 256 << 20


@dataclass(frozen=True)
class Segmented:
    """Every view read and segmented.

    views : the views kept, with ideal pinhole cameras (:func:`.geometry.lens.ideal_camera`)
    masks : their silhouettes (H, W) bool, undistorted onto those cameras
    taken : {view name: (H, W) bool silhouette as taken, through the lens}
    lenses : {view name: Camera as taken, with its lens}, every view of the input
    rejected : [{"view", "reason"}] the views of the input that could not be used
    exact : names of the views whose mask is their image's alpha channel (exact: the
        fusion never overrules it)
    coverage : {view name: (H, W) uint8 alpha channel, undistorted} of those views: the
        fraction of each pixel the object covers, which places the hull's surface within
        the pixels along the silhouette (:class:`.meshing.hull_distance.HullDistance`)
    backdrop : the report's piece on the backdrop of the whole scan, ``{"colours_rgb":
        [[r, g, b], ...], "views": [names segmented with it]}``, or None (fewer than
        three views segmented by the graph cut)
    images : {view name: (H, W, 3) uint8 RGB image as read} the segmentation kept for the
        consensus to cut again (:func:`segment_views`' ``keep_images``); empty after it
    """

    views: list[View]
    masks: list[np.ndarray]
    taken: dict[str, np.ndarray]
    lenses: dict[str, Camera]
    rejected: list[dict]
    exact: frozenset = frozenset()
    coverage: dict = field(default_factory=dict)
    backdrop: dict | None = None
    images: dict = field(default_factory=dict)


@dataclass(frozen=True)
class UsedViews:
    """The views that carve: ``indices`` into :attr:`Segmented.views`, their ideal
    ``cameras``, their ``masks`` (H, W) bool, and the masks' carving tables
    (``prepared``, built once for every carve of these views)."""

    indices: list[int]
    cameras: list[Camera]
    masks: list[np.ndarray]
    prepared: PreparedMasks

    @classmethod
    def of(cls, views: list[View], indices: list[int], masks: list[np.ndarray]) -> UsedViews:
        cameras = [views[i].camera for i in indices]
        return cls(list(indices), cameras, list(masks), PreparedMasks(cameras, masks))

    def names(self, views: list[View]) -> list[str]:
        return [views[i].name for i in self.indices]


@dataclass(frozen=True)
class _ViewMask:
    """One view's silhouette (H, W) bool as taken (``taken``) and undistorted onto its
    ideal pinhole (``ideal``), the alpha channel it is exact from, undistorted
    (``coverage``, (H, W) uint8; None: segmented or given), the pixels of its image's
    border its graph cut learnt the backdrop from (``band``, (n, 3) uint8) and the model
    it learnt (``own_backdrop``, :attr:`.segmentation.segment.Segmentation.border_backdrop`;
    both None: not segmented by the graph cut), and its (H, W, 3) uint8 RGB image as read
    when kept (``image``; else None)."""

    taken: np.ndarray
    ideal: np.ndarray
    coverage: np.ndarray | None
    band: np.ndarray | None = None
    own_backdrop: BackdropModel | None = None
    image: np.ndarray | None = None


def _read_and_segment(view: View, params: SegmentationParams, given: np.ndarray | None,
                      undistorted: np.ndarray | None,
                      scan_backdrop: BackdropModel | None = None,
                      keep_image: bool = False) -> _ViewMask | str:
    """The view's silhouette (``given``, else segmented from its image, with the scan's
    backdrop ``scan_backdrop`` when given) and what it is exact from, each undistorted
    (``undistorted``: the mask's undistortion already made), or why the view cannot be
    used. With ``keep_image``, an RGB image read is kept in the result."""
    if given is not None:
        expected = (view.camera.height, view.camera.width)
        if np.shape(given) != expected or np.asarray(given).dtype != np.bool_:
            return (f"given silhouette is {np.asarray(given).dtype} {np.shape(given)}, "
                    f"expected {expected} bool (the camera's size)")
        if not given.any():
            return "empty silhouette: no object found"
        mask, alpha, band, own, image = given, None, None, None, None
    else:
        try:
            image = read_image(view.image_path, keep_alpha=not params.ignore_alpha,
                               expected_size=(view.camera.width, view.camera.height))
        except ValueError as err:
            return str(err)
        result = segment(image, params, scan_backdrop=scan_backdrop)
        band, own = backdrop_samples(image, params), result.border_backdrop
        if result.empty:
            return _Empty(band, own)
        exact = image.ndim == 3 and image.shape[2] == 4 and not params.ignore_alpha
        mask, alpha = result.mask, (image[:, :, 3].copy() if exact else None)
    ideal = undistort_mask(mask, view.camera) if undistorted is None else undistorted
    rgb = image is not None and image.ndim == 3 and image.shape[2] == 3
    return _ViewMask(mask, ideal, None if alpha is None else undistort_image(alpha, view.camera),
                     band, own, image if keep_image and rgb else None)


@dataclass(frozen=True)
class _Empty:
    """A view segmented empty, its border's pixels and their backdrop model (``band`` and
    ``own_backdrop``, as :class:`_ViewMask`'s)."""

    band: np.ndarray | None
    own_backdrop: BackdropModel | None
    reason: str = "empty silhouette: no object found"


def _with_scan_backdrop(views: list[View], results: list, params: SegmentationParams,
                        keep_images: bool) -> tuple[list, dict | None]:
    """``results`` (one per view: :class:`_ViewMask`, :class:`_Empty` or the reason it
    cannot be used), each view segmented again with the backdrop of the whole scan
    (:func:`.segmentation.backdrop.fit_scan_backdrop`, from the borders of the views the
    graph cut segmented, when there are three or more) where that changes its own
    border's model (:func:`.segmentation.segment.scan_backdrop_changes`): the turntable
    plate is backdrop in a view that sees it wholly in the frame, the object's colours are
    not in a view whose frame it reaches; with ``keep_images``, the images read again are
    kept. Also the report's ``backdrop`` piece (the scan's backdrop colours and the views
    segmented with it), None without one."""
    results = list(results)
    bands = [getattr(r, "band", None) for r in results]
    learnt = [band for band in bands if band is not None]
    if len(learnt) < 3:
        return results, None
    scan = fit_scan_backdrop(learnt)
    again = [n for n, (band, result) in enumerate(zip(bands, results))
             if band is not None and scan_backdrop_changes(band, scan, params,
                                                           own=result.own_backdrop)]
    redone = map_in_threads(
        lambda n: _read_and_segment(views[n], params, None, None, scan, keep_images), again)
    for n, result in zip(again, redone):
        results[n] = result
    return results, {"colours_rgb": [[round(float(c), 1) for c in m] for m in scan.means],
                     "views": [views[n].name for n in again]}


def segment_views(view_set: ViewSet, params: SegmentationParams, given: dict,
                  progress: Progress, undistorted: dict | None = None, *,
                  keep_images: bool = False) -> Segmented:
    """Read, segment and undistort every view not in ``given`` ({view name: (H, W) bool
    silhouette already made}), in threads (one view's decoding beside another's
    segmentation), results in input order; the views that cannot be used
    join the input's rejected ones with the reason. Each mask is segmented as taken and
    undistorted once onto its view's ideal pinhole (:mod:`.geometry.lens`), unless
    ``undistorted`` ({view name: (H, W) bool}) holds that undistortion already. The views
    whose border disagrees with the backdrop of the whole scan are segmented again with
    it (:func:`_with_scan_backdrop`). With ``keep_images`` (a consensus to follow), the RGB
    images read are kept in :attr:`Segmented.images` when all the views' images fit in
    :data:`KEPT_IMAGES_BYTES`."""
    undistorted = undistorted or {}
    views = view_set.views
    rejected = [{"view": name, "reason": reason} for name, reason in view_set.rejected]
    kept, masks, taken, coverage, images = [], [], {}, {}, {}
    keep = keep_images and sum(3 * v.camera.width * v.camera.height
                               for v in views) <= KEPT_IMAGES_BYTES
    progress("segmentation", 0.0)
    results, backdrop = _with_scan_backdrop(views, map_in_threads(
        lambda view: _read_and_segment(view, params, given.get(view.name),
                                       undistorted.get(view.name), keep_image=keep), views),
        params, keep)
    for n, (view, result) in enumerate(zip(views, results)):
        if isinstance(result, (str, _Empty)):
            rejected.append({"view": view.name, "reason": getattr(result, "reason", result)})
        else:
            kept.append(replace(view, camera=ideal_camera(view.camera)))
            masks.append(result.ideal)
            taken[view.name] = result.taken
            if result.coverage is not None:
                coverage[view.name] = result.coverage
            if result.image is not None:
                images[view.name] = result.image
        progress("segmentation", (n + 1) / max(1, len(views)))
    return Segmented(kept, masks, taken, {v.name: v.camera for v in views}, rejected,
                     frozenset(coverage), coverage, backdrop, images)


@dataclass(frozen=True)
class GridChoice:
    """The carving box and its grid.

    bounds : (2, 3) float64 ``[min, max]``, metres, the box chosen (``grid`` covers it,
        its far corner rounded up to whole voxels)
    grid : VoxelGrid
    bounds_source : "given", "input" or "estimated"
    refined : whether the box was shrunk to a tolerant carve's hull plus a margin
    resolution : how the voxel size was chosen
    clipped : names of the used views whose silhouette the box cuts
    """

    bounds: np.ndarray
    grid: VoxelGrid
    bounds_source: str
    refined: bool
    resolution: ResolutionChoice
    clipped: list[str]

    @property
    def report(self) -> dict:
        grid, choice = self.grid, self.resolution
        return {"shape": list(grid.shape), "voxel_size_m": grid.voxel_size,
                "bounds_m": [grid.bounds_min.tolist(), grid.bounds_max.tolist()],
                "bounds_source": self.bounds_source, "bounds_refined": self.refined,
                "resolution_source": choice.source, "resolution_reason": choice.reason,
                "pixel_footprint_m": {"finest": choice.footprint_m,
                                      "median": choice.footprint_median_m},
                "thin_part_share": choice.thin_share,
                "memory_bytes": choice.memory_bytes,
                "max_memory_bytes": choice.max_memory_bytes}


def _some(names: list[str], limit: int = 3) -> str:
    return ", ".join(names[:limit]) + (f" and {len(names) - limit} more"
                                       if len(names) > limit else "")


def _fills_frame(mask: np.ndarray) -> bool:
    """Whether the silhouette touches two opposite sides of its image."""
    return bool((mask[:, 0].any() and mask[:, -1].any()) or (mask[0].any() and mask[-1].any()))


def check_max_misses(max_misses: int, n_views: int, left: str = "") -> None:
    """ValueError when ``max_misses`` lets every one of ``n_views`` views miss a voxel."""
    if max_misses >= n_views:
        raise ValueError(
            f"max_misses {max_misses} lets every one of the {n_views} views{left} miss a "
            f"voxel, so nothing would be carved; expected fewer than {n_views}")


def _first_box(used: UsedViews, given_box, input_box) -> tuple[np.ndarray, str]:
    """The box before its refinement, ``[min, max]`` metres, and where it came from."""
    if given_box is not None:
        bounds, source = np.asarray(given_box, dtype=np.float64), "given"
    elif input_box is not None:
        bounds, source = np.asarray(input_box, dtype=np.float64), "input"
    else:
        n = len(used.cameras)
        bounds, source = estimate_bounds(used.cameras, used.prepared,
                                         max_misses=reference_misses(n) if n >= 3 else 0), \
            "estimated"
    return as_bounds(bounds, what=f"the {source} bounding box"), source


def choose_grid(views: list[View], used: UsedViews, *, given_box, input_box,
                max_misses: int, resolution: int | None, voxel_size_m: float | None,
                max_memory_bytes: int | None, known_box: BoxCarve | None) -> GridChoice:
    """The carving box (``given_box``, else ``input_box``, else estimated from the
    silhouettes; the latter two shrunk to a tolerant carve's hull, ``known_box`` the
    coarse carve a live scan already made) and its voxel size
    (:func:`.carving.resolution.choose_voxel_size`; the options as
    :class:`~sfs_ros.core.pipeline.ReconstructionParams`'). Refuses a box that cuts the
    object, an object the frame cuts in every view and a ``max_misses`` that carves
    nothing."""
    cameras = used.cameras
    bounds, source = _first_box(used, given_box, input_box)
    clipped = [views[used.indices[i]].name
               for i in bbox_clips_object(VoxelGrid.cube(bounds[0], bounds[1], 2), cameras,
                                          used.prepared)]
    # An estimated box holds all the views agree on: foreground outside it
    # is clutter the other views carve away, not object the box misses.
    if (source == "given" and clipped) or (source == "input" and 2 * len(clipped) > len(cameras)):
        raise ValueError(
            f"the {source} bounding box {bounds.round(4).tolist()} m misses part of "
            f"the object in {len(clipped)} of {len(cameras)} views ({_some(clipped)}); "
            "enlarge it")
    framed = [name for name, m in zip(used.names(views), used.masks) if _fills_frame(m)]
    if len(framed) == len(cameras):
        raise ValueError(
            f"the object is cut by the frame on two opposite sides in every view "
            f"({len(framed)}): the hull would be bounded by the frames, not the object; "
            "move the camera back or use a wider lens")
    check_max_misses(max_misses, len(cameras))
    refined = source != "given" and len(cameras) >= 3
    if refined:
        bounds = refine_bounds(cameras, used.prepared, bounds,
                               max_misses=reference_misses(len(cameras)), known=known_box)
    share = thin_share(used.masks, THIN_PART_PX) \
        if resolution is None and voxel_size_m is None else None
    choice = choose_voxel_size(bounds, cameras, resolution=resolution,
                               voxel_size_m=voxel_size_m, thin_share=share,
                               max_memory_bytes=max_memory_bytes or default_memory_budget())
    return GridChoice(bounds, VoxelGrid(bounds[0], bounds[1], choice.voxel_size_m), source,
                      refined, choice, clipped)


@dataclass(frozen=True)
class Resegmented:
    """What the consensus left: the views with the new masks (``segmented``; ``taken``
    redistorted through each lens), the ``used`` views carving with them, and the
    report's ``resegmentation`` piece."""

    segmented: Segmented
    used: UsedViews
    report: dict


def resegment_views(segmented: Segmented, used: UsedViews, grid: VoxelGrid,
                    params: SegmentationParams) -> Resegmented:
    """The used views' masks re-segmented with the hull of all views as a prior
    (:func:`sfs_ros.core.segmentation.consensus.consensus_masks`); alpha masks are kept. The masks
    and cameras are on the ideal pinhole's pixel grid, so each image is undistorted
    through its lens before it is read (the one the segmentation kept, else read again).
    The images kept are let go (:attr:`Segmented.images` empty)."""
    views, lenses, kept = segmented.views, segmented.lenses, segmented.images
    segmented = replace(segmented, images={})
    reference = (VoxelGrid(grid.bounds_min, grid.bounds_max, 2 * grid.voxel_size)
                 if max(grid.shape) >= 128 else grid)

    def read_rgb(n: int) -> np.ndarray | None:
        view = views[used.indices[n]]
        image = kept.get(view.name)
        if image is None:
            image = read_image(view.image_path, keep_alpha=not params.ignore_alpha)
        if image.ndim != 3 or image.shape[2] != 3:
            return None
        return undistort_image(image, lenses[view.name])

    consensus = consensus_masks(reference, used.cameras, used.masks, read_rgb,
                                prepared=used.prepared)
    report = {
        "applied": consensus.applied, "reason": consensus.reason,
        "resegmented": int(consensus.resegmented.sum()),
        "per_view": [{"view": views[i].name, "prior_iou": float(iou),
                      "resegmented": bool(again), "added_px": int(a), "removed_px": int(r)}
                     for i, iou, again, a, r in zip(
                         used.indices, consensus.prior_iou, consensus.resegmented,
                         consensus.added_px, consensus.removed_px)]}
    if not consensus.applied:
        return Resegmented(segmented, used, report)
    masks, taken = list(segmented.masks), dict(segmented.taken)
    through_lens = map_in_threads(lambda pair: distort_mask(pair[1], lenses[views[pair[0]].name]),
                                  zip(used.indices, consensus.masks))
    for i, mask, as_taken in zip(used.indices, consensus.masks, through_lens):
        masks[i] = mask
        taken[views[i].name] = as_taken
    return Resegmented(replace(segmented, masks=masks, taken=taken),
                       UsedViews.of(views, used.indices, consensus.masks), report)


@dataclass(frozen=True)
class Fused:
    """What the fusion of the silhouettes left: the ``used`` views with their repaired
    masks (the dropped ones out), the report's ``consistency`` (one entry per view
    judged) and ``fusion`` pieces, and the views ``dropped`` ({"view", "reason"})."""

    used: UsedViews
    consistency: list[dict]
    report: dict | None
    dropped: list[dict]


def fusion_grid(bounds: np.ndarray, grid: VoxelGrid) -> VoxelGrid:
    """The grid of the fusion's reference hull over the box ``bounds`` (2, 3), metres,
    whose carving grid is ``grid``: the hull needs the shape, not the finest detail, so
    voxels twice the carving grid's from 128 voxels on a side (the fill follows its
    projection, a footprint wider only where a view is overruled)."""
    return (VoxelGrid(bounds[0], bounds[1], 2 * grid.voxel_size)
            if max(grid.shape) >= 128 else grid)


def fuse_views(views: list[View], used: UsedViews, box: GridChoice, max_missing: float,
               progress: Progress, exact: frozenset = frozenset(),
               kept: tuple[KeptCarve, ...] = ()) -> Fused:
    """The used views' silhouettes fused (:func:`.carving.fusion.fuse_silhouettes`): one
    view's mask overruled where the others agree it is wrong (never one named in
    ``exact``, an alpha channel), a view that disagrees as a whole dropped. ``kept``:
    carves kept as the views arrived (the reference hull from one that holds it)."""
    progress("fusion", 0.0)
    fusion = fuse_silhouettes(fusion_grid(box.bounds, box.grid), used.cameras, used.prepared,
                              max_missing=max_missing,
                              exact=[views[i].name in exact for i in used.indices], kept=kept)
    consistency, dropped = [], []
    for verdict in fusion.verdicts:
        name = views[used.indices[verdict.index]].name
        consistency.append({"view": name, "iou": verdict.iou,
                            "missing_fraction": verdict.missing_fraction,
                            "consistent": not verdict.dropped,
                            "overruled_pixels": verdict.overruled_pixels,
                            "overruled_depth_px": verdict.overruled_depth_px,
                            "depth_threshold_px": verdict.depth_threshold_px,
                            "reason": verdict.reason})
        if verdict.dropped:
            dropped.append({"view": name, "reason": verdict.reason})
    report = {
        "reference_misses": fusion.reference_misses,
        "neighbour_angle_deg": float(np.degrees(fusion.neighbour_angle_rad)),
        "overruled": [c["view"] for c in consistency
                      if c["consistent"] and c["overruled_pixels"]]}
    if report["overruled"] or len(fusion.kept) < len(used.indices):
        used = UsedViews.of(views, [used.indices[n] for n in fusion.kept],
                            [fusion.masks[n] for n in fusion.kept])
    progress("fusion", 1.0)
    return Fused(used, consistency, report, dropped)


@dataclass(frozen=True)
class Hull:
    """The carved (or refined) hull: ``occupancy`` (nx, ny, nz) bool on the grid, the
    signed ``distance`` to it the meshers put their vertices on, the ``specks_removed``
    after carving, and the report's ``refinement`` piece (None: not asked for)."""

    occupancy: np.ndarray
    distance: HullDistance
    specks_removed: int
    refinement: dict | None = None


def carve_hull(grid: VoxelGrid, used: UsedViews, max_misses: int, progress: Progress,
               kept: tuple[KeptCarve, ...] = ()) -> tuple[np.ndarray, int]:
    """The visual hull (nx, ny, nz) bool without its specks, and how many specks went;
    from one of the carves ``kept`` as the views arrived that holds it, if any."""
    progress("carving", 0.0)
    occupancy = kept_or_carved(kept, grid, used.cameras, used.prepared, max_misses)
    progress("carving", 1.0)
    occupancy, specks_removed = drop_specks(occupancy)
    if not occupancy.any():
        raise ValueError(
            "the visual hull is empty: the silhouettes have no common volume inside the "
            "bounding box (check the bounding box, the camera calibration and the masks)")
    return occupancy, specks_removed


def colour_image(view: View, images: dict | None) -> np.ndarray:
    """The RGB image ``view`` colours the mesh with: ``images[view.name]`` (read if a
    path), or the view's own file when ``images`` is None."""
    given = view.image_path if images is None else images[view.name]
    return read_image(given) if isinstance(given, (str, os.PathLike)) else given


def refine_hull(hull: Hull, grid: VoxelGrid, segmented: Segmented, used: UsedViews,
                images: dict | None, progress: Progress) -> Hull:
    """The refinement below the hull (:func:`.refinement.scan.refine_views`) from the used
    views' RGB images (``images``: {view name: image or path}, None: the views' files),
    undistorted; skipped, with the reason, when a used view has no image."""
    progress("refinement", 0.0)
    views = [segmented.views[i] for i in used.indices]
    if images is not None and any(v.name not in images for v in views):
        refined = replace(hull, refinement={"applied": False,
                                            "reason": "not every view used has an image"})
    else:
        rgb = list(map_in_threads(
            lambda v: undistort_image(colour_image(v, images), segmented.lenses[v.name]), views))
        occupancy, distance, report = refine_views(hull.occupancy, grid, used.cameras,
                                                   used.masks, rgb, hull.distance)
        refined = replace(hull, occupancy=occupancy, distance=distance, refinement=report)
    progress("refinement", 1.0)
    return refined


@dataclass(frozen=True)
class ColourViews:
    """The views that colour the mesh: ``indices`` into :attr:`Segmented.views`, their
    ``masks`` as carved and their RGB ``images`` undistorted onto the ideal cameras."""

    indices: list[int]
    masks: list[np.ndarray]
    images: list[np.ndarray]


def choose_colour_views(segmented: Segmented, used: UsedViews, images: dict | None,
                        colour: bool) -> ColourViews:
    """The used views with an image to colour from (all of them, from their files, unless
    ``images`` is given), at most ``MAX_COLOUR_VIEWS`` spread out; none without
    ``colour``."""
    views = segmented.views
    coloured = ([n for n, i in enumerate(used.indices)
                 if images is None or views[i].name in images] if colour else [])
    coloured = [coloured[k] for k in spread_views([used.cameras[n] for n in coloured],
                                                  MAX_COLOUR_VIEWS)] if coloured else []
    chosen = [used.indices[n] for n in coloured]
    return ColourViews(chosen, [used.masks[n] for n in coloured], list(map_in_threads(
        lambda i: undistort_image(colour_image(views[i], images), segmented.lenses[views[i].name]),
        chosen)))
