"""The cloud of points: one surface voxel per M x M x M block of the volume.

The paper (section 4.1) divides the binary volume into M x M x M sub-blocks and,
in each block holding part of the surface, keeps the surface voxel closest to
the block centre. Each kept point gets an outward normal, the negated gradient
of the occupancy smoothed by a small Gaussian, which the triangulation uses for
its tangent planes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..carving.hull import surface_voxels as hull_surface_voxels
from ..geometry.grid import VoxelGrid

__all__ = ["CloudOfPoints", "surface_voxels", "cloud_of_points"]


@dataclass(frozen=True, eq=False)
class CloudOfPoints:
    """Points on the object surface with outward unit normals.

    Attributes
    ----------
    points : (n, 3) float64
        Surface voxel centres, metres, object frame.
    normals : (n, 3) float64
        Unit outward normals.
    voxels : (n, 3) int64
        Voxel indices ``(i, j, k)`` of the points.
    """

    points: np.ndarray
    normals: np.ndarray
    voxels: np.ndarray


def _check_occupancy(occupancy) -> np.ndarray:
    occ = np.asarray(occupancy)
    if occ.ndim != 3:
        raise ValueError(f"occupancy must be a 3-D (nx, ny, nz) array, got shape {occ.shape}")
    if occ.dtype != np.bool_:
        raise ValueError(f"occupancy must be a bool array, got dtype {occ.dtype}")
    return occ


def surface_voxels(occupancy) -> np.ndarray:
    """Indices of occupied voxels with at least one empty 6-neighbour.

    Parameters
    ----------
    occupancy : (nx, ny, nz) bool
        True = object. Voxels outside the array count as empty, so occupied
        voxels on the border of the volume are surface voxels.

    Returns
    -------
    (n, 3) int64
        Voxel indices ``(i, j, k)``, in C order of the volume
        (:func:`.carving.hull.surface_voxels`).
    """
    return hull_surface_voxels(_check_occupancy(occupancy))


def _gaussian_derivative_kernels(sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """Offsets (m, 3) int64 and gradient weights (m, 3) of a sampled derivative of Gaussian."""
    radius = max(1, int(np.ceil(3.0 * sigma)))
    r = np.arange(-radius, radius + 1)
    offsets = np.stack(np.meshgrid(r, r, r, indexing="ij"), axis=-1).reshape(-1, 3)
    weight = np.exp(-0.5 * np.sum(offsets ** 2, axis=1) / sigma ** 2)
    # d/dx of the Gaussian at the centre voxel, correlated with the volume: sum f(x + o) * (o / sigma^2) g(o)
    return offsets.astype(np.int64), offsets * (weight / (weight.sum() * sigma ** 2))[:, None]


def _outward_normals(occ: np.ndarray, ijk: np.ndarray, sigma: float) -> np.ndarray:
    """Unit outward normals at voxels ``ijk``: minus the gradient of the smoothed occupancy."""
    offsets, weights = _gaussian_derivative_kernels(sigma)
    shape = np.asarray(occ.shape)
    grad = np.zeros((len(ijk), 3))
    for offset, weight in zip(offsets, weights):
        idx = ijk + offset
        inside = np.all((idx >= 0) & (idx < shape), axis=1)
        idx = np.where(inside[:, None], idx, 0)
        value = inside & occ[idx[:, 0], idx[:, 1], idx[:, 2]]
        grad += value[:, None] * weight
    normals = -grad
    # A symmetric one-voxel sheet has no smoothed gradient: use the empty 6-neighbours instead.
    flat = np.linalg.norm(normals, axis=1) < 1e-9
    if np.any(flat):
        fallback = np.zeros((int(flat.sum()), 3))
        for axis in range(3):
            for step in (-1, 1):
                idx = ijk[flat].copy()
                idx[:, axis] += step
                inside = (idx[:, axis] >= 0) & (idx[:, axis] < shape[axis])
                idx = np.where(inside[:, None], idx, 0)
                empty = ~(inside & occ[idx[:, 0], idx[:, 1], idx[:, 2]])
                fallback[:, axis] += step * empty
        fallback[np.linalg.norm(fallback, axis=1) < 1e-9] = (0.0, 0.0, 1.0)
        normals[flat] = fallback
    return normals / np.linalg.norm(normals, axis=1, keepdims=True)


def cloud_of_points(occupancy, grid: VoxelGrid, *, block: int = 2,
                    smoothing_voxels: float = 1.0) -> CloudOfPoints:
    """The paper's cloud of points: per M x M x M block, the surface voxel nearest the block centre.

    Parameters
    ----------
    occupancy : (nx, ny, nz) bool
        Carved volume, True = object, laid out as ``grid``.
    grid : VoxelGrid
        Geometry of the volume (``grid.shape == occupancy.shape``).
    block : int
        M, the block edge in voxels; block ``b`` covers voxels ``b * M .. b * M + M - 1``
        on each axis and its centre is ``b * M + (M - 1) / 2``. M = 1 keeps every surface voxel.
        Ties in distance go to the first voxel in C order.
    smoothing_voxels : float
        Standard deviation (voxels) of the Gaussian smoothing the occupancy before its
        gradient gives the normals.

    Returns
    -------
    CloudOfPoints
        One point per block that contains surface voxels, ordered by block (C order).
    """
    occ = _check_occupancy(occupancy)
    if not isinstance(grid, VoxelGrid):
        raise ValueError(f"grid must be a VoxelGrid, got {type(grid).__name__}")
    if tuple(occ.shape) != tuple(grid.shape):
        raise ValueError(f"occupancy shape {occ.shape} does not match grid shape {grid.shape}")
    if int(block) != block or block < 1:
        raise ValueError(f"block must be a whole number of voxels >= 1, got {block}")
    if not smoothing_voxels > 0:
        raise ValueError(f"smoothing_voxels must be > 0, got {smoothing_voxels}")
    m = int(block)
    ijk = surface_voxels(occ)
    blocks = ijk // m
    offset = ijk - blocks * m - 0.5 * (m - 1)
    dist2 = np.sum(offset * offset, axis=1)
    n_blocks = -(-np.asarray(occ.shape) // m)
    key = np.ravel_multi_index(blocks.T, n_blocks)
    # Sort by block, then distance, then C order (ijk is already in C order, lexsort is stable).
    order = np.lexsort((dist2, key))
    first = np.ones(len(order), dtype=bool)
    first[1:] = key[order][1:] != key[order][:-1]
    chosen = ijk[order[first]]
    return CloudOfPoints(points=grid.index_to_world(chosen),
                         normals=_outward_normals(occ, chosen, float(smoothing_voxels)),
                         voxels=chosen)
