"""The whole reconstruction: tagged images in, a checked mesh and a report out.

Stages (each timed in the report): segmentation, bounding box, view
consistency, carving, meshing (cloud of points + advancing front, or marching
cubes), mesh checks, colour (on request), reprojection of the mesh into every view.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field

import numpy as np

from .meshing.advancing_front import advancing_front
from .carving.bounds import estimate_bounds
from .carving.carve import carve
from .meshing.cloud import cloud_of_points
from .meshing.colour import vertex_colours
from .carving.consistency import bbox_clips_object, find_inconsistent_views
from .geometry.grid import VoxelGrid
from .carving.hull import drop_specks
from .meshing.marching import marching_cubes_mesh
from .meshing.mesh_checks import check_mesh
from .metrics import reprojection_iou
from .segment import SegmentationParams, segment
from .exchange.views import View, ViewSet, read_image

__all__ = ["MESHERS", "ReconstructionParams", "Reconstruction", "reconstruct"]

MESHERS = ("marching-cubes", "advancing-front")

#: Progress callback: (stage name, fraction of the stage done in [0, 1]).
Progress = Callable[[str, float], None]


@dataclass(frozen=True)
class ReconstructionParams:
    """Options of :func:`reconstruct`.

    Attributes
    ----------
    resolution : int
        Voxels along the longest side of the bounding box (ignored when
        ``voxel_size_m`` is set).
    voxel_size_m : float or None
        Voxel edge, metres.
    bounds_m : (2, 3) sequence or None
        Carving box ``[min, max]``, metres; else the input's, else estimated.
    mesher : str
        ``"marching-cubes"`` or ``"advancing-front"``.
    block : int
        M of the paper's cloud of points (M x M x M sub-blocks), advancing front only.
    max_misses : int
        A voxel survives if at most this many views see it outside their silhouette.
    check_consistency : bool
        Detect and drop views whose silhouette disagrees with the others.
    consistency_min_iou, consistency_max_missing : float
        A view is dropped as inconsistent when its mask and the projection of
        the tolerant hull (each voxel may be missed by one view) have IoU below
        ``consistency_min_iou`` or when more than ``consistency_max_missing`` of
        that projection lies outside the mask. Good views of real photographs
        on a 16-view ring reach 5 % missing (Middlebury dino); a mask with half
        the object erased, 45 %. Damage below ~10 % of a silhouette goes
        undetected (and shaves correspondingly little).
    holdout : tuple of str
        Names of views kept out of carving and only used to evaluate the mesh.
    segmentation : SegmentationParams or None
        None: the input's stored parameters, else the defaults.
    colour : bool
        Colour the mesh's vertices from the images of the views used
        (:func:`sfs_ros.core.meshing.colour.vertex_colours`: the views that see each
        point, blended).
    """

    resolution: int = 192
    voxel_size_m: float | None = None
    bounds_m: tuple | None = None
    mesher: str = "marching-cubes"
    block: int = 2
    max_misses: int = 0
    check_consistency: bool = True
    consistency_min_iou: float = 0.75
    consistency_max_missing: float = 0.10
    holdout: tuple = ()
    segmentation: SegmentationParams | None = None
    colour: bool = False

    def __post_init__(self) -> None:
        if self.mesher not in MESHERS:
            raise ValueError(f"mesher must be one of {MESHERS}, got {self.mesher!r}")
        if self.voxel_size_m is None and not 8 <= int(self.resolution) <= 1024:
            raise ValueError(f"resolution must be 8..1024 voxels, got {self.resolution}")
        if self.voxel_size_m is not None and not self.voxel_size_m > 0:
            raise ValueError(f"voxel size must be > 0 metres, got {self.voxel_size_m}")
        if int(self.block) < 1:
            raise ValueError(f"block (M) must be >= 1 voxel, got {self.block}")
        if int(self.max_misses) < 0:
            raise ValueError(f"max_misses must be >= 0, got {self.max_misses}")
        for name in ("consistency_min_iou", "consistency_max_missing"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {getattr(self, name)}")


@dataclass
class Reconstruction:
    """What :func:`reconstruct` returns.

    vertices : (n, 3) float64, metres, object frame; faces : (m, 3) int64,
    outward; occupancy : (nx, ny, nz) bool on ``grid``; report : JSON-ready dict;
    vertex_colors : (n, 3) uint8 RGB with ``colour=True``, else None;
    masks : {view name: (H, W) bool} silhouette of every view read and segmented.
    """

    vertices: np.ndarray
    faces: np.ndarray
    occupancy: np.ndarray
    grid: VoxelGrid
    report: dict = field(default_factory=dict)
    vertex_colors: np.ndarray | None = None
    masks: dict = field(default_factory=dict)


@contextmanager
def _timed(seconds: dict[str, float], stage: str):
    """Add the wall time of the ``with`` block to ``seconds[stage]``."""
    start = time.perf_counter()
    try:
        yield
    finally:
        seconds[stage] = seconds.get(stage, 0.0) + time.perf_counter() - start


def _segment_views(views: list[View], params: SegmentationParams, progress: Progress,
                   rejected: list[dict]) -> tuple[list[View], list[np.ndarray]]:
    """Read and segment every view; bad ones go to ``rejected`` with the reason."""
    kept, masks = [], []
    for n, view in enumerate(views):
        progress("segmentation", n / max(1, len(views)))
        try:
            image = read_image(view.image_path, keep_alpha=not params.ignore_alpha,
                               expected_size=(view.camera.width, view.camera.height))
        except ValueError as err:
            rejected.append({"view": view.name, "reason": str(err)})
            continue
        result = segment(image, params)
        if result.empty:
            rejected.append({"view": view.name, "reason": "empty silhouette: no object found"})
            continue
        kept.append(view)
        masks.append(result.mask)
    progress("segmentation", 1.0)
    return kept, masks


def _grid(params: ReconstructionParams, bounds: np.ndarray) -> VoxelGrid:
    if params.voxel_size_m is not None:
        return VoxelGrid(bounds[0], bounds[1], params.voxel_size_m)
    return VoxelGrid.cube(bounds[0], bounds[1], params.resolution)


def _mesh(occupancy: np.ndarray, grid: VoxelGrid, params: ReconstructionParams) -> tuple:
    if params.mesher == "marching-cubes":
        vertices, faces = marching_cubes_mesh(occupancy, grid)
        return vertices, faces, {}
    cloud = cloud_of_points(occupancy, grid, block=params.block)
    result = advancing_front(cloud.points, cloud.normals)
    return cloud.points, result.faces, {**result.stats, "cloud_points": int(len(cloud.points))}


def reconstruct(view_set: ViewSet, params: ReconstructionParams = ReconstructionParams(), *,
                progress: Progress | None = None) -> Reconstruction:
    """Reconstruct the object seen in ``view_set``.

    Views that cannot be read, have an empty silhouette or disagree with the
    others are rejected and reported, never silently used or dropped. Raises
    ``ValueError`` with a one-line reason when no mesh can be made (no usable
    view, a bounding box that misses the object, an empty hull).
    """
    progress = progress or (lambda stage, fraction: None)
    timings: dict[str, float] = {}
    rejected = [{"view": name, "reason": reason} for name, reason in view_set.rejected]
    seg_params = params.segmentation or SegmentationParams.from_dict(view_set.segmentation or {})

    names = [v.name for v in view_set.views]
    unknown = sorted(set(params.holdout) - set(names))
    if unknown:
        raise ValueError(f"held-out views {unknown} are not in the input (views: {names[:5]}...)")

    with _timed(timings, "segmentation"):
        views, masks = _segment_views(view_set.views, seg_params, progress, rejected)
    used = [i for i, v in enumerate(views) if v.name not in params.holdout]
    if not used:
        raise ValueError(
            f"no usable view: {len(view_set.views)} in the input, {len(rejected)} rejected, "
            f"{len(params.holdout)} held out")
    cameras = [views[i].camera for i in used]
    used_masks = [masks[i] for i in used]

    with _timed(timings, "bounds"):
        if params.bounds_m is not None:
            bounds, bounds_source = np.asarray(params.bounds_m, dtype=np.float64), "given"
        elif view_set.bounds_m is not None:
            bounds, bounds_source = np.asarray(view_set.bounds_m, dtype=np.float64), "input"
        else:
            bounds, bounds_source = estimate_bounds(cameras, used_masks), "estimated"
        if bounds.shape != (2, 3) or not np.all(np.isfinite(bounds)) or np.any(bounds[1] <= bounds[0]):
            raise ValueError(f"bounding box must be [[xmin, ymin, zmin], [xmax, ymax, zmax]] "
                             f"with min < max, got {bounds.tolist()}")
        grid = _grid(params, bounds)
        clipped = [views[used[i]].name for i in bbox_clips_object(grid, cameras, used_masks)]
        if 2 * len(clipped) > len(cameras):
            raise ValueError(
                f"the bounding box {bounds.round(4).tolist()} m misses part of the object in "
                f"{len(clipped)} of {len(cameras)} views; enlarge it")

    consistency = []
    with _timed(timings, "consistency"):
        if params.check_consistency and len(cameras) >= 4:
            progress("consistency", 0.0)
            # Detecting a bad view needs the hull's shape, not its detail: a coarse grid.
            check_grid = VoxelGrid.cube(bounds[0], bounds[1], min(max(grid.shape), 96))
            checks = find_inconsistent_views(check_grid, cameras, used_masks,
                                             max_misses=max(1, params.max_misses),
                                             min_iou=params.consistency_min_iou,
                                             max_missing_fraction=params.consistency_max_missing)
            for c in checks:
                name = views[used[c.index]].name
                consistency.append({"view": name, "iou": c.iou,
                                    "missing_fraction": c.missing_fraction,
                                    "consistent": c.consistent})
                if not c.consistent:
                    rejected.append({"view": name,
                                     "reason": f"silhouette inconsistent with the other views "
                                               f"(IoU {c.iou:.3f} with the tolerant hull, "
                                               f"{100 * c.missing_fraction:.1f}% of it missing)"})
            bad = {c.index for c in checks if not c.consistent}
            used = [u for n, u in enumerate(used) if n not in bad]
            cameras = [views[i].camera for i in used]
            used_masks = [masks[i] for i in used]

    with _timed(timings, "carving"):
        progress("carving", 0.0)
        occupancy = carve(grid, cameras, used_masks, max_misses=params.max_misses)
        progress("carving", 1.0)
        occupancy, specks_removed = drop_specks(occupancy)
    if not occupancy.any():
        raise ValueError(
            "the visual hull is empty: the silhouettes have no common volume inside the "
            "bounding box (check the bounding box, the camera calibration and the masks)")

    with _timed(timings, "meshing"):
        progress("meshing", 0.0)
        vertices, faces, mesher_stats = _mesh(occupancy, grid, params)
        progress("meshing", 1.0)
    with _timed(timings, "mesh_checks"):
        mesh_report = check_mesh(vertices, faces).as_dict()
    colours = None
    if params.colour:
        with _timed(timings, "colour"):
            progress("colour", 0.0)
            colours = vertex_colours(vertices, faces,
                                     [read_image(views[i].image_path) for i in used],
                                     cameras, masks=used_masks)
            progress("colour", 1.0)

    with _timed(timings, "evaluation"):
        used_names = {views[i].name for i in used}
        per_view = []
        for n, (view, mask) in enumerate(zip(views, masks)):
            progress("evaluation", n / len(views))
            role = ("used" if view.name in used_names
                    else "held-out" if view.name in params.holdout else "rejected")
            per_view.append({"view": view.name, "role": role,
                             "silhouette_iou": reprojection_iou(vertices, faces, view.camera, mask)})
        progress("evaluation", 1.0)

    def mean_iou(role: str) -> float | None:
        values = [p["silhouette_iou"] for p in per_view if p["role"] == role]
        return float(np.mean(values)) if values else None

    report = {
        "input": {"source": view_set.source, "views": len(view_set.views)},
        "parameters": {
            **{k: v for k, v in asdict(params).items() if k != "segmentation"},
            "segmentation": asdict(seg_params),
        },
        "grid": {"shape": list(grid.shape), "voxel_size_m": grid.voxel_size,
                 "bounds_m": [grid.bounds_min.tolist(), grid.bounds_max.tolist()],
                 "bounds_source": bounds_source},
        "views": {"used": [views[i].name for i in used], "held_out": list(params.holdout),
                  "rejected": rejected, "clipped_by_bounds": clipped},
        "consistency": consistency,
        "occupied_voxels": int(occupancy.sum()),
        "specks_removed": specks_removed,
        "mesher": {"name": params.mesher, **mesher_stats},
        "mesh": mesh_report,
        **({"colour": colours.stats} if colours is not None else {}),
        "silhouette_iou": {"per_view": per_view, "mean_used": mean_iou("used"),
                           "mean_held_out": mean_iou("held-out")},
        "timings_s": timings,
    }
    return Reconstruction(vertices=vertices, faces=faces, occupancy=occupancy, grid=grid,
                          report=report,
                          vertex_colors=None if colours is None else colours.colours,
                          masks={v.name: m for v, m in zip(views, masks)})
