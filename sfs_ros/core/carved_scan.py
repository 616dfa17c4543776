"""What the carving half of a reconstruction hands to its meshing half.

:func:`sfs_ros.core.pipeline.carve_scan` makes a :class:`CarvedScan` from the
views (segmentation, the grid, the consensus, the fusion, the carving, the
refinement and the mesher's input); :func:`sfs_ros.core.mesh_scan.mesh_scan`
makes the mesh, its colour, its checks, the evaluation and the report from it
alone. :func:`sfs_ros.core.pipeline.reconstruct` is the two in one process; the
cell's carving and meshing nodes pass a :class:`CarvedScan` between them as a
message (:mod:`sfs_ros.ros.carved_scan_msg`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .geometry.camera import Camera
from .geometry.grid import VoxelGrid

__all__ = ["ROLES", "CarvedScan", "ScanView"]

#: What a view did in a reconstruction: carved the hull, was kept out to evaluate it, or
#: was rejected by the consistency check (views that could not be read or segmented are
#: in the report's rejected list only).
ROLES = ("used", "held-out", "rejected")


@dataclass(frozen=True)
class ScanView:
    """One segmented view: ``name``, its ideal pinhole ``camera`` (the masks are
    undistorted onto it), its ``role`` (:data:`ROLES`) and its encoder angles
    ``(theta, phi)``, radians (None where the input had none)."""

    name: str
    camera: Camera
    role: str
    angles_rad: tuple[float, float] | None = None


@dataclass
class CarvedScan:
    """The carved hull with everything the meshing half needs.

    Attributes
    ----------
    grid : VoxelGrid
    occupancy : (nx, ny, nz) bool on ``grid``
        The carved (or refined) hull.
    mesher : str
        Name in :data:`sfs_ros.core.meshing.meshers.MESHERS`.
    mesher_input : object
        What that mesher's ``prepare`` made (its ``mesh`` takes it).
    views : list of ScanView
        Every segmented view, in input order.
    masks : list of (H, W) bool
        Each view's silhouette on its ideal camera's pixel grid, for the evaluation.
    colour_views : list of int
        Indices into ``views`` of the views that colour the mesh (empty: no colour).
    colour_masks : list of (H, W) bool
        Their silhouettes as carved (after the fusion's repairs).
    colour_images : list of (H, W, 3) uint8
        Their RGB images, undistorted onto the ideal cameras.
    report : dict
        The carving half's part of the report (JSON-ready), its stage times under
        ``timings_s``.
    taken : dict
        {view name: (H, W) bool mask as taken, through the lens}; empty where the
        carving was made in another process (the message carries the ideal masks).
    """

    grid: VoxelGrid
    occupancy: np.ndarray
    mesher: str
    mesher_input: object
    views: list[ScanView]
    masks: list[np.ndarray]
    colour_views: list[int] = field(default_factory=list)
    colour_masks: list[np.ndarray] = field(default_factory=list)
    colour_images: list[np.ndarray] = field(default_factory=list)
    report: dict = field(default_factory=dict)
    taken: dict = field(default_factory=dict)
