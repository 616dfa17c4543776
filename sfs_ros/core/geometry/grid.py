"""The voxel grid: an axis-aligned box in the object frame split into cubes."""

from __future__ import annotations

import numpy as np

__all__ = ["MAX_VOXELS", "VoxelGrid", "resolution_voxel_size"]

#: Largest grid we allocate (voxels): 1024^3 bytes = 1 GiB of occupancy.
MAX_VOXELS = 1024 ** 3


def resolution_voxel_size(bounds_min, bounds_max, resolution: int) -> float:
    """The voxel edge, metres, that splits the longest side of the box
    ``[bounds_min, bounds_max]`` (each (3,), metres) into ``resolution`` voxels."""
    extent = np.asarray(bounds_max, dtype=np.float64) - np.asarray(bounds_min, dtype=np.float64)
    return float(np.max(extent)) / int(resolution)


class VoxelGrid:
    """Cubic voxels of side ``voxel_size`` covering ``[bounds_min, bounds_max]``.

    Voxel ``(i, j, k)`` has its centre at ``origin + (i, j, k) * voxel_size``,
    where ``origin`` is the centre of voxel ``(0, 0, 0)``. The box is rounded
    up to whole voxels, keeping ``bounds_min``.

    Parameters
    ----------
    bounds_min, bounds_max : (3,) float
        Opposite corners of the box, metres, object frame.
    voxel_size_m : float
        Edge length of one voxel, metres.
    """

    def __init__(self, bounds_min, bounds_max, voxel_size_m: float):
        lo = np.asarray(bounds_min, dtype=np.float64).reshape(-1)
        hi = np.asarray(bounds_max, dtype=np.float64).reshape(-1)
        size = float(voxel_size_m)
        if lo.shape != (3,) or hi.shape != (3,):
            raise ValueError(f"bounding box corners must have 3 values, got {lo.shape}, {hi.shape}")
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.isfinite(size)):
            raise ValueError("bounding box and voxel size must be finite")
        if np.any(hi <= lo):
            raise ValueError(f"bounding box is empty: min {lo.tolist()} is not below max {hi.tolist()}")
        if size <= 0:
            raise ValueError(f"voxel size must be > 0 metres, got {size}")
        shape = np.maximum(1, np.ceil((hi - lo) / size - 1e-9)).astype(np.int64)
        if int(np.prod(shape)) > MAX_VOXELS:
            raise ValueError(
                f"grid {tuple(shape.tolist())} has more than {MAX_VOXELS} voxels; "
                "choose a larger voxel size or a smaller bounding box")
        self.voxel_size = size
        self.bounds_min = lo
        self.shape = tuple(int(n) for n in shape)
        self.bounds_max = lo + shape * size
        self.origin = lo + 0.5 * size

    @classmethod
    def cube(cls, bounds_min, bounds_max, resolution: int) -> "VoxelGrid":
        """Grid whose longest box side is split into ``resolution`` voxels
        (:func:`resolution_voxel_size`); any resolution from 2 up, as the internal grids
        take coarser ones than a user may ask for
        (:data:`sfs_ros.core.settings.RESOLUTION`)."""
        if int(resolution) < 2:
            raise ValueError(f"grid resolution must be >= 2 voxels, got {resolution}")
        return cls(bounds_min, bounds_max, resolution_voxel_size(bounds_min, bounds_max,
                                                                 resolution))

    def centers_axis(self, axis: int) -> np.ndarray:
        """(n_axis,) float64 voxel-centre coordinates along ``axis``, metres."""
        return self.origin[axis] + np.arange(self.shape[axis]) * self.voxel_size

    def index_to_world(self, ijk) -> np.ndarray:
        """Voxel indices (n, 3) -> voxel centres (n, 3), metres."""
        return self.origin + np.asarray(ijk, dtype=np.float64).reshape(-1, 3) * self.voxel_size

    def world_to_index(self, points) -> np.ndarray:
        """Points (n, 3), metres -> fractional voxel indices (n, 3) (centres are integers)."""
        return (np.asarray(points, dtype=np.float64).reshape(-1, 3) - self.origin) / self.voxel_size

    def __repr__(self) -> str:
        return (f"VoxelGrid(shape={self.shape}, voxel_size={self.voxel_size:.6g} m, "
                f"min={self.bounds_min.tolist()}, max={self.bounds_max.tolist()})")
