"""The refinement as a stage of a reconstruction: on the views that carved a hull
(:func:`refine_views`, which :func:`sfs_ros.core.pipeline.carve_scan` runs), or on a carved
scan made elsewhere (:func:`refine_carved_scan`, e.g. by a meshing process given the
carving's result and the views' images).
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from ..carved_scan import CarvedScan
from ..geometry.camera import Camera
from ..geometry.grid import VoxelGrid
from ..meshing.hull_distance import HullDistance
from ..meshing.meshers import mesher
from .photo import RefineParams, refine_hull

__all__ = ["refine_carved_scan", "refine_views"]


def refine_views(occupancy: np.ndarray, grid: VoxelGrid, cameras: list[Camera], masks,
                 images, hull, params: RefineParams | None = None) -> tuple:
    """The photo-consistent refinement (:func:`.photo.refine_hull`) of the hull
    ``occupancy`` (nx, ny, nz) bool on ``grid``, carved by ``cameras`` from ``masks``
    ((H, W) bool each; ``images`` their (H, W, 3) uint8 RGB images on the same pixel grid,
    ``hull`` the hull's signed distance).

    Returns ``(occupancy, distance, report)``: the refined hull, its signed distance for
    the meshers and the report (``applied``; what was removed, where and on how many views'
    evidence). Where the views cannot tell (orthographic cameras, images without colour,
    everything carved), the hull and ``hull`` themselves, with the reason in the report.
    """
    def skipped(reason: str) -> tuple:
        return occupancy, hull, {"applied": False, "reason": reason}

    if any(c.orthographic for c in cameras):
        return skipped("orthographic cameras: the plane sweep needs pinhole views")
    if any(np.ndim(image) != 3 or np.shape(image)[2] != 3 for image in images):
        return skipped("the views carry no colour")
    result = refine_hull(occupancy, grid, cameras, masks, images, hull,
                         params or RefineParams())
    if not result.occupancy.any():
        return skipped("the refinement carved everything: kept the hull")
    return result.occupancy, result.distance, {"applied": True, **result.report}


def refine_carved_scan(carved: CarvedScan, images: dict,
                       params: RefineParams | None = None) -> CarvedScan:
    """``carved`` refined below its hull from the colours: the used views' RGB ``images``
    ({view name: (H, W, 3) uint8 on the view's ideal camera, as
    :attr:`CarvedScan.colour_images`}) judge it.

    Returns a new :class:`CarvedScan` for :func:`sfs_ros.core.mesh_scan.mesh_scan`: the
    refined occupancy, its mesher's input made again, the report's ``refinement`` and its
    time (``timings_s["refinement"]``). The hull is that of the carved scan's masks
    (``carved.masks``; without the fusion's repairs of single views, which the meshing
    side does not receive). ValueError when a used view has no image.
    """
    used = [n for n, v in enumerate(carved.views) if v.role == "used"]
    missing = [carved.views[n].name for n in used if carved.views[n].name not in images]
    if missing:
        raise ValueError(f"no image for the used views {missing[:3]}"
                         f"{' and more' if len(missing) > 3 else ''}: every used view's "
                         "RGB image is needed to refine")
    start = time.perf_counter()
    cameras = [carved.views[n].camera for n in used]
    masks = [carved.masks[n] for n in used]
    parameters = carved.report.get("parameters", {})
    grid = carved.grid
    hull = HullDistance(cameras, masks, max_misses=int(parameters.get("max_misses", 0)),
                        bounds_m=(grid.bounds_min, grid.bounds_max))
    occupancy, distance, report = refine_views(
        carved.occupancy, grid, cameras, masks,
        [np.asarray(images[carved.views[n].name]) for n in used], hull, params)
    chosen = mesher(carved.mesher)
    mesher_input = (chosen.prepare(occupancy, grid, distance,
                                   **chosen.option_values(parameters.get("mesher_options", {})))
                    if report["applied"] else carved.mesher_input)
    timings = {**carved.report.get("timings_s", {}),
               "refinement": time.perf_counter() - start}
    return replace(carved, occupancy=occupancy, mesher_input=mesher_input,
                   report={**carved.report, "refinement": report,
                           "occupied_voxels": int(occupancy.sum()), "timings_s": timings})
