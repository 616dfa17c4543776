"""The meshers: each turns a carved hull into a triangle mesh, in two halves.

``prepare`` runs beside the carving, where the views' signed distance to the
hull (:class:`.hull_distance.HullDistance`) is at hand, and makes a small,
self-contained input; ``mesh`` makes the mesh from the occupancy, the grid and
that input alone. Between the two, the input may cross a process or a network
(the cell's carving and meshing nodes): the same input gives the same mesh.

Adding a mesher is one module with its two halves and one entry in
:data:`MESHERS`; its ``options`` name the fields of
:class:`sfs_ros.core.pipeline.ReconstructionParams` it takes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..geometry.grid import VoxelGrid

if TYPE_CHECKING:
    from .hull_distance import HullDistance
    from .marching import BandDistance

__all__ = ["MESHERS", "HullCloud", "Mesher", "mesher"]


@dataclass(frozen=True)
class HullCloud:
    """The advancing front's input: the paper's cloud of points moved onto the hull.

    points, normals : (n, 3) float64, metres and outward (not unit) normals.
    stats : JSON-ready counts for the report (``cloud_points``, ``cloud_points_on_hull``).
    """

    points: np.ndarray
    normals: np.ndarray
    stats: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Mesher:
    """One surface extraction.

    name : str, as asked for (``--mesher``, the node's ``mesher``).
    prepare : (occupancy, grid, hull, **options) -> input, beside the carving.
    mesh : (occupancy, grid, input) -> (vertices (n, 3) float64 metres, faces (m, 3)
        int64, JSON-ready stats).
    options : names of the reconstruction parameters ``prepare`` takes.
    check : (grid, **options) -> None, ValueError for options the grid cannot take.
    closed : whether the mesh is closed and outward by construction (its checks may
        then run beside the colour and the evaluation).
    """

    name: str
    prepare: Callable
    mesh: Callable
    options: tuple[str, ...] = ()
    check: Callable | None = None
    closed: bool = False


# Each half imports its algorithm when it runs: the table of names is read by a command
# line's help, which loads no numba.

def _prepare_band(occupancy, grid: VoxelGrid, hull: HullDistance) -> BandDistance:
    from .marching import hull_band_distance

    return hull_band_distance(occupancy, grid, hull)


def _mesh_band(occupancy, grid: VoxelGrid, band: BandDistance) -> tuple:
    from .marching import band_marching_cubes

    vertices, faces = band_marching_cubes(occupancy, grid, band)
    return vertices, faces, {}


def _prepare_cloud(occupancy, grid: VoxelGrid, hull: HullDistance, *, block: int) -> HullCloud:
    from .cloud import cloud_of_points

    cloud = cloud_of_points(occupancy, grid, block=block)
    # Surface voxel centres lie up to a voxel inside the hull surface: move them onto it.
    points, on_hull = hull.project(cloud.points, cloud.normals, reach_m=2.0 * grid.voxel_size)
    return HullCloud(points=points, normals=cloud.normals,
                     stats={"cloud_points": int(len(points)),
                            "cloud_points_on_hull": int(on_hull.sum())})


def _mesh_cloud(_occupancy, _grid: VoxelGrid, cloud: HullCloud) -> tuple:
    from .advancing_front import advancing_front

    result = advancing_front(cloud.points, cloud.normals)
    return cloud.points, result.faces, {**result.stats, **cloud.stats}


def _check_block(grid: VoxelGrid, *, block: int) -> None:
    most = max(1, max(grid.shape) // 4)
    if block > most:
        raise ValueError(
            f"block (M) {block} leaves fewer than 4 blocks along the grid's longest side "
            f"({tuple(grid.shape)} voxels); expected 1..{most}")


#: The meshers by name; the first is the default.
MESHERS: dict[str, Mesher] = {m.name: m for m in (
    Mesher("marching-cubes", _prepare_band, _mesh_band, closed=True),
    Mesher("advancing-front", _prepare_cloud, _mesh_cloud, options=("block",),
           check=_check_block),
)}


def mesher(name: str) -> Mesher:
    """The mesher called ``name``; ValueError naming the known ones."""
    try:
        return MESHERS[name]
    except (KeyError, TypeError):
        raise ValueError(f"mesher must be one of {tuple(MESHERS)}, got {name!r}") from None
