"""The meshers: each turns a carved hull into a triangle mesh, in two halves.

``prepare`` runs beside the carving, where the views' signed distance to the
hull (:class:`.hull_distance.HullDistance`) is at hand, and makes a small,
self-contained input; ``mesh`` makes the mesh from the occupancy, the grid and
that input alone. Between the two, the input may cross a process or a network
(the cell's carving and meshing nodes): the same input gives the same mesh.

Adding a mesher is one module with its two halves and one entry in
:data:`MESHERS`; its own options are :class:`~sfs_ros.core.settings.Setting` s in the
entry (``sfs-reconstruct`` offers each as an option, ``ReconstructionParams.mesher_options``
takes them by name). The command line, the nodes' ``mesher`` parameter and
``doc/reference.md`` list what the table holds (``doc/architecture.md``, "Extending").
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..geometry.grid import VoxelGrid
from ..settings import Setting

if TYPE_CHECKING:
    from .hull_distance import HullDistance
    from .marching import BandDistance

__all__ = ["MESHER", "MESHERS", "HullCloud", "Mesher", "mesher"]


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
    description : str, one sentence for the help and the docs.
    prepare : (occupancy, grid, hull, **options) -> input, beside the carving.
    mesh : (occupancy, grid, input) -> (vertices (n, 3) float64 metres, faces (m, 3)
        int64, JSON-ready stats).
    options : the :class:`~sfs_ros.core.settings.Setting` s ``prepare`` takes by name.
    check : (grid, **options) -> None, ValueError for options the grid cannot take.
    closed : whether the mesh is closed and outward by construction (its checks may
        then run beside the colour and the evaluation).
    """

    name: str
    description: str
    prepare: Callable
    mesh: Callable
    options: tuple[Setting, ...] = ()
    check: Callable | None = None
    closed: bool = False

    def option_values(self, given: dict) -> dict:
        """``{option name: value}``: ``given`` over the options' defaults; ValueError for
        a name that is not one of this mesher's options or a value out of its range."""
        own = {option.name: option for option in self.options}
        for name, value in given.items():
            if name not in own:
                raise ValueError(f"{name} is not an option of the {self.name} mesher "
                                 f"(its options: {', '.join(own) or 'none'})")
            own[name].check(value)
        return {name: given.get(name, option.default) for name, option in own.items()}


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


#: M of the paper's cloud of points: one point per M x M x M block of voxels.
BLOCK = Setting("block", "The cloud of points: one point per M x M x M block of voxels "
                "on the surface.", int, "--block", bounds=(1, None), default=2, unit="voxels",
                metavar="M")

#: The meshers by name; the first is the default.
MESHERS: dict[str, Mesher] = {m.name: m for m in (
    Mesher("marching-cubes", "Marching cubes on the signed distance to the visual hull "
           "near its surface: closed and outward by construction.",
           _prepare_band, _mesh_band, closed=True),
    Mesher("advancing-front", "The paper's cloud of points moved onto the visual hull, "
           "triangulated by an advancing front with edge swaps.",
           _prepare_cloud, _mesh_cloud, options=(BLOCK,), check=_check_block),
)}

#: The mesher's name, as a setting: its choices are :data:`MESHERS`' names, read when asked.
MESHER = Setting("mesher", "Surface extraction of the carved hull.", str, "--mesher",
                 choices=lambda: tuple(MESHERS), default=next(iter(MESHERS)),
                 cell_default=next(iter(MESHERS)), recorded=True)


def mesher(name: str) -> Mesher:
    """The mesher called ``name``; ValueError naming the known ones."""
    try:
        return MESHERS[name]
    except (KeyError, TypeError):
        raise ValueError(f"mesher must be one of {tuple(MESHERS)}, got {name!r}") from None
